from __future__ import annotations

import bz2
import mmap
import struct
from typing import TYPE_CHECKING, Any

import lz4.frame
import pytest
from rosbags.rosbag1 import Reader
from sourcebags import STRING, as_expected, expected_order, ros1, tie_plan, write_bag

from replaybench.errors import SourceError
from replaybench.sources import open_source

if TYPE_CHECKING:
    from pathlib import Path


@pytest.mark.parametrize('compression', ['none', 'bz2', 'lz4'])
@pytest.mark.parametrize('chunk_threshold', [200, 1 << 20])
def test_bag_messages_come_in_log_time_order_with_ties_broken_by_topic(
    tmp_path: Path, compression: str, chunk_threshold: int
) -> None:
    plan = tie_plan()
    path = write_bag(tmp_path / 'ties.bag', plan, compression, chunk_threshold)
    with open_source(path) as source:
        got = as_expected(source.messages())
        assert (source.format, source.files, source.truncated) == ('rosbag1', [path], False)
        assert source.warnings == []
    assert got == expected_order(plan, ros1)


def test_bag_payloads_equal_what_rosbags_reads(tmp_path: Path) -> None:
    path = write_bag(tmp_path / 'same.bag', tie_plan(), 'lz4', 300)
    with Reader(path) as reader:
        reference = sorted((c.topic, t, bytes(d)) for c, t, d in reader.messages())
    with open_source(path) as source:
        got = sorted((m.topic, m.log_time_ns, bytes(m.data)) for m in source.messages())
    assert got == reference


def test_one_topic_on_two_connections_keeps_file_order_and_one_seq(tmp_path: Path) -> None:
    plan = tie_plan()
    path = write_bag(tmp_path / 'two.bag', plan, 'none', 300, two_connections=True)
    with open_source(path) as source:
        got = as_expected(source.messages())
        topics = {t.name: t.count for t in source.topics()}
    assert got == expected_order(plan, ros1)
    assert topics['/a'] == sum(1 for topic, *_ in plan if topic == '/a')


def test_bag_seq_is_stable_under_topic_and_time_filters(tmp_path: Path) -> None:
    plan = tie_plan()
    path = write_bag(tmp_path / 'filters.bag', plan, 'bz2', 300)
    full = expected_order(plan, ros1)
    start, end = full[21].log_time_ns, full[44].log_time_ns
    with open_source(path) as source:
        window = as_expected(source.messages(['/b', '/c/slow'], start, end))
    assert window == [
        m for m in full if m.topic in {'/b', '/c/slow'} and start <= m.log_time_ns < end
    ]
    assert window[0].seq > 0


def test_uncompressed_bag_data_is_a_zero_copy_view_of_the_file(tmp_path: Path) -> None:
    plan = tie_plan(6)
    path = write_bag(tmp_path / 'zero.bag', plan)
    with open_source(path) as source:
        for msg, exp in zip(source.messages(), expected_order(plan, ros1), strict=True):
            assert isinstance(msg.data, memoryview)
            assert isinstance(msg.data.obj, mmap.mmap)
            assert bytes(msg.data) == exp.payload


def test_bag_msgtypes_use_ros2_spelling_and_ros1_serialization(tmp_path: Path) -> None:
    path = write_bag(tmp_path / 'types.bag', tie_plan(4))
    assert b'type=std_msgs/String' in path.read_bytes()
    with open_source(path) as source:
        infos = source.topics()
        msg = next(source.messages())
    assert {(t.msgtype, t.serialization) for t in infos} == {(STRING, 'ros1')}
    assert (msg.msgtype, msg.serialization, msg.schema) == (STRING, 'ros1', b'')


def _check_cut(got: list[Any], full: list[Any]) -> None:
    rank = {m.payload: i for i, m in enumerate(full)}
    order = [rank[m.payload] for m in got]
    assert order == sorted(order)
    seen: dict[str, int] = {}
    for m in got:
        assert m.seq == seen.get(m.topic, 0)
        seen[m.topic] = m.seq + 1


def test_truncated_bag_replays_every_complete_message(tmp_path: Path) -> None:
    plan = tie_plan(40)
    path = write_bag(tmp_path / 'whole.bag', plan, 'none', 500)
    raw = path.read_bytes()
    full = expected_order(plan, ros1)
    ends = {}
    for m in full:
        assert raw.count(m.payload) == 1
        ends[m.payload] = raw.find(m.payload) + len(m.payload)
    index_pos = struct.unpack_from('<Q', raw, raw.find(b'index_pos=') + 10)[0]
    assert 4096 < index_pos < len(raw)
    size = len(raw)
    cuts = {13, 100, 4200, size // 4, size // 3, size // 2, 3 * size // 4, index_pos, size - 5}
    for cut in sorted(cuts):
        cut_path = tmp_path / f'cut{cut}.bag'
        cut_path.write_bytes(raw[:cut])
        with open_source(cut_path) as source:
            got = as_expected(source.messages())
            assert source.truncated, cut
            assert any('before the cut' in line for line in source.warnings)
        assert {m.payload for m in got} == {p for p, end in ends.items() if end <= cut}, cut
        _check_cut(got, full)


@pytest.mark.parametrize('compression', ['bz2', 'lz4'])
def test_truncated_compressed_bag_replays_every_complete_chunk(
    tmp_path: Path, compression: str
) -> None:
    plan = tie_plan(40)
    path = write_bag(tmp_path / 'whole.bag', plan, compression, 500)
    raw = path.read_bytes()
    full = expected_order(plan, ros1)
    decompress = bz2.decompress if compression == 'bz2' else lz4.frame.decompress
    with Reader(path) as reader:
        chunks = [
            (c.datapos + c.datasize, decompress(raw[c.datapos : c.datapos + c.datasize]))
            for c in reader.chunks.values()
        ]
    assert len(chunks) > 3
    data_size = len(raw) - 4109  # after the magic and the 4 KiB bag header record
    for cut in sorted({4109 + data_size * f // 10 for f in (2, 4, 6, 8)} | {len(raw) - 3}):
        cut_path = tmp_path / f'cut{cut}.bag'
        cut_path.write_bytes(raw[:cut])
        with open_source(cut_path) as source:
            got = as_expected(source.messages())
            assert source.truncated
        complete = {
            m.payload for m in full if any(end <= cut and m.payload in d for end, d in chunks)
        }
        assert complete <= {m.payload for m in got} <= {m.payload for m in full}, cut
        _check_cut(got, full)
    assert len(complete) == len(full)


def test_unclosed_bag_without_index_replays_its_flushed_chunks(tmp_path: Path) -> None:
    plan = tie_plan(40)
    path = write_bag(tmp_path / 'open.bag', plan, 'lz4', 300, close=False)
    with pytest.raises(Exception, match='not indexed'):
        Reader(path).open()
    with open_source(path) as source:
        got = as_expected(source.messages())
        assert source.truncated
        assert any('not indexed' in line for line in source.warnings)
    assert len(got) > len(plan) // 2
    _check_cut(got, expected_order(plan, ros1))


def test_bag_of_another_version_is_refused_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / 'old.bag'
    path.write_bytes(b'#ROSBAG V1.2\n' + bytes(100))
    with pytest.raises(SourceError, match=r'version 1\.2') as info:
        open_source(path)
    assert '\n' not in str(info.value)
