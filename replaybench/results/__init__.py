"""Frame records, statistics and the run folder's files.

The accuracy scorer lives in ``replaybench.results.accuracy`` and is imported on demand.
"""

from __future__ import annotations

from replaybench.results.records import (
    FRAMES_CSV_COLUMNS,
    FrameRecord,
    FramesCsvWriter,
    FrameStatus,
    read_frames_csv,
)
from replaybench.results.runfile import (
    SCHEMA_VERSION,
    RunData,
    environment,
    load_run,
    write_json_atomic,
    write_run_json,
    write_summary_csv,
    write_text_atomic,
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
    'write_run_json',
    'write_summary_csv',
    'write_text_atomic',
]
