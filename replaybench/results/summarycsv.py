"""summary.csv: one row per (backend, topic), columns ``SUMMARY_CSV_COLUMNS``."""

from __future__ import annotations

import io
import math
from typing import TYPE_CHECKING, Any

from replaybench.results.atomic import write_text_atomic
from replaybench.results.records import csv_writer
from replaybench.results.stats import SUMMARY_CSV_COLUMNS, summary_row
from replaybench.textsafe import csv_text

if TYPE_CHECKING:
    from collections.abc import Iterable
    from pathlib import Path

    from replaybench.results.stats import Summary

__all__ = ['summary_cell', 'write_summary_csv']


def summary_cell(value: Any) -> str:
    """One summary.csv cell: floats to 4 decimals, non-finite and None empty, text escaped."""
    if value is None:
        return ''
    if isinstance(value, bool):
        return '1' if value else '0'
    if isinstance(value, float):
        return format(value, '.4f') if math.isfinite(value) else ''
    return csv_text(value) if isinstance(value, str) else str(value)


def write_summary_csv(path: str | Path, summaries: Iterable[Summary]) -> None:
    """Write summary.csv (columns ``SUMMARY_CSV_COLUMNS``) atomically."""
    buffer = io.StringIO()
    writer = csv_writer(buffer)
    writer.writerow(SUMMARY_CSV_COLUMNS)
    for summary in summaries:
        row = summary_row(summary)
        writer.writerow([summary_cell(row[name]) for name in SUMMARY_CSV_COLUMNS])
    write_text_atomic(path, buffer.getvalue())
