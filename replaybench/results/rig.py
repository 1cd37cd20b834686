"""A rig's rows: one summary row per backend over all its camera topics (topic ``rig``), and
run.json's ``rig`` section.

A run has a rig where an input replays more than one camera topic, whether its backends serve
them with one instance (``--pipelines shared``) or one per camera (``per-topic``): the
question "does the machine keep up with the rig" is asked of both. The rig row of a backend
holds its cameras' frames, processed, measured, warm-up, dropped and skipped frames (the sums
of its camera rows), the latency statistics and stage means over all its cameras' measured
frames, and the throughput of all of them over the union of the cameras' windows (from the
earliest camera's window start to the last measured frame's completion; the passes of
``--repeat`` each a window of their own, added up). It has no intervals, no jitter (the
cameras' frames interleave: no one series) and no task figures (accuracy stays per camera);
the resource use is the backend's, as on its camera rows.

Everything that adds summary rows up (the run's counts, the sweep, compare's pairing, the
report's tables, the gate) keeps the rig row apart (``is_rig``), so that no frame counts twice.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from replaybench.results.model import RigBackend, RigCamera, RigReport, SummaryRow, WorstCamera
from replaybench.results.model.summary import RIG_TOPIC
from replaybench.results.records import written

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from replaybench.results.records import FrameRecord

__all__ = [
    'RIG_TOPIC',
    'is_rig',
    'rig_groups',
    'rig_report',
    'rig_summary',
    'with_rig_rows',
]


def is_rig(row: SummaryRow) -> bool:
    """Whether ``row`` is a rig row (all of a backend's cameras), not one camera's."""
    return row.topic == RIG_TOPIC


def rig_groups(records: Sequence[FrameRecord]) -> dict[str, list[FrameRecord]]:
    """Each backend's records, for the backends of a run with a rig (an input replaying more
    than one camera topic) that replayed more than one topic; empty for any other run. In
    record order, by the backend's first record."""
    topics: dict[int, set[str]] = {}
    for record in records:
        topics.setdefault(record.input, set()).add(record.topic)
    if not any(len(found) > 1 for found in topics.values()):
        return {}
    groups: dict[str, list[FrameRecord]] = {}
    for record in records:
        groups.setdefault(record.backend, []).append(record)
    return {
        backend: group for backend, group in groups.items() if len({r.topic for r in group}) > 1
    }


def _window(records: Sequence[FrameRecord]) -> tuple[float, float] | None:
    """One camera's (one pass's) measured window, as its row's throughput takes it: from the
    completion of the processed frame before its first measured one (else that frame's start)
    to its last measured completion."""
    ordered = sorted(records, key=lambda r: r.release_s)
    measured = [r for r in ordered if r.status == 'ok' and not r.warmup and r.done_s is not None]
    if not measured:
        return None
    start = measured[0].start_s
    for record in ordered:
        if record is measured[0]:
            break
        if record.status == 'ok' and record.done_s is not None:
            start = record.done_s
    if start is None:
        return None
    end = max(written(r.done_s, 'done_s') for r in measured if r.done_s is not None)
    return written(start, 'done_s'), end


def _union_throughput(records: Sequence[FrameRecord]) -> float | None:
    """All cameras' measured frames over the union of their windows, pass by pass (each
    input's pass and each pass of ``--repeat`` times its frames from its own start)."""
    frames = 0
    window = 0.0
    passes: dict[tuple[int, int], list[FrameRecord]] = {}
    for record in records:
        passes.setdefault((record.repeat, record.input), []).append(record)
    for group in passes.values():
        cameras: dict[str, list[FrameRecord]] = {}
        for record in group:
            cameras.setdefault(record.topic, []).append(record)
        found = [w for w in map(_window, cameras.values()) if w is not None]
        if not found:
            continue
        span = max(end for _, end in found) - min(start for start, _ in found)
        if not span > 0:
            return None
        frames += sum(1 for r in group if r.status == 'ok' and not r.warmup)
        window += span
    return frames / window if window > 0 else None


def rig_summary(records: Sequence[FrameRecord], cameras: Sequence[SummaryRow]) -> SummaryRow:
    """A backend's rig row from its records (every camera's) and its camera rows."""
    from replaybench.results.stats import summarize

    pooled = [r._replace(topic=RIG_TOPIC) for r in records]
    (row,) = summarize(pooled)
    first = cameras[0] if cameras else SummaryRow()
    return dataclasses.replace(
        row,
        throughput_fps=_union_throughput(records),
        jitter_ms=None,
        cpu_percent_mean=first.cpu_percent_mean,
        private_mb_peak=first.private_mb_peak,
        mapped_mb_peak=first.mapped_mb_peak,
        rss_mb_peak=first.rss_mb_peak,
        gpu_util_mean=first.gpu_util_mean,
        gpu_mem_mb_peak=first.gpu_mem_mb_peak,
        gpu_power_w_mean=first.gpu_power_w_mean,
    )


def with_rig_rows(rows: Sequence[SummaryRow], records: Sequence[FrameRecord]) -> list[SummaryRow]:
    """``rows`` (the camera rows) with each rig backend's rig row after its camera rows."""
    groups = rig_groups(records)
    out: list[SummaryRow] = []
    for index, row in enumerate(rows):
        out.append(row)
        last = index + 1 == len(rows) or rows[index + 1].backend != row.backend
        if last and row.backend in groups:
            mine = [r for r in rows if r.backend == row.backend]
            out.append(rig_summary(groups[row.backend], mine))
    return out


def _drop_rate(row: SummaryRow) -> float | None:
    return row.dropped / row.frames if row.frames else None


def _worst(cameras: Iterable[tuple[str, float | None]]) -> WorstCamera | None:
    """The camera with the highest value (the first of equals); None where none has one."""
    best: WorstCamera | None = None
    for topic, value in cameras:
        if value is not None and (best is None or value > best.value):
            best = WorstCamera(topic, value)
    return best


def rig_report(
    rows: Sequence[SummaryRow],
    records: Sequence[FrameRecord],
    *,
    mode: str,
    cores: int,
    threads: int | None,
) -> RigReport | None:
    """run.json's ``rig`` section from the summary rows (with their rig rows) and the records
    (each camera's pipeline); None for a run without a rig."""
    rigs = {row.backend: row for row in rows if is_rig(row)}
    if not rigs:
        return None
    pipelines: dict[tuple[str, str], int] = {}
    for record in records:
        pipelines.setdefault((record.backend, record.topic), record.pipeline)
    backends = []
    for backend, rig in rigs.items():
        cameras = [r for r in rows if r.backend == backend and not is_rig(r)]
        served = [pipelines.get((backend, c.topic), 0) for c in cameras]
        backends.append(
            RigBackend(
                backend=backend,
                cameras=tuple(RigCamera(c.topic, p) for c, p in zip(cameras, served, strict=True)),
                pipelines=len(set(served)),
                frames=rig.frames,
                dropped=rig.dropped,
                drop_rate=_drop_rate(rig),
                latency_ms_p99=rig.latency_ms_p99,
                throughput_fps=rig.throughput_fps,
                worst_p99=_worst((c.topic, c.latency_ms_p99) for c in cameras),
                worst_drop_rate=_worst((c.topic, rate) for c in cameras if (rate := _drop_rate(c))),
            )
        )
    return RigReport(mode=mode, cores=cores, threads_per_pipeline=threads, backends=tuple(backends))
