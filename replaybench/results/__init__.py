"""Frame records, statistics and the run folder's files.

The accuracy scorer lives in ``replaybench.results.accuracy`` and is imported on demand.
"""

from __future__ import annotations

from replaybench.results.atomic import write_json_atomic, write_text_atomic
from replaybench.results.folder import RunData, load_run
from replaybench.results.machine import environment
from replaybench.results.model import RUN_SCHEMA_VERSION as SCHEMA_VERSION
from replaybench.results.records import (
    FRAMES_CSV_COLUMNS,
    FrameRecord,
    FramesCsvWriter,
    FrameStatus,
    read_frames_csv,
)
from replaybench.results.stats import (
    ACCURACY_COLUMNS,
    PERCENTILES,
    SUMMARY_CSV_COLUMNS,
    Summary,
    summarize,
    summary_json,
    summary_row,
)
from replaybench.results.summarycsv import write_summary_csv

__all__ = [
    'ACCURACY_COLUMNS',
    'FRAMES_CSV_COLUMNS',
    'PERCENTILES',
    'SCHEMA_VERSION',
    'SUMMARY_CSV_COLUMNS',
    'FrameRecord',
    'FrameStatus',
    'FramesCsvWriter',
    'RunData',
    'Summary',
    'environment',
    'load_run',
    'read_frames_csv',
    'summarize',
    'summary_json',
    'summary_row',
    'write_json_atomic',
    'write_summary_csv',
    'write_text_atomic',
]
