"""Line charts (one polyline, dots or both per series) and empirical CDFs as step lines."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from replaybench.report.markup import escaped
from replaybench.report.svg.parts import (
    AXIS,
    GRID,
    TEXT,
    Label,
    Marks,
    Rule,
    Scale,
    Series,
    coord,
    downsample,
    finite_points,
    in_words,
    legend,
    log_ticks,
    nice_ticks,
    plot_top,
    svg_open,
    tick_text,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['line_chart', 'step_cdf']


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
    data = [(s, *finite_points(s.xs, s.ys)) for s in series]
    if min_points and data and all(x.size < min_points for _, x, _ in data):
        return in_words(
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
    top = plot_top(entries, width)
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
        x_ticks = log_ticks(min(pos), max(pos))
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
        y_ticks = log_ticks(min(pos), max(pos) if y_range is None else y_hi)
        y_lo, y_hi = y_ticks[0], y_ticks[-1]
    else:
        y_ticks = nice_ticks(y_lo, y_hi, max_ticks=5)
        if y_range is None:
            y_lo, y_hi = y_ticks[0], y_ticks[-1]
        else:
            y_ticks = [t for t in y_ticks if y_lo - 1e-12 <= t <= y_hi + 1e-12]

    sx = Scale(x_lo, x_hi, left, left + plot_w, log_x)
    sy = Scale(y_lo, y_hi, top + plot_h, top, log_y)
    parts = [svg_open(width, height, title)]
    if entries:
        parts.extend(legend(entries, 12, 40, width - 24))
    for a, b in spans:
        x0, x1 = sx(min(a, b)), sx(max(a, b))
        parts.append(
            f'<rect x="{coord(x0)}" y="{coord(top)}" width="{coord(max(x1 - x0, 1.0))}" '
            f'height="{coord(plot_h)}" fill="#000" fill-opacity="0.07"/>',
        )
    for tick in y_ticks:
        py = sy(tick)
        parts.append(
            f'<line x1="{left}" y1="{coord(py)}" x2="{left + plot_w}" y2="{coord(py)}" '
            f'stroke="{GRID}"/>'
            f'<text x="{left - 6}" y="{coord(py + 4)}" text-anchor="end" fill="{TEXT}">'
            f'{escaped(tick_text(tick, y_ticks, log_y))}</text>',
        )
    base = top + plot_h
    for tick in x_ticks:
        px = sx(tick)
        parts.append(
            f'<line x1="{coord(px)}" y1="{coord(base)}" x2="{coord(px)}" y2="{coord(base + 4)}" '
            f'stroke="{AXIS}"/>'
            f'<text x="{coord(px)}" y="{coord(base + 16 + 6 * mark_rows)}" text-anchor="middle" '
            f'fill="{TEXT}">{escaped(tick_text(tick, x_ticks, log_x))}</text>',
        )
    parts.append(
        f'<path d="M{left} {top}V{coord(base)}H{left + plot_w}" fill="none" stroke="{AXIS}"/>',
    )
    for s, x, y in data:
        if not x.size:
            continue
        pxs, pys = downsample(
            sx.array(x), sy.array(y), left, left + plot_w, plot_w, mean=mean_per_pixel
        )
        coords = list(zip(pxs.tolist(), pys.tolist(), strict=True))
        points = ' '.join(f'{coord(a)},{coord(b)}' for a, b in coords)
        if pxs.size > 1 and s.style != 'dots':
            parts.append(
                f'<polyline points="{points}" fill="none" stroke="{escaped(s.colour)}" '
                'stroke-width="1.3" stroke-linejoin="round"/>',
            )
        if pxs.size == 1 or s.style != 'line':
            radius = '3.5' if s.style != 'line' else '2.5'
            parts.extend(
                f'<circle cx="{coord(a)}" cy="{coord(b)}" r="{radius}" fill="{escaped(s.colour)}"/>'
                for a, b in coords
            )
    for rule in rules:
        if not math.isfinite(rule.value):
            continue
        if rule.axis == 'x':
            px = sx(rule.value)
            parts.append(
                f'<line x1="{coord(px)}" y1="{top}" x2="{coord(px)}" y2="{coord(base)}" '
                f'stroke="{escaped(rule.colour)}" stroke-dasharray="5 3"/>'
                f'<text x="{coord(px + 4)}" y="{top + 12}" fill="{escaped(rule.colour)}">'
                f'{escaped(rule.label)}</text>',
            )
        else:
            py = sy(rule.value)
            parts.append(
                f'<line x1="{left}" y1="{coord(py)}" x2="{left + plot_w}" y2="{coord(py)}" '
                f'stroke="{escaped(rule.colour)}" stroke-dasharray="5 3"/>'
                f'<text x="{left + plot_w - 4}" y="{coord(py - 4)}" text-anchor="end" '
                f'fill="{escaped(rule.colour)}">{escaped(rule.label)}</text>',
            )
    for row, mark in enumerate(marks):
        mx = np.asarray(mark.xs, dtype=np.float64)
        mx = mx[np.isfinite(mx)]
        if not mx.size:
            continue
        columns = sorted({round(v, 1) for v in sx.array(mx).tolist()})
        y0 = base + 2 + 6 * row
        d = ''.join(f'M{coord(c)} {coord(y0)}v5' for c in columns)
        parts.append(f'<path d="{d}" stroke="{escaped(mark.colour)}" stroke-width="1"/>')
    parts.append(
        f'<text x="{coord(left + plot_w / 2)}" y="{coord(base + 32 + 6 * mark_rows)}" '
        f'text-anchor="middle" fill="{TEXT}">{escaped(x_label)}</text>'
        f'<text transform="translate(14 {coord(top + plot_h / 2)}) rotate(-90)" '
        f'text-anchor="middle" fill="{TEXT}">{escaped(y_label)}</text>',
    )
    if note:
        parts.append(
            f'<text x="{left}" y="{coord(height - 6)}" fill="#666" font-size="11">'
            f'{escaped(note)}</text>',
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
