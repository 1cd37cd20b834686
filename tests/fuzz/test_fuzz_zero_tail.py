"""Zero-filled tails at random offsets (power loss: full size, the last part reads as zeros).

Over every format that can lose its tail this way: MCAP with uncompressed, zstd and lz4 chunks,
unchunked MCAP, ROS 1 bags and rosbag2 directories with ``.mcap`` storage. Properties: every
image message whose bytes lie wholly before the zeros is replayed (for compressed chunks: every
message of the chunks that end before them), no replayed message differs from one that was
written (so none is built from zeros), and the damage is reported as a truncation. The variants
of the fixture recording are written with the ``mcap`` library and ``rosbags``; what is expected
is read from the intact file with the same libraries, never with replaybench's readers.
"""

from __future__ import annotations

import functools
import io
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import pytest
from fuzz.fuzzkit import cleanup, fixture_bytes, fuzz_settings, recompressed_bag, replay, write_case
from hypothesis import example, given
from hypothesis import strategies as st

from replaybench.sources import open_source

if TYPE_CHECKING:
    from mcap.records import Message

IMAGE_TOPIC = '/camera/image_raw'
SOURCE = 'rgb8_raw.mcap'


class Variant(NamedTuple):
    """One intact recording: its files, the one whose tail is zeroed, what it holds."""

    files: dict[str, bytes]
    damaged: str  # name of the file whose tail is zeroed
    opened: str  # what is opened: the file, or '.' for the rosbag2 directory
    payloads: tuple[bytes, ...]  # image payloads in log-time order
    #: (file offset where a group of messages is whole, its payloads): one group per message
    #: for uncompressed storage, one per chunk for compressed chunks
    groups: tuple[tuple[int, frozenset[bytes]], ...]
    exact: bool  # True: exactly the groups before the zeros are replayed


def _source_records() -> list[tuple[str, str, str, bytes, Message]]:
    """(topic, schema name, schema encoding, schema data, message) of the fixture, in order."""
    from mcap.reader import make_reader

    reader = make_reader(io.BytesIO(fixture_bytes(SOURCE)))
    out = []
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        assert schema is not None
        out.append((channel.topic, schema.name, schema.encoding, schema.data, message))
    return out


def _mcap_bytes(compression: str, *, chunked: bool) -> bytes:
    from mcap.writer import CompressionType, Writer

    out = io.BytesIO()
    writer = Writer(
        out,
        chunk_size=300_000,
        compression=CompressionType[compression.upper()],
        use_chunking=chunked,
    )
    writer.start(profile='ros2', library='replaybench-fuzz')
    schemas: dict[str, int] = {}
    channels: dict[str, int] = {}
    for topic, name, encoding, data, message in _source_records():
        if name not in schemas:
            schemas[name] = writer.register_schema(name, encoding, data)
        if topic not in channels:
            channels[topic] = writer.register_channel(topic, 'cdr', schemas[name])
        writer.add_message(channels[topic], message.log_time, message.data, message.publish_time)
    writer.finish()
    return out.getvalue()


def _image_payloads_mcap(raw: bytes) -> tuple[bytes, ...]:
    from mcap.reader import make_reader

    reader = make_reader(io.BytesIO(raw))
    return tuple(bytes(m.data) for _, _, m in reader.iter_messages(topics=[IMAGE_TOPIC]))


def _message_groups(
    raw: bytes, payloads: tuple[bytes, ...]
) -> tuple[tuple[int, frozenset[bytes]], ...]:
    """One group per payload, whole where its last byte is (payloads end their records)."""
    assert all(raw.count(p) == 1 for p in payloads)
    return tuple((raw.find(p) + len(p), frozenset([p])) for p in payloads)


def _chunk_groups(raw: bytes) -> tuple[tuple[int, frozenset[bytes]], ...]:
    """One group per chunk: where the chunk record ends, the image payloads it holds."""
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import Chunk, Message
    from mcap.stream_reader import breakup_chunk

    summary = make_reader(io.BytesIO(raw)).get_summary()
    assert summary is not None
    image = {cid for cid, ch in summary.channels.items() if ch.topic == IMAGE_TOPIC}
    out = []
    for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        stream = io.BytesIO(raw)
        stream.seek(ci.chunk_start_offset + 9)
        records = breakup_chunk(Chunk.read(ReadDataStream(stream)))
        held = frozenset(
            bytes(r.data) for r in records if isinstance(r, Message) and r.channel_id in image
        )
        out.append((ci.chunk_start_offset + ci.chunk_length, held))
    return tuple(out)


def _mcap_variant(compression: str, *, chunked: bool = True) -> Variant:
    raw = (
        fixture_bytes(SOURCE)
        if (compression, chunked) == ('none', True)
        else _mcap_bytes(compression, chunked=chunked)
    )
    payloads = _image_payloads_mcap(raw)
    if compression == 'none':
        return Variant({'in.mcap': raw}, 'in.mcap', 'in.mcap', payloads,
                       _message_groups(raw, payloads), exact=True)  # fmt: skip
    return Variant({'in.mcap': raw}, 'in.mcap', 'in.mcap', payloads, _chunk_groups(raw),
                   exact=False)  # fmt: skip


def _bag_variant(compression: str) -> Variant:
    """The fixture bag, or written again with lz4 / bz2 chunks of about one frame each."""
    import bz2

    import lz4.frame
    from rosbags.rosbag1 import Reader

    raw = fixture_bytes('rgb8.bag')
    if compression != 'none':
        raw = recompressed_bag('rgb8.bag', compression, frames=10)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'in.bag'
        path.write_bytes(raw)
        with Reader(path) as reader:
            conns = [c for c in reader.connections if c.topic == IMAGE_TOPIC]
            payloads = tuple(bytes(data) for _, _, data in reader.messages(connections=conns))
            spans = [(c.datapos, c.datapos + c.datasize) for c in reader.chunks.values()]
    if compression == 'none':
        return Variant({'in.bag': raw}, 'in.bag', 'in.bag', payloads,
                       _message_groups(raw, payloads), exact=True)  # fmt: skip
    decompress = bz2.decompress if compression == 'bz2' else lz4.frame.decompress
    groups = []
    for start, end in sorted(spans):
        data = decompress(raw[start:end])
        groups.append((end, frozenset(p for p in payloads if p in data)))
    assert set().union(*(g for _, g in groups)) == set(payloads)
    return Variant({'in.bag': raw}, 'in.bag', 'in.bag', payloads, tuple(groups), exact=False)


def _rosbag2_variant() -> Variant:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / 'bag'
        writer = Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP)
        with writer:
            conns: dict[str, object] = {}
            for topic, name, _, _, message in _source_records():
                if name not in store.types:  # vision_msgs are not in the stock type store
                    continue
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, name, typestore=store)
                writer.write(conns[topic], message.log_time, message.data)  # type: ignore[arg-type]
        files = {p.name: p.read_bytes() for p in bag.iterdir()}
        shutil.rmtree(bag)
    (name,) = [n for n in files if n.endswith('.mcap')]
    payloads = _image_payloads_mcap(files[name])
    return Variant(files, name, '.', payloads, _message_groups(files[name], payloads), exact=True)


@functools.cache
def variant(kind: str) -> Variant:
    if kind.startswith('bag'):
        return _bag_variant(kind.partition('-')[2] or 'none')
    if kind == 'rosbag2-mcap':
        return _rosbag2_variant()
    if kind == 'mcap-unchunked':
        return _mcap_variant('none', chunked=False)
    return _mcap_variant(kind.removeprefix('mcap-'))


KINDS = ['mcap-none', 'mcap-zstd', 'mcap-lz4', 'mcap-unchunked', 'bag', 'bag-lz4', 'bag-bz2']
KINDS += ['rosbag2-mcap']


def zeroed(v: Variant, at: int) -> dict[str, bytes]:
    raw = v.files[v.damaged]
    at = min(max(at, 1), len(raw))
    return {**v.files, v.damaged: raw[:at] + bytes(len(raw) - at)}


def expectation(v: Variant, damaged: bytes) -> tuple[set[bytes], bool]:
    """The payloads that must be replayed, and whether exactly those."""
    zeros_at = len(damaged.rstrip(b'\x00'))
    must = {p for end, group in v.groups if end <= zeros_at for p in group}
    return must, v.exact


def check_source(v: Variant, files: dict[str, bytes], case: Path) -> set[bytes]:
    """Open the zeroed recording with the reader; check every property; what it replayed."""
    damaged = files[v.damaged]
    with open_source(case / v.opened) as source:
        got = [bytes(m.data) for m in source.messages(topics=[IMAGE_TOPIC])]
        truncated, warnings = source.truncated, source.warnings
    rank = {p: i for i, p in enumerate(v.payloads)}
    assert all(p in rank for p in got), 'a replayed image is not one that was written'
    assert [rank[p] for p in got] == sorted(rank[p] for p in got), 'replay order changed'
    assert len(set(got)) == len(got)
    must, exact = expectation(v, damaged)
    if exact:
        assert set(got) == must, f'{len(got)} replayed, {len(must)} lie before the zeros'
    else:
        assert must <= set(got), 'a message of a chunk that ends before the zeros was lost'
    if damaged != v.files[v.damaged]:
        assert truncated, 'a zeroed tail was not reported as a truncation'
        zeros_at = len(damaged.rstrip(b'\x00'))
        assert any(f'byte {zeros_at}' in w and 'zeros' in w for w in warnings), warnings
    return set(got)


def tail_offsets(kind: str) -> st.SearchStrategy[int]:
    """Offsets anywhere, or within a few bytes of where a group of messages is whole (the
    recording is built when the first example is drawn, not when the tests are collected)."""
    return st.deferred(lambda: _tail_offsets(kind))


def _tail_offsets(kind: str) -> st.SearchStrategy[int]:
    v = variant(kind)
    size = len(v.files[v.damaged])
    ends = sorted({end for end, _ in v.groups})
    # past the magic bytes: a file with zeros there is not of its format any more
    low = 14 if kind.startswith('bag') else 9
    near = st.tuples(st.sampled_from(ends), st.integers(-48, 48)).map(lambda p: p[0] + p[1])
    return st.one_of(near, st.integers(low, size - 1)).map(lambda at: min(max(at, low), size - 1))


def _source_case(tmp_path: Path, kind: str, at: int) -> None:
    v = variant(kind)
    files = zeroed(v, at)
    case = write_case(tmp_path, files)
    check_source(v, files, case)
    cleanup(case)


@fuzz_settings(1.0)
@given(at=tail_offsets('mcap-none'))
@example(at=len(fixture_bytes(SOURCE)) - 8)
def test_uncompressed_mcap_zeroed_anywhere_replays_every_message_before_the_zeros(tmp_path, at):
    _source_case(tmp_path, 'mcap-none', at)


@fuzz_settings(1.0)
@given(at=tail_offsets('mcap-zstd'))
def test_zstd_mcap_zeroed_anywhere_replays_every_chunk_before_the_zeros(tmp_path, at):
    _source_case(tmp_path, 'mcap-zstd', at)


@fuzz_settings(1.0)
@given(at=tail_offsets('mcap-lz4'))
def test_lz4_mcap_zeroed_anywhere_replays_every_chunk_before_the_zeros(tmp_path, at):
    _source_case(tmp_path, 'mcap-lz4', at)


@fuzz_settings(1.0)
@given(at=tail_offsets('mcap-unchunked'))
def test_unchunked_mcap_zeroed_anywhere_replays_every_message_before_the_zeros(tmp_path, at):
    _source_case(tmp_path, 'mcap-unchunked', at)


@fuzz_settings(1.0)
@given(at=tail_offsets('bag'))
@example(at=len(fixture_bytes('rgb8.bag')) - 16)
@example(at=len(fixture_bytes('rgb8.bag')) - 3000)
@example(at=82)  # the bag header's chunk_count: zeroed, it declared an empty bag
def test_ros1_bag_zeroed_anywhere_replays_every_message_before_the_zeros(tmp_path, at):
    _source_case(tmp_path, 'bag', at)


@pytest.mark.parametrize('compression', ['lz4', 'bz2'])
@fuzz_settings(0.5)
@given(data=st.data())
def test_compressed_ros1_bag_zeroed_anywhere_replays_every_chunk_before_the_zeros(
    tmp_path, compression, data
):
    kind = f'bag-{compression}'
    _source_case(tmp_path, kind, data.draw(tail_offsets(kind), label='at'))


@fuzz_settings(1.0)
@given(at=tail_offsets('rosbag2-mcap'))
def test_rosbag2_mcap_zeroed_anywhere_replays_every_message_before_the_zeros(tmp_path, at):
    _source_case(tmp_path, 'rosbag2-mcap', at)


@pytest.mark.parametrize('kind', KINDS)
@fuzz_settings(0.15)
@given(data=st.data())
def test_a_zeroed_tail_replays_through_the_cli_as_a_reported_truncation(tmp_path, kind, data):
    v = variant(kind)
    at = data.draw(tail_offsets(kind), label='at')
    files = zeroed(v, at)
    case = write_case(tmp_path, files)
    replayed = check_source(v, files, case)
    outcome = replay(case / v.opened, tmp_path)
    if replayed:
        assert outcome.code == 0, outcome.stderr
    if outcome.run is None:  # nothing to replay: exit 2 with one line, like a cut file
        assert not replayed
        assert outcome.stderr.startswith('replaybench: error: ')
    else:
        rows = [r for r in outcome.rows if r['topic'] == IMAGE_TOPIC]
        assert len(rows) == len(replayed)
        assert all(r['status'] == 'ok' for r in rows)
        (meta,) = outcome.run['inputs']
        assert meta['truncated'] is True
        (line,) = [w for w in meta['warnings'] if 'zeros' in w]
        assert f'replaybench: warning: {line}' in outcome.stderr
    cleanup(case, outcome.out)
