"""Hostile rosbag2 sqlite bags (directory with metadata.yaml, and the bare .db3): corrupted
pages, files cut at page boundaries, wrong or missing topic types, broken message blobs and
images claiming huge sizes."""

from __future__ import annotations

import tempfile
import tracemalloc
from pathlib import Path
from typing import Any

import pytest
from fuzz.fuzzkit import (
    cdr_image_fields,
    cleanup,
    db3_page_size,
    db3_structural_spans,
    edit_db3,
    every_or_sample,
    fixture_bytes,
    flip_bits,
    fuzz_settings,
    overwrite,
    put_uint,
    replay,
    write_case,
)
from hypothesis import given
from hypothesis import strategies as st

DIR = 'bgr8_rosbag2'
DB3 = 'bgr8_rosbag2.db3'
META = 'metadata.yaml'
MEMORY_LIMIT = 200 << 20


def db3_bytes() -> bytes:
    return fixture_bytes(f'{DIR}/{DB3}')


def meta_bytes() -> bytes:
    return fixture_bytes(f'{DIR}/{META}')


def make_case(tmp_path: Path, db3: bytes, bare: bool, meta: bytes | None = None) -> Path:
    """A bag directory (or a bare .db3) holding ``db3``; returns the path to replay."""
    if bare:
        return write_case(tmp_path, {DB3: db3}) / DB3
    return write_case(tmp_path, {f'{DIR}/{DB3}': db3, f'{DIR}/{META}': meta or meta_bytes()}) / DIR


def positions(data: bytes) -> st.SearchStrategy[int]:
    spans = db3_structural_spans(data)
    structural = st.sampled_from(spans).flatmap(lambda s: st.integers(s[0], s[1] - 1))
    return st.one_of(structural, structural, st.integers(0, len(data) - 1))


@fuzz_settings(1.5)
@given(draw=st.data(), bare=st.booleans())
def test_corrupted_db3_replays_or_fails_cleanly(tmp_path, draw, bare):
    data = db3_bytes()
    if draw.draw(st.booleans(), label='flip'):
        flips = draw.draw(
            st.lists(st.tuples(positions(data), st.integers(0, 7)), min_size=1, max_size=8)
        )
        data = flip_bits(data, flips)
    else:
        new = draw.draw(st.one_of(st.binary(min_size=1, max_size=16), st.just(b'\xff' * 8)))
        data = overwrite(data, draw.draw(positions(data)), new)
    case = make_case(tmp_path, data, bare)
    outcome = replay(case, tmp_path, info=True)
    cleanup(case, outcome.out)


def page_cuts() -> list[int]:
    data = db3_bytes()
    size = db3_page_size(data)
    return every_or_sample(list(range(0, len(data), size)), 24)


@pytest.mark.parametrize('cut', page_cuts(), ids=str)
def test_db3_cut_at_a_page_boundary_replays_or_fails_cleanly(tmp_path, cut):
    data = db3_bytes()
    bare = (cut // db3_page_size(data)) % 2 == 1
    case = make_case(tmp_path, data[:cut], bare)
    outcome = replay(case, tmp_path)
    image_rows = [r for r in outcome.rows if r['topic'] == '/camera/image_raw']
    assert len(image_rows) <= 10
    cleanup(case, outcome.out)


# -- topic types, definitions and message blobs --------------------------------------------

TYPES = [
    '',
    'garbage',
    'sensor_msgs/msg/CompressedImage',
    'sensor_msgs/msg/CameraInfo',
    'sensor_msgs/msg/Image',
    'vision_msgs/msg/Detection2DArray',
    'std_msgs/msg/String',
    'sensor_msgs/Image',
    'a/b/c/d',
]
TEXT = st.text(max_size=20)
IDS = st.integers(1, 4)
MESSAGE_IDS = st.integers(1, 31)


@st.composite
def sql_edits(draw) -> list[tuple[str, tuple[Any, ...]]]:
    """A few statements that damage the bag's meaning while keeping it a valid database."""
    edits: list[tuple[str, tuple[Any, ...]]] = []
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(
            st.sampled_from(
                ['type', 'format', 'drop_topic', 'definition', 'blob', 'time', 'topic_id',
                 'drop_table', 'metadata']
            )
        )  # fmt: skip
        if kind == 'type':
            value = draw(st.one_of(st.sampled_from(TYPES), TEXT))
            edits.append(('UPDATE topics SET type = ? WHERE id = ?', (value, draw(IDS))))
        elif kind == 'format':
            value = draw(st.one_of(st.sampled_from(['ros1', 'json', '', 'CDR', 'cdr ']), TEXT))
            edits.append(
                ('UPDATE topics SET serialization_format = ? WHERE id = ?', (value, draw(IDS)))
            )
        elif kind == 'drop_topic':
            edits.append(('DELETE FROM topics WHERE id = ?', (draw(IDS),)))
        elif kind == 'definition':
            text = draw(st.one_of(st.just(''), TEXT, st.just('uint8[] data')))
            encoding = draw(st.sampled_from(['ros2msg', 'ros2idl', '', 'garbage']))
            sql = (
                'UPDATE message_definitions SET encoded_message_definition = ?, '
                'encoding = ? WHERE id = ?'
            )
            edits.append((sql, (text, encoding, draw(IDS))))
        elif kind == 'blob':
            blob = draw(
                st.one_of(
                    st.binary(max_size=64),
                    st.just(b''),
                    st.integers(0, 240_000).map(lambda n: -n),  # keep only the first n bytes
                )
            )
            if isinstance(blob, int):
                edits.append(
                    (
                        'UPDATE messages SET data = substr(data, 1, ?) WHERE id = ?',
                        (-blob, draw(MESSAGE_IDS)),
                    )
                )
            else:
                edits.append(
                    ('UPDATE messages SET data = ? WHERE id = ?', (blob, draw(MESSAGE_IDS)))
                )
        elif kind == 'time':
            value = draw(st.sampled_from([0, -1, 2**63 - 1, -(2**63), 1_700_000_000_000_000_000]))
            edits.append(
                ('UPDATE messages SET timestamp = ? WHERE id = ?', (value, draw(MESSAGE_IDS)))
            )
        elif kind == 'topic_id':
            value = draw(st.sampled_from([0, 1, 2, 3, 99, -1]))
            edits.append(
                ('UPDATE messages SET topic_id = ? WHERE id = ?', (value, draw(MESSAGE_IDS)))
            )
        elif kind == 'drop_table':
            table = draw(st.sampled_from(['message_definitions', 'metadata', 'schema', 'topics']))
            edits.append((f'DROP TABLE {table}', ()))
        else:
            edits.append(('UPDATE metadata SET metadata = ?', (draw(TEXT),)))
    return edits


def edited_db3(edits: list[tuple[str, tuple[Any, ...]]]) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / DB3
        path.write_bytes(db3_bytes())
        edit_db3(path, edits)
        return path.read_bytes()


@fuzz_settings(1.5)
@given(edits=sql_edits(), bare=st.booleans())
def test_db3_with_wrong_types_and_broken_rows_replays_or_fails_cleanly(tmp_path, edits, bare):
    case = make_case(tmp_path, edited_db3(edits), bare)
    outcome = replay(case, tmp_path, backends=('null', 'hsv'), report=True, info=True)
    cleanup(case, outcome.out)


META_EDITS = [
    (b'type: sensor_msgs/msg/Image', b'type: sensor_msgs/msg/Imagf'),
    (b'type: sensor_msgs/msg/Image', b'type: sensor_msgs/msg/CameraInfo'),
    (b'serialization_format: cdr', b'serialization_format: ros1'),
    (b'storage_identifier: sqlite3', b'storage_identifier: mcap'),
    (b'storage_identifier: sqlite3', b'storage_identifier: nope'),
    (b'  - bgr8_rosbag2.db3', b'  - missing.db3'),
    (b'  - bgr8_rosbag2.db3', b'  - ../bgr8_rosbag2.db3'),
    (b'version: 8', b'version: 99'),
    (b'version: 8', b'version: x'),
    (b"compression_mode: ''", b'compression_mode: file'),
    (b"compression_format: ''", b'compression_format: zstd'),
    (b'message_count: 30', b'message_count: 18446744073709551615'),
    (b'rosbag2_bagfile_information:', b'rosbag2_bagfile_informatio:'),
    (b'relative_file_paths:', b'relative_file_paths: 7\nx:'),
    (b'topics_with_message_count:', b'topics_with_message_count: 3\nx:'),
]


@pytest.mark.parametrize(('old', 'new'), META_EDITS, ids=[n.decode() for _, n in META_EDITS])
def test_bag_directory_with_wrong_metadata_replays_or_fails_cleanly(tmp_path, old, new):
    meta = meta_bytes()
    assert old in meta
    case = make_case(tmp_path, db3_bytes(), bare=False, meta=meta.replace(old, new))
    outcome = replay(case, tmp_path, info=True)
    cleanup(case, outcome.out)


@fuzz_settings(0.5)
@given(
    which=st.sets(st.integers(0, 9), min_size=1, max_size=10),
    width=st.sampled_from([100_000, 65_536, 2**31, 2**32 - 1, 0, 320]),
    height=st.sampled_from([100_000, 32_769, 2**32 - 1, 240]),
    bare=st.booleans(),
)
def test_db3_image_claiming_huge_dimensions_is_rejected_before_allocation(
    tmp_path, which, width, height, bare
):
    import sqlite3

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / DB3
        path.write_bytes(db3_bytes())
        db = sqlite3.connect(path)
        rows = db.execute(
            'SELECT m.id, m.data FROM messages m JOIN topics t ON m.topic_id = t.id '
            "WHERE t.name = '/camera/image_raw' ORDER BY m.timestamp"
        ).fetchall()
        for i, (mid, blob) in enumerate(rows):
            if i in which:
                fields = cdr_image_fields(blob, 0)
                blob = put_uint(blob, fields['width'].pos, 4, width)
                blob = put_uint(blob, fields['height'].pos, 4, height)
                db.execute('UPDATE messages SET data = ? WHERE id = ?', (blob, mid))
        db.commit()
        db.close()
        data = path.read_bytes()
    case = make_case(tmp_path, data, bare)
    tracemalloc.start()
    try:
        outcome = replay(case, tmp_path, backends=('hsv',))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MEMORY_LIMIT, f'{peak >> 20} MiB traced'
    cleanup(case, outcome.out)
