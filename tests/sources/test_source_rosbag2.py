from __future__ import annotations

import mmap
import sqlite3
from typing import TYPE_CHECKING

import pytest
import zstandard
from rosbags.rosbag2 import Reader
from sourcebags import (
    MS,
    STRING,
    T0,
    as_expected,
    expected_order,
    tie_plan,
    write_rosbag2,
    write_split_rosbag2,
)

from replaybench.errors import SourceError
from replaybench.sources import open_source

if TYPE_CHECKING:
    from pathlib import Path


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_rosbag2_messages_come_in_log_time_order_with_ties_broken_by_topic(
    tmp_path: Path, storage: str
) -> None:
    plan = tie_plan()
    path = write_rosbag2(tmp_path / 'bag', plan, storage)
    with open_source(path) as source:
        got = as_expected(source.messages())
        assert source.format == 'rosbag2'
        assert [f.parent for f in source.files] == [path]
        assert source.files[0].suffix == ('.db3' if storage == 'sqlite3' else '.mcap')
        assert not source.truncated
    assert got == expected_order(plan)


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_rosbag2_payloads_equal_what_rosbags_reads(tmp_path: Path, storage: str) -> None:
    path = write_rosbag2(tmp_path / 'bag', tie_plan(), storage)
    with Reader(path) as reader:
        reference = sorted((c.topic, t, bytes(d)) for c, t, d in reader.messages())
    with open_source(path) as source:
        got = sorted((m.topic, m.log_time_ns, bytes(m.data)) for m in source.messages())
    assert got == reference


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_rosbag2_seq_is_stable_under_topic_and_time_filters(tmp_path: Path, storage: str) -> None:
    plan = tie_plan()
    path = write_rosbag2(tmp_path / 'bag', plan, storage)
    full = expected_order(plan)
    start, end = full[23].log_time_ns, full[61].log_time_ns
    with open_source(path) as source:
        window = as_expected(source.messages(start_ns=start, end_ns=end))
        only_a = as_expected(source.messages(topics=['/a'], start_ns=start))
    assert window == [m for m in full if start <= m.log_time_ns < end]
    assert only_a == [m for m in full if m.topic == '/a' and m.log_time_ns >= start]
    assert only_a[0].seq > 0


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_rosbag2_topics_report_counts_and_first_last_log_time(tmp_path: Path, storage: str) -> None:
    plan = tie_plan()
    path = write_rosbag2(tmp_path / 'bag', plan, storage)
    with open_source(path) as source:
        topics = source.topics()
    assert [t.name for t in topics] == ['/a', '/b', '/c/slow']
    for info in topics:
        times = [t for topic, t, _ in plan if topic == info.name]
        assert (info.count, info.first_ns, info.last_ns) == (len(times), min(times), max(times))
        assert (info.msgtype, info.serialization) == (STRING, 'cdr')


def test_rosbag2_mcap_storage_yields_zero_copy_views(tmp_path: Path) -> None:
    path = write_rosbag2(tmp_path / 'bag', tie_plan(5), 'mcap')
    with open_source(path) as source:
        messages = list(source.messages())
    assert all(isinstance(m.data, memoryview) for m in messages)
    assert isinstance(messages[0].data.obj, mmap.mmap)  # type: ignore[union-attr]


def test_a_bare_db3_file_opens_as_rosbag2(tmp_path: Path) -> None:
    plan = tie_plan()
    bag = write_rosbag2(tmp_path / 'bag', plan, 'sqlite3')
    (db3,) = bag.glob('*.db3')
    with open_source(db3) as source:
        assert (source.format, source.files) == ('rosbag2', [db3])
        assert as_expected(source.messages()) == expected_order(plan)


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_a_split_bag_replays_as_one_input(tmp_path: Path, storage: str) -> None:
    # The parts overlap in time, so reading them one after the other would be out of order.
    first = [('/b', T0 + i * 10 * MS, f'/b#{i}') for i in range(0, 20, 2)]
    first += [('/a', T0 + i * 10 * MS, f'/a#{i}') for i in range(0, 20, 2)]
    second = [('/a', T0 + i * 10 * MS, f'/a#{i}') for i in range(1, 20, 2)]
    second += [('/b', T0 + i * 10 * MS, f'/b#{i}') for i in range(1, 20, 2)]
    second += [('/a', T0 + 40 * MS, '/a#4-second-file')]
    path = write_split_rosbag2(tmp_path / 'split', [first, second], storage)
    with open_source(path) as source:
        assert len(source.files) == 2
        got = as_expected(source.messages())
        counts = {t.name: t.count for t in source.topics()}
        late = as_expected(source.messages(topics=['/a'], start_ns=T0 + 100 * MS))
    expected = expected_order(first + second)
    assert got == expected
    assert counts == {'/a': 21, '/b': 20}
    assert late == [m for m in expected if m.topic == '/a' and m.log_time_ns >= T0 + 100 * MS]


@pytest.mark.parametrize(('storage', 'mode'), [('sqlite3', 'message'), ('mcap', 'file')])
def test_compressed_rosbag2_bags_yield_the_uncompressed_payloads(
    tmp_path: Path, storage: str, mode: str
) -> None:
    plan = tie_plan(12)
    path = write_rosbag2(tmp_path / 'bag', plan, storage, mode)
    with open_source(path) as source:
        assert as_expected(source.messages()) == expected_order(plan)
        assert {t.name: t.count for t in source.topics()}['/a'] == 13


@pytest.mark.parametrize(
    'bad',
    [
        pytest.param(b'garbage, not a zstd frame', id='not-zstd'),
        pytest.param(zstandard.ZstdCompressor().compress(bytes(2000))[:-3], id='cut-short'),
        pytest.param(zstandard.ZstdCompressor().compress(bytes(3000)), id='over-the-limit'),
    ],
)
def test_a_compressed_message_that_cannot_be_decompressed_is_skipped_and_counted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, bad: bytes
) -> None:
    monkeypatch.setattr('replaybench.sources._common.MAX_CHUNK_BYTES', 2500)
    plan = tie_plan(12)
    path = write_rosbag2(tmp_path / 'bag', plan, 'sqlite3', 'message')
    (db3,) = path.glob('*.db3')
    with sqlite3.connect(db3) as db:
        first_b, second_b = db.execute(
            'SELECT m.id FROM messages m JOIN topics t ON t.id = m.topic_id '
            "WHERE t.name = '/b' ORDER BY m.timestamp LIMIT 2"
        ).fetchall()
        for (row,) in (first_b, second_b):
            db.execute('UPDATE messages SET data = ? WHERE id = ?', (bad, row))
    db.close()
    expected = [m for m in expected_order(plan) if not (m.topic == '/b' and m.seq < 2)]
    with open_source(path) as source:
        got = as_expected(source.messages())
        warnings = source.warnings
    assert [(m.topic, m.log_time_ns, m.payload) for m in got] == [
        (m.topic, m.log_time_ns, m.payload) for m in expected
    ]
    assert len(warnings) == 1
    assert '2 message(s) on /b could not be decompressed' in warnings[0]
    assert db3.name in warnings[0]


def test_a_missing_data_file_is_a_one_line_source_error(tmp_path: Path) -> None:
    path = write_rosbag2(tmp_path / 'bag', tie_plan(3), 'mcap')
    next(path.glob('*.mcap')).unlink()
    with pytest.raises(SourceError, match='missing') as info:
        open_source(path)
    assert '\n' not in str(info.value)


def test_broken_metadata_is_a_one_line_source_error(tmp_path: Path) -> None:
    path = write_rosbag2(tmp_path / 'bag', tie_plan(3), 'sqlite3')
    (path / 'metadata.yaml').write_text('rosbag2_bagfile_information: [unclosed\n')
    with pytest.raises(SourceError, match='metadata') as info:
        open_source(path)
    assert '\n' not in str(info.value)
    assert info.value.__cause__ is not None  # the YAML parser's error, for --debug


def test_a_cut_mcap_in_a_rosbag2_directory_replays_what_is_complete(tmp_path: Path) -> None:
    plan = tie_plan(30)
    path = write_rosbag2(tmp_path / 'bag', plan, 'mcap')
    (data,) = path.glob('*.mcap')
    raw = data.read_bytes()
    data.write_bytes(raw[: len(raw) // 2])
    full = expected_order(plan)
    with open_source(path) as source:
        got = as_expected(source.messages())
        assert source.truncated
        assert any(data.name in line for line in source.warnings)
    complete = {m.payload for m in full if raw.find(m.payload) + len(m.payload) <= len(raw) // 2}
    assert {m.payload for m in got} == complete
    assert len(complete) > 10


def test_a_directory_of_one_mcap_file_without_metadata_is_replayed(tmp_path: Path) -> None:
    plan = tie_plan(3)
    path = write_rosbag2(tmp_path / 'bag', plan, 'mcap')
    (path / 'metadata.yaml').unlink()
    with open_source(path) as source:
        assert as_expected(source.messages()) == expected_order(plan)
        assert any('metadata.yaml is missing' in line for line in source.warnings)
