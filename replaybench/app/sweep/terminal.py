"""What the ``sweep`` command prints: a progress bar on a terminal, the cells table, where the
outputs are, and the failed and flagged cells."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.app.sweep.record import csv_rows

if TYPE_CHECKING:
    from replaybench.app.sweep.record import SweepProgress, SweepResult

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


#: The accuracy column of the cells table.
_ACCURACY = 'map50'


def _fmt(value: Any, digits: int = 2) -> str:
    return '-' if value is None or value == '' else f'{float(value):.{digits}f}'


def result_lines(result: SweepResult) -> tuple[list[str], list[str]]:
    """What the ``sweep`` command prints: the cells table and where the outputs are (stdout),
    failed and flagged cells (stderr)."""
    from replaybench.tasks import all_metrics

    rows = csv_rows(result.sweep.cells)
    # the boxes' main figure, which every backend has (its terminal heading and digits)
    (boxes,) = [m for m in all_metrics() if m.name == _ACCURACY]
    header = (
        'input',
        'backend',
        'params',
        'status',
        'fps',
        'p50 ms',
        'p99 ms',
        str(boxes.terminal_label),
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
            _fmt(r[boxes.name], boxes.terminal_digits),
            str(r['node'] or '-') + (f' gpu {r["gpu"]}' if r['gpu'] else ''),
        )
        for r in rows
    ]
    widths = [max([len(h), *(len(t[i]) for t in table)]) for i, h in enumerate(header)]
    out = [
        '  '.join(
            c.rjust(w) if 4 <= i <= 7 else c.ljust(w)
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
