"""The command group and what every command shares: placeholders in help, two-line usage
errors, ``--debug``, and the one-line error output (``fail``)."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption

from replaybench._version import __version__
from replaybench.textsafe import visible, visible_lines

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from replaybench.errors import ReplaybenchError

__all__ = [
    'EXIT_FAILURE',
    'EXIT_INTERRUPTED',
    'EXIT_USAGE',
    'app',
    'echo',
    'fail',
    'fmt',
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
    'param': 'BACKEND.KEY=V,...',
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
    followed by ``<list[Path]>``."""

    def _usage_display_name(self) -> str:
        name = self.display_name_raw + ('...' if self.nargs != 1 else '')
        return name if self.required else f'[{name}]'

    def _rich_display_name(self) -> str:
        return self.display_name_raw + ('...' if self.nargs != 1 else '')

    def display_type_rich(self, ctx: Any) -> str | None:  # noqa: ARG002  click's signature
        return None


class _Option(TyperOption):
    """An option whose bad value is named in the error, next to what was wrong with it."""

    def process_value(self, ctx: Any, value: Any) -> Any:
        try:
            return super().process_value(ctx, value)
        except typer.BadParameter as err:
            if value is not None and repr(value) not in err.message:
                err.message = f'{value!r}: {err.message}'
            raise


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


class _Group(TyperGroup):
    """The command group: a usage error is two lines on stderr, what is wrong (naming the value)
    and the usage line, exit status 2; not click's four."""

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
