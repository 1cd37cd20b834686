"""Numbers and values of results as the report's pages write them ('–' for a missing one), and
the small pieces of HTML that hold them: a definition list, a backend's colour swatch."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

from replaybench.report.markup import escaped, number_text
from replaybench.results.numbers import finite_number

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

__all__ = [
    'definition_list',
    'fmt',
    'fmt_bytes',
    'fmt_fps',
    'fmt_frac',
    'fmt_hz',
    'fmt_ms',
    'fmt_value',
    'swatch',
]


def fmt_ms(value: Any) -> str:
    number = finite_number(value)
    if number is None:
        return '–'
    if abs(number) < 1:
        return f'{number:.3f}'
    if abs(number) < 100:
        return f'{number:.2f}'
    return f'{number:.1f}'


def fmt(value: Any, digits: int = 2) -> str:
    return number_text(finite_number(value), f'.{digits}f')


def fmt_fps(value: Any) -> str:
    number = finite_number(value)
    if number is None:
        return '–'
    return f'{number:.2f}' if number < 10 else f'{number:.1f}'


def fmt_bytes(value: Any) -> str:
    number = finite_number(value)
    if number is None:
        return '–'
    if number < 1024:
        return f'{number:.0f} B'
    units = ('KiB', 'MiB', 'GiB', 'TiB')
    power = min(len(units), max(1, int(math.log(number, 1024))))
    return f'{number / 1024**power:.1f} {units[power - 1]}'


def fmt_value(value: Any) -> str:
    if value is None:
        return '–'
    if isinstance(value, bool):
        return 'yes' if value else 'no'
    if isinstance(value, float):
        return f'{value:g}'
    if isinstance(value, list | dict):
        return json.dumps(value, ensure_ascii=False, sort_keys=True)
    return str(value)


def fmt_frac(value: Any) -> str:
    number = finite_number(value)
    return '–' if number is None else f'{100 * number:.1f} %'


def fmt_hz(value: Any) -> str:
    number = finite_number(value)
    return '–' if number is None else f'{number:g} Hz'


def definition_list(items: Iterable[tuple[str, Any]]) -> str:
    rows = ''.join(f'<dt>{escaped(k)}</dt><dd>{escaped(fmt_value(v))}</dd>' for k, v in items)
    return f'<dl>{rows}</dl>'


def swatch(colours: Mapping[str, str], backend: str) -> str:
    return (
        f'<span class="swatch" style="background:{escaped(colours.get(backend, "#777"))}"></span>'
    )
