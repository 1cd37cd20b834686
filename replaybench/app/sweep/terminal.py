"""What the ``sweep`` command prints: a progress bar on a terminal, the cells table, where the
outputs are, and the failed and flagged cells."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.app.sweep.record import csv_rows

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.app.sweep.record import SweepProgress, SweepResult
    from replaybench.tasks import MetricSpec

__all__ = ['ProgressBar', 'progress_bar', 'result_lines']


class ProgressBar:
    """A one-line progress bar on a terminal: cells done / running / failed."""

    def __init__(self, stream: Any) -> None:
        self.stream = stream
        self.last: SweepProgress | None = None

    def __call__(self, p: SweepProgress) -> None:
        if p == self.last:
            return
        self.last = p
        filled = p.done * 25 // p.total if p.total else 25
        bar = '#' * filled + '.' * (25 - filled)
        self.stream.write(
            f'\r[{bar}] {p.done}/{p.total} cells done, {p.running} running, {p.failed} failed '
        )
        self.stream.flush()

    def close(self) -> None:
        if self.last is not None:
            self.stream.write('\n')
            self.stream.flush()


def progress_bar(stream: Any) -> ProgressBar | None:
    """A ``ProgressBar`` on ``stream`` when it is a terminal, else None."""
    isatty = getattr(stream, 'isatty', None)
    return ProgressBar(stream) if callable(isatty) and isatty() else None


def _fmt(value: Any, digits: int = 2) -> str:
    return '-' if value is None or value == '' else f'{float(value):.{digits}f}'


def _accuracy_columns(rows: Sequence[Mapping[str, Any]]) -> list[MetricSpec]:
    """The sweep metrics in the cells table: each one with a terminal heading, as
    ``replaybench run``'s table shows them: a task shown on every row (``terminal='always'``:
    the boxes', which every backend has) always, another only where a cell has a value."""
    from replaybench.app.sweep.record import sweep_metrics
    from replaybench.tasks import get_task, task_names, task_views

    every_row = {
        m.name
        for name in task_names()
        if task_views(task := get_task(name)).terminal == 'always'
        for m in task.metrics
    }
    return [
        m
        for m in sweep_metrics()
        if m.terminal_label is not None
        and (m.name in every_row or any(r[m.name] is not None for r in rows))
    ]


def result_lines(result: SweepResult) -> tuple[list[str], list[str]]:
    """What the ``sweep`` command prints: the cells table and where the outputs are (stdout),
    failed and flagged cells (stderr)."""
    rows = csv_rows(result.sweep.cells)
    shown = _accuracy_columns(rows)
    header = (
        'input',
        'backend',
        'params',
        'status',
        'fps',
        'p50 ms',
        'p99 ms',
        *(str(m.terminal_label) for m in shown),
        'node',
    )
    table = [
        (
            Path(str(r['input'])).name,
            str(r['backend']),
            str(r['params']) or '-',
            str(r['status']),
            _fmt(r['fps'], 1),
            _fmt(r['p50_ms']),
            _fmt(r['p99_ms']),
            *(_fmt(r[m.name], m.terminal_digits) for m in shown),
            str(r['node'] or '-') + (f' gpu {r["gpu"]}' if r['gpu'] else ''),
        )
        for r in rows
    ]
    numbers = range(4, 7 + len(shown))  # right-aligned: the timings and the metrics
    widths = [max([len(h), *(len(t[i]) for t in table)]) for i, h in enumerate(header)]
    out = [
        '  '.join(
            c.rjust(w) if i in numbers else c.ljust(w)
            for i, (c, w) in enumerate(zip(line, widths, strict=True))
        ).rstrip()
        for line in (header, *table)
    ]
    counts = result.sweep.counts
    out.append(
        f'{counts.complete} of {counts.cells} cells complete '
        f'({counts.resumed} kept from an earlier run), {counts.failed} failed'
    )
    out.append(f'Sweep folder: {result.out}')
    out.append(f'Report: {result.out / "sweep.html"}')
    err = [
        f'replaybench: error: cell {r["cell"]} failed: {r["error"]}'
        for r in rows
        if r['status'] == 'failed'
    ]
    err += [
        f'replaybench: warning: cell {r["cell"]}: {r["flags"]}'
        for r in rows
        if r['flags'] and r['status'] == 'complete'
    ]
    if result.status == 'interrupted':
        err.append('replaybench: interrupted: complete cells are kept; run again to resume')
    return out, err
