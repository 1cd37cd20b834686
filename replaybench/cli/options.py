"""The run options on the command line, declared once (``replaybench.app.options.RunOptions``)
and added to ``run``, ``sweep`` and ``peak`` alike by ``with_run_options``."""

from __future__ import annotations

import functools
import inspect
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer

from replaybench.app.options import RunOptions, option_specs

if TYPE_CHECKING:
    from collections.abc import Callable

    from replaybench.app.options import RunOption

__all__ = ['cli_name', 'run_option_names', 'with_run_options']

_Function = TypeVar('_Function', bound='Callable[..., Any]')

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
