"""pandas DataFrames of the results: frames.csv, summary.csv and a peak search's trials.

The frames and summary tables have exactly the CSV files' columns, in order, and hold what the
files hold (times rounded to the file's decimals): ``RunResult.frames`` of a run made in memory
equals the one read back from its folder. Column types: float columns ``float64`` (NaN where
the cell is empty), integer columns ``Int64`` (``<NA>`` where empty), ``warmup`` / ``dropped``
and ``ok`` ``bool``, text columns ``str``.

pandas is imported when a table is made, never when this module is. It is not part of the
default install (the command line needs none of it): ``pip install 'replaybench[pandas]'``;
without it a table raises ``MissingDependencyError`` naming that command.
"""

from __future__ import annotations

import csv
import functools
import types
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.errors import MissingDependencyError, SourceError
from replaybench.results.columns import (
    INTEGER_COLUMNS,
    SUMMARY_CSV_COLUMNS,
    TEXT_COLUMNS,
    summary_cell,
)
from replaybench.results.records import FRAMES_CSV_COLUMNS, FrameRecord, as_written
from replaybench.textsafe import from_csv

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

    import pandas as pd

__all__ = [
    'FRAMES_DTYPES',
    'PANDAS_HINT',
    'SUMMARY_DTYPES',
    'frames_table',
    'read_summary_csv',
    'records_table',
    'require_pandas',
    'summary_table',
    'trials_table',
]


#: how to get the DataFrames when pandas is missing
PANDAS_HINT = "pip install 'replaybench[pandas]'"


def require_pandas() -> None:
    """Import pandas; ``MissingDependencyError`` naming the extra when it is not installed."""
    try:
        import pandas  # noqa: F401
    except ImportError as err:
        msg = (
            "the Python API's DataFrames need pandas, which the default install leaves out: "
            + PANDAS_HINT
        )
        raise MissingDependencyError(msg) from err


def _dtype(tp: Any) -> str:
    """The pandas dtype of a field annotated ``tp``."""
    if typing.get_origin(tp) in (types.UnionType, typing.Union):
        (tp,) = [a for a in typing.get_args(tp) if a is not type(None)]
    if tp is bool:
        return 'bool'
    if tp is int:
        return 'Int64'
    if tp is float:
        return 'float64'
    return 'str'  # str, and the tuple of texts (``warnings``) joined by '; '


def _dtypes(cls: type[Any], columns: Sequence[str]) -> dict[str, str]:
    """The pandas dtype of each column, from ``cls``'s annotations."""
    hints = typing.get_type_hints(cls)
    return {name: _dtype(hints[name]) for name in columns}


#: frames.csv column -> pandas dtype (``RunResult.frames``)
FRAMES_DTYPES: dict[str, str] = _dtypes(FrameRecord, FRAMES_CSV_COLUMNS)
#: summary.csv column -> pandas dtype (``RunResult.summary``): integer counts, text, numbers
SUMMARY_DTYPES: dict[str, str] = {
    name: 'Int64' if name in INTEGER_COLUMNS else 'str' if name in TEXT_COLUMNS else 'float64'
    for name in SUMMARY_CSV_COLUMNS
}
#: summary.csv columns before the segmentation columns were added (still read)
_BEFORE_SEGMENTATION = SUMMARY_CSV_COLUMNS[: SUMMARY_CSV_COLUMNS.index('warnings') + 1]


def _frame(columns: Mapping[str, list[Any]], dtypes: Mapping[str, str]) -> pd.DataFrame:
    require_pandas()
    import pandas as pd

    return pd.DataFrame(
        {name: pd.array(values, dtype=dtypes[name]) for name, values in columns.items()}
    )


def frames_table(records: Iterable[FrameRecord]) -> pd.DataFrame:
    """frames.csv as a DataFrame: one row per record, rounded as the file rounds."""
    rows = [as_written(r) for r in records]
    columns = {name: [r[i] for r in rows] for i, name in enumerate(FRAMES_CSV_COLUMNS)}
    # after them: the frame values of tasks without fields of their own, in first-seen order
    extra: dict[str, None] = {}
    for r in rows:
        extra.update(dict.fromkeys(r.task_values or {}))
    for name in extra:
        columns[name] = [(r.task_values or {}).get(name) for r in rows]
    return _frame(columns, {**FRAMES_DTYPES, **dict.fromkeys(extra, 'float64')})


def summary_table(rows: Sequence[object]) -> pd.DataFrame:
    """summary.csv as a DataFrame, from run.json's ``summary`` rows: each value is written as
    the file's cell (``summary_cell``) and read back as ``read_summary_csv`` reads it."""
    parsers = _parsers()

    def cell(value: Any) -> str:
        return summary_cell('; '.join(value) if isinstance(value, tuple) else value)

    columns = {
        name: [parsers[name](cell(getattr(row, name))) for row in rows]
        for name in SUMMARY_CSV_COLUMNS
    }
    extra = _task_metric_names(rows)
    for name in extra:
        columns[name] = [_task_number(cell(_task_metric(row, name))) for row in rows]
    return _frame(columns, {**SUMMARY_DTYPES, **dict.fromkeys(extra, 'float64')})


def _task_metric(row: object, name: str) -> Any:
    found: Mapping[str, Any] | None = getattr(row, 'task_metrics', None)
    return None if found is None else found.get(name)


def _task_metric_names(rows: Sequence[object]) -> tuple[str, ...]:
    """summary.csv's columns after ``SUMMARY_CSV_COLUMNS``: the rows' ``task_metrics`` names
    in the order they first appear (``replaybench.results.stats.task_metric_columns``)."""
    names: dict[str, None] = {}
    for row in rows:
        names.update(dict.fromkeys(getattr(row, 'task_metrics', None) or {}))
    return tuple(names)


def _task_number(text: str) -> float | None:
    return float(text) if text else None


@functools.cache
def _parsers() -> dict[str, Any]:
    def number(kind: type[Any]) -> Any:
        return lambda text: kind(text) if text else None

    by_dtype = {'Int64': number(int), 'float64': number(float), 'bool': lambda t: t == '1'}
    return {name: by_dtype.get(dtype, from_csv) for name, dtype in SUMMARY_DTYPES.items()}


def read_summary_csv(path: str | Path) -> pd.DataFrame:
    """A summary.csv file as the DataFrame ``summary_table`` makes; ``SourceError`` when the
    file is not one."""
    path = Path(path)
    try:
        with path.open(newline='', encoding='utf-8') as file:
            reader = csv.reader(file)
            header = tuple(next(reader, ()))
            # after the known columns: the metrics of tasks without fields of their own
            extra = header[len(SUMMARY_CSV_COLUMNS) :]
            known = header[: len(SUMMARY_CSV_COLUMNS)]
            if known not in (SUMMARY_CSV_COLUMNS, _BEFORE_SEGMENTATION) or (
                extra and not _task_columns_ok(extra)
            ):
                msg = f'{path}: not a summary.csv (header does not match the expected columns)'
                raise SourceError(msg)
            parsers = {**_parsers(), **dict.fromkeys(extra, _task_number)}
            names = (*SUMMARY_CSV_COLUMNS, *extra)
            columns: dict[str, list[Any]] = {name: [] for name in names}
            # a summary.csv from before the recorded-latency columns: those read empty
            missing = [''] * (len(SUMMARY_CSV_COLUMNS) - len(known))
            for cells in reader:
                if len(cells) != len(header):
                    msg = f'{path}:{reader.line_num}: {len(cells)} cells, not {len(header)}'
                    raise SourceError(msg)
                texts = [*cells[: len(known)], *missing, *cells[len(known) :]]
                for name, text in zip(names, texts, strict=True):
                    columns[name].append(parsers[name](text))
    except (OSError, ValueError, csv.Error) as err:
        msg = f'{path}: cannot read summary.csv: {err}'
        raise SourceError(msg) from err
    return _frame(columns, {**SUMMARY_DTYPES, **dict.fromkeys(extra, 'float64')})


def _task_columns_ok(extra: Sequence[str]) -> bool:
    """Whether columns after the known ones can be task metrics: new, distinct names."""
    return len(set(extra)) == len(extra) and all(
        name and name not in SUMMARY_DTYPES for name in extra
    )


def trials_table(trials: Sequence[object], cls: type[Any]) -> pd.DataFrame:
    """A peak search's trials (``cls``: peak.json's trial, ``PeakTrial``), in run order:
    ``rate_hz``, ``ok`` and its other fields. This module takes the model classes from its
    callers, so that it does not import the model that imports it."""
    names = tuple(typing.get_type_hints(cls))
    columns = {name: [getattr(t, name) for t in trials] for name in names}
    return _frame(columns, _dtypes(cls, names))


def records_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> pd.DataFrame:
    """A DataFrame of ``rows`` (mappings keyed by ``columns``; None = empty cell), columns in
    order: comparison.csv's and sweep.csv's rows."""
    require_pandas()
    import pandas as pd

    return pd.DataFrame.from_records(list(rows), columns=list(columns))
