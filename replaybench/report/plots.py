"""report.html's charts of latency, throughput, stages and detections per frame."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.report.markup import escaped
from replaybench.report.svg import (
    TREND_POINTS,
    Marks,
    Segment,
    Series,
    bar_chart,
    line_chart,
    nice_ticks,
    stacked_bar_chart,
    step_cdf,
)
from replaybench.results.numbers import finite_number
from replaybench.results.recorded_latency import replays_recording
from replaybench.results.repeats import one_timeline

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

    from replaybench.results.model import SummaryRow
    from replaybench.results.records import FrameRecord

__all__ = ['CHART_PIXELS', 'latency_timeline', 'plots_html']

CHART_PIXELS = 640  # plot-area width of the default 720 px charts

#: (summary key, legend name, colour) of the stage breakdown, in stacking order.
_STAGES: tuple[tuple[str, str, str], ...] = (
    ('queue_wait_ms_mean', 'queue wait', '#bab0ac'),
    ('read_decode_ms_mean', 'read + decode', '#4e79a7'),
    ('preprocess_ms_mean', 'preprocess', '#f28e2b'),
    ('infer_ms_mean', 'infer', '#e15759'),
    ('postprocess_ms_mean', 'postprocess', '#76b7b2'),
    ('h2d_ms_mean', 'host→device', '#59a14f'),
    ('d2h_ms_mean', 'device→host', '#edc948'),
)


def _spans(intervals: Iterable[tuple[float, float]]) -> list[tuple[float, float]]:
    merged: list[tuple[float, float]] = []
    for lo, hi in sorted(intervals):
        if merged and lo <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return merged


def _median(values: Sequence[float]) -> float:
    ordered = sorted(values)
    mid = len(ordered) // 2
    return ordered[mid] if len(ordered) % 2 else (ordered[mid - 1] + ordered[mid]) / 2


def latency_timeline(
    topic: str,
    groups: Mapping[str, Sequence[FrameRecord]],
    colours: Mapping[str, str],
) -> str:
    """The chart of latency over release time, one line per group (a backend's frames of
    ``topic``; the Rig section's: a camera's of one backend), dropped frames marked."""
    series: list[Series] = []
    marks: list[Marks] = []
    warm: list[tuple[float, float]] = []
    measured_max = 0.0
    medians: list[float] = []
    clipped = 0
    for backend, records in groups.items():
        ok = [r for r in records if r.status == 'ok' and r.latency_ms is not None]
        measured = [r.latency_ms for r in ok if not r.warmup and r.latency_ms is not None]
        if measured:
            measured_max = max(measured_max, max(measured))
            medians.append(_median(measured))
        series.append(
            Series(
                backend,
                colours[backend],
                [r.release_s for r in ok],
                [r.latency_ms for r in ok if r.latency_ms is not None],
            ),
        )
        warm_x = [r.release_s for r in ok if r.warmup]
        if warm_x:
            first_measured = min((r.release_s for r in ok if not r.warmup), default=max(warm_x))
            warm.append((min(warm_x), first_measured))
        dropped = [r.release_s for r in records if r.status == 'dropped']
        if dropped:
            marks.append(Marks(f'{backend} dropped ({len(dropped)})', colours[backend], dropped))
    y_range = None
    if measured_max > 0:
        top = nice_ticks(0.0, measured_max * 1.05, max_ticks=5)[-1]
        y_range = (0.0, top)
        clipped = sum(
            1
            for records in groups.values()
            for r in records
            if r.status == 'ok' and r.warmup and r.latency_ms is not None and r.latency_ms > top
        )
    positive = [m for m in medians if m > 0]
    log_y = len(positive) >= 2 and max(positive) / min(positive) > 10
    if log_y and y_range is not None:
        y_range = (min(positive) / 10, y_range[1])
    note = (
        f'{clipped} warm-up frame(s) above the axis are drawn at its top edge.' if clipped else ''
    )
    return line_chart(
        series,
        title=f'Latency over time · {topic}',
        x_label='release time since the backend started replaying (s)',
        y_label='latency (ms)' + (', log scale' if log_y else ''),
        y_range=y_range,
        log_y=log_y,
        spans=_spans(warm),
        span_label='warm-up' if warm else '',
        marks=marks,
        note=note,
        min_points=TREND_POINTS,
    )


def _latency_cdf(
    topic: str,
    groups: Mapping[str, Sequence[FrameRecord]],
    colours: Mapping[str, str],
) -> str:
    series = [
        (
            backend,
            colours[backend],
            [
                r.latency_ms
                for r in records
                if r.status == 'ok' and not r.warmup and r.latency_ms is not None
            ],
        )
        for backend, records in groups.items()
    ]
    return step_cdf(
        series, title=f'Latency CDF · {topic} (measured frames)', x_label='latency (ms)'
    )


def _detections_timeline(
    topic: str,
    groups: Mapping[str, Sequence[FrameRecord]],
    colours: Mapping[str, str],
) -> str:
    series = []
    longest = 0
    for backend, records in groups.items():
        ok = [r for r in records if r.status == 'ok' and r.detections is not None]
        longest = max(longest, len(ok))
        series.append(
            Series(
                backend,
                colours[backend],
                [r.release_s for r in ok],
                [float(r.detections) for r in ok if r.detections is not None],
            ),
        )
    return line_chart(
        series,
        title=f'Detections per frame · {topic}',
        x_label='release time since the backend started replaying (s)',
        y_label='detections',
        mean_per_pixel=True,
        note='Each point is the mean over the frames of one pixel column.'
        if longest > CHART_PIXELS
        else '',
        min_points=TREND_POINTS,
    )


def _group_label(row: SummaryRow, many_topics: bool) -> str:
    backend = row.backend or '?'
    return f'{backend} · {row.topic or "?"}' if many_topics else backend


def _throughput_chart(
    rows: Sequence[SummaryRow],
    colours: Mapping[str, str],
    many_topics: bool,
) -> str:
    """Replayed rows only: a recording's rate of reading the bag is no detector's speed."""
    rows = [r for r in rows if not replays_recording(r)]
    if not rows:
        return ''
    return bar_chart(
        [_group_label(r, many_topics) for r in rows],
        [finite_number(r.throughput_fps) for r in rows],
        [colours.get(r.backend, '#777') for r in rows],
        title='Throughput (measured frames per second)',
        x_label='frames per second',
    )


def _stage_chart(rows: Sequence[SummaryRow], many_topics: bool) -> str:
    """Replayed rows only (a recording's stages did not run here)."""
    rows = [r for r in rows if not replays_recording(r)]
    if not rows:
        return ''
    segments = []
    for key, name, fill in _STAGES:
        values = [finite_number(getattr(r, key)) for r in rows]
        if not any(v for v in values):
            continue
        segments.append(Segment(name, fill, values))
    rest: list[float | None] = []
    for r in rows:
        mean = finite_number(r.latency_ms_mean)
        parts = [finite_number(getattr(r, key)) for key, _, _ in _STAGES]
        known = sum(p for p in parts if p is not None)
        rest.append(mean - known if mean is not None and mean - known > 1e-4 else None)
    if any(v is not None for v in rest):
        segments.append(Segment('other (not attributed to a stage)', '#d7d7d7', rest))
    return stacked_bar_chart(
        [_group_label(r, many_topics) for r in rows],
        segments,
        title='Mean latency by stage (measured frames)',
        x_label='milliseconds',
    )


def plots_html(
    frames: Sequence[FrameRecord],
    rows: Sequence[SummaryRow],
    backends: Sequence[str],
    topics: Sequence[str],
    colours: Mapping[str, str],
) -> str:
    by_topic: dict[str, dict[str, list[FrameRecord]]] = {
        t: {b: [] for b in backends} for t in topics
    }
    for record in frames:
        by_topic[record.topic][record.backend].append(record)
    parts = ['<h2 id="latency">Latency</h2>']
    for topic in topics:
        groups = _by_release(by_topic[topic])
        if not groups:
            continue
        parts.append(
            f'<div class="charts">{latency_timeline(topic, groups, colours)}'
            f'{_latency_cdf(topic, groups, colours)}</div>',
        )
    many_topics = len(topics) > 1
    parts.append('<h2 id="throughput">Throughput and stages</h2>')
    if rows:
        parts.append(
            f'<div class="charts">{_throughput_chart(rows, colours, many_topics)}'
            f'{_stage_chart(rows, many_topics)}</div>',
        )
    recordings = list(dict.fromkeys(r.backend for r in rows if replays_recording(r)))
    if recordings:
        parts.append(
            f'<p class="muted">Not charted here: {escaped(", ".join(recordings))}, the outputs '
            'recorded in the bag. Their replay is no detector running on this machine: the '
            'rate they were read at is how fast the bag was read. Their recorded output rate '
            'and latency are in the Summary and under Recorded latency.</p>'
        )
    parts.append('<h2 id="detections">Detections</h2>')
    for topic in topics:
        groups = _by_release(by_topic[topic])
        if groups:
            parts.append(
                f'<div class="charts">{_detections_timeline(topic, groups, colours)}</div>'
            )
    return ''.join(parts)


# --------------------------------------------------------------------------- agreement


def _by_release(groups: Mapping[str, list[FrameRecord]]) -> dict[str, list[FrameRecord]]:
    # the passes of --repeat one after the other (results.repeats.one_timeline)
    return {b: one_timeline(rs) for b, rs in groups.items() if rs}
