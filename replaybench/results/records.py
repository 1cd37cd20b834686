"""One row per (backend, frame): the ``FrameRecord`` model and the frames.csv reader/writer."""

from __future__ import annotations

import contextlib
import csv
import io
import math
import os
from collections.abc import Mapping  # noqa: TC003 - FrameRecord's hints are read at run time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, NamedTuple, get_args

from replaybench.errors import SourceError
from replaybench.results.runfolder import with_filename
from replaybench.textsafe import csv_text, from_csv

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Sequence
    from types import TracebackType
    from typing import IO, Self

__all__ = [
    'FRAMES_CSV_COLUMNS',
    'FrameRecord',
    'FrameStatus',
    'FramesCsvWriter',
    'as_written',
    'csv_writer',
    'read_frames_csv',
    'written',
]

FrameStatus = Literal['ok', 'dropped', 'skipped']

_STATUSES: frozenset[str] = frozenset(get_args(FrameStatus))


class FrameRecord(NamedTuple):
    """One frames.csv row: what happened to one frame in one backend.

    Times ending in ``_s`` are seconds since the backend's replay start; ``_ms`` are durations.
    ``None`` means the value does not apply (a stage the backend does not have, or a frame that
    was dropped or skipped) and is written as an empty cell. The stage times are the host's
    (wall clock); the ``*_device_ms`` ones, at the end, the GPU's own for the same stages.
    """

    input: int
    backend: str
    topic: str
    seq: int
    log_time_ns: int
    stamp_ns: int | None
    status: FrameStatus
    note: str
    warmup: bool
    dropped: bool
    release_s: float
    start_s: float | None = None
    done_s: float | None = None
    queue_wait_ms: float | None = None
    read_decode_ms: float | None = None
    preprocess_ms: float | None = None
    infer_ms: float | None = None
    postprocess_ms: float | None = None
    h2d_ms: float | None = None
    d2h_ms: float | None = None
    latency_ms: float | None = None
    detections: int | None = None
    preprocess_device_ms: float | None = None
    infer_device_ms: float | None = None
    postprocess_device_ms: float | None = None
    h2d_device_ms: float | None = None
    d2h_device_ms: float | None = None
    #: the pass of ``run --repeat N`` the frame belongs to (0 to N - 1; 0 without repeats)
    repeat: int = 0
    # segmentation backends: the frame's mIoU and pixel accuracy against its ground-truth mask
    miou: float | None = None
    pixel_accuracy: float | None = None
    # a recorded output's times (``replaybench.results.recorded_latency``); empty elsewhere
    output_log_time_ns: int | None = None
    capture_to_output_ms: float | None = None
    pipeline_ms: float | None = None
    # tag backends (replaybench.tasks.tags.scoring.TAG_FRAME_COLUMNS); empty for the others
    tags: int | None = None
    tag_truth: int | None = None
    tag_matched: int | None = None
    tag_wrong_ids: int | None = None
    tag_phantoms: int | None = None
    tag_corner_rmse_px: float | None = None
    tag_trans_err_m: float | None = None
    tag_rot_err_deg: float | None = None
    #: which of the backend's pipelines served the frame: 0 for a shared run (one instance
    #: serves every camera topic); with ``--pipelines per-topic`` the index of the camera
    #: topic's instance, in the order of the run's camera topics (run.json's ``rig`` section)
    pipeline: int = 0
    #: at a timed rate (or from a recording's output log times), the age of the output in use
    #: when the frame was released: its release time minus the release time of the frame that
    #: output came from (``replaybench.replay.streaming``); empty before the first output, at
    #: ``--rate max`` and in later passes of ``--repeat``
    output_age_ms: float | None = None
    #: the frame's values of a task that has no fields of its own here (a task from an entry
    #: point, ``Task.frame_columns``), by column name; None for the built-in tasks. frames.csv
    #: writes them after ``pipeline``, in the columns its writer was given.
    task_values: Mapping[str, float | None] | None = None


#: frames.csv's columns, in order (a task without fields here adds its ``frame_columns`` after
#: them: ``FramesCsvWriter(task_columns=...)``)
FRAMES_CSV_COLUMNS: tuple[str, ...] = FrameRecord._fields[:-1]

_TAG_INT_FIELDS = frozenset({'tags', 'tag_truth', 'tag_matched', 'tag_wrong_ids', 'tag_phantoms'})
_TAG_FIELDS = _TAG_INT_FIELDS | {'tag_corner_rmse_px', 'tag_trans_err_m', 'tag_rot_err_deg'}
_INT_FIELDS = (
    frozenset(
        {
            'input',
            'seq',
            'log_time_ns',
            'stamp_ns',
            'detections',
            'repeat',
            'output_log_time_ns',
            'pipeline',
        }
    )
    | _TAG_INT_FIELDS
)
_BOOL_FIELDS = frozenset({'warmup', 'dropped'})
_STR_FIELDS = frozenset({'backend', 'topic', 'status', 'note'})
_OPTIONAL_FIELDS = frozenset(
    {
        'stamp_ns',
        'start_s',
        'done_s',
        'queue_wait_ms',
        'read_decode_ms',
        'preprocess_ms',
        'infer_ms',
        'postprocess_ms',
        'h2d_ms',
        'd2h_ms',
        'latency_ms',
        'detections',
        'preprocess_device_ms',
        'infer_device_ms',
        'postprocess_device_ms',
        'h2d_device_ms',
        'd2h_device_ms',
        'miou',
        'pixel_accuracy',
        'output_log_time_ns',
        'capture_to_output_ms',
        'pipeline_ms',
        'output_age_ms',
    },
)
_OPTIONAL_FIELDS |= _TAG_FIELDS
#: The columns of frames.csv files written before the ``*_device_ms`` columns were added.
_COLUMNS_BEFORE_DEVICE_TIMES = FRAMES_CSV_COLUMNS[:22]
#: The columns of frames.csv files written before the ``repeat``, segmentation and
#: recorded-output columns.
_COLUMNS_BEFORE_REPEAT = FRAMES_CSV_COLUMNS[:27]
#: The columns of frames.csv files written before the ``pipeline`` column.
_COLUMNS_BEFORE_PIPELINE = FRAMES_CSV_COLUMNS[: FRAMES_CSV_COLUMNS.index('pipeline')]
#: The columns of frames.csv files written before the ``output_age_ms`` column.
_COLUMNS_BEFORE_OUTPUT_AGE = FRAMES_CSV_COLUMNS[: FRAMES_CSV_COLUMNS.index('output_age_ms')]
_KNOWN_HEADERS = (
    FRAMES_CSV_COLUMNS,
    _COLUMNS_BEFORE_OUTPUT_AGE,
    _COLUMNS_BEFORE_DEVICE_TIMES,
    _COLUMNS_BEFORE_REPEAT,
    _COLUMNS_BEFORE_PIPELINE,
)


def _float_format(name: str) -> str:
    return '.6f' if name.endswith('_s') else '.4f'


_FORMATS: tuple[tuple[str, str], ...] = tuple(
    (name, _float_format(name))
    for name in FRAMES_CSV_COLUMNS
    if name not in _INT_FIELDS | _BOOL_FIELDS | _STR_FIELDS
)
_FLOAT_FORMAT = dict(_FORMATS)


def _float_cell(spec: str) -> Callable[[object], str]:
    fmt = f'%{spec}'

    def cell(value: object) -> str:
        text = fmt % value
        if text[-1] in 'nf':  # nan, inf, -inf
            return ''
        return '0' + text[2:] if text[0] == '-' and float(text) == 0 else text

    return cell


def _int_cell(value: object) -> str:
    return str(int(value))  # type: ignore[call-overload]


def _bool_cell(value: object) -> str:
    return '1' if value else '0'


def _text_cell(value: object) -> str:
    return csv_text(str(value))


def _cell_formatter(name: str) -> Callable[[object], str]:
    if name in _BOOL_FIELDS:
        return _bool_cell
    if name in _FLOAT_FORMAT:
        return _float_cell(_FLOAT_FORMAT[name])
    if name in _INT_FIELDS:
        return _int_cell
    return _text_cell


#: One formatter per frames.csv column, in column order (a row is written per frame); None is
#: an empty cell and never reaches them.
_CELLS: tuple[Callable[[object], str], ...] = tuple(map(_cell_formatter, FRAMES_CSV_COLUMNS))


def _row(record: FrameRecord) -> list[str]:
    return [
        '' if value is None else cell(value)
        for cell, value in zip(_CELLS, record[: len(_CELLS)], strict=True)
    ]


_TASK_CELL = _float_cell('.4f')


def _task_cells(record: FrameRecord, columns: Sequence[str]) -> str:
    """The cells of a task's columns (``FrameRecord.task_values``), each after its comma."""
    values = record.task_values or {}
    return ''.join(
        ',' if (v := values.get(name)) is None else ',' + _TASK_CELL(v) for name in columns
    )


#: The cells from release_s to d2h_ms (with latency_ms) of a row whose times are all present.
_TIMES = '%.6f,%.6f,%.6f,%.4f,%.4f'
_STAGE_CELLS = _CELLS[15:20]
_DEVICE_CELLS = _CELLS[22:27]
_SCORE_CELLS = _CELLS[28:30]
_QUOTED: dict[str, str] = {}
_NO_STAGES = [None] * 5
_NO_RECORDED = [None] * 3
_AGE_CELL = _CELLS[FRAMES_CSV_COLUMNS.index('output_age_ms')]


def _quote(text: str) -> str:
    """A text cell (``csv_text``: bag text escaped) as ``csv.writer`` writes it: quoted when it
    holds , or " (escaping leaves no CR or LF)."""
    cell = _QUOTED.get(text)
    if cell is None:
        safe = csv_text(text)
        special = any(c in safe for c in ',"\r\n')
        cell = '"' + safe.replace('"', '""') + '"' if special else safe
        if len(_QUOTED) < 4096:
            _QUOTED[text] = cell
    return cell


def _scores(values: Sequence[object]) -> str:
    """The segmentation cells (``miou``, ``pixel_accuracy``) of a frames.csv line."""
    return ','.join(
        '' if v is None else cell(v) for cell, v in zip(_SCORE_CELLS, values, strict=True)
    )


_TAG_CELLS = _CELLS[FRAMES_CSV_COLUMNS.index('tags') : FRAMES_CSV_COLUMNS.index('pipeline')]
_NO_TAGS = ',' * len(_TAG_CELLS)


def _tag_cells(values: Sequence[object]) -> str:
    """The tag columns' cells, each after its comma."""
    if all(v is None for v in values):
        return _NO_TAGS
    cells = ['' if v is None else cell(v) for cell, v in zip(_TAG_CELLS, values, strict=True)]
    return ',' + ','.join(cells)


def _line(record: FrameRecord) -> str:
    """One frames.csv line with its ``\\r\\n``: what ``csv_writer`` writes for ``_row(record)``.

    The common case (every time present, non-negative and finite) is formatted in one
    operation; any other record goes through the per-cell formatters.
    """
    (
        input_,
        backend,
        topic,
        seq,
        log_time_ns,
        stamp_ns,
        status,
        note,
        warmup,
        dropped,
        release_s,
        start_s,
        done_s,
        queue_wait_ms,
        read_decode_ms,
        preprocess_ms,
        infer_ms,
        postprocess_ms,
        h2d_ms,
        d2h_ms,
        latency_ms,
        detections,
        *rest,
    ) = record
    device, repeat, scores, recorded = rest[:5], rest[5], rest[6:8], rest[8:11]
    tagged, pipeline, age = rest[11:19], rest[19], rest[20]
    # rest[21]: task_values, not a cell of its own
    stages = [preprocess_ms, infer_ms, postprocess_ms, h2d_ms, d2h_ms]
    if (
        latency_ms is not None
        and detections is not None
        and recorded == _NO_RECORDED
        and None not in (stamp_ns, start_s, done_s, queue_wait_ms, read_decode_ms)
    ):
        times = _TIMES % (release_s, start_s, done_s, queue_wait_ms, read_decode_ms)
        latency = '%.4f' % latency_ms  # noqa: UP031 - the same format as the cells above
        if '-' not in times and 'n' not in times and '-' not in latency and 'n' not in latency:
            if stages == _NO_STAGES:
                staged = ',,,,'
            else:
                staged = ','.join(
                    [
                        '' if v is None else cell(v)
                        for cell, v in zip(_STAGE_CELLS, stages, strict=True)
                    ]
                )
            if device == _NO_STAGES:
                on_device = ',,,,'
            else:
                on_device = ','.join(
                    [
                        '' if v is None else cell(v)
                        for cell, v in zip(_DEVICE_CELLS, device, strict=True)
                    ]
                )
            quoted = _QUOTED
            try:
                return (
                    f'{input_:d},{quoted.get(backend) or _quote(backend)},'
                    f'{quoted.get(topic) or _quote(topic)},{seq:d},{log_time_ns:d},{stamp_ns:d},'
                    f'{quoted.get(status) or _quote(status)},{quoted.get(note) or _quote(note)},'
                    f'{"1" if warmup else "0"},{"1" if dropped else "0"},{times},{staged},'
                    f'{latency},{detections:d},{on_device},{repeat:d},{_scores(scores)},,,'
                    f'{_tag_cells(tagged)},{pipeline:d},{"" if age is None else _AGE_CELL(age)}\r\n'
                )
            except ValueError:  # an int cell holding something else
                pass
    buffer = io.StringIO()
    csv_writer(buffer).writerow(_row(record))
    return buffer.getvalue()


def as_written(record: FrameRecord) -> FrameRecord:
    """``record`` as frames.csv holds it: times rounded to the file's decimals (6 for ``*_s``,
    4 for ``*_ms`` and a task's values), non-finite ones None; what ``read_frames_csv`` reads
    back."""
    values = list(record)
    for index, cell in _ROUNDED:
        value = values[index]
        if value is not None:
            text = cell(value)
            values[index] = float(text) if text else None
    if record.task_values:
        values[-1] = {
            name: None if v is None or not (text := _TASK_CELL(v)) else float(text)
            for name, v in record.task_values.items()
        }
    return FrameRecord(*values)  # type: ignore[arg-type]


#: (index, cell formatter) of each float column of frames.csv
_ROUNDED: tuple[tuple[int, Callable[[object], str]], ...] = tuple(
    (i, _CELLS[i]) for i, name in enumerate(FRAMES_CSV_COLUMNS) if name in _FLOAT_FORMAT
)
_ROUNDED_BY_NAME: dict[str, Callable[[object], str]] = {
    FRAMES_CSV_COLUMNS[i]: cell for i, cell in _ROUNDED
}


def written(value: float, column: str) -> float:
    """One value of the float ``column`` as frames.csv holds it (``as_written`` for a single
    field, where rounding the whole record would be wasted); NaN for a non-finite value."""
    text = _ROUNDED_BY_NAME[column](value)
    return float(text) if text else math.nan


def _parse_bool(text: str) -> bool:
    if text in {'1', 'true', 'True'}:
        return True
    if text in {'0', 'false', 'False', ''}:
        return False
    msg = f'not a boolean: {text!r}'
    raise ValueError(msg)


def _parser(name: str) -> Callable[[str], object]:
    if name in _BOOL_FIELDS:
        return _parse_bool
    if name in _INT_FIELDS:
        return int
    if name in _FLOAT_FORMAT:
        return float
    return from_csv


_PARSERS: tuple[tuple[str, Callable[[str], object]], ...] = tuple(
    (name, _parser(name)) for name in FRAMES_CSV_COLUMNS
)


def _parse_row(cells: list[str], task_columns: Sequence[str] = ()) -> FrameRecord:
    values: list[object] = []
    for (name, parse), text in zip(_PARSERS, cells[: len(_PARSERS)], strict=True):
        if text == '' and name in _OPTIONAL_FIELDS:
            values.append(None)
        else:
            values.append(parse(text))
    if task_columns:
        texts = cells[len(_PARSERS) :]
        values.append(
            {name: float(t) if t else None for name, t in zip(task_columns, texts, strict=True)}
        )
    record = FrameRecord(*values)  # type: ignore[arg-type]
    if record.status not in _STATUSES:
        msg = f'unknown status {record.status!r}'
        raise ValueError(msg)
    return record


def csv_writer(file: IO[str]) -> Any:
    """The CSV writer of every CSV replaybench writes: RFC 4180 ``\r\n`` line ends.

    With ``\r\n`` as the line terminator the writer quotes every field that holds a ``\r``
    or a ``\n`` (a topic name may), so that readers split rows only at row ends.
    """
    return csv.writer(file, lineterminator='\r\n')


class FramesCsvWriter:
    """Stream ``FrameRecord`` rows to frames.csv.

    Rows go to ``<path>.part`` (flushed every ``flush_every`` rows, so a killed process leaves
    the rows done so far); ``close()`` renames it to ``path``. Used as a context manager it
    closes on exit also when the run is interrupted (``KeyboardInterrupt``), so an interrupted
    run still leaves a complete CSV holding the rows written before the interruption; on any
    other exception, and when a write fails, nothing is left: no ``path``, no ``.part``. A
    failed write raises ``OSError`` naming ``path``.
    """

    def __init__(
        self, path: str | Path, *, flush_every: int = 100, task_columns: Sequence[str] = ()
    ) -> None:
        self.path = Path(path)
        #: the columns after ``FRAMES_CSV_COLUMNS``: the frame values of the run's tasks that
        #: have no fields of their own (``FrameRecord.task_values``)
        self.task_columns = tuple(task_columns)
        _check_task_columns(self.task_columns, self.path)
        self.part_path = self.path.with_name(self.path.name + '.part')
        self._flush_every = max(1, flush_every)
        # a buffer larger than flush_every rows: rows reach the file when flushed, not before
        self._file: IO[str] | None = self.part_path.open(
            'w', newline='', encoding='utf-8', buffering=1 << 20
        )
        self._csv = csv_writer(self._file)
        self._csv.writerow((*FRAMES_CSV_COLUMNS, *self.task_columns))
        self._pending = 0
        self.rows = 0

    @property
    def closed(self) -> bool:
        """True once ``close()`` has run."""
        return self._file is None

    def write(self, record: FrameRecord) -> None:
        """Append one row."""
        if self._file is None:
            msg = f'{self.path}: writer is closed'
            raise ValueError(msg)
        try:
            if self.task_columns:
                self._file.write(
                    _line(record)[:-2] + _task_cells(record, self.task_columns) + '\r\n'
                )
            else:
                self._file.write(_line(record))
            self.rows += 1
            self._pending += 1
            if self._pending >= self._flush_every:
                self._file.flush()
                self._pending = 0
        except OSError as err:
            self.discard()
            raise with_filename(err, self.path) from None

    def write_many(self, records: Iterable[FrameRecord]) -> None:
        """Append several rows."""
        for record in records:
            self.write(record)

    def close(self) -> None:
        """Flush, sync and move the file into place; a second call does nothing."""
        if self._file is None:
            return
        file = self._file
        try:
            file.flush()
            os.fsync(file.fileno())
            self._file = None
            file.close()
            self.part_path.replace(self.path)
        except OSError as err:
            self.discard()
            raise with_filename(err, self.path) from None

    def discard(self) -> None:
        """Close without keeping anything: the ``.part`` file is removed."""
        file, self._file = self._file, None
        if file is not None:
            with contextlib.suppress(OSError):
                file.close()
        with contextlib.suppress(OSError):
            self.part_path.unlink(missing_ok=True)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if isinstance(exc, Exception):
            self.discard()
        else:
            self.close()


def _check_task_columns(columns: Sequence[str], path: Path) -> None:
    """``ValueError`` for task columns that repeat or take a known column's name."""
    if len(set(columns)) != len(columns) or set(columns) & set(FRAMES_CSV_COLUMNS):
        msg = f'{path}: task columns {list(columns)} repeat or take a frames.csv column name'
        raise ValueError(msg)


def read_frames_csv(path: str | Path) -> list[FrameRecord]:
    """Read a frames.csv written by ``FramesCsvWriter``; SourceError when it is not one.

    A frames.csv from before the ``*_device_ms`` columns, or before the recorded-output ones
    (``output_log_time_ns``, ``capture_to_output_ms``, ``pipeline_ms``), reads with them empty
    (None); one from before the ``pipeline`` column reads as pipeline 0 (a shared run's).
    """
    path = Path(path)
    try:
        with path.open(newline='', encoding='utf-8') as file:
            reader = csv.reader(file)
            header = next(reader, None)
            columns = tuple(header) if header is not None else ()
            # after the known columns: a task's without fields of its own
            task_columns: tuple[str, ...] = ()
            if columns[: len(FRAMES_CSV_COLUMNS)] == FRAMES_CSV_COLUMNS:
                columns, task_columns = FRAMES_CSV_COLUMNS, columns[len(FRAMES_CSV_COLUMNS) :]
                if len(set(task_columns)) != len(task_columns) or '' in task_columns:
                    columns = ()
            if columns not in _KNOWN_HEADERS:
                msg = f'{path}: not a frames.csv (header does not match the expected columns)'
                raise SourceError(msg) from None
            # an older file's absent columns: pass 0 of one, pipeline 0 (one shared
            # instance), the rest empty
            missing = [
                '0' if name in {'repeat', 'pipeline'} else ''
                for name in FRAMES_CSV_COLUMNS[len(columns) :]
            ]
            records = []
            for cells in reader:
                if not cells:
                    continue
                try:
                    width = len(columns) + len(task_columns)
                    if len(cells) != width:
                        msg = f'{len(cells)} cells, the header has {width}'
                        raise ValueError(msg)
                    known, extra = cells[: len(columns)], cells[len(columns) :]
                    records.append(_parse_row(known + missing + extra, task_columns))
                except ValueError as err:
                    msg = f'{path}:{reader.line_num}: bad row: {err}'
                    raise SourceError(msg) from err
    except OSError as err:
        msg = f'{path}: cannot read frames.csv: {err.strerror or err}'
        raise SourceError(msg) from err
    except csv.Error as err:
        msg = f'{path}: not a valid CSV: {err}'
        raise SourceError(msg) from err
    return records
