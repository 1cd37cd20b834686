"""Horizontal bar charts: one colour per bar, or stacked segments with a legend."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.report.markup import escaped
from replaybench.report.svg.parts import (
    AXIS,
    CHAR_W,
    GRID,
    TEXT,
    Label,
    Scale,
    Segment,
    coord,
    fit_label,
    legend,
    nice_ticks,
    plot_top,
    svg_open,
    tick_text,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['bar_chart', 'stacked_bar_chart']


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
    top = plot_top(entries, width)
    longest = max((len(str(t)) for t in labels), default=4)
    label_w = min(260, max(60, int(longest * CHAR_W) + 12))
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
    sx = Scale(x_ticks[0], x_ticks[-1], left, left + plot_w, log=False)
    parts = [svg_open(width, height, title)]
    if entries:
        parts.extend(legend(entries, 12, 40, width - 24))
    base = top + plot_h
    for tick in x_ticks:
        px = sx(tick)
        parts.append(
            f'<line x1="{coord(px)}" y1="{top}" x2="{coord(px)}" y2="{coord(base)}" '
            f'stroke="{GRID}"/>'
            f'<text x="{coord(px)}" y="{coord(base + 16)}" text-anchor="middle" fill="{TEXT}">'
            f'{escaped(tick_text(tick, x_ticks))}</text>',
        )
    for i, label in enumerate(labels):
        y = top + gap + i * (bar_h + gap)
        shown = fit_label(label, int(label_w / CHAR_W))
        parts.append(
            f'<text x="{left - 6}" y="{coord(y + bar_h / 2 + 4)}" text-anchor="end" fill="{TEXT}">'
            f'<title>{escaped(label)}</title>{escaped(shown)}</text>',
        )
        x = 0.0
        for segment in segments:
            value = segment.values[i]
            if value is None or not value > 0:
                continue
            fill = bar_colours[i] if bar_colours is not None else segment.colour
            x0, x1 = sx(x), sx(x + float(value))
            parts.append(
                f'<rect x="{coord(x0)}" y="{coord(y)}" width="{coord(max(x1 - x0, 0.5))}" '
                f'height="{bar_h}" fill="{escaped(fill)}"><title>{escaped(label)} · '
                f'{escaped(segment.name)}: {escaped(totals_format.format(float(value)))}</title>'
                '</rect>',
            )
            x += float(value)
        total_text = totals_format.format(totals[i]) if i in present else 'n/a'
        parts.append(
            f'<text x="{coord(sx(x) + 5)}" y="{coord(y + bar_h / 2 + 4)}" fill="{TEXT}">'
            f'{escaped(total_text)}</text>',
        )
    parts.append(
        f'<path d="M{left} {top}V{coord(base)}H{left + plot_w}" fill="none" stroke="{AXIS}"/>'
        f'<text x="{coord(left + plot_w / 2)}" y="{coord(base + 32)}" text-anchor="middle" '
        f'fill="{TEXT}">{escaped(x_label)}</text></svg>',
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
