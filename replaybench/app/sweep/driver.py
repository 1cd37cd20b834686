"""The driver: resume, submit the cells to Ray, collect them, and write the sweep folder.

The inputs are hashed once, here (``plan.input_identity``). A cell folder whose run.json is
complete and carries the cell's key is kept untouched (resume); its run.json is read once per
invocation, and its figures are taken from the earlier sweep.json when that recorded the same
key. Each finished cell is turned into its ``SweepCell`` once, in memory, and appended to
sweep.csv; sweep.json, sweep.html and sweep.csv (in cell order) are written at the start and at
the end, so a finished cell costs the same however many cells the sweep has.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
import shutil
import sys
import time
from collections import Counter, deque
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from replaybench import _version
from replaybench.app.sweep.engine import Placement, alive_nodes, engine, engine_record, error_line
from replaybench.app.sweep.engine import import_ray as _import_ray
from replaybench.app.sweep.record import (
    CsvLog,
    NodeSpans,
    SweepProgress,
    SweepResult,
    cell_metrics,
    conditions,
    csv_row,
    csv_rows,
    csv_text,
    flagged,
)
from replaybench.errors import SourceError, UsageError

if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Mapping

    from replaybench.app.sweep.plan import Cell, InputId, SweepConfig
    from replaybench.results.model import RunResult
    from replaybench.results.sweepfile import CellMetrics, SweepCell, SweepEngine, SweepRecord

__all__ = ['CELLS_DIR', 'Driver']

CELLS_DIR = 'cells'


def _placement_name(cell: Cell, pack: bool) -> str:
    if cell.gpu:
        return 'gpu'
    return 'packed' if pack else 'node-slot'


def _run_of(data: bytes, where: str) -> RunResult:
    """A run.json's bytes (sent back by a node) as a RunResult."""
    from replaybench.results.io import from_json
    from replaybench.results.model import RunResult

    return from_json(RunResult, json.loads(data), where=where)


class Driver:
    """Plans nothing (the cells are given), resumes, submits, collects and writes OUT."""

    def __init__(
        self,
        config: SweepConfig,
        cells: list[Cell],
        inputs: list[InputId],
        progress: Callable[[SweepProgress], None] | None = None,
        stop: threading.Event | None = None,
    ) -> None:
        self.config = config
        self.out = config.out
        self.cells = cells
        self.inputs = inputs
        self.progress = progress
        self.stop = stop
        self.started = dt.datetime.now(dt.UTC)
        self.t0 = time.perf_counter()
        self.entries: dict[int, SweepCell] = {}
        self.runs: dict[int, RunResult] = {}  # cells run by this invocation, as written
        self.resumed: set[int] = set()
        self.engine: SweepEngine | None = None
        self.spans = NodeSpans()
        self.counts: Counter[str] = Counter()
        self.csv: CsvLog | None = None

    # -- the cells' entries

    def _entry(self, cell: Cell, status: str, **values: Any) -> SweepCell:
        from replaybench.results.sweepfile import SweepCell

        return SweepCell(
            index=cell.index,
            cell=cell.name,
            key=cell.key,
            input=cell.input.given,
            input_index=cell.input_index,
            backend=cell.backend,
            params=dict(cell.params),
            status=status,
            **{'placement': _placement_name(cell, self.config.pack), **values},
        )

    def _set(self, cell: Cell, entry: SweepCell) -> None:
        old = self.entries.get(cell.index)
        if old is not None:
            self.counts[old.status] -= 1
        self.entries[cell.index] = entry
        self.counts[entry.status] += 1

    def _finished(self, cell: Cell, entry: SweepCell) -> None:
        self._set(cell, entry)
        if self.csv is not None:
            self.csv.append(csv_row(entry))

    def _complete_entry(self, cell: Cell, run: RunResult, metrics: CellMetrics) -> SweepCell:
        from replaybench.results.sweepfile import CellConcurrency

        section = run.sweep or {}
        concurrency = section.get('concurrency')
        return self._entry(
            cell,
            'complete',
            resumed=cell.index in self.resumed,
            run_dir=f'{CELLS_DIR}/{cell.name}',
            node_id=section.get('node_id'),
            hostname=section.get('hostname'),
            gpu_ids=tuple(section.get('gpu_ids') or ()),
            placement=section.get('placement') or _placement_name(cell, self.config.pack),
            concurrency=CellConcurrency(**concurrency) if concurrency else None,
            started_at=section.get('started_at'),
            finished_at=section.get('finished_at'),
            metrics=metrics,
            conditions=conditions(run, cell.gpu),
        )

    # -- resume

    def prepare(self) -> list[Cell]:
        """Create OUT, keep the complete cells, return the ones to run."""
        from replaybench.results.sweepfile import read_sweep_result

        out = self.out
        if out.exists() and not out.is_dir():
            msg = f'{out} exists and is not a directory'
            raise UsageError(msg)
        previous = out / 'sweep.json'
        if (
            out.is_dir()
            and any(out.iterdir())
            and not previous.exists()
            and not (out / CELLS_DIR).is_dir()
        ):
            msg = f'output folder {out} is not empty and holds no sweep: choose another --out'
            raise UsageError(msg)
        (out / CELLS_DIR).mkdir(parents=True, exist_ok=True)
        for stale in (out / CELLS_DIR).glob('.*.partial-*'):
            shutil.rmtree(stale, ignore_errors=True)
        known: dict[str, CellMetrics] = {}
        with contextlib.suppress(SourceError):  # no earlier sweep.json, or an unreadable one
            earlier = read_sweep_result(previous)
            self.engine = earlier.engine
            known = {c.key: c.metrics for c in earlier.cells if c.metrics is not None}
        todo = []
        for cell in self.cells:
            run = self._complete_run(cell)
            if run is None:
                self._set(cell, self._entry(cell, 'pending'))
                todo.append(cell)
                continue
            self.resumed.add(cell.index)
            metrics = known.get(cell.key) or self._metrics_on_disk(cell, run)
            self._set(cell, self._complete_entry(cell, run, metrics))
        return todo

    def _complete_run(self, cell: Cell) -> RunResult | None:
        """The run.json of a complete earlier run of this very cell, or None."""
        from replaybench.results.io import read_run_result

        path = self.out / CELLS_DIR / cell.name / 'run.json'
        if not path.is_file():
            return None
        try:
            run = read_run_result(path)
        except SourceError:
            return None
        if run.status != 'complete' or run.sweep is None or run.sweep.get('key') != cell.key:
            return None
        return run

    def _metrics_on_disk(self, cell: Cell, run: RunResult) -> CellMetrics:
        from replaybench.results.records import read_frames_csv

        records = read_frames_csv(self.out / CELLS_DIR / cell.name / 'frames.csv')
        return cell_metrics(run, records, cell.key)

    # -- running

    def run(self, todo: list[Cell]) -> bool:
        """Run ``todo`` on Ray; False when interrupted."""
        ray = _import_ray()
        # Ray prints its cluster messages (a worker that died, memory pressure) on stdout:
        # they go to stderr, stdout keeps the sweep's own output
        with contextlib.redirect_stdout(sys.stderr), engine(self.config.address) as info:
            placement = Placement.of(alive_nodes(ray), self.config.pack)
            self.engine = engine_record(ray, info, placement)
            runnable = self._feasible(todo, placement)
            self.write('running')
            self.csv = CsvLog(self.out / 'sweep.csv', csv_rows(self._done_entries()))
            return self._loop(ray, runnable, placement)

    def _done_entries(self) -> list[SweepCell]:
        return [e for e in self.entries.values() if e.status in ('complete', 'failed')]

    def _feasible(self, todo: list[Cell], placement: Placement) -> list[Cell]:
        """Cells Ray can place; GPU cells on a cluster without GPUs fail at once."""
        assert self.engine is not None
        if placement.mode == 'whole-node' and not placement.nodes and any(not c.gpu for c in todo):
            where = self.engine.address or 'this Ray cluster'
            msg = f'no node of the Ray cluster at {where} has a CPU for a timed cell'
            raise UsageError(msg)
        runnable = []
        for cell in todo:
            if cell.gpu and not self.engine.resources.get('GPU'):
                error = 'no GPU in the Ray cluster for this GPU backend'
                self._set(cell, self._entry(cell, 'failed', error=error))
            else:
                runnable.append(cell)
        return runnable

    def _loop(self, ray: Any, cells: list[Cell], placement: Placement) -> bool:
        from ray.exceptions import RayError

        from replaybench.app.sweep.cell import Board, execute_cell

        assert self.engine is not None
        board = None
        if self.progress is not None:
            board = ray.remote(num_cpus=0)(Board).remote()
        remote = ray.remote(
            max_retries=self.config.max_retries, retry_exceptions=False, max_calls=1
        )(execute_cell)
        pending: dict[Any, tuple[Cell, tuple[str, float] | None]] = {}
        queue = deque(c for c in cells if placement.one_node_each(c))
        free = deque(placement.nodes)
        # the other cells go to Ray a window at a time: enough to fill the cluster, few enough
        # that waiting on them costs the same however many cells the sweep has
        backlog = deque(c for c in cells if not placement.one_node_each(c))
        window = max(16, 2 * int(sum(self.engine.resources.get(k, 0) for k in ('CPU', 'GPU'))))

        def submit(cell: Cell, node: tuple[str, float] | None = None) -> None:
            ref = remote.options(**placement.options(cell, node)).remote(
                cell, self.config.options, self.config.command, _version.__version__, board
            )
            pending[ref] = (cell, node)

        interrupted = False
        try:
            while pending or queue or backlog:
                while queue and free:  # one timed cell per node
                    submit(queue.popleft(), free.popleft())
                while backlog and len(pending) < window:
                    submit(backlog.popleft())
                if queue and not pending:  # every node that could run them is gone
                    for cell in queue:
                        error = 'no node of the Ray cluster is left to run this timed cell'
                        self._finished(cell, self._entry(cell, 'failed', error=error))
                    queue.clear()
                    break
                if self.stop is not None and self.stop.is_set():
                    interrupted = True
                    break
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
                for ref in ready:
                    cell, node = pending.pop(ref)
                    try:
                        report = ray.get(ref)
                    except RayError as err:
                        if node is not None and node[0] in alive_nodes(ray):
                            free.append(node)  # a node that died takes no more cells
                        retried = (
                            f'{error_line(err)} (Ray retried {self.config.max_retries} time(s))'
                        )
                        self._finished(cell, self._entry(cell, 'failed', error=retried))
                        continue
                    if node is not None:
                        free.append(node)
                    self._collect(cell, report)
                self._show(ray, board, pending)
        except KeyboardInterrupt:
            interrupted = True
        if interrupted:
            for ref in pending:
                with contextlib.suppress(Exception):
                    ray.cancel(ref)
            for cell in [*(c for c, _ in pending.values()), *queue, *backlog]:
                self._set(cell, self._entry(cell, 'interrupted'))
        if board is not None:
            with contextlib.suppress(Exception):
                ray.kill(board)
        return not interrupted

    def _show(self, ray: Any, board: Any, pending: Mapping[Any, tuple[Cell, Any]]) -> None:
        if self.progress is None:
            return
        started: dict[int, str] = {}
        if board is not None:
            with contextlib.suppress(Exception):
                started = ray.get(board.snapshot.remote(), timeout=5)
        running = sum(1 for c, _ in pending.values() if c.index in started)
        failed = self.counts['failed']
        done = self.counts['complete'] + failed
        self.progress(SweepProgress(done, running, failed, len(self.cells)))

    def _collect(self, cell: Cell, report: Mapping[str, Any]) -> None:
        where = dict(report.get('where') or {})
        span = (float(report['started_at']), float(report['finished_at']))
        self.spans.add(cell.index, where.get('node_id'), span)
        status = report.get('status')
        if status == 'complete':
            run = self._store(cell, report['files'], where, span)
            self._finished(cell, self._complete_entry(cell, run, report['metrics']))
            return
        values = {
            'node_id': where.get('node_id'),
            'hostname': where.get('hostname'),
            'gpu_ids': tuple(where.get('gpu_ids') or ()),
        }
        if status == 'failed':
            self._finished(cell, self._entry(cell, 'failed', error=report.get('error'), **values))
        else:
            self._set(cell, self._entry(cell, 'interrupted', **values))

    def _section(self, cell: Cell, where: Mapping[str, Any], span: tuple[float, float]) -> Any:
        start, end = span
        return {
            'key': cell.key,
            'cell': cell.name,
            'backend': cell.backend,
            'params': dict(cell.params),
            'node_id': where.get('node_id'),
            'node_ip': where.get('node_ip'),
            'hostname': where.get('hostname'),
            'gpu_ids': where.get('gpu_ids') or [],
            'placement': _placement_name(cell, self.config.pack),
            'concurrency': {
                'limit_per_node': None if cell.gpu or self.config.pack else 1,
                'max_cells_on_node': self.spans.max_overlap(cell.index),
            },
            'started_at': dt.datetime.fromtimestamp(start, dt.UTC).isoformat(),
            'finished_at': dt.datetime.fromtimestamp(end, dt.UTC).isoformat(),
            'ray_version': self.engine.ray_version if self.engine else None,
        }

    def _store(
        self, cell: Cell, files: Mapping[str, bytes], where: Mapping[str, Any], span: Any
    ) -> RunResult:
        """Write the cell's folder next to its final place, then swap it in; its run.json gets
        the cell's ``sweep`` section."""
        from replaybench.results.io import write_run_result

        cells = self.out / CELLS_DIR
        final = cells / cell.name
        tmp = cells / f'.{cell.name}.partial-{os.getpid()}'
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for rel, data in files.items():
            target = (tmp / rel).resolve()
            if not target.is_relative_to(tmp.resolve()):
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
        run = _run_of(files['run.json'], f'{cell.name}/run.json')
        run = replace(run, sweep=self._section(cell, where, span))
        write_run_result(tmp / 'run.json', run)
        if final.exists():
            shutil.rmtree(final)
        tmp.rename(final)
        self.runs[cell.index] = run
        return run

    def finish_concurrency(self) -> None:
        """Cells run now: their run.json and entry get the concurrency seen over the whole
        sweep (a cell that finished later may have run beside them), from memory."""
        from replaybench.results.io import write_run_result
        from replaybench.results.sweepfile import CellConcurrency

        for index, run in self.runs.items():
            section = dict(run.sweep or {})
            concurrency = {**section['concurrency']}
            concurrency['max_cells_on_node'] = self.spans.max_overlap(index)
            if concurrency == section['concurrency']:
                continue
            run = replace(run, sweep={**section, 'concurrency': concurrency})
            write_run_result(self.out / CELLS_DIR / self.cells[index].name / 'run.json', run)
            self.runs[index] = run
            entry = self.entries[index]
            self._set(
                self.cells[index],
                replace(
                    entry,
                    concurrency=CellConcurrency(**concurrency),
                    conditions=conditions(run, self.cells[index].gpu),
                ),
            )

    # -- outputs

    def record(self, status: str) -> SweepRecord:
        """sweep.json as it stands, with ``status``."""
        from replaybench.results.model import Tool
        from replaybench.results.sweepfile import (
            SweepAxis,
            SweepCounts,
            SweepInput,
            SweepRecord,
            SweepSettings,
        )

        config = self.config
        cells = flagged([self.entries[c.index] for c in self.cells])
        counts = Counter(e.status for e in cells)
        return SweepRecord(
            tool=Tool(version=_version.__version__),
            status=status,
            command=tuple(config.command),
            started_at=self.started.isoformat(),
            finished_at=dt.datetime.now(dt.UTC).isoformat(),
            wall_s=time.perf_counter() - self.t0,
            settings=SweepSettings(
                backends=config.backend_texts,
                params=tuple(SweepAxis(a.backend, a.key, a.values) for a in config.axes),
                pack=config.pack,
                max_retries=config.max_retries,
                options=config.options.as_dict(),
            ),
            engine=self.engine,
            inputs=tuple(
                SweepInput(
                    path=i.given, resolved=str(i.path), size_bytes=i.size_bytes, sha256=i.sha256
                )
                for i in self.inputs
            ),
            counts=SweepCounts(
                cells=len(cells),
                complete=counts.get('complete', 0),
                failed=counts.get('failed', 0),
                interrupted=counts.get('interrupted', 0),
                pending=counts.get('pending', 0),
                resumed=len(self.resumed),
            ),
            cells=tuple(cells),
        )

    def write(self, status: str) -> tuple[SweepRecord, dict[str, Any]]:
        """sweep.json, sweep.csv (in cell order) and sweep.html, written whole."""
        from replaybench.report.sweep_html import render_sweep_html
        from replaybench.results.atomic import write_text_atomic
        from replaybench.results.sweepfile import write_sweep_result

        record = self.record(status)
        document = write_sweep_result(self.out / 'sweep.json', record)
        write_text_atomic(self.out / 'sweep.csv', csv_text(csv_rows(record.cells)))
        write_text_atomic(self.out / 'sweep.html', render_sweep_html(document))
        return record, document

    def result(self, status: str) -> SweepResult:
        """Write the outputs with the final ``status``; the ``SweepResult``."""
        record, document = self.write(status)
        return SweepResult(self.out, status, record, document, tuple(csv_rows(record.cells)))
