"""Option and argument values read without typer's general coercion, where they are plain.

typer coerces every parameter of a command through a pydantic ``TypeAdapter`` built for it on
first use; importing pydantic and building the adapters of ``run``'s options costs more than
a tenth of a second before a run can start. Every value whose conversion is plain is read here
instead: a ``str``, a ``bool`` flag, an ``int`` or ``float`` written as plain digits and inside
its parameter's range, a ``Path`` (that is not an unreadable existing file), a list of those,
or ``None``, for parameters that ask for no parser, clamping or path check (a callback is the
caller's to call afterwards, as typer does). Anything else, and any value this module is not
sure of, goes to typer (``SLOW``), so errors keep typer's wording.
tests/cli/test_plain_values.py checks that both ways give the same value for every parameter of
every command.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Final, get_args, get_origin

__all__ = ['SLOW', 'plain_value']


class _Slow:
    def __repr__(self) -> str:
        return 'SLOW'


#: what ``plain_value`` returns for a value typer must coerce
SLOW: Final = _Slow()

_INT = re.compile(r'[+-]?[0-9]+')
_FLOAT = re.compile(r'[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?')
#: ParameterInfo attributes that must hold these values for a parameter to be read here
_PLAIN_INFO: Final = {
    'parser': None,
    'click_type': None,
    'clamp': False,
    'exists': False,
    'file_okay': True,
    'dir_okay': True,
    'writable': False,
    'readable': True,
    'resolve_path': False,
    'allow_dash': False,
    'path_type': None,
}


def _plain_parameter(param: Any) -> bool:
    descriptor = getattr(param, 'type_descriptor', None)
    if descriptor is None or descriptor.file_annotation is not None:
        return False
    info = descriptor.parameter_info
    return all(getattr(info, name, default) == default for name, default in _PLAIN_INFO.items())


def _path(value: Any) -> Any:
    if isinstance(value, Path):
        path = value
    elif isinstance(value, str) and value and value != '-':
        path = Path(value)
    else:
        return SLOW
    if path.exists() and not os.access(path, os.R_OK):
        return SLOW  # typer says it is not readable
    return path


def _in_range(number: float, info: Any) -> bool:
    low, high = getattr(info, 'min', None), getattr(info, 'max', None)
    return (low is None or number >= low) and (high is None or number <= high)


def _number(kind: Any, value: Any, info: Any) -> Any:
    if kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            number: Any = value
        elif isinstance(value, str) and _INT.fullmatch(value):
            number = int(value)
        else:
            return SLOW
    elif (isinstance(value, int | float) and not isinstance(value, bool)) or (
        isinstance(value, str) and _FLOAT.fullmatch(value)
    ):
        number = float(value)
    else:
        return SLOW
    return number if _in_range(number, info) else SLOW


def _one(kind: Any, value: Any, info: Any) -> Any:
    if kind is bool:
        return value if isinstance(value, bool) else SLOW
    if kind is str:
        return value if isinstance(value, str) else SLOW
    if kind is int or kind is float:
        return _number(kind, value, info)
    if kind is Path:
        return _path(value)
    return SLOW


def plain_value(param: Any, value: Any) -> Any:
    """``value`` of ``param`` (a typer option or argument) as typer would coerce it, or
    ``SLOW`` when typer must (anything but the plain cases above)."""
    if not _plain_parameter(param):
        return SLOW
    annotation = param.type_descriptor.annotation
    info = param.type_descriptor.parameter_info
    many = bool(param.multiple) or param.nargs == -1
    if value is None:
        return SLOW if param.required else (() if many else None)
    if not many:
        return _one(annotation, value, info)
    if get_origin(annotation) is not list or not isinstance(value, list | tuple):
        return SLOW
    (kind,) = get_args(annotation)
    items = [_one(kind, item, info) for item in value]
    if any(item is SLOW for item in items) or (param.required and not items):
        return SLOW
    return items
