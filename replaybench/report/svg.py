"""Small inline-SVG charts: line/step charts, horizontal (stacked) bars.

Output is a string of SVG markup meant to be embedded in HTML. It is deterministic (fixed number
formatting, no random ids) and every text is escaped. Long series are reduced to the first, last,
minimum and maximum point of each pixel column, so the markup size is bounded by the chart width.
"""

from __future__ import annotations

import itertools
import math
from html import escape
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from replaybench.colours import PALETTE, colour
from replaybench.textsafe import visible

if TYPE_CHECKING:
    from collections.abc import Sequence
    from typing import TypeAlias

    import numpy.typing as npt

    Values: TypeAlias = Sequence[float] | npt.NDArray[np.float64]

__all__ = [
    'PALETTE',
    'TREND_POINTS',
    'Label',
    'Marks',
    'Rule',
    'Segment',
    'Series',
    'bar_chart',
    'colour',
    'downsample',
    'fit_label',
    'line_chart',
    'nice_ticks',
    'stacked_bar_chart',
    'step_cdf',
]

_FONT = 'system-ui, -apple-system, Segoe UI, Roboto, sans-serif'
_CHAR_W = 6.6  # approximate width of one 12 px character
_AXIS = '#444'
_GRID = '#e4e4e4'
_TEXT = '#222'


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


def _n(value: float) -> str:
    """Coordinate text: one decimal, no negative zero."""
    text = f'{value:.1f}'
    return '0.0' if text == '-0.0' else text


def _e(text: object) -> str:
    """HTML-escaped text, control characters shown as escapes (``replaybench.textsafe``)."""
    return escape(visible(str(text)), quote=True)


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


def _log_ticks(lo: float, hi: float) -> list[float]:
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


def _tick_text(value: float, ticks: Sequence[float], log: bool = False) -> str:
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


class _Scale:
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


def _finite(xs: Values, ys: Values) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
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


def _legend(
    entries: Sequence[tuple[str | Label, str]], x0: float, y0: float, width: float
) -> list[str]:
    """Legend swatches laid out left to right, wrapping at ``width``; returns SVG parts. An
    entry too long is shortened (``fit_label``), its full text its tooltip."""
    parts: list[str] = []
    x, y = x0, y0
    for name, fill in entries:
        label = fit_label(name, _LEGEND_CHARS)
        item_w = 18 + len(label) * _CHAR_W + 16
        if x > x0 and x + item_w > x0 + width:
            x, y = x0, y + 18
        tip = f'<title>{_e(name)}</title>' if label != str(name) else ''
        parts.append(
            f'<rect x="{_n(x)}" y="{_n(y - 9)}" width="12" height="10" rx="2" fill="{_e(fill)}"/>'
            f'<text x="{_n(x + 17)}" y="{_n(y)}" fill="{_TEXT}">{tip}{_e(label)}</text>',
        )
        x += item_w
    return parts


def _top(entries: Sequence[tuple[str | Label, str]], width: int) -> int:
    """Y of the plot area: below the title and the legend rows."""
    if not entries:
        return 32
    return 40 + 18 * (_legend_rows(entries, width - 24) - 1) + 16


def _legend_rows(entries: Sequence[tuple[str | Label, str]], width: float) -> int:
    rows, x = 1, 0.0
    for name, _ in entries:
        item_w = 18 + len(fit_label(name, _LEGEND_CHARS)) * _CHAR_W + 16
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


def _in_words(
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
    per_line = int((width - 24) / _CHAR_W)
    lines = [fit_label(line, per_line) for line in lines]
    height = 32 + 20 * len(lines) + 8
    parts = [_open(width, height, title)]
    for i, line in enumerate(lines):
        fill = '#666' if i < 2 else _TEXT
        parts.append(f'<text x="12" y="{_n(48 + 20 * i)}" fill="{fill}">{_e(line)}</text>')
    parts.append('</svg>')
    return ''.join(parts)


def _open(width: int, height: int, title: str) -> str:
    return (
        f'<svg class="chart" viewBox="0 0 {width} {height}" width="{width}" height="{height}" '
        f'role="img" aria-label="{_e(title)}" font-family="{_FONT}" font-size="12">'
        f'<title>{_e(title)}</title>'
        f'<text x="8" y="18" font-size="14" font-weight="600" fill="{_TEXT}">{_e(title)}</text>'
    )


def line_chart(
    series: Sequence[Series],
    *,
    title: str,
    x_label: str,
    y_label: str,
    width: int = 720,
    height: int = 280,
    x_range: tuple[float, float] | None = None,
    y_range: tuple[float, float] | None = None,
    log_y: bool = False,
    log_x: bool = False,
    spans: Sequence[tuple[float, float]] = (),
    span_label: str = '',
    marks: Sequence[Marks] = (),
    note: str = '',
    mean_per_pixel: bool = False,
    rules: Sequence[Rule] = (),
    min_points: int = 0,
) -> str:
    """A chart of one polyline per series, with axes, ticks, grid and legend.

    With ``min_points`` (a chart over time: ``TREND_POINTS``), where no series has that many
    points the chart says in words what the points are, instead of drawing axes around one
    or two dots.

    ``spans`` are shaded x-intervals (e.g. warm-up); ``marks`` are rows of short ticks below
    the x axis (e.g. dropped frames); ``rules`` are labelled reference lines (a threshold, a
    found value), kept inside the axes. Values outside ``y_range`` are drawn at its edge.
    Series longer than the plot is wide are reduced per pixel column (``downsample``): to their
    envelope, or to the column means with ``mean_per_pixel``.
    """
    data = [(s, *_finite(s.xs, s.ys)) for s in series]
    if min_points and data and all(x.size < min_points for _, x, _ in data):
        return _in_words(
            data,
            title=title,
            x_label=x_label,
            y_label=y_label,
            width=width,
            min_points=min_points,
        )
    all_x: list[float] = []
    for _, x, _ in data:
        if x.size:
            all_x += [float(np.min(x)), float(np.max(x))]
    for mark in marks:
        mx = np.asarray(mark.xs, dtype=np.float64)
        mx = mx[np.isfinite(mx)]
        if mx.size:
            all_x += [float(mx.min()), float(mx.max())]
    for a, b in spans:
        all_x += [a, b]
    all_y = [float(v) for _, _, y in data if y.size for v in (np.min(y), np.max(y))]
    all_x += [r.value for r in rules if r.axis == 'x' and math.isfinite(r.value)]
    all_y += [r.value for r in rules if r.axis != 'x' and math.isfinite(r.value)]

    entries: list[tuple[str | Label, str]] = [(s.name, s.colour) for s in series]
    entries += [(m.name, m.colour) for m in marks if m.name]
    if spans and span_label:
        entries.append((span_label, '#d9d9d9'))
    top = _top(entries, width)
    mark_rows = len(marks)
    left, right = 64, 28
    bottom = 40 + 6 * mark_rows + (14 if note else 0)
    plot_w = width - left - right
    plot_h = max(40, height - top - bottom)
    height = top + plot_h + bottom

    if x_range is not None:
        x_lo, x_hi = x_range
    elif all_x:
        x_lo, x_hi = min(all_x), max(all_x)
    else:
        x_lo, x_hi = 0.0, 1.0
    if log_x:
        pos = [v for v in [*all_x, x_lo, x_hi] if v > 0] or [1.0]
        x_ticks = _log_ticks(min(pos), max(pos))
        x_lo, x_hi = x_ticks[0], x_ticks[-1]
    else:
        if x_hi <= x_lo:
            x_lo, x_hi = x_lo - 0.5, x_hi + 0.5
        x_ticks = [t for t in nice_ticks(x_lo, x_hi) if x_lo - 1e-9 <= t <= x_hi + 1e-9]
    if y_range is None:
        y_lo, y_hi = (min(0.0, *all_y), max(all_y)) if all_y else (0.0, 1.0)
    else:
        y_lo, y_hi = y_range
    if log_y:
        pos = [v for v in all_y if v > 0] or [1.0]
        y_ticks = _log_ticks(min(pos), max(pos) if y_range is None else y_hi)
        y_lo, y_hi = y_ticks[0], y_ticks[-1]
    else:
        y_ticks = nice_ticks(y_lo, y_hi, max_ticks=5)
        if y_range is None:
            y_lo, y_hi = y_ticks[0], y_ticks[-1]
        else:
            y_ticks = [t for t in y_ticks if y_lo - 1e-12 <= t <= y_hi + 1e-12]

    sx = _Scale(x_lo, x_hi, left, left + plot_w, log_x)
    sy = _Scale(y_lo, y_hi, top + plot_h, top, log_y)
    parts = [_open(width, height, title)]
    if entries:
        parts.extend(_legend(entries, 12, 40, width - 24))
    for a, b in spans:
        x0, x1 = sx(min(a, b)), sx(max(a, b))
        parts.append(
            f'<rect x="{_n(x0)}" y="{_n(top)}" width="{_n(max(x1 - x0, 1.0))}" '
            f'height="{_n(plot_h)}" fill="#000" fill-opacity="0.07"/>',
        )
    for tick in y_ticks:
        py = sy(tick)
        parts.append(
            f'<line x1="{left}" y1="{_n(py)}" x2="{left + plot_w}" y2="{_n(py)}" '
            f'stroke="{_GRID}"/>'
            f'<text x="{left - 6}" y="{_n(py + 4)}" text-anchor="end" fill="{_TEXT}">'
            f'{_e(_tick_text(tick, y_ticks, log_y))}</text>',
        )
    base = top + plot_h
    for tick in x_ticks:
        px = sx(tick)
        parts.append(
            f'<line x1="{_n(px)}" y1="{_n(base)}" x2="{_n(px)}" y2="{_n(base + 4)}" '
            f'stroke="{_AXIS}"/>'
            f'<text x="{_n(px)}" y="{_n(base + 16 + 6 * mark_rows)}" text-anchor="middle" '
            f'fill="{_TEXT}">{_e(_tick_text(tick, x_ticks, log_x))}</text>',
        )
    parts.append(
        f'<path d="M{left} {top}V{_n(base)}H{left + plot_w}" fill="none" stroke="{_AXIS}"/>',
    )
    for s, x, y in data:
        if not x.size:
            continue
        pxs, pys = downsample(
            sx.array(x), sy.array(y), left, left + plot_w, plot_w, mean=mean_per_pixel
        )
        coords = list(zip(pxs.tolist(), pys.tolist(), strict=True))
        points = ' '.join(f'{_n(a)},{_n(b)}' for a, b in coords)
        if pxs.size > 1 and s.style != 'dots':
            parts.append(
                f'<polyline points="{points}" fill="none" stroke="{_e(s.colour)}" '
                'stroke-width="1.3" stroke-linejoin="round"/>',
            )
        if pxs.size == 1 or s.style != 'line':
            radius = '3.5' if s.style != 'line' else '2.5'
            parts.extend(
                f'<circle cx="{_n(a)}" cy="{_n(b)}" r="{radius}" fill="{_e(s.colour)}"/>'
                for a, b in coords
            )
    for rule in rules:
        if not math.isfinite(rule.value):
            continue
        if rule.axis == 'x':
            px = sx(rule.value)
            parts.append(
                f'<line x1="{_n(px)}" y1="{top}" x2="{_n(px)}" y2="{_n(base)}" '
                f'stroke="{_e(rule.colour)}" stroke-dasharray="5 3"/>'
                f'<text x="{_n(px + 4)}" y="{top + 12}" fill="{_e(rule.colour)}">'
                f'{_e(rule.label)}</text>',
            )
        else:
            py = sy(rule.value)
            parts.append(
                f'<line x1="{left}" y1="{_n(py)}" x2="{left + plot_w}" y2="{_n(py)}" '
                f'stroke="{_e(rule.colour)}" stroke-dasharray="5 3"/>'
                f'<text x="{left + plot_w - 4}" y="{_n(py - 4)}" text-anchor="end" '
                f'fill="{_e(rule.colour)}">{_e(rule.label)}</text>',
            )
    for row, mark in enumerate(marks):
        mx = np.asarray(mark.xs, dtype=np.float64)
        mx = mx[np.isfinite(mx)]
        if not mx.size:
            continue
        columns = sorted({round(v, 1) for v in sx.array(mx).tolist()})
        y0 = base + 2 + 6 * row
        d = ''.join(f'M{_n(c)} {_n(y0)}v5' for c in columns)
        parts.append(f'<path d="{d}" stroke="{_e(mark.colour)}" stroke-width="1"/>')
    parts.append(
        f'<text x="{_n(left + plot_w / 2)}" y="{_n(base + 32 + 6 * mark_rows)}" '
        f'text-anchor="middle" fill="{_TEXT}">{_e(x_label)}</text>'
        f'<text transform="translate(14 {_n(top + plot_h / 2)}) rotate(-90)" '
        f'text-anchor="middle" fill="{_TEXT}">{_e(y_label)}</text>',
    )
    if note:
        parts.append(
            f'<text x="{left}" y="{_n(height - 6)}" fill="#666" font-size="11">{_e(note)}</text>',
        )
    parts.append('</svg>')
    return ''.join(parts)


def step_cdf(
    series: Sequence[tuple[str | Label, str, Sequence[float]]],
    *,
    title: str,
    x_label: str,
    width: int = 720,
    height: int = 280,
    log_x: bool | None = None,
) -> str:
    """Empirical CDF per (name, colour, values) as a step line; log x when spread is wide.

    ``log_x=None`` picks a log axis when the largest value is over 20 times the smallest.
    """
    lines: list[Series] = []
    lows: list[float] = []
    highs: list[float] = []
    for name, fill, values in series:
        v = np.sort(np.asarray(values, dtype=np.float64)[np.isfinite(values)])
        if not v.size:
            continue
        lows.append(float(v[0]))
        highs.append(float(v[-1]))
        frac = np.arange(1, v.size + 1, dtype=np.float64) / v.size
        xs = np.repeat(v, 2)
        ys = np.empty_like(xs)
        ys[0::2] = np.r_[0.0, frac[:-1]]
        ys[1::2] = frac
        lines.append(Series(name, fill, xs, ys))
    if log_x is None:
        log_x = bool(lows) and min(lows) > 0 and max(highs) / min(lows) > 20
    return line_chart(
        lines,
        title=title,
        x_label=x_label + (' (log scale)' if log_x else ''),
        y_label='fraction of frames',
        width=width,
        height=height,
        y_range=(0.0, 1.0),
        log_x=log_x,
    )


def _hbars(
    labels: Sequence[str | Label],
    segments: Sequence[Segment],
    bar_colours: Sequence[str] | None,
    *,
    title: str,
    x_label: str,
    width: int,
    totals_format: str,
) -> str:
    n = len(labels)
    show_legend = bar_colours is None
    entries: list[tuple[str | Label, str]] = (
        [(s.name, s.colour) for s in segments] if show_legend else []
    )
    top = _top(entries, width)
    longest = max((len(str(t)) for t in labels), default=4)
    label_w = min(260, max(60, int(longest * _CHAR_W) + 12))
    left, right = label_w + 8, 72
    bar_h, gap = 18, 8
    plot_h = max(1, n) * (bar_h + gap) + gap
    height = top + plot_h + 40
    plot_w = width - left - right
    totals: list[float] = []
    present: list[int] = []
    for i in range(n):
        values = [v for v in (s.values[i] for s in segments) if v is not None]
        totals.append(float(sum(values)))
        if values:
            present.append(i)
    x_ticks = nice_ticks(0.0, max((totals[i] for i in present), default=1.0) or 1.0)
    sx = _Scale(x_ticks[0], x_ticks[-1], left, left + plot_w, log=False)
    parts = [_open(width, height, title)]
    if entries:
        parts.extend(_legend(entries, 12, 40, width - 24))
    base = top + plot_h
    for tick in x_ticks:
        px = sx(tick)
        parts.append(
            f'<line x1="{_n(px)}" y1="{top}" x2="{_n(px)}" y2="{_n(base)}" stroke="{_GRID}"/>'
            f'<text x="{_n(px)}" y="{_n(base + 16)}" text-anchor="middle" fill="{_TEXT}">'
            f'{_e(_tick_text(tick, x_ticks))}</text>',
        )
    for i, label in enumerate(labels):
        y = top + gap + i * (bar_h + gap)
        shown = fit_label(label, int(label_w / _CHAR_W))
        parts.append(
            f'<text x="{left - 6}" y="{_n(y + bar_h / 2 + 4)}" text-anchor="end" fill="{_TEXT}">'
            f'<title>{_e(label)}</title>{_e(shown)}</text>',
        )
        x = 0.0
        for segment in segments:
            value = segment.values[i]
            if value is None or not value > 0:
                continue
            fill = bar_colours[i] if bar_colours is not None else segment.colour
            x0, x1 = sx(x), sx(x + float(value))
            parts.append(
                f'<rect x="{_n(x0)}" y="{_n(y)}" width="{_n(max(x1 - x0, 0.5))}" '
                f'height="{bar_h}" fill="{_e(fill)}"><title>{_e(label)} · {_e(segment.name)}: '
                f'{_e(totals_format.format(float(value)))}</title></rect>',
            )
            x += float(value)
        total_text = totals_format.format(totals[i]) if i in present else 'n/a'
        parts.append(
            f'<text x="{_n(sx(x) + 5)}" y="{_n(y + bar_h / 2 + 4)}" fill="{_TEXT}">'
            f'{_e(total_text)}</text>',
        )
    parts.append(
        f'<path d="M{left} {top}V{_n(base)}H{left + plot_w}" fill="none" stroke="{_AXIS}"/>'
        f'<text x="{_n(left + plot_w / 2)}" y="{_n(base + 32)}" text-anchor="middle" '
        f'fill="{_TEXT}">{_e(x_label)}</text></svg>',
    )
    return ''.join(parts)


def bar_chart(
    labels: Sequence[str | Label],
    values: Sequence[float | None],
    colours: Sequence[str],
    *,
    title: str,
    x_label: str,
    width: int = 720,
    value_format: str = '{:.1f}',
) -> str:
    """Horizontal bars, one colour per bar; None values are shown as 'n/a'."""
    return _hbars(
        labels,
        [Segment(x_label, '#000', values)],
        list(colours),
        title=title,
        x_label=x_label,
        width=width,
        totals_format=value_format,
    )


def stacked_bar_chart(
    labels: Sequence[str | Label],
    segments: Sequence[Segment],
    *,
    title: str,
    x_label: str,
    width: int = 720,
    value_format: str = '{:.2f}',
) -> str:
    """Horizontal stacked bars with a legend of the segment kinds; the total is printed."""
    return _hbars(
        labels,
        segments,
        None,
        title=title,
        x_label=x_label,
        width=width,
        totals_format=value_format,
    )
