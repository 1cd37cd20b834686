"""``report RUN_DIR --github-benchmark DIR``: a run's figures in github-action-benchmark's custom
format, for tracking them across commits.

github-action-benchmark (``benchmark-action/github-action-benchmark``) reads, with ``tool:
customSmallerIsBetter`` or ``customBiggerIsBetter``, a JSON array of
``{"name", "unit", "value", "range"?, "extra"?}``. Two files are written:

- ``DIR/smaller_is_better.json``: per (backend, topic) the median, p99 and mean latency (ms);
- ``DIR/bigger_is_better.json``: per (backend, topic) the throughput (frames/s) and, with ground
  truth, the tasks' tracked metrics (``MetricSpec.tracked``: the boxes' mAP@0.5, recall@0.5 and
  precision@0.5), where the row has the task's summary.

Names are ``<backend> <topic> <metric>``, the same for every run of the same backends and bag,
so the action lines up the same series across commits. ``range`` is the half-width of the 95 %
interval of the value where run.json has one (``± x``); ``extra`` names the frames measured, the
passes (``--repeat``) and the machine. Everything comes from the ``RunResult`` in memory.
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.results.model import RunResult, SummaryRow
    from replaybench.tasks import MetricSpec

__all__ = ['BIGGER_FILE', 'SMALLER_FILE', 'github_benchmark', 'write_github_benchmark']

SMALLER_FILE = 'smaller_is_better.json'
BIGGER_FILE = 'bigger_is_better.json'

_LATENCY = (
    ('p50 latency', 'latency_ms_p50', 'latency_ms_p50_ci_low', 'latency_ms_p50_ci_high'),
    ('p99 latency', 'latency_ms_p99', 'latency_ms_p99_ci_low', 'latency_ms_p99_ci_high'),
    ('mean latency', 'latency_ms_mean', None, None),
)


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _range(row: SummaryRow, low: str | None, high: str | None) -> str | None:
    if low is None or high is None:
        return None
    lo, hi = _number(getattr(row, low)), _number(getattr(row, high))
    if lo is None or hi is None:
        return None
    return f'± {(hi - lo) / 2:.4g}'


def _entry(name: str, unit: str, value: float, span: str | None, extra: str) -> dict[str, Any]:
    entry: dict[str, Any] = {'name': name, 'unit': unit, 'value': value}
    if span is not None:
        entry['range'] = span
    entry['extra'] = extra
    return entry


def _extra(run: RunResult, row: SummaryRow) -> str:
    env = run.environment
    machine = ' / '.join(p for p in (env.hostname, env.cpu.model) if p)
    passes = run.settings.repeat
    parts = [f'{row.measured} measured frames']
    if passes > 1:
        parts.append(f'{passes} passes (--repeat)')
    parts.append(f'rate {run.settings.rate}')
    if machine:
        parts.append(machine)
    return '; '.join(parts)


def _tracked() -> list[tuple[str | None, MetricSpec]]:
    """(the ``SummaryRow`` field of the task's summary, None for a task without one; metric)
    of each task's tracked metric."""
    from replaybench.tasks import get_task, task_names, task_views

    tracked: list[tuple[str | None, MetricSpec]] = []
    for name in task_names():
        task = get_task(name)
        field = task_views(task).summary_field
        tracked += [(field, m) for m in task.metrics if m.tracked]
    return tracked


def github_benchmark(run: RunResult) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(smaller is better, bigger is better) entries of ``run``'s summary rows."""
    tracked = _tracked()
    smaller: list[dict[str, Any]] = []
    bigger: list[dict[str, Any]] = []
    for row in run.summary_rows:
        key = f'{row.backend} {row.topic}'
        extra = _extra(run, row)
        for label, field, low, high in _LATENCY:
            value = _number(getattr(row, field))
            if value is not None:
                smaller.append(_entry(f'{key} {label}', 'ms', value, _range(row, low, high), extra))
        fps = _number(row.throughput_fps)
        if fps is not None:
            span = _range(row, 'throughput_fps_ci_low', 'throughput_fps_ci_high')
            bigger.append(_entry(f'{key} throughput', 'frames/s', fps, span, extra))
        for summary_field, metric in tracked:
            if summary_field is not None and getattr(row, summary_field, None) is None:
                continue  # not the task's row
            value = row.metric(metric.name)
            if value is not None:
                bigger.append(_entry(f'{key} {metric.label}', 'fraction', value, None, extra))
    return smaller, bigger


def write_github_benchmark(run: RunResult, out_dir: Path) -> tuple[Path, Path]:
    """Write ``SMALLER_FILE`` and ``BIGGER_FILE`` into ``out_dir`` (created); their paths.
    ``OSError`` naming the file when one cannot be written."""
    from replaybench.results.atomic import write_text_atomic

    smaller, bigger = github_benchmark(run)
    paths = (out_dir / SMALLER_FILE, out_dir / BIGGER_FILE)
    for path, entries in zip(paths, (smaller, bigger), strict=True):
        write_text_atomic(path, json.dumps(entries, indent=2, ensure_ascii=False) + '\n')
    return paths
