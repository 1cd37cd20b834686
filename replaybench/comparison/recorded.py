"""Recorded latency in ``compare``: the on-robot latency of a recording's outputs, compared.

A row of the ``recorded`` backend has no replay latency (its timing metrics are empty), but each
of its frames carries the latency its output had when the bag was recorded
(``replaybench.results.recorded_latency``): pipeline (output log time - image log time) and
capture-to-output (output log time - image header stamp). These are compared as the timing
metrics are, under their own names:

================================  ==================================================
``recorded_pipeline_ms``          median pipeline latency of the recorded outputs
``recorded_pipeline_p99_ms``      its 99th percentile
``recorded_capture_ms``           median capture-to-output latency
``recorded_capture_p99_ms``       its 99th percentile
================================  ==================================================

The value of a row is that of summary.csv (``pipeline_ms_p50``, ...: the matched outputs of the
measured frames, linear percentiles) with its 95 % interval (of a run of ``--repeat``, the first
pass: every pass replays the same recording); a candidate's change is the ratio
of the whole series, and the interval the gate judges is ``blocks.change_interval`` over the
two series of outputs **in log-time order** (the image's log time): between blocks of
consecutive outputs from ``MIN_FRAMES`` on each side, output by output below. A row that
replays (no recorded outputs) and a figure the run refused (zero stamps, outputs logged before
their image, an image stamp on another clock: ``recorded_latency_note`` says which) have none.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replaybench.comparison.metric import MetricComparison
from replaybench.results.blocks import change_interval, point_value
from replaybench.results.recorded_latency import (
    RECORDED_FIGURES,
    first_pass,
    recorded_summary,
    recorded_times,
)
from replaybench.results.records import written
from replaybench.tasks.common import COMMON_METRICS

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from replaybench.results.records import FrameRecord

__all__ = [
    'RECORDED_METRICS',
    'RecordedSeries',
    'recorded_metric_parts',
    'recorded_series',
]

#: The recorded-latency metrics of compare, in table order (``COMMON_METRICS`` of kind
#: ``recorded``).
RECORDED_METRICS: tuple[str, ...] = tuple(m.name for m in COMMON_METRICS if m.kind == 'recorded')

# metric -> (the frames.csv figure, the statistic as blocks.py names it, summary.csv's column)
_SOURCE: dict[str, tuple[str, str, str]] = {
    'recorded_pipeline_ms': ('pipeline_ms', 'median_ms', 'pipeline_ms_p50'),
    'recorded_pipeline_p99_ms': ('pipeline_ms', 'p99_ms', 'pipeline_ms_p99'),
    'recorded_capture_ms': ('capture_to_output_ms', 'median_ms', 'capture_to_output_ms_p50'),
    'recorded_capture_p99_ms': ('capture_to_output_ms', 'p99_ms', 'capture_to_output_ms_p99'),
}


class RecordedSeries(NamedTuple):
    """The recorded latencies of one (backend, topic) that replays recorded outputs."""

    #: recorded outputs matched to measured frames (of the first pass)
    outputs: int
    #: figure (``pipeline_ms``, ``capture_to_output_ms``) -> its latencies (ms) in log-time
    #: order, as frames.csv holds them; None where the run refused the figure
    figures: dict[str, npt.NDArray[np.float64] | None]
    #: the summary.csv columns of the recorded latency (``RECORDED_COLUMNS``)
    summary: dict[str, Any]

    @property
    def note(self) -> str:
        """summary.csv's ``recorded_latency_note``: why a figure is not reported ('' if none)."""
        return str(self.summary.get('recorded_latency_note') or '')


def recorded_series(
    backend: str, topic: str, records: Sequence[FrameRecord], *, seed: int = 0
) -> RecordedSeries | None:
    """The recorded latencies of one (backend, topic)'s frame records; None when it replays
    (its frames are timed, it has no recorded outputs)."""
    summary = recorded_summary(backend, topic, records, seed=seed)
    if summary is None:
        return None
    # the first pass: more passes would only repeat the same recorded latencies
    ordered = sorted(first_pass(records), key=lambda r: (r.log_time_ns, r.input, r.seq))
    times = [recorded_times(r.log_time_ns, r.stamp_ns, r.output_log_time_ns) for r in ordered]
    figures: dict[str, npt.NDArray[np.float64] | None] = {}
    for figure in RECORDED_FIGURES:
        if summary.get(f'{figure}_p50') is None:
            figures[figure] = None  # refused (or no output matched)
            continue
        values = [v for t in times if (v := getattr(t, figure)) is not None]
        figures[figure] = np.asarray([written(v, figure) for v in values], dtype=np.float64)
    outputs = sum(t.output_log_time_ns is not None for t in times)
    return RecordedSeries(outputs, figures, summary)


def _value(
    metric: str, series: RecordedSeries | None
) -> tuple[npt.NDArray[np.float64] | None, float | None]:
    if series is None:
        return None, None
    figure, stat, _ = _SOURCE[metric]
    values = series.figures.get(figure)
    if values is None or not values.size:
        return None, None
    return values, point_value(stat, values)


def recorded_metric_parts(
    metric: str,
    own: RecordedSeries | None,
    base: RecordedSeries | None,
    *,
    paired: bool,
    confidence: float,
) -> MetricComparison:
    """One recorded metric of a row (``own``) against its baseline row (``base``; ``paired``:
    the row is a candidate). The baseline's value is given for a candidate even when the row
    itself has none (a replayed backend against a recording: the two latencies side by side);
    a ratio and its interval only when both have the figure."""
    _, stat, column = _SOURCE[metric]
    mine, value = _value(metric, own)
    value_ci = None
    if own is not None and value is not None:
        low, high = own.summary.get(f'{column}_ci_low'), own.summary.get(f'{column}_ci_high')
        if low is not None and high is not None:
            value_ci = (float(low), float(high))
    if not paired:
        return MetricComparison(metric, value, value_ci)
    theirs, base_value = _value(metric, base)
    if mine is None or theirs is None or value is None or base_value is None:
        return MetricComparison(metric, value, value_ci, baseline=base_value)
    change = change_interval(stat, theirs, mine, confidence=confidence)
    ratio = value / base_value if base_value > 0 else None
    return MetricComparison(
        metric,
        value,
        value_ci,
        baseline=base_value,
        ratio=ratio,
        ratio_ci=change.ratio_ci if ratio is not None else None,
        diff=value - base_value,
        diff_ci=change.diff_ci,
        typical_ratio=change.ratio,
        typical_diff=change.diff,
        method=change.method,
        blocks=change.blocks,
    )
