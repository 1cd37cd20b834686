from __future__ import annotations

import mmap
from typing import TYPE_CHECKING, Any

import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer
from sourcebags import (
    STRING,
    T0,
    TS2,
    as_expected,
    cdr,
    expected_order,
    tie_plan,
    write_bag,
    write_mcap,
)

from replaybench.errors import SourceError
from replaybench.sources import open_source
from replaybench.sources.mcap import McapSource

if TYPE_CHECKING:
    from pathlib import Path


@pytest.mark.parametrize('compression', ['none', 'zstd', 'lz4'])
@pytest.mark.parametrize('chunk_size', [300, 1 << 20])
def test_messages_come_in_log_time_order_with_ties_broken_by_topic(
    tmp_path: Path, compression: str, chunk_size: int
) -> None:
    plan = tie_plan()
    path = write_mcap(tmp_path / 'ties.mcap', plan, compression, chunk_size)
    with open_source(path) as source:
        got = as_expected(source.messages())
        assert source.format == 'mcap'
        assert source.files == [path]
        assert not source.truncated
        assert source.warnings == []
    assert got == expected_order(plan)


def test_every_run_yields_the_identical_sequence(tmp_path: Path) -> None:
    path = write_mcap(tmp_path / 'det.mcap', tie_plan(), 'zstd', 500)
    with open_source(path) as source:
        first = as_expected(source.messages())
        second = as_expected(source.messages())
    with open_source(path) as source:
        third = as_expected(source.messages())
    assert first == second == third


@pytest.mark.parametrize('compression', ['none', 'lz4'])
def test_seq_is_stable_under_topic_and_time_filters(tmp_path: Path, compression: str) -> None:
    plan = tie_plan()
    path = write_mcap(tmp_path / 'filters.mcap', plan, compression, 400)
    full = expected_order(plan)
    start, end = full[17].log_time_ns, full[50].log_time_ns
    with open_source(path) as source:
        window = as_expected(source.messages(start_ns=start, end_ns=end))
        only_a = as_expected(source.messages(topics=['/a']))
        both = as_expected(source.messages(topics={'/a', '/c/slow'}, start_ns=start))
        as_string = as_expected(source.messages(topics='/a'))
    assert window == [m for m in full if start <= m.log_time_ns < end]
    assert window[0].log_time_ns == start
    assert all(m.log_time_ns != end for m in window)
    assert only_a == [m for m in full if m.topic == '/a']
    assert both == [m for m in full if m.topic in {'/a', '/c/slow'} and m.log_time_ns >= start]
    assert as_string == only_a
    assert window[0].seq > 0


def test_empty_filters_yield_nothing(tmp_path: Path) -> None:
    path = write_mcap(tmp_path / 'empty.mcap', tie_plan(10))
    with open_source(path) as source:
        assert list(source.messages(topics=['/nope'])) == []
        assert list(source.messages(start_ns=T0 + 10**12)) == []
        assert list(source.messages(start_ns=T0 + 50, end_ns=T0 + 50)) == []
        assert list(source.messages(end_ns=0)) == []


def test_uncompressed_chunk_data_is_a_zero_copy_view_of_the_file(tmp_path: Path) -> None:
    plan = tie_plan(8)
    path = write_mcap(tmp_path / 'zero.mcap', plan, 'none')
    expected = expected_order(plan)
    with open_source(path) as source:
        messages = list(source.messages())
        for msg, exp in zip(messages, expected, strict=True):
            assert isinstance(msg.data, memoryview)
            assert isinstance(msg.data.obj, mmap.mmap)
            assert msg.data.readonly
            assert bytes(msg.data) == exp.payload
        del msg
    # Messages outlive the source: closing never invalidates what was yielded.
    assert bytes(messages[0].data) == expected[0].payload


@pytest.mark.parametrize('compression', ['zstd', 'lz4'])
def test_compressed_chunks_yield_the_same_messages_as_the_mcap_reader(
    tmp_path: Path, compression: str
) -> None:
    plan = tie_plan(60)
    path = write_mcap(tmp_path / 'comp.mcap', plan, compression, 700)
    with path.open('rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        assert {c.compression for c in summary.chunk_indexes} == {compression}
        reference = sorted(
            (channel.topic, message.log_time, message.data)
            for _, channel, message in reader.iter_messages()
        )
    with open_source(path) as source:
        got = list(source.messages())
    assert all(isinstance(m.data, memoryview) for m in got)
    assert sorted((m.topic, m.log_time_ns, bytes(m.data)) for m in got) == reference
    assert as_expected(got) == expected_order(plan)


def test_topics_report_counts_types_and_first_last_log_time(tmp_path: Path) -> None:
    plan = tie_plan()
    path = write_mcap(tmp_path / 'topics.mcap', plan, 'zstd', 500)
    with open_source(path) as source:
        topics = source.topics()
    assert [t.name for t in topics] == ['/a', '/b', '/c/slow']
    for info in topics:
        times = [t for topic, t, _ in plan if topic == info.name]
        assert info.count == len(times)
        assert (info.first_ns, info.last_ns) == (min(times), max(times))
        assert info.msgtype == STRING
        assert info.serialization == 'cdr'


def _cut_points(size: int) -> list[int]:
    return sorted({8, 30, size // 5, size // 3, size // 2, 2 * size // 3, size - 200, size - 1})


def _check_cut_order(got: list[Any], full: list[Any]) -> None:
    """Yielded messages keep the replay order; seq numbers each topic's yielded messages."""
    rank = {(m.topic, m.payload): i for i, m in enumerate(full)}
    assert [rank[(m.topic, m.payload)] for m in got] == sorted(
        rank[(m.topic, m.payload)] for m in got
    )
    seen: dict[str, int] = {}
    for m in got:
        assert m.seq == seen.get(m.topic, 0)
        seen[m.topic] = m.seq + 1


def test_truncated_mcap_replays_every_complete_message(tmp_path: Path) -> None:
    plan = tie_plan(40)
    path = write_mcap(tmp_path / 'whole.mcap', plan, 'none', 600)
    raw = path.read_bytes()
    full = expected_order(plan)
    # A payload is the end of its Message record: it is complete when its last byte is there.
    ends = {}
    for m in full:
        assert raw.count(m.payload) == 1
        ends[m.payload] = raw.find(m.payload) + len(m.payload)
    for cut in _cut_points(len(raw)):
        cut_path = tmp_path / f'cut{cut}.mcap'
        cut_path.write_bytes(raw[:cut])
        with open_source(cut_path) as source:
            got = as_expected(source.messages())
            assert source.truncated, cut
            assert any('cut short' in line for line in source.warnings)
            assert sum(t.count for t in source.topics()) == len(got)
        assert {m.payload for m in got} == {p for p, end in ends.items() if end <= cut}, cut
        _check_cut_order(got, full)


@pytest.mark.parametrize('compression', ['zstd', 'lz4'])
def test_truncated_compressed_mcap_replays_every_complete_chunk(
    tmp_path: Path, compression: str
) -> None:
    plan = tie_plan(40)
    path = write_mcap(tmp_path / 'whole.mcap', plan, compression, 600)
    raw = path.read_bytes()
    full = expected_order(plan)
    chunks: list[tuple[int, set[bytes]]] = []
    with path.open('rb') as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        for index in summary.chunk_indexes:
            f.seek(index.chunk_start_offset + 9)
            records = breakup_chunk(Chunk.read(ReadDataStream(f)))
            payloads = {r.data for r in records if isinstance(r, Message)}
            chunks.append((index.chunk_start_offset + index.chunk_length, payloads))
    assert len(chunks) > 3
    for cut in _cut_points(len(raw)):
        cut_path = tmp_path / f'cut{cut}.mcap'
        cut_path.write_bytes(raw[:cut])
        with open_source(cut_path) as source:
            got = as_expected(source.messages())
            assert source.truncated
        complete = set().union(*(p for end, p in chunks if end <= cut))
        assert complete <= {m.payload for m in got} <= {m.payload for m in full}, cut
        _check_cut_order(got, full)


def test_cut_in_the_summary_still_replays_everything(tmp_path: Path) -> None:
    plan = tie_plan(20)
    path = write_mcap(tmp_path / 'whole.mcap', plan, 'zstd', 400)
    raw = path.read_bytes()
    cut_path = tmp_path / 'cut.mcap'
    cut_path.write_bytes(raw[:-20])
    with open_source(cut_path) as source:
        got = as_expected(source.messages())
        assert source.truncated
    assert got == expected_order(plan)


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_mcap_without_index_is_scanned_in_the_same_order(tmp_path: Path, compression: str) -> None:
    plan = tie_plan()
    path = write_mcap(tmp_path / 'noindex.mcap', plan, compression, 400, indexed=False)
    with path.open('rb') as f:
        summary = make_reader(f).get_summary()
        assert summary is None or not summary.chunk_indexes
    with open_source(path) as source:
        got = as_expected(source.messages())
        assert not source.truncated
        counts = {t.name: t.count for t in source.topics()}
    assert got == expected_order(plan)
    assert counts == {name: [t for t, *_ in plan].count(name) for name in ('/a', '/b', '/c/slow')}
    assert counts['/a'] == counts['/b'] + 1


def test_unchunked_mcap_is_read_from_its_records(tmp_path: Path) -> None:
    plan = tie_plan()
    path = write_mcap(tmp_path / 'flat.mcap', plan, chunked=False)
    with open_source(path) as source:
        messages = list(source.messages())
        assert not source.truncated
        assert as_expected(messages) == expected_order(plan)
        assert isinstance(messages[0].data.obj, mmap.mmap)  # type: ignore[union-attr]


def test_ros1_style_schema_names_use_ros2_spelling(tmp_path: Path) -> None:
    plan = [('/x', T0, 'one')]
    path = write_mcap(
        tmp_path / 'ros1.mcap', plan, schema_name='std_msgs/String', message_encoding='ros1'
    )
    with open_source(path) as source:
        (info,) = source.topics()
        (msg,) = source.messages()
    assert (info.msgtype, info.serialization) == ('std_msgs/msg/String', 'ros1')
    assert (msg.msgtype, msg.serialization, msg.schema) == ('std_msgs/msg/String', 'ros1', b'')


def test_protobuf_channels_carry_schema_name_and_descriptor(tmp_path: Path) -> None:
    descriptor = b'\x0a\x10fake-descriptor'
    path = tmp_path / 'pb.mcap'
    with path.open('wb') as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile='', library='tests')
        schema = writer.register_schema('foxglove.RawImage', 'protobuf', descriptor)
        channel = writer.register_channel('/cam', 'protobuf', schema)
        writer.add_message(channel, log_time=5, publish_time=5, data=b'\x08\x01')
        writer.finish()
    with open_source(path) as source:
        (msg,) = source.messages()
        (info,) = source.topics()
    assert (msg.msgtype, msg.serialization, msg.schema) == (
        'foxglove.RawImage',
        'protobuf',
        descriptor,
    )
    assert bytes(msg.data) == b'\x08\x01'
    assert (info.msgtype, info.serialization, info.count) == ('foxglove.RawImage', 'protobuf', 1)


def test_channels_with_unsupported_encodings_are_skipped_with_a_warning(tmp_path: Path) -> None:
    path = tmp_path / 'json.mcap'
    with path.open('wb') as f:
        writer = Writer(f, compression=CompressionType.NONE)
        writer.start(profile='', library='tests')
        js = writer.register_schema('thing', 'jsonschema', b'{}')
        text = TS2.generate_msgdef(STRING, ros_version=2)[0].encode()
        ros = writer.register_schema(STRING, 'ros2msg', text)
        json_channel = writer.register_channel('/json', 'json', js)
        cdr_channel = writer.register_channel('/cdr', 'cdr', ros)
        writer.add_message(json_channel, log_time=1, publish_time=1, data=b'{}')
        writer.add_message(cdr_channel, log_time=2, publish_time=2, data=cdr('ok'))
        writer.finish()
    with open_source(path) as source:
        assert [m.topic for m in source.messages()] == ['/cdr']
        assert [t.name for t in source.topics()] == ['/cdr']
        assert any('/json' in line and 'json' in line for line in source.warnings)


def test_a_closed_source_refuses_to_read(tmp_path: Path) -> None:
    path = write_mcap(tmp_path / 'closed.mcap', tie_plan(4))
    source = McapSource(path)
    kept = next(source.messages())
    source.close()
    source.close()
    with pytest.raises(SourceError, match='closed'):
        source.messages()
    with pytest.raises(SourceError, match='closed'):
        source.topics()
    assert bytes(kept.data) == cdr('/b#0') or bytes(kept.data) == cdr('/a#0')


def test_an_mcap_magic_followed_by_garbage_is_a_cut_file_with_no_messages(
    tmp_path: Path,
) -> None:
    path = tmp_path / 'garbage.mcap'
    path.write_bytes(b'\x89MCAP0\r\n' + bytes(range(256)) * 4)
    with open_source(path) as source:
        assert list(source.messages()) == []
        assert source.topics() == []
        assert source.truncated


def test_closing_during_iteration_stops_it_with_a_source_error(tmp_path: Path) -> None:
    path = write_mcap(tmp_path / 'mid.mcap', tie_plan(10))
    source = open_source(path)
    messages = source.messages()
    first = next(messages)
    source.close()
    with pytest.raises(SourceError, match='closed'):
        next(messages)
    assert len(bytes(first.data)) > 0


def test_out_of_range_time_bounds_are_clamped(tmp_path: Path) -> None:
    plan = tie_plan(10)
    path = write_mcap(tmp_path / 'range.mcap', plan)
    with open_source(path) as source:
        assert len(list(source.messages(start_ns=-5, end_ns=2**70))) == len(plan)
        assert list(source.messages(start_ns=2**70)) == []
        assert list(source.messages(end_ns=-1)) == []


@pytest.mark.parametrize('kind', ['mcap', 'ros1'])
def test_a_window_one_nanosecond_wide_holds_exactly_the_message_logged_then(
    tmp_path: Path, kind: str
) -> None:
    # epoch times in nanoseconds are beyond float64's integer precision: 1 ns apart must count
    t = T0 + 166_666_667
    plan = [('/a', t - 1, 'before'), ('/a', t, 'at'), ('/a', t + 1, 'after')]
    path = (
        write_mcap(tmp_path / 'ns.mcap', plan)
        if kind == 'mcap'
        else write_bag(tmp_path / 'ns.bag', plan)
    )
    with open_source(path) as source:
        window = [(m.log_time_ns, m.seq) for m in source.messages(start_ns=t, end_ns=t + 1)]
        from_t = [m.seq for m in source.messages(start_ns=t)]
    assert window == [(t, 1)]
    assert from_t == [1, 2]
