"""Per (backend, topic) statistics over frame records.

Only measured frames (status ``ok`` and not warm-up) enter latency, jitter, throughput,
detection and stage statistics; warm-up, dropped and skipped frames are only counted.

``summarize`` leaves the 95 % intervals and the warnings empty: ``replaybench.results.intervals``
fills them in (``with_intervals``), since they cost a bootstrap.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.results.records import written
from replaybench.results.tags import TAG_SUMMARY_COLUMNS
from replaybench.results.tags import summary_columns as tag_summary_columns

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.records import FrameRecord

__all__ = [
    'ACCURACY_COLUMNS',
    'INTERVAL_COLUMNS',
    'PERCENTILES',
    'RESOURCE_COLUMNS',
    'SUMMARY_CSV_COLUMNS',
    'Summary',
    'summarize',
    'summary_json',
    'summary_row',
]

#: Latency percentiles reported, computed with numpy's 'linear' method.
PERCENTILES: tuple[int, ...] = (50, 90, 95, 99)

#: Accuracy keys flattened into summary.csv columns.
ACCURACY_COLUMNS: tuple[str, ...] = ('precision50', 'recall50', 'map50', 'map50_95')

_STAGES: tuple[str, ...] = (
    'queue_wait_ms',
    'read_decode_ms',
    'preprocess_ms',
    'infer_ms',
    'postprocess_ms',
    'h2d_ms',
    'd2h_ms',
)


@dataclass(frozen=True, slots=True)
class Summary:
    """Statistics of one (backend, topic); see docs/outputs.md for the definitions."""

    backend: str
    topic: str
    frames: int
    processed: int
    measured: int
    warmup: int
    dropped: int
    skipped: int
    throughput_fps: float | None
    latency_ms_mean: float | None
    latency_ms_std: float | None
    latency_ms_min: float | None
    latency_ms_p50: float | None
    latency_ms_p90: float | None
    latency_ms_p95: float | None
    latency_ms_p99: float | None
    latency_ms_max: float | None
    jitter_ms: float | None
    detections_per_frame: float | None
    queue_wait_ms_mean: float | None
    read_decode_ms_mean: float | None
    preprocess_ms_mean: float | None
    infer_ms_mean: float | None
    postprocess_ms_mean: float | None
    h2d_ms_mean: float | None
    d2h_ms_mean: float | None
    accuracy: dict[str, Any] | None = None
    resources: dict[str, Any] | None = None
    # 95 % block-bootstrap intervals (None below MIN_FRAMES measured frames) and warnings,
    # filled in by replaybench.results.intervals.with_intervals
    latency_ms_p50_ci_low: float | None = None
    latency_ms_p50_ci_high: float | None = None
    latency_ms_p99_ci_low: float | None = None
    latency_ms_p99_ci_high: float | None = None
    throughput_fps_ci_low: float | None = None
    throughput_fps_ci_high: float | None = None
    warnings: tuple[str, ...] = ()
    # tag backends against tag ground truth (replaybench.results.tags.TagAccuracy.document)
    tag_accuracy: dict[str, Any] | None = None


#: Interval columns of summary.csv (after the resource columns, before ``warnings``).
INTERVAL_COLUMNS: tuple[str, ...] = (
    'latency_ms_p50_ci_low',
    'latency_ms_p50_ci_high',
    'latency_ms_p99_ci_low',
    'latency_ms_p99_ci_high',
    'throughput_fps_ci_low',
    'throughput_fps_ci_high',
)

_FLAT_FIELDS: tuple[str, ...] = tuple(
    f.name
    for f in fields(Summary)
    if f.name not in {'accuracy', 'resources', 'warnings', 'tag_accuracy', *INTERVAL_COLUMNS}
)

#: Resource-use columns of summary.csv (from the backend's ResourceSampler summary).
RESOURCE_COLUMNS: tuple[str, ...] = (
    'cpu_percent_mean',
    'private_mb_peak',
    'mapped_mb_peak',
    'rss_mb_peak',
    'gpu_util_mean',
    'gpu_mem_mb_peak',
    'gpu_power_w_mean',
)

#: Columns of summary.csv, in order (later additions at the end, so older readers keep working).
SUMMARY_CSV_COLUMNS: tuple[str, ...] = (
    _FLAT_FIELDS
    + ACCURACY_COLUMNS
    + RESOURCE_COLUMNS
    + INTERVAL_COLUMNS
    + ('warnings',)
    + TAG_SUMMARY_COLUMNS
)


def _mean(values: Sequence[float | int | None]) -> float | None:
    present = [v for v in values if v is not None]
    if not present:
        return None
    return float(np.mean(np.asarray(present, dtype=np.float64)))


def _replay_order(records: Sequence[FrameRecord]) -> list[FrameRecord]:
    # Stable: frames released at the same instant keep their order in the records.
    return sorted(records, key=lambda r: r.release_s)


def _throughput(ordered: Sequence[FrameRecord], measured: Sequence[FrameRecord]) -> float | None:
    if not measured:
        return None
    first = measured[0]
    start: float | None = None
    previous = None
    for record in ordered:
        if record is first:
            break
        if record.status == 'ok':
            previous = record
    if previous is not None and previous.done_s is not None:
        start = previous.done_s
    else:
        start = first.start_s
    ends = [written(r.done_s, 'done_s') for r in measured if r.done_s is not None]
    if start is None or not ends:
        return None
    window = max(ends) - written(start, 'done_s')
    if not window > 0:
        return None
    return len(measured) / window


def _summary(backend: str, topic: str, records: Sequence[FrameRecord]) -> Summary:
    ordered = _replay_order(records)
    processed = [r for r in ordered if r.status == 'ok']
    measured = [r for r in processed if not r.warmup]
    # as frames.csv holds them (0.1 µs): summary.csv follows from frames.csv, and from the same
    # values as the intervals around it (replaybench.results.intervals.measured_series)
    latencies = np.asarray(
        [written(r.latency_ms, 'latency_ms') for r in measured if r.latency_ms is not None],
        dtype=np.float64,
    )
    lat: dict[str, float | None] = dict.fromkeys(
        ('mean', 'std', 'min', 'max', *(f'p{q}' for q in PERCENTILES)),
    )
    jitter = None
    if latencies.size:
        lat['mean'] = float(latencies.mean())
        lat['std'] = float(latencies.std(ddof=0))
        lat['min'] = float(latencies.min())
        lat['max'] = float(latencies.max())
        values = np.percentile(latencies, PERCENTILES, method='linear')
        for q, value in zip(PERCENTILES, values, strict=True):
            lat[f'p{q}'] = float(value)
        if latencies.size >= 2:
            jitter = float(np.mean(np.abs(np.diff(latencies))))
    stage_means = {name: _mean([getattr(r, name) for r in measured]) for name in _STAGES}
    return Summary(
        backend=backend,
        topic=topic,
        frames=len(records),
        processed=len(processed),
        measured=len(measured),
        warmup=sum(1 for r in records if r.warmup),
        dropped=sum(1 for r in records if r.status == 'dropped'),
        skipped=sum(1 for r in records if r.status == 'skipped'),
        throughput_fps=_throughput(ordered, measured),
        latency_ms_mean=lat['mean'],
        latency_ms_std=lat['std'],
        latency_ms_min=lat['min'],
        latency_ms_p50=lat['p50'],
        latency_ms_p90=lat['p90'],
        latency_ms_p95=lat['p95'],
        latency_ms_p99=lat['p99'],
        latency_ms_max=lat['max'],
        jitter_ms=jitter,
        detections_per_frame=_mean([r.detections for r in measured]),
        queue_wait_ms_mean=stage_means['queue_wait_ms'],
        read_decode_ms_mean=stage_means['read_decode_ms'],
        preprocess_ms_mean=stage_means['preprocess_ms'],
        infer_ms_mean=stage_means['infer_ms'],
        postprocess_ms_mean=stage_means['postprocess_ms'],
        h2d_ms_mean=stage_means['h2d_ms'],
        d2h_ms_mean=stage_means['d2h_ms'],
    )


def summarize(records: Sequence[FrameRecord]) -> list[Summary]:
    """One ``Summary`` per (backend, topic).

    Ordered by the first appearance of the backend in ``records``, then by the first appearance
    of the topic.
    """
    backend_order: dict[str, int] = {}
    topic_order: dict[str, int] = {}
    groups: dict[tuple[str, str], list[FrameRecord]] = {}
    for record in records:
        backend_order.setdefault(record.backend, len(backend_order))
        topic_order.setdefault(record.topic, len(topic_order))
        groups.setdefault((record.backend, record.topic), []).append(record)
    keys = sorted(groups, key=lambda k: (backend_order[k[0]], topic_order[k[1]]))
    return [_summary(backend, topic, groups[backend, topic]) for backend, topic in keys]


def _flat(summary: Summary) -> dict[str, Any]:
    row: dict[str, Any] = {name: getattr(summary, name) for name in _FLAT_FIELDS}
    accuracy = summary.accuracy or {}
    for name in ACCURACY_COLUMNS:
        row[name] = accuracy.get(name)
    resources = summary.resources or {}
    for name in RESOURCE_COLUMNS:
        row[name] = resources.get(name)
    for name in INTERVAL_COLUMNS:
        row[name] = getattr(summary, name)
    row['warnings'] = None  # set by the callers; here it keeps its place before the tag columns
    row.update(tag_summary_columns(summary.tag_accuracy))
    return row


def summary_row(summary: Summary) -> dict[str, Any]:
    """Flat dict of one summary.csv row; accuracy keys are None when there is no accuracy;
    ``warnings`` joined by ``'; '`` ('' when there is none)."""
    row = _flat(summary)
    row['warnings'] = '; '.join(summary.warnings)
    return row


def summary_json(summary: Summary) -> dict[str, Any]:
    """One run.json ``summary`` entry: the summary.csv columns with ``warnings`` as a list, and
    the full ``accuracy`` dict."""
    row = _flat(summary)
    row['warnings'] = list(summary.warnings)
    row['accuracy'] = dict(summary.accuracy) if summary.accuracy is not None else None
    row['tag_accuracy'] = dict(summary.tag_accuracy) if summary.tag_accuracy is not None else None
    return row
