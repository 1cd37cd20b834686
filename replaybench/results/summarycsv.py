"""summary.csv: one row per (backend, topic), columns ``SUMMARY_CSV_COLUMNS``."""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

from replaybench.results.atomic import write_text_atomic
from replaybench.results.columns import SUMMARY_CSV_COLUMNS, summary_cell
from replaybench.results.records import csv_writer
from replaybench.results.stats import summary_row

if TYPE_CHECKING:
    from collections.abc import Iterable
    from pathlib import Path

    from replaybench.results.stats import Summary

__all__ = ['summary_cell', 'write_summary_csv']


def write_summary_csv(path: str | Path, summaries: Iterable[Summary]) -> None:
    """Write summary.csv (columns ``SUMMARY_CSV_COLUMNS``) atomically."""
    buffer = io.StringIO()
    writer = csv_writer(buffer)
    writer.writerow(SUMMARY_CSV_COLUMNS)
    for summary in summaries:
        row = summary_row(summary)
        writer.writerow([summary_cell(row[name]) for name in SUMMARY_CSV_COLUMNS])
    write_text_atomic(path, buffer.getvalue())
