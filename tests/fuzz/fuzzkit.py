"""Shared pieces of the hostile-input tests: profiles, file maps, mutations, checked replays.

The maps of the fixture files (record offsets, length fields, image header fields) are read by
small parsers here and by the ``mcap`` / ``rosbags`` libraries, never by replaybench's readers,
so the expectations they give are independent of the code under test.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import hashlib
import io
import json
import os
import shutil
import sqlite3
import struct
import tempfile
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

if TYPE_CHECKING:
    from typer.testing import Result

REPO = Path(__file__).resolve().parents[2]
FIXTURE_BAGS = REPO / 'fixtures' / 'bags'

# -- profiles ------------------------------------------------------------------------------

#: ``REPLAYBENCH_FUZZ=long`` selects the long profile (thousands of examples, random seeds).
PROFILE_NAME = 'long' if os.environ.get('REPLAYBENCH_FUZZ', '').strip().lower() == 'long' else 'ci'
LONG = PROFILE_NAME == 'long'

_HEALTH = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large]
settings.register_profile(
    'ci',
    max_examples=20,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=_HEALTH,
    print_blob=True,
)
settings.register_profile(
    'long',
    max_examples=1000,
    derandomize=False,
    database=None,
    deadline=None,
    suppress_health_check=_HEALTH,
    print_blob=True,
)
PROFILE = settings.get_profile(PROFILE_NAME)

#: Wall-clock bound of one in-process replay of a mutant (the fixtures replay in < 0.2 s).
CASE_LIMIT_S = 10.0


#: Replay windows drawn for the corrupted-file tests (``--rate recorded`` is left out: a log time
#: corrupted into the far future makes a timed replay wait for it).
WINDOWS = st.sampled_from(
    [(), ('--max-frames', '3'), ('--start', '0.1'), ('--duration', '0.15'), ('--start', '1e9')]
)


def fuzz_settings(share: float = 1.0) -> settings:
    """The active profile with ``share`` times its number of examples."""
    return settings(PROFILE, max_examples=max(1, round(PROFILE.max_examples * share)))


def every_or_sample(items: list[int], ci_count: int) -> list[int]:
    """All of ``items`` in the long profile; an even, deterministic spread of them in CI."""
    if LONG or len(items) <= ci_count:
        return list(items)
    step = (len(items) - 1) / (ci_count - 1)
    return sorted({items[round(i * step)] for i in range(ci_count)})


# -- fixture bytes ------------------------------------------------------------------------


@functools.cache
def fixture_bytes(rel: str) -> bytes:
    """The bytes of a committed fixture file (opened read-only, read once)."""
    with (FIXTURE_BAGS / rel).open('rb') as handle:
        return handle.read()


def fixture_digests() -> dict[str, str]:
    """sha256 of every committed fixture file, to prove the tests never modify them."""
    return {
        str(p.relative_to(FIXTURE_BAGS)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(FIXTURE_BAGS.rglob('*'))
        if p.is_file()
    }


# -- mutations -----------------------------------------------------------------------------


def flip_bits(data: bytes, positions: list[tuple[int, int]]) -> bytes:
    """``data`` with bit ``bit`` of byte ``pos`` inverted for each (pos, bit)."""
    buf = bytearray(data)
    for pos, bit in positions:
        buf[pos % len(buf)] ^= 1 << (bit % 8)
    return bytes(buf)


def overwrite(data: bytes, pos: int, new: bytes) -> bytes:
    """``data`` with ``new`` written over it at ``pos`` (clipped at the end)."""
    buf = bytearray(data)
    pos %= len(buf)
    chunk = new[: len(buf) - pos]
    buf[pos : pos + len(chunk)] = chunk
    return bytes(buf)


def put_uint(data: bytes, pos: int, width: int, value: int, order: str = '<') -> bytes:
    """``data`` with an unsigned ``width``-byte integer ``value`` (wrapped) stored at ``pos``."""
    fmt = order + {1: 'B', 2: 'H', 4: 'I', 8: 'Q'}[width]
    buf = bytearray(data)
    struct.pack_into(fmt, buf, pos, value % (1 << (8 * width)))
    return bytes(buf)


def huge_values(width: int, file_size: int, current: int) -> list[int]:
    """Oversized (and a few off-by-one) values for a ``width``-byte length or offset field."""
    top = (1 << (8 * width)) - 1
    values = {top, top - 1, 1 << (8 * width - 1), (1 << (8 * width - 1)) - 1, current + 1}
    values |= {file_size, file_size + 1, 2 * file_size, current * 2 + 7, 100_000}
    if width == 8:
        values |= {1 << 32, (1 << 32) - 1, 1 << 40}
    return sorted(v for v in values if 0 <= v <= top and v != current)


class Field(NamedTuple):
    """A numeric field in a file: where it lies, how wide it is, what it holds."""

    name: str
    pos: int
    width: int
    value: int


# -- MCAP map ------------------------------------------------------------------------------

MCAP_MAGIC = b'\x89MCAP0\r\n'
OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x03, 0x04, 0x05, 0x06

# Field layouts per opcode: (name, kind); kinds u8/u16/u32/u64, str (u32 length + bytes),
# b32 / b64 (u32 / u64 length + bytes), rest (remaining bytes).
_MCAP_LAYOUT: dict[int, tuple[tuple[str, str], ...]] = {
    0x01: (('profile', 'str'), ('library', 'str')),
    0x02: (('summary_start', 'u64'), ('summary_offset_start', 'u64'), ('crc', 'u32')),
    0x03: (('id', 'u16'), ('name', 'str'), ('encoding', 'str'), ('data', 'b32')),
    0x04: (('id', 'u16'), ('schema_id', 'u16'), ('topic', 'str'), ('encoding', 'str'),
           ('metadata', 'b32')),
    0x05: (('channel_id', 'u16'), ('sequence', 'u32'), ('log_time', 'u64'),
           ('publish_time', 'u64'), ('data', 'rest')),
    0x06: (('start_time', 'u64'), ('end_time', 'u64'), ('uncompressed_size', 'u64'),
           ('uncompressed_crc', 'u32'), ('compression', 'str'), ('records', 'b64')),
    0x07: (('channel_id', 'u16'), ('entries', 'b32')),
    0x08: (('start_time', 'u64'), ('end_time', 'u64'), ('chunk_start', 'u64'),
           ('chunk_length', 'u64'), ('index_offsets', 'b32'), ('index_length', 'u64'),
           ('compression', 'str'), ('compressed_size', 'u64'), ('uncompressed_size', 'u64')),
    0x0B: (('message_count', 'u64'), ('schema_count', 'u16'), ('channel_count', 'u32'),
           ('attachment_count', 'u32'), ('metadata_count', 'u32'), ('chunk_count', 'u32'),
           ('start_time', 'u64'), ('end_time', 'u64'), ('channel_counts', 'b32')),
    0x0E: (('group_opcode', 'u8'), ('group_start', 'u64'), ('group_length', 'u64')),
    0x0F: (('crc', 'u32'),),
}  # fmt: skip
_WIDTH = {'u8': 1, 'u16': 2, 'u32': 4, 'u64': 8}


class McapRecord(NamedTuple):
    """One MCAP record: opcode, file offsets, the chunk holding it (-1: top level), fields."""

    op: int
    start: int
    end: int
    chunk: int
    fields: dict[str, Field]
    body: dict[str, tuple[int, int]]  # name -> (start, end) of str / bytes / rest values


def _mcap_fields(
    data: bytes, op: int, body: int, end: int
) -> tuple[dict[str, Field], dict[str, tuple[int, int]]]:
    fields: dict[str, Field] = {}
    spans: dict[str, tuple[int, int]] = {}
    pos = body
    for name, kind in _MCAP_LAYOUT.get(op, ()):
        if kind in _WIDTH:
            width = _WIDTH[kind]
            if pos + width > end:
                break
            value = int.from_bytes(data[pos : pos + width], 'little')
            fields[name] = Field(name, pos, width, value)
            pos += width
        elif kind == 'rest':
            spans[name] = (pos, end)
            pos = end
        else:
            width = 8 if kind == 'b64' else 4
            if pos + width > end:
                break
            n = int.from_bytes(data[pos : pos + width], 'little')
            fields[f'{name}_len'] = Field(f'{name}_len', pos, width, n)
            spans[name] = (pos + width, pos + width + n)
            pos += width + n
    return fields, spans


def _mcap_walk(data: bytes, start: int, end: int, chunk: int, out: list[McapRecord]) -> None:
    pos = start
    while pos + 9 <= end:
        op = data[pos]
        length = int.from_bytes(data[pos + 1 : pos + 9], 'little')
        rec_end = pos + 9 + length
        if rec_end > end:
            return
        fields, spans = _mcap_fields(data, op, pos + 9, rec_end)
        fields['record_length'] = Field('record_length', pos + 1, 8, length)
        out.append(McapRecord(op, pos, rec_end, chunk, fields, spans))
        if op == OP_CHUNK and 'records' in spans:
            compression = data[spans['compression'][0] : spans['compression'][1]]
            if not compression:
                _mcap_walk(data, *spans['records'], pos, out)
        if op == 0x02:
            return
        pos = rec_end


@functools.cache
def mcap_records(rel: str) -> tuple[McapRecord, ...]:
    """Every record of a fixture MCAP, records inside uncompressed chunks included."""
    data = fixture_bytes(rel)
    assert data.startswith(MCAP_MAGIC)
    out: list[McapRecord] = []
    _mcap_walk(data, len(MCAP_MAGIC), len(data) - len(MCAP_MAGIC), -1, out)
    return tuple(out)


@functools.cache
def mcap_chunk_boundaries(rel: str) -> tuple[int, ...]:
    """File offsets where a chunk starts or ends, plus the summary and footer starts.

    Chunk positions come from the ``mcap`` library's chunk index (summary).
    """
    from mcap.reader import make_reader

    data = fixture_bytes(rel)
    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    assert summary.chunk_indexes
    cuts = set()
    for ci in summary.chunk_indexes:
        cuts |= {ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length}
    footer = len(data) - len(MCAP_MAGIC) - 29
    summary_start = int.from_bytes(data[footer + 9 : footer + 17], 'little')
    cuts |= {summary_start, footer}
    return tuple(sorted(cuts))


@functools.cache
def mcap_message_ends(rel: str) -> tuple[tuple[str, int], ...]:
    """(topic, file offset one past the Message record) for every message of an uncompressed
    MCAP, from the ``mcap`` library's chunk and message indexes."""
    from mcap.reader import make_reader
    from mcap.records import Chunk, MessageIndex
    from mcap.stream_reader import StreamReader

    data = fixture_bytes(rel)
    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    topics = {cid: ch.topic for cid, ch in summary.channels.items()}
    out: list[tuple[str, int]] = []
    for ci in summary.chunk_indexes:
        assert ci.compression == '', 'message offsets are only known for uncompressed chunks'
        stream = StreamReader(
            io.BytesIO(data[ci.chunk_start_offset :]), skip_magic=True, emit_chunks=True
        )
        chunk = next(iter(stream.records))
        assert isinstance(chunk, Chunk)
        records_start = ci.chunk_start_offset + ci.chunk_length - len(chunk.data)
        for cid, pos in ci.message_index_offsets.items():
            stream = StreamReader(io.BytesIO(data[pos:]), skip_magic=True)
            index = next(iter(stream.records))
            assert isinstance(index, MessageIndex)
            assert index.channel_id == cid
            for _, offset in index.records:
                at = records_start + offset
                assert data[at] == OP_MESSAGE
                length = int.from_bytes(data[at + 1 : at + 9], 'little')
                out.append((topics[cid], at + 9 + length))
    return tuple(sorted(out, key=lambda item: item[1]))


def cdr_image_fields(data: bytes, payload: int, compressed: bool = False) -> dict[str, Field]:
    """The header fields of a CDR (little endian) Image / CompressedImage at ``payload``."""
    assert data[payload : payload + 2] == b'\x00\x01'
    base = payload + 4  # CDR alignment is relative to the byte after the encapsulation header

    def align(pos: int) -> int:
        return base + ((pos - base + 3) & ~3)

    def u32(name: str, pos: int) -> Field:
        return Field(name, pos, 4, int.from_bytes(data[pos : pos + 4], 'little'))

    out = {'sec': u32('sec', base), 'nanosec': u32('nanosec', base + 4)}
    out['frame_id_len'] = u32('frame_id_len', base + 8)
    pos = base + 12 + out['frame_id_len'].value
    if compressed:
        out['format_len'] = u32('format_len', align(pos))
        pos = align(pos) + 4 + out['format_len'].value
        out['data_len'] = u32('data_len', align(pos))
        out['data'] = Field('data', align(pos) + 4, 0, out['data_len'].value)
        return out
    pos = align(pos)
    out['height'] = u32('height', pos)
    out['width'] = u32('width', pos + 4)
    out['encoding_len'] = u32('encoding_len', pos + 8)
    pos = align(pos + 12 + out['encoding_len'].value + 1)  # + is_bigendian
    out['step'] = u32('step', pos)
    out['data_len'] = u32('data_len', pos + 4)
    return out


def ros1_image_fields(data: bytes, payload: int) -> dict[str, Field]:
    """The header fields of a ROS 1 sensor_msgs/Image at ``payload``."""

    def u32(name: str, pos: int) -> Field:
        return Field(name, pos, 4, int.from_bytes(data[pos : pos + 4], 'little'))

    out = {'seq': u32('seq', payload), 'sec': u32('sec', payload + 4)}
    out['frame_id_len'] = u32('frame_id_len', payload + 12)
    pos = payload + 16 + out['frame_id_len'].value
    out['height'] = u32('height', pos)
    out['width'] = u32('width', pos + 4)
    out['encoding_len'] = u32('encoding_len', pos + 8)
    pos += 12 + out['encoding_len'].value + 1
    out['step'] = u32('step', pos)
    out['data_len'] = u32('data_len', pos + 4)
    return out


def mcap_image_fields(rel: str) -> list[dict[str, Field]]:
    """Header fields of every Image message payload of an uncompressed fixture MCAP."""
    data = fixture_bytes(rel)
    records = mcap_records(rel)
    schemas = {r.fields['id'].value: r for r in records if r.op == OP_SCHEMA}
    image_channels = set()
    for r in records:
        if r.op == OP_CHANNEL:
            schema = schemas[r.fields['schema_id'].value]
            name = data[slice(*schema.body['name'])]
            if name == b'sensor_msgs/msg/Image':
                image_channels.add(r.fields['id'].value)
    return [
        cdr_image_fields(data, r.body['data'][0])
        for r in records
        if r.op == OP_MESSAGE and r.fields['channel_id'].value in image_channels
    ]


@functools.cache
def mcap_length_fields(rel: str) -> tuple[Field, ...]:
    """Every length / size / offset field of a fixture MCAP, message payload fields included."""
    names: tuple[str, ...] = (
        '_len',
        'record_length',
        'size',
        'chunk_start',
        'chunk_length',
        'index_length',
    )
    names += ('summary_start', 'summary_offset_start', 'group_start', 'group_length')
    out = [f for r in mcap_records(rel) for f in r.fields.values() if f.name.endswith(names)]
    data = fixture_bytes(rel)
    for r in mcap_records(rel):
        if r.op == 0x07:  # message index entries: (log time, offset)
            lo, hi = r.body['entries']
            out += [Field('entry_offset', p + 8, 8, 0) for p in range(lo, min(hi, lo + 64), 16)]
        if r.op == 0x08:
            lo, hi = r.body['index_offsets']
            out += [Field('index_offset', p + 2, 8, 0) for p in range(lo, hi, 10)]
    for fields in mcap_image_fields(rel) if rel == 'rgb8_raw.mcap' else []:
        out += [fields[k] for k in ('frame_id_len', 'encoding_len', 'data_len', 'step')]
    return tuple(
        f._replace(value=int.from_bytes(data[f.pos : f.pos + f.width], 'little')) for f in out
    )


def structural_spans(
    records: tuple[McapRecord, ...] | list[McapRecord], head: int = 96
) -> list[tuple[int, int]]:
    """(start, end) of the first ``head`` bytes of every record: headers, lengths, payload heads."""
    return [(r.start, min(r.end, r.start + head)) for r in records]


def rewrite_mcap(
    data: bytes,
    *,
    schema=None,
    channel=None,
    message=None,
    compression: str = 'none',
) -> bytes:
    """Write the records of ``data`` again with the ``mcap`` library, each through a hook.

    ``schema(id, name, encoding, data)`` returns (name, encoding, data); ``channel(id, topic,
    encoding, schema_id)`` returns (topic, encoding, schema_id); ``message(topic, data)`` returns
    the new payload. Schema and channel ids keep their numbering.
    """
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    out = io.BytesIO()
    writer = Writer(out, compression=CompressionType[compression.upper()])
    writer.start(profile='ros2', library='replaybench-fuzz')
    topics: dict[int, str] = {}
    seen_schemas: set[int] = set()
    seen_channels: set[int] = set()
    for record in StreamReader(io.BytesIO(data)).records:
        if isinstance(record, Schema) and record.id not in seen_schemas:
            seen_schemas.add(record.id)
            schema_values = (record.name, record.encoding, record.data)
            if schema is not None:
                schema_values = schema(record.id, *schema_values)
            assert writer.register_schema(*schema_values) == record.id
        elif isinstance(record, Channel) and record.id not in seen_channels:
            seen_channels.add(record.id)
            channel_values = (record.topic, record.message_encoding, record.schema_id)
            if channel is not None:
                channel_values = channel(record.id, *channel_values)
            topics[record.id] = record.topic
            assert writer.register_channel(*channel_values) == record.id
        elif isinstance(record, Message):
            payload = record.data
            if message is not None:
                payload = message(topics[record.channel_id], payload)
            writer.add_message(
                record.channel_id, record.log_time, payload, record.publish_time, record.sequence
            )
    writer.finish()
    return out.getvalue()


def drop_records(name: str, op: int, ids: set[int] | None) -> bytes:
    """The file with matching Schema / Channel records turned into an unknown opcode (0x80+):
    readers skip such records, so the record is gone without moving any byte."""
    data = fixture_bytes(name)
    for record in mcap_records(name):
        if record.op == op and (ids is None or record.fields['id'].value in ids):
            data = put_uint(data, record.start, 1, 0x80 | op)
    return data


def patch_sof(jpeg: bytes, width: int, height: int) -> bytes:
    """A JPEG whose frame header (SOF0..SOF15) claims ``width`` x ``height``."""
    pos = 2
    while pos + 9 < len(jpeg):
        marker = jpeg[pos + 1]
        (length,) = struct.unpack_from('>H', jpeg, pos + 2)
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            buf = bytearray(jpeg)
            struct.pack_into('>HH', buf, pos + 5, height % 65536, width % 65536)
            return bytes(buf)
        pos += 2 + length
    msg = 'no SOF marker'
    raise AssertionError(msg)


# -- ROS 1 bag map --------------------------------------------------------------------------

ROSBAG_MAGIC = b'#ROSBAG V2.0\n'


class BagRecord(NamedTuple):
    """One ROS 1 bag record: op, offsets, chunk holding it (-1: top level), header fields."""

    op: int
    start: int
    data_start: int
    end: int
    chunk: int
    header: dict[str, tuple[int, int]]  # field name -> (value start, value end)
    lengths: list[Field]


def _bag_walk(data: bytes, start: int, end: int, chunk: int, out: list[BagRecord]) -> None:
    pos = start
    while pos + 4 <= end:
        hlen = int.from_bytes(data[pos : pos + 4], 'little')
        hend = pos + 4 + hlen
        if hend + 4 > end:
            return
        dlen = int.from_bytes(data[hend : hend + 4], 'little')
        dend = hend + 4 + dlen
        if dend > end:
            return
        header: dict[str, tuple[int, int]] = {}
        lengths = [Field('header_len', pos, 4, hlen), Field('data_len', hend, 4, dlen)]
        p = pos + 4
        while p + 4 <= hend:
            n = int.from_bytes(data[p : p + 4], 'little')
            lengths.append(Field('field_len', p, 4, n))
            name, _, _ = data[p + 4 : p + 4 + n].partition(b'=')
            header[name.decode('latin-1')] = (p + 4 + len(name) + 1, p + 4 + n)
            p += 4 + n
        op_span = header.get('op')
        op = data[op_span[0]] if op_span else -1
        out.append(BagRecord(op, pos, hend + 4, dend, chunk, header, lengths))
        if op == 0x05 and data[slice(*header['compression'])] == b'none':
            _bag_walk(data, hend + 4, dend, pos, out)
        pos = dend


def bag_records(rel: str) -> tuple[BagRecord, ...]:
    """Every record of a fixture bag, records inside uncompressed chunks included."""
    return bag_records_of(fixture_bytes(rel))


@functools.cache
def bag_records_of(data: bytes) -> tuple[BagRecord, ...]:
    """Every record of a bag, records inside uncompressed chunks included."""
    assert data.startswith(ROSBAG_MAGIC)
    out: list[BagRecord] = []
    _bag_walk(data, len(ROSBAG_MAGIC), len(data), -1, out)
    return tuple(out)


@functools.cache
def bag_length_fields(data: bytes) -> tuple[Field, ...]:
    """Record / header-field / data lengths plus the numeric header fields of a bag."""
    out: list[Field] = []
    numeric = {'index_pos': 8, 'conn_count': 4, 'chunk_count': 4, 'size': 4, 'count': 4}
    numeric |= {'chunk_pos': 8, 'ver': 4, 'conn': 4}
    for r in bag_records_of(data):
        out += r.lengths
        for name, (lo, hi) in r.header.items():
            if numeric.get(name) == hi - lo:
                value = int.from_bytes(data[lo:hi], 'little')
                out.append(Field(name, lo, hi - lo, value))
        if r.op == 0x04:  # index data: (time u64, offset u32) entries
            for p in range(r.data_start, min(r.end, r.data_start + 36), 12):
                out.append(Field('entry_offset', p + 8, 4, 0))
    for fields in bag_image_fields(data):
        out += [fields[k] for k in ('frame_id_len', 'encoding_len', 'data_len', 'step')]
    return tuple(
        f._replace(value=int.from_bytes(data[f.pos : f.pos + f.width], 'little')) for f in out
    )


def bag_image_fields(data: bytes) -> list[dict[str, Field]]:
    """Header fields of every Image message stored uncompressed in a bag."""
    records = bag_records_of(data)
    image_conns = set()
    for r in records:
        if r.op == 0x07:
            info = data[r.data_start : r.end]
            if b'type=sensor_msgs/Image' in info:
                image_conns.add(data[slice(*r.header['conn'])])
    return [
        ros1_image_fields(data, r.data_start)
        for r in records
        if r.op == 0x02 and data[slice(*r.header['conn'])] in image_conns
    ]


@functools.cache
def bag_chunk_boundaries(rel: str) -> tuple[int, ...]:
    """File offsets where a chunk record starts or ends (from ``rosbags``), plus the index start."""
    from rosbags.rosbag1 import Reader

    reader = Reader(FIXTURE_BAGS / rel)
    reader.open()
    try:
        cuts = set()
        for pos, chunk in reader.chunks.items():
            cuts |= {pos, chunk.datapos + chunk.datasize}
    finally:
        reader.close()
    index_pos = next(
        int.from_bytes(fixture_bytes(rel)[slice(*r.header['index_pos'])], 'little')
        for r in bag_records(rel)
        if r.op == 0x03
    )
    cuts.add(index_pos)
    return tuple(sorted(cuts))


@functools.cache
def bag_message_ends(rel: str) -> tuple[tuple[str, int], ...]:
    """(topic, file offset one past the record) of every message of an uncompressed bag, from
    ``rosbags``' chunk table and per-connection index."""
    from rosbags.rosbag1 import Reader

    data = fixture_bytes(rel)
    reader = Reader(FIXTURE_BAGS / rel)
    reader.open()
    try:
        topics = {c.id: c.topic for c in reader.connections}
        out: list[tuple[str, int]] = []
        for cid, entries in reader.indexes.items():
            for entry in entries:
                at = reader.chunks[entry.chunk_pos].datapos + entry.offset
                hlen = int.from_bytes(data[at : at + 4], 'little')
                dlen = int.from_bytes(data[at + 4 + hlen : at + 8 + hlen], 'little')
                out.append((topics[cid], at + 8 + hlen + dlen))
    finally:
        reader.close()
    return tuple(sorted(out, key=lambda item: item[1]))


# -- sqlite (.db3) --------------------------------------------------------------------------


def db3_page_size(data: bytes) -> int:
    """The page size from a SQLite header."""
    assert data.startswith(b'SQLite format 3\x00')
    size = int.from_bytes(data[16:18], 'big')
    return 65536 if size == 1 else size


def db3_structural_spans(data: bytes) -> list[tuple[int, int]]:
    """The file header and every page's first 16 bytes (b-tree header / overflow link)."""
    ps = db3_page_size(data)
    return [(0, 112)] + [(p, p + 16) for p in range(ps, len(data), ps)]


def edit_db3(path: Path, statements: list[tuple[str, tuple[Any, ...]]]) -> None:
    """Run SQL statements against a copied .db3 (never a fixture) and close it cleanly.

    A statement on a table an earlier one dropped, or one the schema's constraints refuse
    (e.g. ``substr`` of an empty blob is NULL in a NOT NULL column), is skipped.
    """
    assert FIXTURE_BAGS not in path.resolve().parents
    db = sqlite3.connect(path)
    try:
        for sql, params in statements:
            with contextlib.suppress(sqlite3.OperationalError, sqlite3.IntegrityError):
                db.execute(sql, params)
        db.commit()
    finally:
        db.close()


# -- checked replays ------------------------------------------------------------------------


class Outcome(NamedTuple):
    """What one replay of a mutant left behind."""

    code: int
    stderr: str
    out: Path
    run: dict[str, Any] | None
    rows: list[dict[str, str]]
    elapsed: float


def _snapshot(path: Path) -> dict[str, str]:
    files = sorted(path.rglob('*')) if path.is_dir() else [path]
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in files if p.is_file()}


def write_case(workdir: Path, files: dict[str, bytes]) -> Path:
    """Write a mutant (file name -> bytes) into a new folder under ``workdir``; read-only."""
    case = Path(tempfile.mkdtemp(prefix='case', dir=workdir))
    for name, content in files.items():
        target = case / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(content)
        target.chmod(0o444)
    return case


def check_run_folder(code: int, out: Path) -> tuple[dict[str, Any] | None, list[dict[str, str]]]:
    """The output contract: exit 2 claims nothing complete; exit 0 leaves readable outputs."""
    run_json = out / 'run.json'
    if code != 0:
        if run_json.exists():
            run = json.loads(run_json.read_text())
            assert run.get('status') != 'complete', 'failed run left a run.json saying complete'
        return None, []
    run = json.loads(run_json.read_text())
    assert run['status'] == 'complete'
    leftovers = [p.name for p in out.rglob('*') if p.name.endswith(('.part', '.tmp'))]
    assert not leftovers, f'complete run left partial files: {leftovers}'
    with (out / 'frames.csv').open(newline='') as handle:
        reader = csv.DictReader(handle)
        rows = list(reader)
        header = reader.fieldnames or []
    assert {'backend', 'topic', 'seq', 'status'} <= set(header)
    assert all(None not in row and None not in row.values() for row in rows), 'ragged frames.csv'
    assert {row['status'] for row in rows} <= {'ok', 'skipped', 'dropped'}
    assert len(rows) == run['counts']['frames']
    ok = sum(row['status'] == 'ok' for row in rows)
    assert ok == run['counts']['processed']
    from mcap.reader import make_reader

    with (out / 'outputs.mcap').open('rb') as handle:
        mcap_reader = make_reader(handle, validate_crcs=True)
        topics = [channel.topic for _, channel, _ in mcap_reader.iter_messages()]
    detections = sum(t.startswith('/replaybench/') and t.endswith('/detections') for t in topics)
    assert detections == ok, f'{detections} detection messages for {ok} processed frames'
    assert (out / 'summary.csv').is_file()
    return run, rows


def invoke_cli(args: list[str], case: Path) -> tuple[Result, float]:
    """Run the CLI in-process: no exception but SystemExit, exit code 0 or 2, bounded time."""
    from typer.testing import CliRunner

    from replaybench.cli import app

    t0 = time.perf_counter()
    result = CliRunner().invoke(app, args, catch_exceptions=True)
    elapsed = time.perf_counter() - t0
    exc = result.exception
    if exc is not None and not isinstance(exc, SystemExit):
        trace = ''.join(traceback.format_exception(*result.exc_info)) if result.exc_info else exc
        msg = f'replaybench {args[0]} raised on {case}:\n{trace}'
        raise AssertionError(msg)
    assert result.exit_code in (0, 2), f'exit code {result.exit_code}: {result.output[-2000:]}'
    assert 'Traceback' not in result.output
    assert elapsed < CASE_LIMIT_S, f'replaybench {args[0]} took {elapsed:.1f} s'
    if result.exit_code == 2:
        assert result.stderr.startswith('replaybench: error: '), result.stderr[-2000:]
    return result, elapsed


def replay(
    case: Path,
    workdir: Path,
    *,
    backends: tuple[str, ...] = ('null',),
    extra: tuple[str, ...] = (),
    report: bool = False,
    info: bool = False,
) -> Outcome:
    """Replay ``case`` in-process with the real CLI and check every hostile-input invariant.

    No traceback (only SystemExit), exit code 0 or 2, bounded time, input untouched, and the
    run folder contract of :func:`check_run_folder`. ``info`` also runs ``replaybench info``
    on the case under the same checks.
    """
    folder = case.parent if case.is_file() else case
    before = _snapshot(folder)
    if info:
        invoke_cli(['info', str(case)], case)
    out = Path(tempfile.mkdtemp(prefix='out', dir=workdir)) / 'run'
    args = ['run', str(case), '--out', str(out)]
    for name in backends:
        args += ['--backend', name]
    if not report:
        args.append('--no-report')
    args += list(extra)
    result, elapsed = invoke_cli(args, case)
    after = _snapshot(folder)
    assert after == before, 'the input files changed (or files appeared beside them)'
    run, rows = check_run_folder(result.exit_code, out)
    if report and result.exit_code == 0:
        assert (out / 'report.html').is_file()
    return Outcome(result.exit_code, result.stderr, out, run, rows, elapsed)


def cleanup(*paths: Path) -> None:
    """Remove the temporary folders of a case whose checks passed (keeps tmp_path small)."""
    for path in paths:
        target = path if path.name.startswith(('case', 'out')) else path.parent
        shutil.rmtree(target, ignore_errors=True)


def rewrite_bag(
    rel: str,
    target: Path,
    *,
    connection=None,
    message=None,
    compression: str | None = None,
    frames: int | None = None,
) -> bytes:
    """Write a fixture bag again with ``rosbags``, each connection / message through a hook.

    ``connection(topic, msgtype, msgdef, md5sum)`` returns the same four values (or None to
    drop the connection and its messages); ``message(topic, data)`` returns the new payload.
    ``compression`` is None, 'bz2' or 'lz4'; ``frames`` keeps only the first frames (with
    chunks of about one frame). Returns the new file's bytes.
    """
    from rosbags.rosbag1 import Reader, Writer

    target = Path(tempfile.mkdtemp(dir=target.parent)) / target.name
    writer = Writer(target)
    if frames is not None:
        writer.chunk_threshold = 200_000
    if compression:
        writer.set_compression(Writer.CompressionFormat[compression.upper()])
    reader = Reader(FIXTURE_BAGS / rel)
    reader.open()
    writer.open()
    try:
        conns = {}
        for conn in reader.connections:
            values = (conn.topic, conn.msgtype, conn.msgdef.data, conn.digest)
            if connection is not None:
                values = connection(*values)
            if values is not None:
                topic, msgtype, msgdef, md5sum = values
                conns[conn.id] = writer.add_connection(topic, msgtype, msgdef=msgdef, md5sum=md5sum)
        end = None if frames is None else reader.start_time + frames * 33_300_000
        for conn, timestamp, data in reader.messages(stop=end):
            if conn.id in conns:
                payload = message(conn.topic, data) if message is not None else data
                writer.write(conns[conn.id], timestamp, payload)
    finally:
        writer.close()
        reader.close()
    content = target.read_bytes()
    shutil.rmtree(target.parent)
    return content


@functools.cache
def recompressed_bag(rel: str, compression: str, frames: int = 3) -> bytes:
    """The first ``frames`` frames of a fixture bag written again with bz2 or lz4 chunks of about
    one frame each (built once, in a temporary folder)."""
    with tempfile.TemporaryDirectory() as tmp:
        name = f'{compression}.bag'
        return rewrite_bag(rel, Path(tmp) / name, compression=compression, frames=frames)
