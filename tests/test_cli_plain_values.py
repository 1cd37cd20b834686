"""Plain option values are read without typer's coercion (replaybench/cli/_values.py), and read
to the very value typer's own coercion gives, for every parameter of every command."""

from __future__ import annotations

import copy
import itertools
from pathlib import Path
from typing import Any

import typer
from typer.core import TyperArgument, TyperOption

from replaybench.cli import app
from replaybench.cli._values import SLOW, plain_value

_TEXT = [
    '', '0', '1', '20', '-3', '+4', '007', '1.5', '.5', '5.', '1e3', '-1e-2', '2E+2', 'x', ' 5',
    '5 ', '1_000', 'inf', 'nan', '\u0663', '0x10', '1.5.2', '-', 'a/b', '/no/such/path',
]  # fmt: skip
_OTHER: list[Any] = [None, True, False, 0, 1, -1, 10, 0.5, 2.0, Path('rel/p'), Path('/tmp')]
_LISTS: list[Any] = [(), [], ['a', 'b'], ('1', '2'), ['1.5'], ['x', '3'], [Path('p')], ['-']]


def _parameters() -> list[tuple[str, Any, Any]]:
    group = typer.main.get_command(app)
    context = typer.main.get_command(app).make_context('replaybench', [], resilient_parsing=True)
    found: list[tuple[str, Any, Any]] = [('replaybench', p, context) for p in group.params]
    found.append(('replaybench', group.get_help_option(context), context))
    for name, command in sorted(group.commands.items()):  # type: ignore[attr-defined]
        ctx = command.make_context(name, [], resilient_parsing=True, parent=context)
        found += [(name, p, ctx) for p in command.params]
        found.append((name, command.get_help_option(ctx), ctx))
    return found


def _typer_value(param: Any, ctx: Any, value: Any) -> Any:
    bare = copy.copy(param)
    bare.callback = None
    base = TyperArgument if isinstance(param, TyperArgument) else TyperOption
    return base.process_value(bare, ctx, value)


def test_every_value_read_plainly_is_the_value_typer_gives(tmp_path):
    readable = tmp_path / 'file.txt'
    readable.write_text('x')
    values = [*_TEXT, *_OTHER, *_LISTS, str(readable), str(tmp_path), [str(readable)]]
    plain = 0
    for (command, param, ctx), value in itertools.product(_parameters(), values):
        fast = plain_value(param, value)
        if fast is SLOW:
            continue
        plain += 1
        slow = _typer_value(param, ctx, value)
        where = f'{command} {param.name} {value!r}'
        assert fast == slow, where
        assert type(fast) is type(slow), where
        if isinstance(fast, list):
            assert [type(v) for v in fast] == [type(v) for v in slow], where
    assert plain > 500  # most of the cases are read plainly


def test_every_parameter_of_run_is_read_plainly_from_a_typical_command_line(tmp_path):
    group = typer.main.get_command(app)
    run = group.commands['run']  # type: ignore[attr-defined]
    given = {
        'bags': [str(tmp_path)], 'backends': ['hsv', 'null'], 'max_frames': '20', 'out': 'runs/x',
        'conf': '0.25', 'rate': 'max', 'warmup': '0', 'repeat': '3',
    }  # fmt: skip
    for param in run.params:
        value = given.get(param.name, param.default)
        if param.multiple or param.nargs == -1:
            value = value if isinstance(value, list) else ()
        assert plain_value(param, value) is not SLOW, (param.name, value)


def test_values_typer_must_read_are_left_to_it_and_keep_its_error():
    from typer.testing import CliRunner

    result = CliRunner().invoke(app, ['run', 'x.mcap', '--max-frames', '0'])
    assert result.exit_code == 2
    assert '--max-frames' in result.output
    assert "'0'" in result.output
    result = CliRunner().invoke(app, ['run', 'x.mcap', '--conf', 'lots'])
    assert result.exit_code == 2
    assert 'lots' in result.output
