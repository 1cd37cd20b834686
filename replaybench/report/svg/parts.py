"""What the inline-SVG charts are made of: their series, labels, ticks, scales and legend.

The chart kinds (``lines``: line and step charts; ``bars``: horizontal and stacked bars) draw
with these. Numbers are written with fixed formatting (``coord``) and every text is escaped.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from replaybench.report.markup import escaped

if TYPE_CHECKING:
    from collections.abc import Sequence
    from typing import TypeAlias

    import numpy.typing as npt

    Values: TypeAlias = Sequence[float] | npt.NDArray[np.float64]

__all__ = [
    'AXIS',
    'CHAR_W',
    'FONT',
    'GRID',
    'TEXT',
    'TREND_POINTS',
    'Label',
    'Marks',
    'Rule',
    'Scale',
    'Segment',
    'Series',
    'coord',
    'downsample',
    'finite_points',
    'fit_label',
    'in_words',
    'legend',
    'log_ticks',
    'nice_ticks',
    'plot_top',
    'svg_open',
    'tick_text',
]

FONT = 'system-ui, -apple-system, Segoe UI, Roboto, sans-serif'
CHAR_W = 6.6  # approximate width of one 12 px character
AXIS = '#444'
GRID = '#e4e4e4'
TEXT = '#222'


class Label(NamedTuple):
    """A chart label in three parts, shown as ``head + middle + tail``. Where it is too long
    for its place, ``middle`` (a machine's name, say) is shortened first, so that the head
    (the run, the backend) and the tail (the kind of series) stay whole; the full text is the
    label's tooltip."""

    head: str
    middle: str = ''
    tail: str = ''

    def __str__(self) -> str:
        return self.head + self.middle + self.tail


def fit_label(label: str | Label, limit: int) -> str:
    """``label`` in at most ``limit`` characters: whole when it fits; else a ``Label``'s middle
    shortened (down to '…'), then the end of its head; plain text, or a tail too long itself,
    is cut in its middle, so that its start and its end (what the series is) stay."""
    text = str(label)
    limit = max(limit, 3)
    if len(text) <= limit:
        return text
    if isinstance(label, Label):
        room = limit - len(label.head) - len(label.tail) - 1
        if label.middle and room >= 0:
            return f'{label.head}{label.middle[:room].rstrip()}…{label.tail}'
        keep = limit - len(label.tail) - 1
        if keep >= min(len(label.head), 8):
            return f'{label.head[:keep].rstrip()}…{label.tail}'
    tail = (limit - 1) // 2
    return f'{text[: limit - 1 - tail].rstrip()}…{text[len(text) - tail :].lstrip()}'


class Series(NamedTuple):
    """One polyline; points whose x or y is not finite are left out.

    ``style``: ``'line'`` (a polyline), ``'dots'`` (a circle per point) or ``'line+dots'``.
    ``name`` is shortened to fit the legend (``fit_label``), its full text the tooltip.
    """

    name: str | Label
    colour: str
    xs: Values
    ys: Values
    style: str = 'line'


class Rule(NamedTuple):
    """A dashed reference line across the plot: vertical at x (``axis='x'``) or horizontal."""

    axis: str
    value: float
    label: str
    colour: str = '#444'


class Marks(NamedTuple):
    """Short ticks drawn under the x axis at ``xs`` (e.g. dropped frames), one row per Marks."""

    name: str
    colour: str
    xs: Values


class Segment(NamedTuple):
    """One segment kind of a stacked bar chart: a value (or None) per bar."""

    name: str | Label
    colour: str
    values: Sequence[float | None]


def coord(value: float) -> str:
    """Coordinate text: one decimal, no negative zero."""
    text = f'{value:.1f}'
    return '0.0' if text == '-0.0' else text


def nice_ticks(lo: float, hi: float, max_ticks: int = 6) -> list[float]:
    """Round tick values covering [lo, hi] (first tick <= lo, last tick >= hi)."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return [0.0, 1.0]
    if hi < lo:
        lo, hi = hi, lo
    if hi == lo:
        pad = abs(lo) * 0.5 or 1.0
        lo, hi = lo - pad, hi + pad
    raw = (hi - lo) / max(1, max_ticks - 1)
    magnitude = 10.0 ** math.floor(math.log10(raw))
    step = magnitude
    for factor in (1.0, 2.0, 2.5, 5.0, 10.0):
        step = factor * magnitude
        if step >= raw:
            break
    first = math.floor(lo / step + 1e-9) * step
    count = math.ceil((hi - first) / step - 1e-9)
    return [_clean_float(first + i * step) for i in range(count + 1)]


def _clean_float(value: float) -> float:
    rounded = round(value, 12)
    return 0.0 if rounded == 0 else rounded


def log_ticks(lo: float, hi: float) -> list[float]:
    lo_exp = math.floor(math.log10(lo))
    hi_exp = math.ceil(math.log10(hi))
    if hi_exp == lo_exp:
        hi_exp += 1
    factors = (1.0, 2.0, 5.0) if hi_exp - lo_exp <= 3 else (1.0,)
    ticks = [_clean_float(f * 10.0**e) for e in range(lo_exp, hi_exp + 1) for f in factors]
    below = [t for t in ticks if t <= lo]
    above = [t for t in ticks if t >= hi]
    start = below[-1] if below else ticks[0]
    end = above[0] if above else ticks[-1]
    return [t for t in ticks if start <= t <= end]


def tick_text(value: float, ticks: Sequence[float], log: bool = False) -> str:
    if log:
        return f'{value:g}'
    if len(ticks) > 1:
        step = min(abs(b - a) for a, b in itertools.pairwise(ticks)) or 1.0
    else:
        step = abs(value) or 1.0
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    if decimals and not math.isclose(round(step, decimals), step, rel_tol=1e-9):
        decimals += 1
    decimals = min(decimals, 6)
    if abs(value) >= 1e6:
        return f'{value:.3g}'
    text = f'{value:.{decimals}f}'
    return '0' if float(text) == 0 else text


class Scale:
    """Maps data values to pixels, linear or log10."""

    def __init__(self, lo: float, hi: float, p0: float, p1: float, log: bool) -> None:
        self.log = log
        self.lo = math.log10(lo) if log else lo
        self.hi = math.log10(hi) if log else hi
        self.p0 = p0
        self.p1 = p1
        if self.hi == self.lo:
            self.hi = self.lo + 1.0

    def __call__(self, value: float) -> float:
        if self.log:
            value = math.log10(max(value, 10.0**self.lo))
        value = min(max(value, self.lo), self.hi)
        return self.p0 + (value - self.lo) / (self.hi - self.lo) * (self.p1 - self.p0)

    def array(self, values: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        if self.log:
            values = np.log10(np.maximum(values, 10.0**self.lo))
        values = np.clip(values, self.lo, self.hi)
        result: npt.NDArray[np.float64] = self.p0 + (values - self.lo) / (self.hi - self.lo) * (
            self.p1 - self.p0
        )
        return result


def finite_points(
    xs: Values, ys: Values
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    x = np.asarray(xs, dtype=np.float64).reshape(-1)
    y = np.asarray(ys, dtype=np.float64).reshape(-1)
    keep = np.isfinite(x) & np.isfinite(y)
    return x[keep], y[keep]


def downsample(
    xs: Values,
    ys: Values,
    lo: float,
    hi: float,
    buckets: int,
    *,
    mean: bool = False,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Reduce a series to at most a few points per x-column (``buckets`` columns over lo..hi).

    By default each column keeps its first, last, lowest and highest point (the envelope, so
    spikes stay visible), in the original order. With ``mean`` each column becomes one point at
    the mean x and mean y of its points. Series with few points are returned unchanged.
    """
    x = np.asarray(xs, dtype=np.float64)
    y = np.asarray(ys, dtype=np.float64)
    limit = buckets if mean else 4 * buckets
    if x.size <= limit or buckets < 1 or not hi > lo:
        return x, y
    column = np.clip(((x - lo) / (hi - lo) * buckets).astype(np.int64), 0, buckets - 1)
    if mean:
        counts = np.bincount(column, minlength=buckets)
        used = counts > 0
        mean_x = np.bincount(column, weights=x, minlength=buckets)[used] / counts[used]
        mean_y = np.bincount(column, weights=y, minlength=buckets)[used] / counts[used]
        return mean_x, mean_y
    order = np.argsort(column, kind='stable')
    sorted_columns = column[order]
    starts = np.flatnonzero(np.r_[True, sorted_columns[1:] != sorted_columns[:-1]])
    ends = np.r_[starts[1:], sorted_columns.size]
    keep: set[int] = set()
    for start, end in zip(starts.tolist(), ends.tolist(), strict=True):
        idx = order[start:end]
        segment = y[idx]
        keep.update(
            (
                int(idx[0]),
                int(idx[-1]),
                int(idx[int(np.argmin(segment))]),
                int(idx[int(np.argmax(segment))]),
            ),
        )
    chosen = np.fromiter(sorted(keep), dtype=np.int64, count=len(keep))
    return x[chosen], y[chosen]


#: The most characters of a legend entry (longer ones: ``fit_label``).
_LEGEND_CHARS = 48


def legend(
    entries: Sequence[tuple[str | Label, str]], x0: float, y0: float, width: float
) -> list[str]:
    """Legend swatches laid out left to right, wrapping at ``width``; returns SVG parts. An
    entry too long is shortened (``fit_label``), its full text its tooltip."""
    parts: list[str] = []
    x, y = x0, y0
    for name, fill in entries:
        label = fit_label(name, _LEGEND_CHARS)
        item_w = 18 + len(label) * CHAR_W + 16
        if x > x0 and x + item_w > x0 + width:
            x, y = x0, y + 18
        tip = f'<title>{escaped(name)}</title>' if label != str(name) else ''
        parts.append(
            f'<rect x="{coord(x)}" y="{coord(y - 9)}" width="12" height="10" rx="2" '
            f'fill="{escaped(fill)}"/>'
            f'<text x="{coord(x + 17)}" y="{coord(y)}" fill="{TEXT}">{tip}{escaped(label)}</text>',
        )
        x += item_w
    return parts


def plot_top(entries: Sequence[tuple[str | Label, str]], width: int) -> int:
    """Y of the plot area: below the title and the legend rows."""
    if not entries:
        return 32
    return 40 + 18 * (_legend_rows(entries, width - 24) - 1) + 16


def _legend_rows(entries: Sequence[tuple[str | Label, str]], width: float) -> int:
    rows, x = 1, 0.0
    for name, _ in entries:
        item_w = 18 + len(fit_label(name, _LEGEND_CHARS)) * CHAR_W + 16
        if x > 0 and x + item_w > width:
            rows, x = rows + 1, 0.0
        x += item_w
    return rows


#: The fewest points of a series over time that can show a trend: with fewer, a chart over
#: time says what it has in words (``line_chart``'s ``min_points``).
TREND_POINTS = 3


def _figure(value: float) -> str:
    return f'{value:.4g}'


def _at(value: float) -> str:
    """An x value in words: at most 3 decimals (seconds to the millisecond, hertz)."""
    text = f'{value:.3f}'.rstrip('0').rstrip('.')
    return '0' if text in ('', '-0') else text


def in_words(
    data: Sequence[tuple[Series, npt.NDArray[np.float64], npt.NDArray[np.float64]]],
    *,
    title: str,
    x_label: str,
    y_label: str,
    width: int,
    min_points: int,
) -> str:
    """A chart's box holding, instead of axes, what its few points are."""
    lines = [
        f'Too few points to show a trend: fewer than {min_points} per series.',
        f'{y_label} at {x_label}:',
    ]
    for s, x, y in data:
        if not x.size:
            lines.append(f'{fit_label(s.name, 40)}: no point')
            continue
        shown = ', '.join(f'{_figure(b)} at {_at(a)}' for a, b in zip(x, y, strict=True))
        count = f'{x.size} point' + ('' if x.size == 1 else 's')
        lines.append(f'{fit_label(s.name, 40)}: {count}: {shown}')
    per_line = int((width - 24) / CHAR_W)
    lines = [fit_label(line, per_line) for line in lines]
    height = 32 + 20 * len(lines) + 8
    parts = [svg_open(width, height, title)]
    for i, line in enumerate(lines):
        fill = '#666' if i < 2 else TEXT
        parts.append(f'<text x="12" y="{coord(48 + 20 * i)}" fill="{fill}">{escaped(line)}</text>')
    parts.append('</svg>')
    return ''.join(parts)


def svg_open(width: int, height: int, title: str) -> str:
    return (
        f'<svg class="chart" viewBox="0 0 {width} {height}" width="{width}" height="{height}" '
        f'role="img" aria-label="{escaped(title)}" font-family="{FONT}" font-size="12">'
        f'<title>{escaped(title)}</title>'
        f'<text x="8" y="18" font-size="14" font-weight="600" fill="{TEXT}">{escaped(title)}</text>'
    )
