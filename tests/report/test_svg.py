"""The inline SVG chart helpers."""

from __future__ import annotations

import re

import numpy as np
import pytest

from replaybench.report.svg import (
    PALETTE,
    Label,
    Marks,
    Segment,
    Series,
    bar_chart,
    colour,
    downsample,
    fit_label,
    line_chart,
    nice_ticks,
    stacked_bar_chart,
    step_cdf,
)


@pytest.mark.parametrize(
    ('lo', 'hi', 'expected'),
    [
        (0.0, 10.0, [0.0, 2.0, 4.0, 6.0, 8.0, 10.0]),
        (0.0, 0.93, [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]),
        (3.0, 3.0, [1.0, 2.0, 3.0, 4.0, 5.0]),
        (-7.0, 12.0, [-10.0, -5.0, 0.0, 5.0, 10.0, 15.0]),
    ],
)
def test_nice_ticks_cover_the_range_with_round_steps(
    lo: float, hi: float, expected: list[float]
) -> None:
    assert nice_ticks(lo, hi) == pytest.approx(expected)


def test_downsampling_keeps_spikes_and_bounds_the_point_count() -> None:
    rng = np.random.default_rng(0)
    x = np.arange(100_000, dtype=np.float64)
    y = rng.normal(10.0, 1.0, x.size)
    y[12_345] = 500.0
    y[77_777] = -200.0
    dx, dy = downsample(x, y, 0.0, float(x[-1]), 200)
    assert dx.size <= 4 * 200
    assert 500.0 in dy
    assert -200.0 in dy
    assert dx[0] == 0.0
    assert dx[-1] == x[-1]
    assert np.all(np.diff(dx) > 0)


def test_mean_downsampling_gives_one_point_per_column() -> None:
    x = np.arange(1000, dtype=np.float64)
    y = np.where(x % 2 == 0, 0.0, 4.0)
    dx, dy = downsample(x, y, 0.0, 1000.0, 10, mean=True)
    assert dx.size == 10
    assert dy == pytest.approx([2.0] * 10)


def test_short_series_are_left_alone() -> None:
    dx, dy = downsample([1.0, 2.0, 3.0], [3.0, 1.0, 2.0], 0.0, 3.0, 100)
    assert dx.tolist() == [1.0, 2.0, 3.0]
    assert dy.tolist() == [3.0, 1.0, 2.0]


def test_line_chart_draws_axes_legend_and_one_polyline_per_series() -> None:
    svg = line_chart(
        [
            Series('a & b', PALETTE[0], [0.0, 1.0, 2.0], [1.0, 3.0, 2.0]),
            Series('c', PALETTE[1], [0.0, 2.0], [0.5, 0.5]),
        ],
        title='T <1>',
        x_label='time (s)',
        y_label='ms',
        spans=[(0.0, 0.5)],
        span_label='warm-up',
        marks=[Marks('a dropped (1)', PALETTE[0], [1.5])],
    )
    assert svg.startswith('<svg')
    assert svg.endswith('</svg>')
    assert svg.count('<polyline') == 2
    assert '<title>T &lt;1&gt;</title>' in svg
    assert '>a &amp; b</text>' in svg
    assert '>warm-up</text>' in svg
    assert '>a dropped (1)</text>' in svg
    assert 'fill-opacity="0.07"' in svg
    assert '>time (s)</text>' in svg
    assert 'NaN' not in svg
    assert 'nan' not in svg


def test_charts_are_deterministic_and_ignore_non_finite_points() -> None:
    def chart() -> str:
        return line_chart(
            [Series('s', colour(0), [0.0, 1.0, float('nan'), 3.0], [1.0, float('inf'), 2.0, 4.0])],
            title='t',
            x_label='x',
            y_label='y',
        )

    first = chart()
    assert first == chart()
    points = re.search(r'points="([^"]*)"', first)
    assert points is not None
    assert len(points.group(1).split()) == 2


def test_values_above_the_range_are_drawn_at_the_top_edge() -> None:
    svg = line_chart(
        [Series('s', colour(0), [0.0, 1.0], [1.0, 1000.0])],
        title='t',
        x_label='x',
        y_label='y',
        y_range=(0.0, 10.0),
    )
    points = re.search(r'points="([^"]*)"', svg)
    assert points is not None
    ys = [float(p.split(',')[1]) for p in points.group(1).split()]
    top = min(float(v) for v in re.findall(r'<line x1="\d+" y1="([\d.]+)"', svg))
    assert min(ys) == pytest.approx(top)


def test_log_axis_ticks_are_powers_of_ten() -> None:
    svg = step_cdf(
        [('fast', colour(0), [0.01, 0.02, 0.03]), ('slow', colour(1), [10.0, 20.0, 50.0])],
        title='cdf',
        x_label='latency (ms)',
    )
    assert '(log scale)' in svg
    for tick in ('0.01', '0.1', '1', '10', '100'):
        assert f'>{tick}</text>' in svg


def test_bar_charts_print_values_and_n_a() -> None:
    svg = bar_chart(['x', 'y'], [12.34, None], [colour(0), colour(1)], title='fps', x_label='f')
    assert '>12.3</text>' in svg
    assert '>n/a</text>' in svg
    stacked = stacked_bar_chart(
        ['x'],
        [Segment('infer', '#e15759', [2.0]), Segment('decode', '#4e79a7', [0.5])],
        title='stages',
        x_label='ms',
    )
    assert stacked.count('<rect') >= 2 + 2  # two segments + two legend swatches
    assert '>2.50</text>' in stacked


MACHINE = 'ci runner «nœud-07» <b>&amp;</b> — rack 12, bay 3 🚀 build-farm.example.internal / CPU'


def test_a_long_label_loses_its_machine_before_its_run_or_its_kind() -> None:
    label = Label('p99 · fast (', MACHINE, ') · null · recorded pipeline')
    assert fit_label(label, 48) == 'p99 · fast (ci runn…) · null · recorded pipeline'
    # room for none of the machine: it is only '…'; with less room the head is cut at its end
    assert fit_label(label, 41) == 'p99 · fast (…) · null · recorded pipeline'
    assert fit_label(label, 39) == 'p99 · fast…) · null · recorded pipeline'
    assert fit_label(label, 500) == str(label)
    # plain text keeps both ends
    assert fit_label('a' * 30 + 'z' * 30, 21) == 'a' * 10 + '…' + 'z' * 10


def test_a_legend_and_a_bar_label_show_the_kind_and_keep_the_whole_name_as_tooltip() -> None:
    label = Label('fast (', MACHINE, ') · recorded pipeline')
    chart = line_chart(
        [Series(label, '#123456', [0.0, 1.0, 2.0], [1.0, 2.0, 3.0])],
        title='t',
        x_label='x',
        y_label='y',
    )
    assert '…) · recorded pipeline</text>' in chart
    assert '&lt;b&gt;&amp;amp;&lt;/b&gt;' in chart  # the whole name, escaped, in its <title>
    assert '<b>' not in chart
    bars = bar_chart([label], [3.0], ['#123456'], title='t', x_label='fps')
    assert '…) · recorded pipeline</text>' in bars
    assert f'<title>{str(label).replace("&", "&amp;").replace("<", "&lt;")}' in bars.replace(
        '&gt;', '>'
    )


def test_a_chart_over_time_with_too_few_points_says_what_they_are_in_words() -> None:
    few = [
        Series('hsv', '#123456', [0.05], [199.0]),
        Series('null', '#654321', [0.0004, 0.1], [12.5, float('nan')]),
    ]
    chart = line_chart(
        few, title='CPU use over time', x_label='time (s)', y_label='CPU (%)', min_points=3
    )
    assert 'Too few points to show a trend: fewer than 3 per series.' in chart
    assert '>hsv: 1 point: 199 at 0.05</text>' in chart
    assert '>null: 1 point: 12.5 at 0</text>' in chart  # the NaN is no point
    assert '<circle' not in chart
    assert '<polyline' not in chart
    # one series with enough points: the chart is drawn, the short one as its dot
    enough = [*few, Series('onnx', '#000000', [0.0, 0.1, 0.2], [1.0, 2.0, 3.0])]
    drawn = line_chart(enough, title='t', x_label='x', y_label='y', min_points=3)
    assert 'Too few points' not in drawn
    assert '<polyline' in drawn
    # without min_points (a chart not over time), one point is drawn as before
    assert '<circle' in line_chart(few[:1], title='t', x_label='x', y_label='y')
