"""Frame records, statistics and the run folder's files.

The accuracy scorer lives in ``replaybench.results.accuracy`` and is imported on demand; so is
every name below (module ``__getattr__``), so that importing one submodule imports only that
one and what it needs.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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

#: name -> (module, attribute), imported on first use
_LAZY: dict[str, tuple[str, str]] = {
    'ACCURACY_COLUMNS': ('stats', 'ACCURACY_COLUMNS'),
    'FRAMES_CSV_COLUMNS': ('records', 'FRAMES_CSV_COLUMNS'),
    'PERCENTILES': ('stats', 'PERCENTILES'),
    'SCHEMA_VERSION': ('model', 'RUN_SCHEMA_VERSION'),
    'SUMMARY_CSV_COLUMNS': ('stats', 'SUMMARY_CSV_COLUMNS'),
    'FrameRecord': ('records', 'FrameRecord'),
    'FrameStatus': ('records', 'FrameStatus'),
    'FramesCsvWriter': ('records', 'FramesCsvWriter'),
    'RunData': ('folder', 'RunData'),
    'Summary': ('stats', 'Summary'),
    'environment': ('machine', 'environment'),
    'load_run': ('folder', 'load_run'),
    'read_frames_csv': ('records', 'read_frames_csv'),
    'summarize': ('stats', 'summarize'),
    'summary_json': ('stats', 'summary_json'),
    'summary_row': ('stats', 'summary_row'),
    'write_json_atomic': ('atomic', 'write_json_atomic'),
    'write_summary_csv': ('summarycsv', 'write_summary_csv'),
    'write_text_atomic': ('atomic', 'write_text_atomic'),
}


def __getattr__(name: str) -> Any:
    found = _LAZY.get(name)
    if found is None:
        msg = f'module {__name__!r} has no attribute {name!r}'
        raise AttributeError(msg)
    module, attr = found
    value = getattr(importlib.import_module(f'{__name__}.{module}'), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
