"""summary.csv: one row per (backend, topic), columns ``SUMMARY_CSV_COLUMNS`` and then the
metrics of tasks without fields of their own (``task_metric_columns``), empty in other rows."""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

from replaybench.results.atomic import write_text_atomic
from replaybench.results.columns import SUMMARY_CSV_COLUMNS, summary_cell
from replaybench.results.records import csv_writer
from replaybench.results.stats import summary_row, task_metric_columns

if TYPE_CHECKING:
    from collections.abc import Iterable
    from pathlib import Path

    from replaybench.results.stats import Summary

__all__ = ['summary_cell', 'write_summary_csv']


def write_summary_csv(path: str | Path, summaries: Iterable[Summary]) -> None:
    """Write summary.csv (columns ``SUMMARY_CSV_COLUMNS``, then ``task_metric_columns``)
    atomically."""
    rows = list(summaries)
    columns = (*SUMMARY_CSV_COLUMNS, *task_metric_columns(rows))
    buffer = io.StringIO()
    writer = csv_writer(buffer)
    writer.writerow(columns)
    for summary in rows:
        row = summary_row(summary)
        writer.writerow([summary_cell(row.get(name)) for name in columns])
    write_text_atomic(path, buffer.getvalue())
