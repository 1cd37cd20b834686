"""What a sweep records: each cell's figures, the conditions it was measured under, the flags of
cells unlike the others, sweep.csv's rows and the ``SweepResult`` handed back.

A finished cell becomes one ``SweepCell`` (``replaybench.results.sweepfile``) once, in memory;
sweep.csv grows by one row per finished cell while the sweep runs (``CsvLog``) and is written
again in cell order at the end, with sweep.json and sweep.html.
"""

from __future__ import annotations

import bisect
import csv
import io
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench.tasks import all_metrics

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence
    from pathlib import Path

    import pandas as pd

    from replaybench.results.model import RunResult, SummaryRow
    from replaybench.results.records import FrameRecord
    from replaybench.results.sweepfile import CellConditions, CellMetrics, SweepCell, SweepRecord
    from replaybench.tasks import MetricSpec

__all__ = [
    'CSV_COLUMNS',
    'SWEEP_METRICS',
    'CsvLog',
    'NodeSpans',
    'SweepProgress',
    'SweepResult',
    'cell_metrics',
    'conditions',
    'csv_columns',
    'csv_row',
    'csv_rows',
    'csv_text',
    'flagged',
    'metric_value',
    'sweep_metrics',
]


def sweep_metrics() -> tuple[MetricSpec, ...]:
    """The registered tasks' metrics a sweep shows (``MetricSpec.sweep``), the ones not
    ``appended`` first: the mean over a cell's topics, a value of ``CellMetrics.values`` and a
    column of sweep.csv each. Read from the registry each time, so that a task from an entry
    point counts (``TaskUnavailableError`` for one that cannot be loaded)."""
    shown = sorted(all_metrics(), key=lambda m: m.appended)
    return tuple(m for m in shown if m.sweep and m.accuracy)


def metric_value(row: SummaryRow, spec: MetricSpec) -> float | None:
    """``row``'s value of the metric ``spec`` (``SummaryRow.metric``); None where the row has
    none (a row of another task's backend)."""
    return row.metric(spec.name)


_BEFORE_METRICS: tuple[str, ...] = (
    'cell',
    'input',
    'backend',
    'params',
    'status',
    'frames',
    'fps',
    'fps_low',
    'fps_high',
    'p50_ms',
    'p50_low',
    'p50_high',
    'p99_ms',
    'p99_low',
    'p99_high',
)
_AFTER_METRICS: tuple[str, ...] = (
    'node',
    'gpu',
    'concurrency',
    'flags',
    'error',
    'run_dir',
    'key',
)


def csv_columns() -> tuple[str, ...]:
    """sweep.csv's columns, in order: the cell, its timings, each of ``sweep_metrics`` by name,
    where it ran; ``SweepResult.cells`` has the same columns."""
    return (*_BEFORE_METRICS, *(m.name for m in sweep_metrics()), *_AFTER_METRICS)


if TYPE_CHECKING:
    #: ``csv_columns()`` and the names of ``sweep_metrics()``, read when asked for
    CSV_COLUMNS: tuple[str, ...]
    SWEEP_METRICS: tuple[str, ...]
else:

    def __getattr__(name: str) -> tuple[str, ...]:
        if name == 'CSV_COLUMNS':
            return csv_columns()
        if name == 'SWEEP_METRICS':
            return tuple(m.name for m in sweep_metrics())
        msg = f'module {__name__!r} has no attribute {name!r}'
        raise AttributeError(msg)


class SweepProgress(NamedTuple):
    """Cells finished (complete or failed), running and failed, out of ``total``."""

    done: int
    running: int
    failed: int
    total: int


@dataclass(frozen=True, eq=False)
class SweepResult:
    """What a sweep left in ``out``: its status, sweep.json (``record``, the typed model, and
    ``document``, the JSON written) and the cells table."""

    out: Path
    status: str  # 'complete' | 'failed' | 'interrupted'
    sweep: SweepRecord = field(repr=False)
    #: sweep.json as written (a JSON object)
    record: dict[str, Any] = field(repr=False)
    #: sweep.csv's rows, one mapping per cell keyed by ``csv_columns()``
    cell_rows: tuple[Mapping[str, Any], ...] = field(repr=False)

    @property
    def cells(self) -> pd.DataFrame:
        """sweep.csv as a pandas DataFrame (``pip install 'replaybench[pandas]'``)."""
        from replaybench.results.tables import records_table

        return records_table(self.cell_rows, csv_columns())

    @property
    def exit_code(self) -> int:
        """0 complete, 1 a cell failed, 130 interrupted."""
        return {'complete': 0, 'failed': 1}.get(self.status, 130)


def _interval(values: Any) -> tuple[float, float] | None:
    from replaybench.results.bootstrap import percentile_interval

    if values is None:
        return None
    found = percentile_interval(values)
    return (float(found[0]), float(found[1])) if found is not None else None


def cell_metrics(run: RunResult, records: Sequence[FrameRecord], key: str) -> CellMetrics:
    """Frames, FPS, p50 and p99 latency with 95 % block-bootstrap intervals over all the cell's
    measured frames (every topic together), and each of ``sweep_metrics()`` (the built-in tasks'
    mAP@0.5, mIoU, tag recall and rotation error: the mean over the topics that have it, read
    by ``metric_value``; None where none has). ``records``: frames.csv's rows as written
    (``as_written``)."""
    import numpy as np

    from replaybench.results.bootstrap import replicates
    from replaybench.results.intervals import measured_series
    from replaybench.results.stats import summarize
    from replaybench.results.sweepfile import CellMetrics

    rows = run.summary_rows
    if len(rows) == 1:  # one topic: the run's own figures (frames.csv rounds its times)
        only = rows[0]
        frames, fps = only.measured, only.throughput_fps
        p50, p99 = only.latency_ms_p50, only.latency_ms_p99
    else:
        pooled = summarize([r._replace(topic='*') for r in records])
        summary = pooled[0] if pooled else None
        frames = summary.measured if summary else 0
        fps = summary.throughput_fps if summary else None
        p50 = summary.latency_ms_p50 if summary else None
        p99 = summary.latency_ms_p99 if summary else None
    series = measured_series(records)  # every topic together, in replay order
    reps = replicates(*series, rng=np.random.default_rng(int(key[:16], 16)))

    def mean_of(spec: MetricSpec) -> float | None:
        # a task's accuracy over the cell's topics that have it
        values = [v for row in rows if (v := metric_value(row, spec)) is not None]
        return float(np.mean(values)) if values else None

    return CellMetrics(
        frames=frames,
        fps=fps,
        fps_ci=_interval(reps.fps) if reps is not None else None,
        p50_ms=p50,
        p50_ci=_interval(reps.p50) if reps is not None else None,
        p99_ms=p99,
        p99_ci=_interval(reps.p99) if reps is not None else None,
        topics=len({r.topic for r in records}),
        values={spec.name: mean_of(spec) for spec in sweep_metrics()},
    )


def conditions(run: RunResult, gpu: bool) -> CellConditions:
    """The CPU, GPU, placement and concurrency a complete cell's run.json records."""
    from replaybench.results.sweepfile import CellConditions

    env = run.environment
    cpu = env.cpu
    section = run.sweep or {}
    gpus = env.gpus
    gpu_name = None
    if gpu and gpus:
        ids = section.get('gpu_ids') or []
        at = int(ids[0]) if ids and str(ids[0]).isdigit() and int(ids[0]) < len(gpus) else 0
        gpu_name = gpus[at].name  # the GPU Ray gave the cell, in nvidia-smi's order
    concurrency = section.get('concurrency') or {}
    return CellConditions(
        cpu=f'{cpu.model} x{cpu.logical_cores}',
        gpu=gpu_name,
        placement=section.get('placement'),
        max_cells_on_node=concurrency.get('max_cells_on_node'),
    )


def flagged(cells: Sequence[SweepCell]) -> list[SweepCell]:
    """``cells`` with the flags of complete cells measured under conditions unlike the others'."""
    done = [c.conditions for c in cells if c.status == 'complete' and c.conditions is not None]
    cpus = Counter(c.cpu for c in done)
    gpus = Counter(c.gpu for c in done if c.gpu)
    usual_cpu = cpus.most_common(1)[0][0] if cpus else None
    usual_gpu = gpus.most_common(1)[0][0] if gpus else None
    out = []
    for cell in cells:
        c = cell.conditions
        if cell.status != 'complete' or c is None:
            out.append(cell)
            continue
        flags: list[str] = []
        shared = c.max_cells_on_node
        if isinstance(shared, int) and shared > 1:
            flags.append(f'shared its node with {shared - 1} other cell(s)')
        if c.placement == 'packed':
            flags.append('packed placement: timings not comparable')
        if len(cpus) > 1 and c.cpu != usual_cpu:
            flags.append(f'other CPU: {c.cpu} (most cells: {usual_cpu})')
        if len(gpus) > 1 and c.gpu and c.gpu != usual_gpu:
            flags.append(f'other GPU: {c.gpu} (most cells: {usual_gpu})')
        out.append(replace(cell, flags=tuple(flags)))
    return out


class NodeSpans:
    """The (start, end) times of the cells each node ran, and for each cell the cells that ran
    beside it on its node: kept as cells finish, sorted by end, so that a finished cell costs
    the cells that overlap it, not every cell of the node."""

    def __init__(self) -> None:
        self._ends: dict[str | None, list[tuple[float, float, int]]] = {}
        self._spans: dict[int, tuple[float, float]] = {}
        self._beside: dict[int, list[int]] = {}

    def add(self, index: int, node: str | None, span: tuple[float, float]) -> None:
        """Cell ``index`` ran on ``node`` during ``span`` (it has just finished)."""
        start, end = span
        ends = self._ends.setdefault(node, [])
        first = bisect.bisect_right(ends, (start, float('inf'), -1))
        beside = [i for _, s, i in ends[first:] if s < end]  # they ended after it started
        self._beside[index] = beside
        for other in beside:
            self._beside[other].append(index)
        self._spans[index] = span
        bisect.insort(ends, (end, start, index))

    def max_overlap(self, index: int) -> int:
        """Most cells running at once during cell ``index``'s span (itself included)."""
        start, end = self._spans[index]
        events: list[tuple[float, int]] = []
        for other in self._beside.get(index, []):
            s, e = self._spans[other]
            events += [(max(s, start), 1), (min(e, end), -1)]
        best = running = 1
        for _, step in sorted(events, key=lambda ev: (ev[0], ev[1])):
            running += step
            best = max(best, running)
        return best


def csv_row(cell: SweepCell, metrics: Sequence[MetricSpec] | None = None) -> dict[str, Any]:
    """sweep.csv's row of one cell, keyed by ``csv_columns()``; ``metrics``: the sweep's
    (``sweep_metrics()`` when not given). A metric the cell has no value of is None."""
    m = cell.metrics
    shown = sweep_metrics() if metrics is None else metrics

    def ci(found: tuple[float, float] | None, side: int) -> float | None:
        return found[side] if found else None

    return {
        'cell': cell.cell,
        'input': cell.input,
        'backend': cell.backend,
        'params': ' '.join(f'{k}={v}' for k, v in cell.params.items()),
        'status': cell.status,
        'frames': m.frames if m else None,
        'fps': m.fps if m else None,
        'fps_low': ci(m.fps_ci, 0) if m else None,
        'fps_high': ci(m.fps_ci, 1) if m else None,
        'p50_ms': m.p50_ms if m else None,
        'p50_low': ci(m.p50_ci, 0) if m else None,
        'p50_high': ci(m.p50_ci, 1) if m else None,
        'p99_ms': m.p99_ms if m else None,
        'p99_low': ci(m.p99_ci, 0) if m else None,
        'p99_high': ci(m.p99_ci, 1) if m else None,
        **{spec.name: m.value(spec.name) if m else None for spec in shown},
        'node': cell.hostname or cell.node_id,
        'gpu': ','.join(cell.gpu_ids),
        'concurrency': cell.concurrency.max_cells_on_node if cell.concurrency else None,
        'flags': '; '.join(cell.flags),
        'error': cell.error,
        'run_dir': cell.run_dir,
        'key': cell.key,
    }


def csv_rows(cells: Iterable[SweepCell]) -> list[dict[str, Any]]:
    """One row per cell, with the ``csv_columns()``."""
    shown = sweep_metrics()
    return [csv_row(c, shown) for c in cells]


def _line(row: Mapping[str, Any], columns: Sequence[str]) -> str:
    buffer = io.StringIO()
    csv.writer(buffer).writerow(['' if row[c] is None else row[c] for c in columns])
    return buffer.getvalue()


def csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    """sweep.csv: the header, then ``rows``."""
    columns = csv_columns()
    return _line({c: c for c in columns}, columns) + ''.join(_line(r, columns) for r in rows)


class CsvLog:
    """sweep.csv while the sweep runs: the header, then one row appended per finished cell
    (in the order they finish); the driver writes it again in cell order at the end."""

    def __init__(self, path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
        from replaybench.results.atomic import write_text_atomic

        self.path = path
        self.columns = csv_columns()
        write_text_atomic(path, csv_text(rows))

    def append(self, row: Mapping[str, Any]) -> None:
        with self.path.open('a', encoding='utf-8', newline='') as f:
            f.write(_line(row, self.columns))
