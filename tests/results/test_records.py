"""frames.csv: column order, fixed formatting, streaming and atomic writes, round trip."""

from __future__ import annotations

import csv
import io
from typing import TYPE_CHECKING, Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from replaybench.errors import SourceError
from replaybench.results.records import (
    FRAMES_CSV_COLUMNS,
    FrameRecord,
    FramesCsvWriter,
    _line,
    _row,
    csv_writer,
    read_frames_csv,
)

if TYPE_CHECKING:
    from pathlib import Path


def _ok(seq: int, **kw: object) -> FrameRecord:
    values: dict[str, object] = {
        'input': 0,
        'backend': 'hsv',
        'topic': '/cam/image_raw',
        'seq': seq,
        'log_time_ns': 1_700_000_000_000_000_000 + seq,
        'stamp_ns': 1_699_999_999_000_000_000 + seq,
        'status': 'ok',
        'note': '',
        'warmup': False,
        'dropped': False,
        'release_s': round(seq * 0.033333, 6),
        'start_s': round(seq * 0.033333 + 0.0001, 6),
        'done_s': round(seq * 0.033333 + 0.0051, 6),
        'queue_wait_ms': 0.1,
        'read_decode_ms': 0.25,
        'preprocess_ms': 1.5,
        'infer_ms': 2.75,
        'postprocess_ms': 0.5,
        'h2d_ms': None,
        'd2h_ms': None,
        'latency_ms': 5.1,
        'detections': 3,
    }
    values.update(kw)
    return FrameRecord(**values)  # type: ignore[arg-type]


def test_columns_are_in_the_documented_order() -> None:
    assert FRAMES_CSV_COLUMNS == (
        'input', 'backend', 'topic', 'seq', 'log_time_ns', 'stamp_ns', 'status', 'note',
        'warmup', 'dropped', 'release_s', 'start_s', 'done_s', 'queue_wait_ms',
        'read_decode_ms', 'preprocess_ms', 'infer_ms', 'postprocess_ms', 'h2d_ms', 'd2h_ms',
        'latency_ms', 'detections', 'preprocess_device_ms', 'infer_device_ms',
        'postprocess_device_ms', 'h2d_device_ms', 'd2h_device_ms', 'repeat', 'miou',
        'pixel_accuracy', 'output_log_time_ns', 'capture_to_output_ms', 'pipeline_ms',
        'tags', 'tag_truth', 'tag_matched', 'tag_wrong_ids', 'tag_phantoms', 'tag_corner_rmse_px',
        'tag_trans_err_m', 'tag_rot_err_deg', 'pipeline', 'output_age_ms',
    )  # fmt: skip


def test_every_kind_of_row_round_trips(tmp_path: Path) -> None:
    records = [
        _ok(0, warmup=True),
        _ok(1, h2d_ms=0.125, d2h_ms=0.0625),
        FrameRecord(
            1, 'null', '/b', 7, 123, None, 'dropped', 'pushed out, "queue" full', False, True, 0.25
        ),
        _ok(
            2,
            status='skipped',
            note='bad\njpeg; ünïcode',
            stamp_ns=None,
            infer_ms=None,
            preprocess_ms=None,
            postprocess_ms=None,
            latency_ms=None,
            detections=None,
        ),
    ]
    path = tmp_path / 'frames.csv'
    with FramesCsvWriter(path) as writer:
        writer.write_many(records)
    assert read_frames_csv(path) == records
    assert writer.rows == 4
    assert writer.closed


def test_values_are_written_with_fixed_precision(tmp_path: Path) -> None:
    path = tmp_path / 'frames.csv'
    record = _ok(
        0, release_s=1 / 3, start_s=-1e-9, done_s=2.0, latency_ms=1 / 3, queue_wait_ms=-0.00001
    )
    with FramesCsvWriter(path) as writer:
        writer.write(record)
    with path.open(newline='') as file:
        row = dict(zip(FRAMES_CSV_COLUMNS, list(csv.reader(file))[1], strict=True))
    assert row['release_s'] == '0.333333'
    assert row['start_s'] == '0.000000'
    assert row['done_s'] == '2.000000'
    assert row['latency_ms'] == '0.3333'
    assert row['queue_wait_ms'] == '0.0000'
    assert row['warmup'] == '0'
    assert row['h2d_ms'] == ''
    assert row['stamp_ns'] == '1699999999000000000'


def test_an_exception_inside_the_writer_still_leaves_a_complete_csv(tmp_path: Path) -> None:
    path = tmp_path / 'frames.csv'
    with pytest.raises(KeyboardInterrupt), FramesCsvWriter(path) as writer:  # noqa: PT012  the exception passes through the context manager under test
        for seq in range(250):
            writer.write(_ok(seq))
        raise KeyboardInterrupt
    assert path.exists()
    assert not (tmp_path / 'frames.csv.part').exists()
    records = read_frames_csv(path)
    assert [r.seq for r in records] == list(range(250))


def test_rows_reach_the_part_file_while_the_run_goes_on(tmp_path: Path) -> None:
    path = tmp_path / 'frames.csv'
    writer = FramesCsvWriter(path, flush_every=100)
    for seq in range(150):
        writer.write(_ok(seq))
    assert not path.exists()
    lines = (tmp_path / 'frames.csv.part').read_text().splitlines()
    assert len(lines) == 1 + 100
    writer.close()
    writer.close()
    assert len(read_frames_csv(path)) == 150
    with pytest.raises(ValueError, match='closed'):
        writer.write(_ok(151))


def test_a_file_with_other_columns_is_refused(tmp_path: Path) -> None:
    path = tmp_path / 'frames.csv'
    path.write_text('a,b,c\n1,2,3\n')
    with pytest.raises(SourceError, match=r'not a frames\.csv'):
        read_frames_csv(path)


def test_a_bad_row_names_its_line(tmp_path: Path) -> None:
    path = tmp_path / 'frames.csv'
    with FramesCsvWriter(path) as writer:
        writer.write(_ok(0))
        writer.write(_ok(1, status='exploded'))
    with pytest.raises(SourceError, match=r'frames\.csv:3: bad row') as caught:
        read_frames_csv(path)
    assert isinstance(caught.value.__cause__, ValueError)  # the cell's own error, for --debug


def test_a_missing_file_is_a_source_error(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match='cannot read'):
        read_frames_csv(tmp_path / 'nope.csv')


def test_a_topic_with_line_breaks_round_trips_through_frames_csv(tmp_path: Path) -> None:
    path = tmp_path / 'frames.csv'
    records = [
        FrameRecord(0, 'hsv', topic, 1, 10, None, 'ok', '', False, False, 0.5)
        for topic in ('\r', '/a\nb', '/cam\r\n/x', '/plain')
    ]
    with FramesCsvWriter(path) as writer:
        writer.write_many(records)
    assert read_frames_csv(path) == records


_TIMES = st.one_of(
    st.none(),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=0, max_value=1e6),
    st.sampled_from([0.0, -0.0, -1e-9, 1e-9, -0.00004]),
)
_TEXT = st.one_of(
    st.sampled_from(['', 'ok', '/cam/image_raw', 'a,b', 'say "hi"', '\r', 'x\ny']),
    st.text(max_size=8),
)


@settings(max_examples=400, deadline=None)
@given(
    ints=st.tuples(*[st.integers(0, 2**63) for _ in range(3)]),
    stamp=st.one_of(st.none(), st.integers(0, 2**63)),
    texts=st.tuples(_TEXT, _TEXT, st.sampled_from(['ok', 'dropped', 'skipped']), _TEXT),
    flags=st.tuples(st.booleans(), st.booleans()),
    release=st.floats(min_value=-1, max_value=1e6),
    times=st.tuples(*[_TIMES for _ in range(10)]),
    detections=st.one_of(st.none(), st.integers(0, 1000)),
)
def test_a_line_is_what_the_csv_writer_writes_for_the_row(
    ints: tuple[int, int, int],
    stamp: int | None,
    texts: tuple[str, str, str, str],
    flags: tuple[bool, bool],
    release: float,
    times: tuple[float | None, ...],
    detections: int | None,
) -> None:
    input_, seq, log_time = ints
    backend, topic, status, note = texts
    # the leading cells in column order (the device times keep their default); hypothesis
    # draws any text for the status
    cells: list[Any] = [
        input_,
        backend,
        topic,
        seq,
        log_time,
        stamp,
        status,
        note,
        *flags,
        release,
        *times,
        detections,
    ]
    record = FrameRecord(*cells)
    buffer = io.StringIO()
    csv_writer(buffer).writerow(_row(record))
    assert _line(record) == buffer.getvalue()


def test_a_plain_ok_row_takes_the_one_format_path() -> None:
    record = FrameRecord(
        0,
        'hsv',
        '/cam/image_raw',
        3,
        10,
        10,
        'ok',
        '',
        False,
        False,
        0.5,
        0.5,
        0.51,
        0.0,
        1.25,
        None,
        2.5,
        None,
        None,
        None,
        3.75,
        2,
    )
    assert _line(record) == (
        '0,hsv,/cam/image_raw,3,10,10,ok,,0,0,0.500000,0.500000,0.510000,0.0000,1.2500,'
        ',2.5000,,,,3.7500,2,,,,,,0,,,,,,,,,,,,,,0,\r\n'
    )
    assert _line(record._replace(pipeline=3)).endswith(',,,,,,,,,3,\r\n')
    assert _line(record._replace(output_age_ms=66.66667)).endswith(',,,,,,,,,0,66.6667\r\n')
    buffer = io.StringIO()
    csv_writer(buffer).writerow(_row(record._replace(pipeline=3)))
    assert _line(record._replace(pipeline=3)) == buffer.getvalue()


def test_a_frames_csv_without_the_pipeline_column_reads_as_pipeline_0(tmp_path: Path) -> None:
    path = tmp_path / 'frames.csv'
    with FramesCsvWriter(path) as writer:
        writer.write_many([_ok(0, pipeline=2), _ok(1, topic='/b', pipeline=1)])
    assert [r.pipeline for r in read_frames_csv(path)] == [2, 1]
    with path.open(newline='', encoding='utf-8') as file:
        rows = list(csv.reader(file))
    assert rows[0][-2:] == ['pipeline', 'output_age_ms']
    older = tmp_path / 'older.csv'
    with older.open('w', newline='', encoding='utf-8') as file:
        csv_writer(file).writerows([row[:-2] for row in rows])
    read = read_frames_csv(older)
    assert [r.pipeline for r in read] == [0, 0]
    assert [r._replace(pipeline=0) for r in read_frames_csv(path)] == read


def test_the_output_age_round_trips_and_a_file_without_its_column_reads_it_empty(
    tmp_path: Path,
) -> None:
    path = tmp_path / 'frames.csv'
    with FramesCsvWriter(path) as writer:
        writer.write_many([_ok(0), _ok(1, output_age_ms=33.3333)])
    assert [r.output_age_ms for r in read_frames_csv(path)] == [None, 33.3333]
    with path.open(newline='', encoding='utf-8') as file:
        rows = list(csv.reader(file))
    assert [row[-1] for row in rows] == ['output_age_ms', '', '33.3333']
    older = tmp_path / 'older.csv'
    with older.open('w', newline='', encoding='utf-8') as file:
        csv_writer(file).writerows([row[:-1] for row in rows])
    assert [r.output_age_ms for r in read_frames_csv(older)] == [None, None]
