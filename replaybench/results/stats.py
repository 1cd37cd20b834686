"""Per (backend, topic) statistics over frame records, as summary rows (``SummaryRow``).

Only measured frames (status ``ok`` and not warm-up) enter latency, jitter, throughput,
detection and stage statistics; warm-up, dropped and skipped frames are only counted.

``summarize`` leaves the accuracy, the resource use, the 95 % intervals and the warnings
empty: the engine adds the first two, and ``replaybench.results.intervals`` fills in the others
(``with_intervals``), since they cost a bootstrap.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.results.columns import (
    ACCURACY_COLUMNS,
    INTERVAL_COLUMNS,
    RESOURCE_COLUMNS,
    SUMMARY_CSV_COLUMNS,
)
from replaybench.results.model import RepeatStats, SummaryRow
from replaybench.results.records import written
from replaybench.results.repeats import by_repeat, pooled_throughput

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from replaybench.results.records import FrameRecord

__all__ = [
    'ACCURACY_COLUMNS',
    'INTERVAL_COLUMNS',
    'PERCENTILES',
    'RESOURCE_COLUMNS',
    'SUMMARY_CSV_COLUMNS',
    'Summary',
    'repeat_statistics',
    'summarize',
    'summary_json',
    'summary_row',
    'task_metric_columns',
]

#: One (backend, topic) of a run: the summary row run.json and summary.csv hold; the one type
#: the statistics, the engine, the report and the comparison pass around.
Summary = SummaryRow

#: Latency percentiles reported, computed with numpy's 'linear' method.
PERCENTILES: tuple[int, ...] = (50, 90, 95, 99)

_STAGES: tuple[str, ...] = (
    'queue_wait_ms',
    'read_decode_ms',
    'preprocess_ms',
    'infer_ms',
    'postprocess_ms',
    'h2d_ms',
    'd2h_ms',
)


def _mean(values: Sequence[float | int | None]) -> float | None:
    present = [v for v in values if v is not None]
    if not present:
        return None
    return float(np.mean(np.asarray(present, dtype=np.float64)))


def _replay_order(records: Sequence[FrameRecord]) -> list[FrameRecord]:
    # Stable: frames released at the same instant keep their order in the records; the passes
    # of --repeat one after the other (their times count from their own start)
    return sorted(records, key=lambda r: (r.repeat, r.release_s))


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


def _summary(backend: str, topic: str, records: Sequence[FrameRecord]) -> SummaryRow:
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
    return SummaryRow(
        backend=backend,
        topic=topic,
        frames=len(records),
        processed=len(processed),
        measured=len(measured),
        warmup=sum(1 for r in records if r.warmup),
        dropped=sum(1 for r in records if r.status == 'dropped'),
        skipped=sum(1 for r in records if r.status == 'skipped'),
        throughput_fps=pooled_throughput(ordered, measured, _throughput),
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


def summarize(records: Sequence[FrameRecord]) -> list[SummaryRow]:
    """One ``SummaryRow`` per (backend, topic).

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


def repeat_statistics(records: Sequence[FrameRecord]) -> tuple[RepeatStats, ...]:
    """``run --repeat N``: the statistics of each pass (``RepeatStats``) per (backend, topic),
    in record order of the (backend, topic) and then by repeat: the measured frames, median,
    p99 and mean latency, throughput and its window."""
    out: list[RepeatStats] = []
    keys: dict[tuple[str, str], list[FrameRecord]] = {}
    for record in records:
        keys.setdefault((record.backend, record.topic), []).append(record)
    for (backend, topic), group in keys.items():
        for number, part in by_repeat(group).items():
            (s,) = summarize(part)
            fps = s.throughput_fps
            out.append(
                RepeatStats(
                    backend=backend,
                    topic=topic,
                    repeat=number,
                    measured=s.measured,
                    latency_ms_p50=s.latency_ms_p50,
                    latency_ms_p99=s.latency_ms_p99,
                    latency_ms_mean=s.latency_ms_mean,
                    throughput_fps=fps,
                    window_s=s.measured / fps if fps else None,
                )
            )
    return tuple(out)


def summary_row(summary: SummaryRow) -> dict[str, Any]:
    """Flat dict of one summary.csv row; accuracy keys are None when there is no accuracy;
    ``warnings`` joined by ``'; '`` ('' when there is none); then the row's ``task_metrics``
    (the metrics of tasks without fields of their own), by metric name."""
    row = {name: getattr(summary, name) for name in SUMMARY_CSV_COLUMNS}
    row['warnings'] = '; '.join(summary.warnings)
    row.update(summary.task_metrics or {})
    return row


def task_metric_columns(summaries: Iterable[SummaryRow]) -> tuple[str, ...]:
    """The columns summary.csv writes after ``SUMMARY_CSV_COLUMNS``: the names in the rows'
    ``task_metrics``, in the order they first appear (row order, then each row's own)."""
    names: dict[str, None] = {}
    for summary in summaries:
        names.update(dict.fromkeys(summary.task_metrics or {}))
    return tuple(names)


def summary_json(summary: SummaryRow) -> dict[str, Any]:
    """One run.json ``summary`` entry: the summary.csv columns with ``warnings`` as a list, and
    each task's full summary (the fields holding one: ``accuracy``, ``segmentation``,
    ``tag_accuracy``) as a dict."""
    row = {name: getattr(summary, name) for name in SUMMARY_CSV_COLUMNS}
    row['warnings'] = list(summary.warnings)
    for name in _TASK_SUMMARIES:
        found = getattr(summary, name)
        row[name] = dataclasses.asdict(found) if found is not None else None
    return row


#: The fields of ``SummaryRow`` that hold a task's full summary (a dataclass), in field order.
_TASK_SUMMARIES: tuple[str, ...] = tuple(
    name
    for name, hint in typing.get_type_hints(SummaryRow).items()
    if any(dataclasses.is_dataclass(arm) for arm in typing.get_args(hint))
)
