"""Small inline-SVG charts: line/step charts, horizontal (stacked) bars.

Output is a string of SVG markup meant to be embedded in HTML. It is deterministic (fixed number
formatting, no random ids) and every text is escaped. Long series are reduced to the first, last,
minimum and maximum point of each pixel column, so the markup size is bounded by the chart width.
"""

from __future__ import annotations

from replaybench.colours import PALETTE, colour
from replaybench.report.svg.bars import bar_chart, stacked_bar_chart
from replaybench.report.svg.lines import line_chart, step_cdf
from replaybench.report.svg.parts import (
    TREND_POINTS,
    Label,
    Marks,
    Rule,
    Segment,
    Series,
    downsample,
    fit_label,
    nice_ticks,
)

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
