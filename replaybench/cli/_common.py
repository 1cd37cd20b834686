"""The command group and what every command shares: placeholders in help, two-line usage
errors, ``--debug``, the one-line error output (``fail``) and the run options
(``with_run_options``: ``replaybench.app.options.RunOptions`` as typer options of ``run``,
``sweep`` and ``peak``, declared once) and the instance options of the same three
(``with_instance_options``: ``--backend [LABEL=]NAME`` and ``--param LABEL.KEY=VALUE``)."""

from __future__ import annotations

import functools
import inspect
import sys
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption

from replaybench._version import __version__
from replaybench.app.options import RunOptions, option_specs
from replaybench.cli._values import SLOW, plain_value
from replaybench.textsafe import visible, visible_lines

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from replaybench.app.options import RunOption
    from replaybench.errors import ReplaybenchError

__all__ = [
    'EXIT_FAILURE',
    'EXIT_INTERRUPTED',
    'EXIT_USAGE',
    'app',
    'cli_name',
    'echo',
    'fail',
    'fmt',
    'run_option_names',
    'with_instance_options',
    'with_run_options',
]

_Function = TypeVar('_Function', bound='Callable[..., Any]')

EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

#: Placeholders shown in help and usage lines, by parameter name; other parameters get one by
#: type (_metavar). Positional arguments are their name in capitals, singular when repeated.
_METAVARS = {
    'backend': 'NAME',
    'out': 'DIR',
    'rate': 'RATE',
    'topic': 'TOPIC',
    'ground_truth': 'TOPIC',
    'recorded_topic': 'TOPIC',
    'ground_truth_image_topic': 'TOPIC',
    'ground_truth_masks': 'TOPIC|DIR',
    'ground_truth_disparity': 'TOPIC|DIR',
    'ground_truth_depth': 'TOPIC',
    'ground_truth_match': 'stamp|seq',
    'model_family': 'FAMILY',
    'labels': 'coco|PATH',
    'engine': 'auto|ort|torch',
    'precision': 'fp32|tf32|fp16',
    'detections_format': 'mcap|rosbag2',
    'start': 'S',
    'duration': 'S',
    'size': 'WxH',
    'fail_if': 'CONDITION',
    'baseline': 'INDEX',
    'baseline_backend': 'NAME',
    'param': 'LABEL.KEY=VALUE',
    'address': 'HOST:PORT',
    'max_drop': 'FRACTION',
    'p99_ms': 'MS',
    'min_hz': 'HZ',
    'max_hz': 'HZ',
}
_TYPE_METAVARS = {'Path': 'PATH', 'int': 'N', 'float': 'X', 'str': 'TEXT'}
#: click's UsageError (bad option, bad value, missing argument), found without importing the
#: click that typer vendors by its private name
_USAGE_ERROR: type[Exception] = next(
    c for c in typer.BadParameter.__mro__ if c.__name__ == 'UsageError'
)


def _metavar(name: str, bare_type: str) -> str:
    known = _METAVARS.get(name)
    if known is not None:
        return known
    return _TYPE_METAVARS.get(bare_type.removeprefix('list[').removesuffix(']'), 'VALUE')


class _Argument(TyperArgument):
    """A positional argument shown by its placeholder alone: ``BAG...``, not ``{bags}...``
    followed by ``<list[Path]>``; a plain value read without typer's coercion (``_values``)."""

    def process_value(self, ctx: Any, value: Any) -> Any:
        found = plain_value(self, value)
        if found is SLOW:
            return super().process_value(ctx, value)
        return found if self.callback is None else self.callback(ctx, self, found)

    def _usage_display_name(self) -> str:
        name = self.display_name_raw + ('...' if self.nargs != 1 else '')
        return name if self.required else f'[{name}]'

    def _rich_display_name(self) -> str:
        return self.display_name_raw + ('...' if self.nargs != 1 else '')

    def display_type_rich(self, ctx: Any) -> str | None:  # noqa: ARG002  click's signature
        return None


class _Option(TyperOption):
    """An option whose bad value is named in the error, next to what was wrong with it; a
    plain value read without typer's coercion (``replaybench.cli._values``)."""

    def process_value(self, ctx: Any, value: Any) -> Any:
        found = plain_value(self, value)
        if found is not SLOW:
            return found if self.callback is None else self.callback(ctx, self, found)
        try:
            return super().process_value(ctx, value)
        except typer.BadParameter as err:
            if value is not None and repr(value) not in err.message:
                err.message = f'{value!r}: {err.message}'
            raise


def _read_plainly(option: Any) -> Any:
    """The help option click makes per command, read as the others are (``_Option``)."""
    if isinstance(option, TyperOption):
        option.__class__ = _Option
    return option


class _Command(TyperCommand):
    """A command whose help shows placeholders people read (``PATH``, ``NAME``, ``N``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.help:
            # examples are copied to a shell: click must not wrap them ('\b' keeps a paragraph)
            self.help = self.help.replace('\n\nExample:', '\n\n\b\nExample:')
        for param in self.params:
            name = param.name or ''
            if isinstance(param, TyperArgument):
                param.__class__ = _Argument
                if param.metavar is None:
                    singular = name.removesuffix('s') if param.nargs != 1 else name
                    param.metavar = singular.upper()
            elif isinstance(param, TyperOption):
                param.__class__ = _Option
                if param.metavar is None and not param.is_flag:
                    param.metavar = _metavar(name, param.bare_type())

    def get_help_option(self, ctx: Any) -> Any:
        return _read_plainly(super().get_help_option(ctx))


class _Group(TyperGroup):
    """The command group: a usage error is two lines on stderr, what is wrong (naming the value)
    and the usage line, exit status 2; not click's four. Its options (``--debug``) are read as
    the commands' are."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for param in self.params:
            _read_plainly(param)

    def get_help_option(self, ctx: Any) -> Any:
        return _read_plainly(super().get_help_option(ctx))

    def main(  # type: ignore[override]
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        **extra: Any,
    ) -> Any:
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        try:
            code = super().main(args, prog_name, complete_var, False, **extra)
        except _USAGE_ERROR as err:
            if type(err).__name__ == 'NoArgsIsHelpError':  # bare `replaybench`: the help
                getattr(err, 'show', lambda: None)()
                sys.exit(EXIT_USAGE)
            ctx = getattr(err, 'ctx', None)
            describe = getattr(err, 'format_message', None)
            message = describe() if callable(describe) else str(err)
            echo(f'replaybench: error: {message}', err=True)
            if ctx is not None:
                usage = ctx.get_usage().strip()
                echo(f'{usage}  (-h for help)', err=True)
            sys.exit(EXIT_USAGE)
        except typer.Abort:
            sys.stderr.write('replaybench: aborted\n')
            sys.exit(EXIT_FAILURE)
        sys.exit(code if isinstance(code, int) else 0)


class _App(typer.Typer):
    """``typer.Typer`` whose commands are ``_Command``s."""

    def command(self, *args: Any, **kwargs: Any) -> Callable[[_Function], _Function]:
        kwargs.setdefault('cls', _Command)
        return super().command(*args, **kwargs)


app = _App(
    cls=_Group,
    name='replaybench',
    help='Replay camera logs through detectors and measure latency, FPS and accuracy.\n\n'
    'Example: replaybench run bag.mcap --backend hsv --backend null',
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    context_settings={'help_option_names': ['-h', '--help']},
)


def echo(text: str, *, err: bool = False) -> None:
    """One line of output with control characters shown as escapes: names from a bag may
    hold terminal control sequences (``replaybench.textsafe``)."""
    typer.echo(visible(text), err=err)


class _Debug:
    """``--debug``: set by the root callback on every invocation, read by ``_fail``."""

    on = False


def fail(err: ReplaybenchError) -> typer.Exit:
    """The error's one line on stderr (after, with ``--debug``, the traceback of the error and
    of the exceptions it was raised from); the exit to raise."""
    if _Debug.on:
        import traceback

        sys.stderr.write(visible_lines(''.join(traceback.format_exception(err))))
    echo(f'replaybench: error: {err}', err=True)
    return typer.Exit(err.exit_code)


def _version(value: bool) -> None:
    if value:
        typer.echo(f'replaybench {__version__}')
        raise typer.Exit


@app.callback()
def _root(
    version: Annotated[  # noqa: ARG001  --version is handled by its eager callback
        bool, typer.Option('--version', callback=_version, is_eager=True, help='Print the version.')
    ] = False,
    debug: Annotated[
        bool,
        typer.Option(
            '--debug',
            help='On an error, print the traceback of its cause before the one-line message.',
        ),
    ] = False,
) -> None:
    """Replay camera logs through detectors and measure latency, FPS and accuracy.

    Example: replaybench run bag.mcap --backend hsv --backend null
    """
    _Debug.on = debug


def fmt(value: float | None, digits: int = 2) -> str:
    return '-' if value is None else f'{value:.{digits}f}'


#: fields whose command-line parameter has another name (``--topic`` repeats)
_NAMES = {'topics': 'topic'}


def cli_name(name: str, spec: RunOption) -> str:
    """The command function's parameter for field ``name``: ``no_report`` for ``report``."""
    if spec.cli_flag is not None:
        return spec.cli_flag.removeprefix('--').replace('-', '_')
    return _NAMES.get(name, name)


def run_option_names(command: str) -> list[str]:
    """The ``RunOptions`` fields ``command`` ('run', 'sweep' or 'peak') takes."""
    return [name for name, spec, _ in option_specs() if command != 'peak' or spec.peak]


def _cli_type(tp: Any) -> Any:
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    if typing.get_origin(tp) is tuple:
        return list[str]
    if len(args) > 1:  # rate: a text on the command line, a number of Hz in the library
        return str
    return tp


def _parameter(name: str, spec: RunOption, default: Any, tp: Any) -> inspect.Parameter:
    flags = [spec.cli_flag or spec.flag, *([spec.short] if spec.short else [])]
    extra: dict[str, Any] = {}
    if spec.low is not None:
        extra['min'] = spec.low
    if spec.high is not None:
        extra['max'] = spec.high
    if spec.metavar is not None:
        extra['metavar'] = spec.metavar
    if spec.cli_flag is not None:
        tp, default = bool, False
    else:
        tp = _cli_type(tp)
        if isinstance(default, tuple):
            default = list(default)
    option = typer.Option(*flags, help=spec.help, **extra)
    return inspect.Parameter(
        cli_name(name, spec),
        inspect.Parameter.KEYWORD_ONLY,
        default=default,
        annotation=Annotated[tp, option],
    )


def with_run_options(command: str) -> Callable[[_Function], _Function]:
    """Add the run options of ``command`` ('run' and 'sweep': every one; 'peak': those a peak
    search takes) to a typer command: the function gets them as one keyword, ``options``, a
    dict by ``RunOptions`` field name (``report`` for ``--no-report``, ``topics`` for
    ``--topic``)."""
    hints = typing.get_type_hints(RunOptions, {'Path': Path})
    names = run_option_names(command)
    specs = {name: (spec, default) for name, spec, default in option_specs() if name in names}

    def decorate(func: _Function) -> _Function:
        own = [
            p
            for p in inspect.signature(func, eval_str=True).parameters.values()
            if p.name != 'options'
        ]
        added = [_parameter(n, s, d, hints[n]) for n, (s, d) in specs.items()]
        by_cli = {cli_name(n, s): (n, s) for n, (s, _) in specs.items()}

        @functools.wraps(func)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            options: dict[str, Any] = {}
            for key in list(kwargs):
                if key in by_cli:
                    name, spec = by_cli[key]
                    value = kwargs.pop(key)
                    options[name] = (not value) if spec.cli_flag is not None else value
            return func(*args, options=options, **kwargs)

        parameters = [*own, *added]
        wrapper.__signature__ = inspect.Signature(parameters)  # type: ignore[attr-defined]
        wrapper.__annotations__ = {p.name: p.annotation for p in parameters}
        return typing.cast('_Function', wrapper)

    return decorate


#: ``--param``'s help by command: a run's instance takes one value, a sweep's an axis of several
_PARAM_HELP = {
    'run': 'One option of one --backend instance: LABEL.KEY=VALUE (repeat), e.g. '
    'int8.threads=1 (docs/cli.md).',
    'peak': 'One option of the --backend instance: LABEL.KEY=VALUE (repeat), e.g. '
    'onnx-cpu.threads=1 (docs/cli.md).',
    'sweep': 'Grid of one option of one --backend instance: LABEL.KEY=V1,V2,... (repeat; one '
    "cell per combination; one value: that instance's fixed setting), e.g. "
    'hsv.min_area=50,100,200.',
}
_BACKEND_HELP = {
    'run': 'Backend to run, as NAME or LABEL=NAME (an instance called LABEL; repeat for several, '
    'also of one backend; see `replaybench backends`).',
    'peak': 'Backend to search, as NAME or LABEL=NAME.',
    'sweep': 'Backend to sweep, as NAME or LABEL=NAME (repeat for several).',
}


def with_instance_options(command: str) -> Callable[[_Function], _Function]:
    """Give a command's keyword parameters ``backend`` and ``param`` their options, declared
    here once for ``run``, ``sweep`` and ``peak``: ``--backend/-b [LABEL=]NAME`` (repeated; in
    ``peak`` once, and required) and ``--param LABEL.KEY=VALUE`` (repeated; in ``sweep``
    several values separated by commas)."""

    def decorate(func: _Function) -> _Function:
        signature = inspect.signature(func, eval_str=True)
        backend_option = typer.Option('--backend', '-b', help=_BACKEND_HELP[command])
        param_option = typer.Option(
            '--param',
            help=_PARAM_HELP[command],
            metavar='LABEL.KEY=V1,V2,...' if command == 'sweep' else 'LABEL.KEY=VALUE',
        )
        changed = []
        for p in signature.parameters.values():
            if p.name == 'backend':
                if command == 'peak':
                    p = p.replace(annotation=Annotated[str, backend_option], default=p.empty)
                else:
                    p = p.replace(annotation=Annotated[list[str], backend_option], default=[])
            elif p.name == 'param':
                p = p.replace(annotation=Annotated[list[str], param_option], default=[])
            changed.append(p)
        func.__signature__ = signature.replace(parameters=changed)  # type: ignore[attr-defined]
        func.__annotations__ = {p.name: p.annotation for p in changed}
        return func

    return decorate
