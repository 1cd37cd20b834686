"""MCAP files: ros2 (cdr), ros1 and protobuf channels.

Indexed files are read from their summary and MessageIndex records only: a single file with a
regular summary lazily (``_lazy_index``: at open its summary alone, each chunk's MessageIndex
records when a reader reaches the chunk), any other at open; a message's ``data``
is a zero-copy view of the memory-mapped file for uncompressed chunks, or of its chunk
decompressed once (a small cache keeps the chunks in use) for zstd / lz4 chunks.

Files without a summary, with an incomplete index, or cut short (no footer) are scanned
record by record instead. The scan keeps only per-message metadata and sorts it like the
index, so such files replay in the same deterministic order as indexed ones; a cut file
yields every complete message before the cut (also those in a partly written chunk) and
sets ``truncated``. A file without a footer that ends in zeros (its last blocks lost to a power
cut) is read as cut where the zeros begin: no message is built from the zeroed bytes.
"""

from __future__ import annotations

import itertools
import struct
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replaybench.errors import SourceError
from replaybench.types import RawMessage, SkippedTopic

from ._common import MappedFile, decompress_chunk, normalize_msgtype, zero_tail_start
from ._table import U64_MAX, Channel, Chunk, TableSource, clamp_time

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Iterator, Sequence

    import numpy.typing as npt

    from replaybench.types import Serialization

__all__ = ['MCAP_MAGIC', 'McapSource', 'mcap_payload']

MCAP_MAGIC = b'\x89MCAP0\r\n'

_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_MESSAGE_INDEX = 0x07
_OP_CHUNK_INDEX = 0x08
_OP_STATISTICS = 0x0B
_FOOTER_TAIL = 1 + 8 + 20 + len(MCAP_MAGIC)  # footer record + closing magic
#: MessageIndex records with fewer entries are read together in one gather (``_add_gathered``)
_GATHER_BELOW = 64

_U16 = struct.Struct('<H').unpack_from
_U32 = struct.Struct('<I').unpack_from
_U64 = struct.Struct('<Q').unpack_from
_MESSAGE_HEAD = struct.Struct('<HIQ').unpack_from  # channel id, sequence, log time

_SERIALIZATIONS: dict[str, Serialization] = {'cdr': 'cdr', 'ros1': 'ros1', 'protobuf': 'protobuf'}


class _CorruptError(ValueError):
    """A record that does not parse."""


class _Schema(NamedTuple):
    name: str
    encoding: str
    data: bytes


class _ChannelRecord(NamedTuple):
    id: int
    schema_id: int
    topic: str
    encoding: str


class _ChunkIndex(NamedTuple):
    chunk_pos: int
    index_offsets: dict[int, int]


class _Summary(NamedTuple):
    start: int  # where the summary section (and so the data section's end) is
    schemas: dict[int, _Schema]
    channels: dict[int, _ChannelRecord]
    chunk_records: list[int]  # where each ChunkIndex record's body begins
    chunk_ends: list[int]  # and where it ends
    message_count: int | None
    #: the ChunkIndex records in runs of one length, one after the other: (first body,
    #: stride, records)
    chunk_runs: list[tuple[int, int, int]]


class _Bulk(NamedTuple):
    """The chunk indexes of a summary read at once (``_bulk_index``): per chunk (in chunk
    position order) its head; per MessageIndex record its chunk (a row of the first arrays),
    channel id, where its entries are and how many."""

    chunk_pos: npt.NDArray[np.int64]
    data_start: npt.NDArray[np.int64]
    data_len: npt.NDArray[np.int64]
    uncompressed_size: npt.NDArray[np.int64]
    compression: str
    chunk: npt.NDArray[np.int64]
    cids: npt.NDArray[np.int64]
    entries_at: npt.NDArray[np.int64]
    counts: npt.NDArray[np.int64]


class _ChunkHead(NamedTuple):
    data_start: int
    data_len: int
    compression: str
    uncompressed_size: int


def mcap_payload(buf: memoryview, pos: int) -> memoryview | None:
    """The data of the Message record at ``pos`` of ``buf``, or None if it is not one."""
    if pos < 0 or pos + 31 > len(buf) or buf[pos] != _OP_MESSAGE:
        return None
    (length,) = _U64(buf, pos + 1)
    end = pos + 9 + length
    if length < 22 or end > len(buf):
        return None
    return buf[pos + 31 : end]


def _string(buf: memoryview, pos: int, end: int) -> tuple[str, int]:
    data, pos = _bytes(buf, pos, end)
    try:
        return data.decode(), pos
    except UnicodeDecodeError as err:
        msg = 'string is not UTF-8'
        raise _CorruptError(msg) from err


def _bytes(buf: memoryview, pos: int, end: int) -> tuple[bytes, int]:
    if pos + 4 > end:
        msg = 'record too short'
        raise _CorruptError(msg)
    (n,) = _U32(buf, pos)
    if pos + 4 + n > end:
        msg = 'field runs past its record'
        raise _CorruptError(msg)
    return bytes(buf[pos + 4 : pos + 4 + n]), pos + 4 + n


def _parse_schema(buf: memoryview, pos: int, end: int) -> tuple[int, _Schema]:
    if pos + 2 > end:
        msg = 'schema record too short'
        raise _CorruptError(msg)
    (sid,) = _U16(buf, pos)
    name, pos = _string(buf, pos + 2, end)
    encoding, pos = _string(buf, pos, end)
    data, _ = _bytes(buf, pos, end)
    return sid, _Schema(name, encoding, data)


def _parse_channel(buf: memoryview, pos: int, end: int) -> _ChannelRecord:
    if pos + 4 > end:
        msg = 'channel record too short'
        raise _CorruptError(msg)
    (cid,) = _U16(buf, pos)
    (sid,) = _U16(buf, pos + 2)
    topic, pos = _string(buf, pos + 4, end)
    encoding, _ = _string(buf, pos, end)
    return _ChannelRecord(cid, sid, topic, encoding)


def _parse_chunk_index(buf: memoryview, pos: int, end: int) -> _ChunkIndex:
    if pos + 36 > end:
        msg = 'chunk index record too short'
        raise _CorruptError(msg)
    (chunk_pos,) = _U64(buf, pos + 16)
    (map_len,) = _U32(buf, pos + 32)
    p = pos + 36
    if p + map_len > end or map_len % 10:
        msg = 'chunk index map is malformed'
        raise _CorruptError(msg)
    offsets: dict[int, int] = {}
    for q in range(p, p + map_len, 10):
        offsets[_U16(buf, q)[0]] = _U64(buf, q + 2)[0]
    return _ChunkIndex(chunk_pos, offsets)


def _chunk_indexes(buf: memoryview, summary: _Summary) -> list[_ChunkIndex]:
    """The summary's ChunkIndex records, parsed one by one."""
    return [
        _parse_chunk_index(buf, body, end)
        for body, end in zip(summary.chunk_records, summary.chunk_ends, strict=True)
    ]


def _chunk_head(buf: memoryview, pos: int, size: int) -> _ChunkHead:
    """Parse the Chunk record at ``pos``; ``data_len`` is what of its records lies in the file."""
    if pos + 9 + 36 > size or buf[pos] != _OP_CHUNK:
        msg = 'no chunk record here'
        raise _CorruptError(msg)
    (length,) = _U64(buf, pos + 1)
    body = pos + 9
    record_end = min(body + length, size)
    (usize,) = _U64(buf, body + 16)
    compression, p = _string(buf, body + 28, record_end)
    if p + 8 > record_end:
        msg = 'chunk record too short'
        raise _CorruptError(msg)
    (records_len,) = _U64(buf, p)
    start = p + 8
    return _ChunkHead(start, max(0, min(records_len, size - start)), compression, usize)


def _read_footer(buf: memoryview, size: int) -> int | None:
    """``summary_start`` from a valid footer (0: no summary); None when there is no footer."""
    if size < len(MCAP_MAGIC) + _FOOTER_TAIL or buf[size - len(MCAP_MAGIC) :] != MCAP_MAGIC:
        return None
    pos = size - _FOOTER_TAIL
    if buf[pos] != _OP_FOOTER or _U64(buf, pos + 1)[0] != 20:
        return None
    return int(_U64(buf, pos + 9)[0])


def _same_records(buf: memoryview, pos: int, stride: int, end: int) -> int:
    """How many records from ``pos`` on (at least this one) have the opcode and the length of
    the one at ``pos``, each ``stride`` bytes after the last, up to ``end``; looked at in
    blocks that double, so that a run costs in proportion to its length."""
    head = bytes(buf[pos : pos + 9])
    data = np.frombuffer(buf, np.uint8)
    try:
        run, block = 1, 8
        while True:
            n = min(block, (end - pos) // stride - run)
            if n <= 0:
                return run
            at = pos + stride * (run + np.arange(n, dtype=np.int64))
            same = np.all(_gather(data, at, 9) == np.frombuffer(head, np.uint8), axis=1)
            if not np.all(same):
                return run + int(np.argmin(same))
            run += n
            block *= 2
    finally:
        del data


def _read_summary(buf: memoryview, start: int, size: int) -> _Summary:
    end = size - _FOOTER_TAIL
    if not len(MCAP_MAGIC) <= start <= end:
        msg = 'summary offset outside the file'
        raise _CorruptError(msg)
    schemas: dict[int, _Schema] = {}
    channels: dict[int, _ChannelRecord] = {}
    chunk_records: list[int] = []
    chunk_ends: list[int] = []
    chunk_runs: list[tuple[int, int, int]] = []
    message_count: int | None = None
    pos = start
    while pos < end:
        if pos + 9 > end:
            msg = 'summary record cut short'
            raise _CorruptError(msg)
        op = buf[pos]
        (length,) = _U64(buf, pos + 1)
        body = pos + 9
        rec_end = body + length
        if rec_end > end:
            msg = 'summary record runs past the footer'
            raise _CorruptError(msg)
        if op == _OP_SCHEMA:
            sid, schema = _parse_schema(buf, body, rec_end)
            schemas[sid] = schema
        elif op == _OP_CHANNEL:
            channel = _parse_channel(buf, body, rec_end)
            channels[channel.id] = channel
        elif op == _OP_CHUNK_INDEX:  # parsed later, all at once where they are regular
            run = _same_records(buf, pos, 9 + length, end)
            chunk_runs.append((body, 9 + length, run))
            chunk_records.extend(range(body, body + run * (9 + length), 9 + length))
            chunk_ends.extend(range(rec_end, rec_end + run * (9 + length), 9 + length))
            pos += run * (9 + length)
            continue
        elif op == _OP_STATISTICS and length >= 8:
            message_count = int(_U64(buf, body)[0])
        pos = rec_end
    return _Summary(start, schemas, channels, chunk_records, chunk_ends, message_count, chunk_runs)


def _bulk_index(buf: memoryview, size: int, summary: _Summary) -> _Bulk | None:
    """Every ChunkIndex record of ``summary``, the Chunk record heads and the MessageIndex
    records they point to, read with array operations; None (nothing decided) unless they are
    regular: every chunk in one compression, listing each of its channels once, and every field
    as ``_parse_chunk_index``, ``_chunk_head`` and ``_message_indexes`` would read it without
    error. A file that is not regular is read record by record, which gives the same index (or
    the same refusal) one chunk at a time."""
    if not summary.chunk_records or len(summary.chunk_records) != len(summary.chunk_ends):
        return None
    bodies = np.array(summary.chunk_records, np.int64)
    lengths = np.array(summary.chunk_ends, np.int64) - bodies
    if np.any(lengths < 36):
        return None
    data = np.frombuffer(buf, np.uint8)
    try:
        return _bulk_read(data, size, bodies, lengths)
    finally:
        del data


def _gather(data: npt.NDArray[np.uint8], pos: npt.NDArray[np.int64], width: int) -> Any:
    """The ``width`` bytes at each of ``pos`` (checked to lie in ``data``), one row each."""
    return data[pos.reshape(-1)[:, None] + np.arange(width)].reshape((*pos.shape, width))


def _uint(data: npt.NDArray[np.uint8], pos: npt.NDArray[np.int64], kind: str) -> Any:
    width = np.dtype(kind).itemsize
    return _gather(data, pos, width).view(kind)[..., 0]


def _strided_uint(
    data: npt.NDArray[np.uint8], first: int, stride: int, n: int, at: int, kind: str
) -> Any:
    """``_uint`` at ``first + at + stride * i`` for i below ``n`` (inside ``data``), read as
    one strided copy."""
    width = np.dtype(kind).itemsize
    rows = np.lib.stride_tricks.as_strided(
        data[first + at :], shape=(n, width), strides=(stride, 1), writeable=False
    )
    return rows.copy().view(kind)[:, 0]


def _ascending(values: npt.NDArray[Any]) -> bool:
    """Whether ``values`` never decrease."""
    return bool(np.all(values[1:] >= values[:-1]))


def _sorted_unique(values: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """The distinct values of a sorted array."""
    if not len(values):
        return values
    return values[np.concatenate(([True], values[1:] != values[:-1]))]


def _bulk_read(
    data: npt.NDArray[np.uint8],
    size: int,
    bodies: npt.NDArray[np.int64],
    lengths: npt.NDArray[np.int64],
) -> _Bulk | None:
    # ChunkIndex: start, end, chunk position (u64 at 16), ..., map length (u32 at 32), map of
    # (channel id u16, MessageIndex position u64); records of one length are read together
    map_lens = _uint(data, bodies + 32, '<u4').astype(np.int64)
    if np.any(map_lens % 10) or np.any(map_lens == 0) or np.any(36 + map_lens > lengths):
        return None
    rows, cid_parts, offset_parts = [], [], []
    for map_len in np.unique(map_lens).tolist():
        sel = np.flatnonzero(map_lens == map_len)
        k = map_len // 10
        at = bodies[sel][:, None] + 36 + 10 * np.arange(k)
        cids = _uint(data, at, '<u2').astype(np.int64)
        if k > 1 and np.any(np.diff(np.sort(cids, axis=1), axis=1) == 0):
            return None  # a channel listed twice: the record reader keeps the last one
        rows.append(np.repeat(sel, k))
        cid_parts.append(cids.reshape(-1))
        offset_parts.append(_uint(data, at + 2, '<u8').reshape(-1))
    record = np.concatenate(rows)
    cids = np.concatenate(cid_parts)
    offsets = np.concatenate(offset_parts)
    chunk_pos = _uint(data, bodies + 16, '<u8')
    if np.any(chunk_pos > size - 45):
        return None
    order = np.argsort(chunk_pos, kind='stable')
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    chunk_pos = chunk_pos[order].astype(np.int64)
    # Chunk: op, record length, then start, end, uncompressed size (u64 at 16), crc, compression
    if np.any(data[chunk_pos] != _OP_CHUNK):
        return None
    body = chunk_pos + 9
    record_len = np.minimum(_uint(data, chunk_pos + 1, '<u8'), np.uint64(size)).astype(np.int64)
    record_end = np.minimum(body + record_len, size)
    usize = _uint(data, body + 16, '<u8')
    comp_len = _uint(data, body + 28, '<u4').astype(np.int64)
    if np.any(comp_len != comp_len[0]):
        return None
    after = body + 32 + int(comp_len[0])  # the records' length (u64), then the records
    if np.any(after + 8 > record_end) or np.any(usize > np.uint64(2**62)):
        return None
    names = _gather(data, body + 32, int(comp_len[0]))
    if np.any(names != names[:1]):
        return None
    try:
        compression = bytes(names[0]).decode()
    except UnicodeDecodeError:
        return None
    records_len = np.minimum(_uint(data, after, '<u8'), np.uint64(size)).astype(np.int64)
    data_start = after + 8
    data_len = np.maximum(0, np.minimum(records_len, size - data_start))
    # MessageIndex: op, record length, channel id (u16), entries' length (u32), entries
    if np.any(offsets > size - 15):
        return None
    entries_at = offsets.astype(np.int64)
    rec_len = _uint(data, entries_at + 1, '<u8')
    nbytes = _uint(data, entries_at + 11, '<u4').astype(np.int64)
    if (
        np.any(data[entries_at] != _OP_MESSAGE_INDEX)
        or np.any(_uint(data, entries_at + 9, '<u2') != cids)
        or np.any(nbytes % 16)
        or np.any(rec_len < (6 + nbytes).astype(np.uint64))
        or np.any(entries_at + 15 + nbytes > size)
    ):
        return None
    return _Bulk(
        chunk_pos,
        data_start,
        data_len,
        usize.astype(np.int64),
        compression,
        rank[record],
        cids,
        entries_at + 15,
        nbytes // 16,
    )


class _Lazy(NamedTuple):
    """A regular summary's chunk indexes as arrays, with nothing of the chunks read
    (``_lazy_index``): per chunk, in position order, its ChunkIndex fields and where its records
    are; per MessageIndex record, by chunk and then position, its chunk (a row of the first
    arrays), channel id, position and entry count (from where the next record begins)."""

    pos: npt.NDArray[np.int64]
    start: npt.NDArray[np.uint64]
    end: npt.NDArray[np.uint64]
    length: npt.NDArray[np.int64]
    data_start: npt.NDArray[np.int64]
    data_len: npt.NDArray[np.int64]
    uncompressed_size: npt.NDArray[np.uint64]
    compression: str
    order: npt.NDArray[np.int64]  # the chunks by (start time, position)
    rec_chunk: npt.NDArray[np.int64]
    rec_cid: npt.NDArray[np.int64]
    rec_at: npt.NDArray[np.int64]
    rec_count: npt.NDArray[np.int64]
    rec_first: npt.NDArray[np.int64]  # chunk k's records are rec_first[k]:rec_first[k + 1]


def _lazy_index(buf: memoryview, summary: _Summary) -> _Lazy | None:
    """The summary's ChunkIndex records read with array operations, touching nothing outside the
    summary; None unless they are regular: one compression, each channel listed once per chunk,
    chunks that do not overlap, and MessageIndex records laid end to end after their chunk, as
    its ``message_index_length`` says (so that a record's entry count is where the next one
    begins). The chunks and their MessageIndex records are read, and checked against this,
    when a reader reaches them (``McapSource._lazy_rows``)."""
    if not summary.chunk_records or len(summary.chunk_records) != len(summary.chunk_ends):
        return None
    data = np.frombuffer(buf, np.uint8)
    try:
        if len(summary.chunk_runs) <= _RUNS_AT_MOST:
            return _lazy_runs(data, summary.start, summary.chunk_runs)
        bodies = np.array(summary.chunk_records, np.int64)
        lengths = np.array(summary.chunk_ends, np.int64) - bodies
        if np.any(lengths < 64):
            return None
        return _lazy_read(data, summary.start, bodies, lengths)
    finally:
        del data


def _lazy_read(
    data: npt.NDArray[np.uint8],
    data_end: int,
    bodies: npt.NDArray[np.int64],
    lengths: npt.NDArray[np.int64],
) -> _Lazy | None:
    # ChunkIndex: start, end, chunk position, chunk length (u64 at 0, 8, 16, 24), map of
    # (channel id u16, MessageIndex position u64) with its length (u32 at 32), then the
    # MessageIndex records' length (u64), compression (string), compressed and uncompressed size
    ends = bodies + lengths
    map_lens = _uint(data, bodies + 32, '<u4').astype(np.int64)
    if np.any(map_lens % 10) or np.any(map_lens == 0) or np.any(64 + map_lens > lengths):
        return None
    tail = bodies + 36 + map_lens
    comp_len = _uint(data, tail + 8, '<u4').astype(np.int64)
    n = int(comp_len[0])
    if np.any(comp_len != n) or np.any(tail + 28 + n > ends):
        return None
    names = _gather(data, tail + 12, n)
    if n and np.any(names != names[:1]):
        return None
    try:
        compression = bytes(names[0]).decode()
    except UnicodeDecodeError:
        return None
    limit = np.uint64(data_end)
    fields = [_uint(data, at, '<u8') for at in (bodies + 16, bodies + 24, tail, tail + 12 + n)]
    if any(np.any(f > limit) for f in fields):
        return None
    pos, clen, mi_len, csize = (f.astype(np.int64) for f in fields)
    start = _uint(data, bodies, '<u8')
    end = _uint(data, bodies + 8, '<u8')
    usize = _uint(data, tail + 20 + n, '<u8')
    if (
        np.any(start > end)
        or np.any(usize > np.uint64(2**62))
        or np.any(pos < len(MCAP_MAGIC))
        or np.any(clen != 49 + n + csize)
        or np.any(pos + clen + mi_len > data_end)
    ):
        return None
    by_pos = np.argsort(pos, kind='stable')
    pos, clen, mi_len, csize = pos[by_pos], clen[by_pos], mi_len[by_pos], csize[by_pos]
    if np.any(pos[1:] < pos[:-1] + clen[:-1] + mi_len[:-1]):
        return None  # chunks (or their MessageIndex records) overlap
    rank = np.empty_like(by_pos)
    rank[by_pos] = np.arange(len(by_pos))
    rows, cid_parts, offset_parts = [], [], []
    for map_len in _sorted_unique(np.sort(map_lens)).tolist():
        sel = np.flatnonzero(map_lens == map_len)
        k = map_len // 10
        at = bodies[sel][:, None] + 36 + 10 * np.arange(k)
        cids = _uint(data, at, '<u2').astype(np.int64)
        if k > 1 and np.any(np.diff(np.sort(cids, axis=1), axis=1) == 0):
            return None
        rows.append(np.repeat(rank[sel], k))
        cid_parts.append(cids.reshape(-1))
        offset_parts.append(_uint(data, at + 2, '<u8').reshape(-1))
    return _lazy_records(
        pos, start[by_pos], end[by_pos], clen, mi_len, csize, usize[by_pos], compression, n,
        np.concatenate(rows), np.concatenate(cid_parts), np.concatenate(offset_parts), limit,
    )  # fmt: skip


#: ChunkIndex records in at most this many runs of one length are read run by run
_RUNS_AT_MOST = 64


class _RunFields(NamedTuple):
    pos: Any
    start: Any
    end: Any
    clen: Any
    mi_len: Any
    csize: Any
    usize: Any
    names: Any  # (records, compression length) bytes
    cids: Any  # (records, channels)
    offsets: Any


def _run_fields(
    data: npt.NDArray[np.uint8], first: int, stride: int, count: int
) -> _RunFields | None:
    """The fields of ``count`` ChunkIndex records of one length (``stride - 9``), one after the
    other from the body at ``first``, each read as one strided copy; None unless they hold one
    map length and compression length."""
    length = stride - 9

    def field(at: int, kind: str) -> Any:
        return _strided_uint(data, first, stride, count, at, kind)

    if length < 64:
        return None
    map_lens = field(32, '<u4')
    map_len = int(map_lens[0])
    if np.any(map_lens != map_len) or map_len % 10 or map_len == 0 or 64 + map_len > length:
        return None
    tail = 36 + map_len
    comp_len = field(tail + 8, '<u4')
    n = int(comp_len[0])
    if np.any(comp_len != n) or tail + 28 + n > length:
        return None
    k = map_len // 10
    return _RunFields(
        field(16, '<u8'),
        field(0, '<u8'),
        field(8, '<u8'),
        field(24, '<u8'),
        field(tail, '<u8'),
        field(tail + 12 + n, '<u8'),
        field(tail + 20 + n, '<u8'),
        np.lib.stride_tricks.as_strided(
            data[first + tail + 12 :], shape=(count, n), strides=(stride, 1), writeable=False
        ).copy(),
        np.stack([field(36 + 10 * j, '<u2') for j in range(k)], axis=1).astype(np.int64),
        np.stack([field(38 + 10 * j, '<u8') for j in range(k)], axis=1),
    )


def _lazy_runs(
    data: npt.NDArray[np.uint8], data_end: int, runs: list[tuple[int, int, int]]
) -> _Lazy | None:
    """``_lazy_read`` for ChunkIndex records in a few runs of one length (as writers make
    them), run by run."""
    parts = []
    for first, stride, count in runs:
        part = _run_fields(data, first, stride, count)
        if part is None:
            return None
        parts.append(part)
    n = parts[0].names.shape[1]
    names = np.concatenate([p.names for p in parts]) if n else parts[0].names
    if any(p.names.shape[1] != n for p in parts) or (n and np.any(names != names[:1])):
        return None
    try:
        compression = bytes(names[0]).decode()
    except UnicodeDecodeError:
        return None
    limit = np.uint64(data_end)
    pos, clen, mi_len, csize = (
        np.concatenate([getattr(p, f) for p in parts]) for f in ('pos', 'clen', 'mi_len', 'csize')
    )
    if any(np.any(f > limit) for f in (pos, clen, mi_len, csize)):
        return None
    pos, clen, mi_len, csize = (f.astype(np.int64) for f in (pos, clen, mi_len, csize))
    start, end, usize = (
        np.concatenate([getattr(p, f) for p in parts]) for f in ('start', 'end', 'usize')
    )
    if (
        np.any(start > end)
        or np.any(usize > np.uint64(2**62))
        or np.any(pos < len(MCAP_MAGIC))
        or np.any(clen != 49 + n + csize)
        or np.any(pos + clen + mi_len > data_end)
    ):
        return None
    for p in parts:
        k = p.cids.shape[1]
        if k > 1 and np.any(np.diff(np.sort(p.cids, axis=1), axis=1) == 0):
            return None
    by_pos = np.argsort(pos, kind='stable')
    rank = np.empty_like(by_pos)
    rank[by_pos] = np.arange(len(by_pos))
    pos, clen, mi_len, csize = pos[by_pos], clen[by_pos], mi_len[by_pos], csize[by_pos]
    if np.any(pos[1:] < pos[:-1] + clen[:-1] + mi_len[:-1]):
        return None
    row = np.cumsum([0] + [len(p.pos) for p in parts])
    chunk = np.concatenate(
        [np.repeat(rank[row[i] : row[i + 1]], p.cids.shape[1]) for i, p in enumerate(parts)]
    )
    return _lazy_records(
        pos, start[by_pos], end[by_pos], clen, mi_len, csize, usize[by_pos], compression, n,
        chunk, np.concatenate([p.cids.reshape(-1) for p in parts]),
        np.concatenate([p.offsets.reshape(-1) for p in parts]), limit,
    )  # fmt: skip


def _lazy_records(
    pos: npt.NDArray[np.int64],
    start: npt.NDArray[np.uint64],
    end: npt.NDArray[np.uint64],
    clen: npt.NDArray[np.int64],
    mi_len: npt.NDArray[np.int64],
    csize: npt.NDArray[np.int64],
    usize: npt.NDArray[np.uint64],
    compression: str,
    n: int,
    chunk: npt.NDArray[np.int64],
    cids: npt.NDArray[np.int64],
    offsets_u: npt.NDArray[np.uint64],
    limit: np.uint64,
) -> _Lazy | None:
    """The ``_Lazy`` of chunks in position order and their MessageIndex records (chunk row,
    channel id, position); None unless the records lie end to end after their chunk."""
    if np.any(offsets_u > limit):
        return None
    if np.any(offsets_u > limit):
        return None
    offsets = offsets_u.astype(np.int64)
    step = np.diff(chunk)
    if not np.all((step > 0) | ((step == 0) & (np.diff(offsets) > 0))):  # as writers write them
        by_rec = np.lexsort((offsets, chunk))
        chunk, cids, offsets = chunk[by_rec], cids[by_rec], offsets[by_rec]
    per_chunk = np.bincount(chunk, minlength=len(pos))
    first = np.concatenate(([0], np.cumsum(per_chunk)))
    following = np.empty_like(offsets)
    following[:-1] = offsets[1:]
    following[first[1:] - 1] = pos + clen + mi_len  # a chunk's last record ends its records
    extent = following - offsets
    if (
        np.any(offsets[first[:-1]] != pos + clen)
        or np.any(extent < 15)
        or np.any((extent - 15) % 16)
    ):
        return None
    return _Lazy(
        pos,
        start,
        end,
        clen,
        pos + 49 + n,
        csize,
        usize,
        compression,
        np.arange(len(pos)) if _ascending(start) else np.lexsort((pos, start)).astype(np.int64),
        chunk,
        cids,
        offsets,
        (extent - 15) // 16,
        first.astype(np.int64),
    )


def _schemas_in(buf: memoryview, start: int, end: int, found: dict[int, _Schema]) -> None:
    """Add the Schema records among the records in ``buf[start:end]`` (first one per id wins)."""
    pos = start
    while pos + 9 <= end:
        (length,) = _U64(buf, pos + 1)
        rec_end = pos + 9 + length
        if rec_end > end:
            return
        if buf[pos] == _OP_SCHEMA:
            sid, schema = _parse_schema(buf, pos + 9, rec_end)
            found.setdefault(sid, schema)
        pos = rec_end


def _data_schemas(buf: memoryview, end: int, wanted: set[int]) -> dict[int, _Schema]:
    """The Schema records with ids in ``wanted`` from the data section ``buf[:end]``.

    For a summary that lists channels but no schemas (``repeat_schemas=False``): the schemas
    are then only where they were first written, at the top level or inside a chunk. Records
    are read in file order, and chunks decompressed, until every wanted id is found; a record
    or chunk that cannot be read is passed over.
    """
    found: dict[int, _Schema] = {}
    pos = len(MCAP_MAGIC)
    while pos + 9 <= end and not wanted <= found.keys():
        op = buf[pos]
        (length,) = _U64(buf, pos + 1)
        rec_end = pos + 9 + length
        if rec_end > end:
            break
        try:
            if op == _OP_SCHEMA:
                _schemas_in(buf, pos, rec_end, found)
            elif op == _OP_CHUNK:
                head = _chunk_head(buf, pos, rec_end)
                if not head.compression:
                    _schemas_in(buf, head.data_start, head.data_start + head.data_len, found)
                else:
                    data = decompress_chunk(
                        buf,
                        head.data_start,
                        head.data_len,
                        head.compression,
                        head.uncompressed_size,
                        partial=False,
                    )
                    with memoryview(data) as view:
                        _schemas_in(view, 0, len(view), found)
        except (ValueError, struct.error):  # _CorruptError and codec errors are ValueErrors
            pass
        pos = rec_end
    return {sid: schema for sid, schema in found.items() if sid in wanted}


class _LazyTable(NamedTuple):
    """A lazily read index (``lz``) with its channels: per MessageIndex record its channel
    (``g``: below 0 for none or an unreadable one; ``channel``: the number of channels for
    those), per channel its topic's rank (and -1 after them), and the summary's chmap."""

    lz: _Lazy
    g: npt.NDArray[np.int64]
    channel: npt.NDArray[np.int64]
    rank: npt.NDArray[np.int64]
    chmap: dict[int, int]
    topics: int
    start_ascending: bool  # the chunks' first log times, in position order, never decrease
    end_ascending: bool  # nor their last ones


def _collect(rows: list[tuple[int, int, int, int]]) -> Callable[[int, int, int, int], None]:
    """A ``_scan_records`` ``add`` that appends its rows to ``rows``."""

    def add(log_time: int, channel: int, chunk: int, offset: int) -> None:
        rows.append((log_time, channel, chunk, offset))

    return add


#: chunks read at most at once by a lazily indexed source's reader (it starts with one)
_LAZY_BATCH = 128


class McapSource(TableSource):
    """One ``.mcap`` file, or the ``.mcap`` files of a rosbag2 directory replayed as one input."""

    def __init__(
        self, path: str | Path, files: Sequence[Path] | None = None, fmt: str = 'mcap'
    ) -> None:
        path = Path(path)
        super().__init__(path, fmt, files if files is not None else [path], mcap_payload)
        self._channel_warned: set[str] = set()
        #: topics of the channels in an unsupported encoding; chmap maps them to -2 - index
        self._unreadable_names: list[str] = []
        #: a single file's regular index, read when a reader reaches each chunk (``_lazy``)
        self._lz: _LazyTable | None = None
        try:
            for file_no, file in enumerate(self.files):
                mapped = MappedFile(file)
                self._maps.append(mapped)
                self._index_file(file_no, mapped)
            if self._lz is None:
                self._finish()
        except BaseException:
            self.close()
            raise

    # -- reading a lazily indexed file ----------------------------------------------------

    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[RawMessage]:
        """Messages in replay order; ``start_ns`` inclusive, ``end_ns`` exclusive (log time)."""
        table = self._lz
        if table is None:
            return super().messages(topics, start_ns, end_ns)
        self._check_open()
        lo = 0 if start_ns is None else clamp_time(start_ns)
        hi = None if end_ns is None or end_ns > U64_MAX else clamp_time(end_ns)
        if hi is not None and hi <= lo:
            return iter(())
        wanted = np.ones(len(table.rank), np.bool_)
        if topics is not None:
            names = {topics} if isinstance(topics, str) else set(topics)
            wanted[:-1] = [ch.topic in names for ch in self._channels]
        wanted[-1] = False
        return self._lazy_generate(table, lo, hi, wanted)

    def _chunk_at(self, k: int) -> Chunk:
        table = self._lz
        if table is None:
            return super()._chunk_at(k)
        lz = table.lz
        return Chunk(
            0,
            int(lz.pos[k]),
            int(lz.data_start[k]),
            int(lz.data_len[k]),
            lz.compression,
            int(lz.uncompressed_size[k]),
            False,
        )

    def _lazy_generate(
        self, table: _LazyTable, lo: int, hi: int | None, wanted: npt.NDArray[np.bool_]
    ) -> Iterator[RawMessage]:
        """The messages of ``wanted`` channels with ``lo <= log time < hi``, in the order and
        with the seq of the table read at once: chunks are read in the order of their first
        log times, and a message is yielded once no chunk left unread can hold one before it
        (the ones left begin later)."""
        lz = table.lz
        topic = table.rank[table.channel]
        listed = wanted[table.channel] & (lz.rec_count > 0)
        has = np.bincount(lz.rec_chunk[listed], minlength=len(lz.pos)) > 0
        lo64 = np.uint64(lo)
        before = has & (lz.end < lo64)  # wholly before the window: counted for seq, not read
        seq_base = np.bincount(
            topic[listed & before[lz.rec_chunk]],
            weights=lz.rec_count[listed & before[lz.rec_chunk]],
            minlength=table.topics,
        ).astype(np.int64)
        todo_mask = has & ~before
        if hi is not None:
            todo_mask &= lz.start < np.uint64(hi)
        todo = lz.order[todo_mask[lz.order]]
        channels = self._channels
        payload = self._payload
        view = self._maps[0].view
        compressed = bool(lz.compression)
        empty_t = np.empty(0, np.uint64)
        empty_i = np.empty(0, np.int64)
        pending = (empty_t, empty_i, empty_i, empty_i)
        i, batch = 0, 1
        while i < len(todo) or len(pending[0]):
            if i < len(todo):
                ks = todo[i : i + batch]
                i += len(ks)
                batch = min(2 * batch, _LAZY_BATCH)
                t, ch, kk, off = self._lazy_rows(table, ks, wanted, strict=False)
                low = t < lo64
                if np.any(low):
                    seq_base += np.bincount(table.rank[ch[low]], minlength=table.topics)
                inside = ~low if hi is None else ~low & (t < np.uint64(hi))
                pending = (
                    np.concatenate((pending[0], t[inside])),
                    np.concatenate((pending[1], ch[inside])),
                    np.concatenate((pending[2], kk[inside])),
                    np.concatenate((pending[3], off[inside])),
                )
            if i < len(todo):
                ready = pending[0] < lz.start[todo[i]]
                if not np.any(ready):
                    continue
                out = tuple(a[ready] for a in pending)
                pending = tuple(a[~ready] for a in pending)
            else:
                out, pending = pending, (empty_t, empty_i, empty_i, empty_i)
            t, ch, kk, off = out
            rank = table.rank[ch]
            order = np.lexsort((off, lz.pos[kk], rank, t))
            t, ch, kk, off, rank = t[order], ch[order], kk[order], off[order], rank[order]
            n = len(t)
            counts = np.bincount(rank, minlength=table.topics)
            by_topic = np.argsort(rank, kind='stable')
            seq = np.empty(n, np.int64)
            seq[by_topic] = (
                np.arange(n, dtype=np.int64)
                - np.repeat(np.cumsum(counts) - counts, counts)
                + seq_base[rank[by_topic]]
            )
            seq_base += counts
            last_use: dict[int, int] = {}
            if compressed:
                done = np.setdiff1d(np.unique(kk), pending[2])
                rev_unique, rev_first = np.unique(kk[::-1], return_index=True)
                finished = np.isin(rev_unique, done)
                last_use = dict(
                    zip(
                        rev_unique[finished].tolist(),
                        (n - 1 - rev_first[finished]).tolist(),
                        strict=True,
                    )
                )
            where = off if compressed else off + lz.data_start[kk]
            yield from self._yield_rows(
                t.tolist(), ch.tolist(), kk.tolist(), where.tolist(), seq.tolist(),
                None if compressed else view, last_use, channels, payload,
            )  # fmt: skip

    def _yield_rows(
        self,
        times: list[int],
        chans: list[int],
        chunks: list[int],
        offsets: list[int],
        seqs: list[int],
        view: memoryview | None,
        last_use: dict[int, int],
        channels: list[Channel],
        payload: Callable[[memoryview, int], memoryview | None],
    ) -> Iterator[RawMessage]:
        """The messages of these rows: at ``offsets`` of ``view`` (file positions), or of their
        decompressed chunk when ``view`` is None (evicted after its ``last_use`` row)."""
        for j in range(len(times)):
            if self._closed:
                msg = f'{self.path}: source closed during iteration'
                raise SourceError(msg)
            k = chunks[j]
            if view is None:
                buf = self._decompressed(k)
                data = payload(buf, offsets[j]) if len(buf) else None
            else:
                data = payload(view, offsets[j])
            ch = channels[chans[j]]
            if data is None:
                self._skipped(k, ch.topic)
            else:
                yield RawMessage(
                    ch.topic, ch.msgtype, ch.serialization, times[j], seqs[j], data, ch.schema
                )
            if last_use and last_use.get(k) == j:
                self._evict(k)

    # -- channels -------------------------------------------------------------------------

    def _register(
        self,
        chmap: dict[int, int],
        record: _ChannelRecord,
        schemas: dict[int, _Schema],
    ) -> None:
        if record.id in chmap:
            return
        serialization = _SERIALIZATIONS.get(record.encoding.lower())
        if serialization is None:
            chmap[record.id] = self._unreadable_channel(record, schemas)
            if record.topic not in self._channel_warned:
                self._channel_warned.add(record.topic)
                self._warn(
                    f'topic {record.topic}: message encoding {record.encoding!r} '
                    'is not supported; skipped'
                )
            return
        schema = schemas.get(record.schema_id)
        name = schema.name if schema else ''
        if schema is None and record.schema_id:
            self._warn(
                f'topic {record.topic}: schema {record.schema_id} is not in the file; '
                'its message type is unknown'
            )
        if serialization == 'protobuf':
            channel = Channel(record.topic, name, serialization, schema.data if schema else b'')
        else:
            channel = Channel(record.topic, normalize_msgtype(name), serialization, b'')
        chmap[record.id] = self._add_channel(channel)

    def _unreadable_channel(self, record: _ChannelRecord, schemas: dict[int, _Schema]) -> int:
        """The chmap value (-2 or less) of a channel whose message encoding is not supported."""
        if record.topic not in self._unreadable:
            schema = schemas.get(record.schema_id)
            msgtype = normalize_msgtype(schema.name) if schema else ''
            reason = f'message encoding {record.encoding!r} is not supported'
            self._unreadable[record.topic] = SkippedTopic(
                record.topic, msgtype, record.encoding, 0, reason
            )
            self._unreadable_names.append(record.topic)
        return -2 - self._unreadable_names.index(record.topic)

    def _count_unreadable(self, g: int, count: int) -> None:
        topic = self._unreadable_names[-2 - g]
        entry = self._unreadable[topic]
        self._unreadable[topic] = entry._replace(count=entry.count + count)

    # -- indexing -------------------------------------------------------------------------

    def _index_file(self, file_no: int, mapped: MappedFile) -> None:
        buf, size = mapped.view, mapped.size
        if size < len(MCAP_MAGIC) or buf[: len(MCAP_MAGIC)] != MCAP_MAGIC:
            msg = f'{mapped.path}: not an MCAP file (no MCAP magic bytes)'
            raise SourceError(msg)
        summary_start = _read_footer(buf, size)
        if summary_start:
            try:
                summary = _read_summary(buf, summary_start, size)
                lazy = _lazy_index(buf, summary) if len(self.files) == 1 else None
                if lazy is not None and self._index_lazy(mapped, summary, lazy):
                    return
                bulk = _bulk_index(buf, size, summary)
                indexes = [] if bulk is not None else _chunk_indexes(buf, summary)
            except (_CorruptError, struct.error) as err:
                self._warn(f'{mapped.path.name}: summary unreadable ({err}); scanned the file')
            else:
                if bulk is not None:
                    if self._index_from_bulk(file_no, mapped, summary, bulk):
                        return
                elif self._index_from_summary(file_no, mapped, summary, indexes):
                    return
        zeros = ''
        if summary_start is None:  # no footer: a zero-filled tail is where the file was cut
            end = zero_tail_start(buf, size)
            if end < size:
                mapped.cut(end)
                zeros = f'; the last {size - end} bytes are zeros'
        if not self._scan_file(file_no, mapped) or zeros:
            self._truncated = True
            self._warn(
                f'{mapped.path.name}: file is cut short at byte {mapped.size} '
                f'(no MCAP footer{zeros}); replaying every complete message before the cut'
            )

    def _summary_channels(self, mapped: MappedFile, summary: _Summary) -> dict[int, int]:
        """Register the summary's channels; their chmap (channel id -> index, or below 0)."""
        chmap: dict[int, int] = {}
        schemas = summary.schemas
        missing = {ch.schema_id for ch in summary.channels.values() if ch.schema_id} - set(schemas)
        if missing:  # channels in the summary, their schemas only in the data section
            schemas = {**_data_schemas(mapped.view, summary.start, missing), **schemas}
        for record in summary.channels.values():
            self._register(chmap, record, schemas)
        return chmap

    def _index_lazy(self, mapped: MappedFile, summary: _Summary, lazy: _Lazy) -> bool:
        """Index a single file from its regular summary (``_lazy_index``) without reading its
        chunks or MessageIndex records: the topics' counts come from the index, their first and
        last log times from the few chunks that can hold them. False (nothing added) where the
        index is refused or those chunks do not match it: the file is then read as before."""
        ids = np.flatnonzero(np.bincount(lazy.rec_cid)).tolist()
        if any(cid not in summary.channels for cid in ids):
            return False
        if summary.message_count not in (None, int(lazy.rec_count.sum())):
            return False  # the record-by-record reader says so, and scans the file
        channels_before = len(self._channels)
        chmap = self._summary_channels(mapped, summary)
        lookup = np.full(1 << 16, -1, np.int64)
        for cid in ids:
            lookup[cid] = chmap.get(cid, -1)
        g = lookup[lazy.rec_cid]
        names = sorted({ch.topic for ch in self._channels})
        index = {name: i for i, name in enumerate(names)}
        # per channel its topic's rank; one more entry (-1) for the records of no channel
        rank = np.array([index[ch.topic] for ch in self._channels] + [-1], np.int64)
        channel = np.where(g >= 0, g, len(self._channels))
        table = _LazyTable(
            lazy,
            g,
            channel,
            rank,
            chmap,
            len(names),
            _ascending(lazy.start),
            _ascending(lazy.end),
        )
        self._lz = table
        try:
            first, last = self._lazy_bounds(table)
        except _CorruptError:
            self._lz = None
            del self._channels[channels_before:]
            return False
        for unreadable in sorted(set(g[g < -1].tolist())):
            self._count_unreadable(unreadable, int(lazy.rec_count[g == unreadable].sum()))
        readable = g >= 0
        counts = np.bincount(
            rank[channel[readable]], weights=lazy.rec_count[readable], minlength=len(names)
        )
        self._topics = self._topic_infos(names, counts.astype(np.int64).tolist(), first, last)
        return True

    def _lazy_bounds(self, table: _LazyTable) -> tuple[list[int], list[int]]:
        """Each topic's first and last log time: read from its chunks in the order of their
        first (last) log times, until no chunk left can hold an earlier (later) one."""
        lz = table.lz
        topic = table.rank[table.channel]
        first, last = [0] * table.topics, [0] * table.topics
        for r in range(table.topics):
            wanted = np.zeros(len(table.rank), np.bool_)
            wanted[np.flatnonzero(table.rank == r)] = True
            wanted[-1] = False
            ks = _sorted_unique(lz.rec_chunk[(topic == r) & (lz.rec_count > 0)])
            if not len(ks):
                continue
            best: int | None = None
            by_start = ks if table.start_ascending else ks[np.argsort(lz.start[ks], kind='stable')]
            for k in by_start.tolist():
                if best is not None and int(lz.start[k]) >= best:
                    break
                times = self._lazy_rows(table, np.array([k]), wanted, strict=True)[0]
                if len(times):
                    low = int(times.min())
                    best = low if best is None else min(best, low)
            first[r] = best or 0
            best = None
            by_end = ks if table.end_ascending else ks[np.argsort(lz.end[ks], kind='stable')]
            for k in by_end[::-1].tolist():
                if best is not None and int(lz.end[k]) <= best:
                    break
                times = self._lazy_rows(table, np.array([k]), wanted, strict=True)[0]
                if len(times):
                    high = int(times.max())
                    best = high if best is None else max(best, high)
            last[r] = best or 0
        return first, last

    def _lazy_rows(
        self,
        table: _LazyTable,
        ks: npt.NDArray[np.int64],
        wanted: npt.NDArray[np.bool_],
        *,
        strict: bool,
    ) -> tuple[
        npt.NDArray[np.uint64], npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64]
    ]:
        """(log time, channel, chunk, offset in chunk) of the messages of chunks ``ks`` on the
        channels ``wanted`` (one flag per channel, and False after them), from their
        MessageIndex records, checked as the record-by-record reader checks them and against
        the chunk index (the Chunk record's head; each record's channel and length; log times
        inside the chunk's). ``strict``: a chunk that fails raises ``_CorruptError``; else it is
        read record by record (a damaged MessageIndex) or skipped with a warning (no Chunk
        record where the index says)."""
        lz = table.lz
        mapped = self._maps[0]
        per = lz.rec_first[ks + 1] - lz.rec_first[ks]
        idx = np.repeat(lz.rec_first[ks], per) + (
            np.arange(int(per.sum()), dtype=np.int64) - np.repeat(np.cumsum(per) - per, per)
        )
        at, count = lz.rec_at[idx], lz.rec_count[idx]
        data = np.frombuffer(mapped.map, np.uint8)
        try:
            p = lz.pos[ks]
            n = len(lz.compression)
            head_ok = (
                (data[p] == _OP_CHUNK)
                & (_uint(data, p + 1, '<u8') == (lz.length[ks] - 9).astype(np.uint64))
                & (_uint(data, p + 25, '<u8') == lz.uncompressed_size[ks])
                & (_uint(data, p + 37, '<u4') == n)
                & (_uint(data, p + 41 + n, '<u8') == lz.data_len[ks].astype(np.uint64))
            )
            if n:
                head_ok &= np.all(
                    _gather(data, p + 41, n) == np.frombuffer(lz.compression.encode(), np.uint8),
                    axis=1,
                )
            rec_ok = (
                (data[at] == _OP_MESSAGE_INDEX)
                & (_uint(data, at + 1, '<u8') == (6 + 16 * count).astype(np.uint64))
                & (_uint(data, at + 9, '<u2') == lz.rec_cid[idx])
                & (_uint(data, at + 11, '<u4') == (16 * count).astype(np.uint64))
            )
            good = head_ok & (
                np.bincount(np.repeat(np.arange(len(ks)), per), weights=~rec_ok, minlength=len(ks))
                == 0
            )
            if strict and not np.all(good):
                raise _CorruptError
            channel = table.channel[idx]
            keep = wanted[channel] & (count > 0) & np.repeat(good, per)
            t, off = self._entries(data, at[keep] + 15, count[keep])
            ch = np.repeat(channel[keep], count[keep])
            kk = np.repeat(lz.rec_chunk[idx][keep], count[keep])
        finally:
            del data
        bounds = (t < lz.start[kk]) | (t > lz.end[kk])
        if np.any(bounds):
            if strict:
                raise _CorruptError
            for k in sorted(set(kk[bounds].tolist())):
                self._warn(
                    f'{mapped.path.name}: chunk at byte {int(lz.pos[k])} holds log times '
                    "outside its index's; replayed where they fall"
                )
        if np.all(good):
            return t, ch, kk, off
        parts = [(t, ch, kk, off)]
        for k, ok_head in zip(ks[~good].tolist(), head_ok[~good].tolist(), strict=True):
            if not ok_head:
                self._warn(
                    f'{mapped.path.name}: no chunk record at byte {int(lz.pos[k])}, where the '
                    'index has one; its messages skipped'
                )
                continue
            found: list[tuple[int, int, int, int]] = []
            self._scan_chunk(k, table.chmap, {}, _collect(found))
            rows = [r for r in found if wanted[r[1]]]
            if rows:
                cols = np.array(rows, np.int64).T
                parts.append((cols[0].astype(np.uint64), cols[1], cols[2], cols[3]))
        return (
            np.concatenate([q[0] for q in parts]),
            np.concatenate([q[1] for q in parts]),
            np.concatenate([q[2] for q in parts]),
            np.concatenate([q[3] for q in parts]),
        )

    @staticmethod
    def _entries(
        data: npt.NDArray[np.uint8], at: npt.NDArray[np.int64], count: npt.NDArray[np.int64]
    ) -> tuple[npt.NDArray[np.uint64], npt.NDArray[np.int64]]:
        """The (log time, offset) entries of the MessageIndex records whose entries begin at
        ``at``, ``count`` each, in record order."""
        small = count < _GATHER_BELOW
        if np.all(small):
            total = int(count.sum())
            rank = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(count) - count, count)
            pos = np.repeat(at, count) + 16 * rank
            pairs = data[pos[:, None] + np.arange(16)].view('<u8')
            return pairs[:, 0].astype(np.uint64), pairs[:, 1].astype(np.int64)
        parts = [
            data[a : a + 16 * c].view('<u8').reshape(c, 2)
            for a, c in zip(at.tolist(), count.tolist(), strict=True)
        ]
        pairs = np.concatenate(parts) if parts else np.empty((0, 2), np.uint64)
        return pairs[:, 0].astype(np.uint64), pairs[:, 1].astype(np.int64)

    def _index_from_bulk(
        self, file_no: int, mapped: MappedFile, summary: _Summary, bulk: _Bulk
    ) -> bool:
        """``_index_from_summary`` for a regular index read at once (``_bulk_index``): the
        same chunks, rows and refusals."""
        ids = set(np.flatnonzero(np.bincount(bulk.cids)).tolist())
        if any(cid not in summary.channels for cid in ids):
            return False
        indexed = int(bulk.counts.sum())
        channels_before = len(self._channels)
        chmap = self._summary_channels(mapped, summary)
        if summary.message_count not in (None, indexed):
            del self._channels[channels_before:]
            self._warn(
                f'{mapped.path.name}: index lists {indexed} of {summary.message_count} '
                'messages; scanned the file'
            )
            return False
        first = len(self._chunks)
        n = len(bulk.chunk_pos)
        self._chunks.extend(
            map(
                Chunk,
                itertools.repeat(file_no, n),
                bulk.chunk_pos.tolist(),
                bulk.data_start.tolist(),
                bulk.data_len.tolist(),
                itertools.repeat(bulk.compression, n),
                bulk.uncompressed_size.tolist(),
                itertools.repeat(False, n),  # Chunk.partial
            )
        )
        lookup = np.full(1 << 16, -1, np.int64)
        for cid in ids:
            lookup[cid] = chmap.get(cid, -1)
        g = lookup[bulk.cids]
        for unreadable in sorted(set(g[g < -1].tolist())):
            self._count_unreadable(unreadable, int(bulk.counts[g == unreadable].sum()))
        chunk = first + bulk.chunk
        keep = (g >= 0) & (bulk.counts > 0)
        small = keep & (bulk.counts < _GATHER_BELOW)
        if np.any(small):
            self._add_gathered(
                mapped,
                np.stack(
                    (bulk.entries_at[small], bulk.counts[small], g[small], chunk[small]), axis=1
                ),
            )
        large = keep & ~small
        for at, count, channel, k in zip(
            bulk.entries_at[large].tolist(),
            bulk.counts[large].tolist(),
            g[large].tolist(),
            chunk[large].tolist(),
            strict=True,
        ):
            pairs = np.frombuffer(mapped.map, '<u8', count=2 * count, offset=at)
            pairs = pairs.reshape(count, 2)
            self._add_rows(pairs[:, 0].astype(np.uint64), channel, k, pairs[:, 1].astype(np.int64))
            del pairs
        return True

    def _index_from_summary(
        self, file_no: int, mapped: MappedFile, summary: _Summary, indexes: list[_ChunkIndex]
    ) -> bool:
        """Index from the summary; False (nothing added) when the index cannot be trusted."""
        if not indexes:
            return False
        ids = {cid for ci in indexes for cid in ci.index_offsets}
        if any(cid not in summary.channels for cid in ids):
            return False
        buf, size = mapped.view, mapped.size
        channels_before = len(self._channels)
        chmap = self._summary_channels(mapped, summary)
        plans: list[tuple[int, _ChunkHead, list[tuple[int, int, int]] | None]] = []
        few: list[tuple[int, int, int, int]] = []  # short MessageIndex records, read at once
        indexed = 0
        for ci in sorted(indexes, key=lambda c: c.chunk_pos):
            try:
                head = _chunk_head(buf, ci.chunk_pos, size)
                entries = self._message_indexes(buf, size, ci) if ci.index_offsets else None
            except (_CorruptError, struct.error):
                del self._channels[channels_before:]
                return False
            if entries is not None:
                indexed += sum(n for _, _, n in entries)
            plans.append((ci.chunk_pos, head, entries))
        # Messages outside chunks are not in any index: count them via the statistics.
        fully_indexed = all(entries is not None for _, _, entries in plans)
        if fully_indexed and summary.message_count not in (None, indexed):
            del self._channels[channels_before:]
            self._warn(
                f'{mapped.path.name}: index lists {indexed} of {summary.message_count} '
                'messages; scanned the file'
            )
            return False
        for chunk_pos, head, entries in plans:
            k = self._add_chunk(
                Chunk(
                    file_no,
                    chunk_pos,
                    head.data_start,
                    head.data_len,
                    head.compression,
                    head.uncompressed_size,
                    False,
                )
            )
            if entries is None:
                self._scan_chunk(k, chmap, {})
                continue
            for cid, offset, count in entries:
                g = chmap.get(cid, -1)
                if g < -1:
                    self._count_unreadable(g, count)
                if g < 0 or not count:
                    continue
                if count < _GATHER_BELOW:
                    few.append((offset, count, g, k))
                    continue
                pairs = np.frombuffer(mapped.map, '<u8', count=2 * count, offset=offset)
                pairs = pairs.reshape(count, 2)
                self._add_rows(pairs[:, 0].astype(np.uint64), g, k, pairs[:, 1].astype(np.int64))
                del pairs
        if few:
            self._add_gathered(mapped, few)
        return True

    def _add_gathered(
        self, mapped: MappedFile, few: list[tuple[int, int, int, int]] | npt.NDArray[np.int64]
    ) -> None:
        """The rows of many short MessageIndex records at once: ``few`` holds (file offset of
        the entries, entry count, channel, chunk) per record."""
        table = np.asarray(few, np.int64)
        counts = table[:, 1]
        total = int(counts.sum())
        rank = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
        pos = np.repeat(table[:, 0], counts) + 16 * rank
        data = np.frombuffer(mapped.map, np.uint8)
        try:
            pairs = data[pos[:, None] + np.arange(16)].view('<u8')
        finally:
            del data
        self._add_rows(
            pairs[:, 0].astype(np.uint64),
            np.repeat(table[:, 2].astype(np.int32), counts),
            np.repeat(table[:, 3].astype(np.int32), counts),
            pairs[:, 1].astype(np.int64),
        )

    @staticmethod
    def _message_indexes(buf: memoryview, size: int, ci: _ChunkIndex) -> list[tuple[int, int, int]]:
        """(channel id, file offset of its entries, entry count) per MessageIndex record."""
        out: list[tuple[int, int, int]] = []
        for cid, pos in sorted(ci.index_offsets.items()):
            if pos + 15 > size or buf[pos] != _OP_MESSAGE_INDEX:
                msg = 'no message index record here'
                raise _CorruptError(msg)
            (length,) = _U64(buf, pos + 1)
            (rcid,) = _U16(buf, pos + 9)
            (nbytes,) = _U32(buf, pos + 11)
            if rcid != cid or nbytes % 16 or 6 + nbytes > length or pos + 15 + nbytes > size:
                msg = 'message index record is malformed'
                raise _CorruptError(msg)
            out.append((cid, pos + 15, nbytes // 16))
        return out

    def _scan_chunk(
        self,
        k: int,
        chmap: dict[int, int],
        schemas: dict[int, _Schema],
        add: Callable[[int, int, int, int], None] | None = None,
    ) -> None:
        """Index the records of chunk ``k`` by reading them (``_scan_records``)."""
        ck = self._chunk_at(k)
        mapped = self._maps[ck.file_no]
        if not ck.compression:
            end = ck.data_start + ck.data_len
            self._scan_records(
                mapped.view, ck.data_start, end, ck.data_start, k, chmap, schemas, add
            )
            return
        data = self._chunk_bytes(k)
        if data is None:
            return
        view = memoryview(data)
        try:
            self._scan_records(view, 0, len(view), 0, k, chmap, schemas, add)
        finally:
            view.release()

    def _scan_records(
        self,
        buf: memoryview,
        start: int,
        end: int,
        base: int,
        k: int,
        chmap: dict[int, int],
        schemas: dict[int, _Schema],
        add: Callable[[int, int, int, int], None] | None = None,
    ) -> None:
        """Index the Schema / Channel / Message records in ``buf[start:end]``.

        Message offsets are stored relative to ``base`` (the start of the chunk's records, or 0
        for messages outside chunks, whose offsets are file positions). ``add`` takes the rows
        instead of the table (and messages on unreadable channels are not counted: the index
        counted them).
        """
        name = self.files[self._chunk_at(k).file_no].name
        add_row = self._add_row if add is None else add
        pos = start
        while pos + 9 <= end:
            op = buf[pos]
            (length,) = _U64(buf, pos + 1)
            body = pos + 9
            rec_end = body + length
            if rec_end > end:
                break
            try:
                if op == _OP_MESSAGE:
                    if length < 22:
                        raise _CorruptError
                    cid, _, log_time = _MESSAGE_HEAD(buf, body)
                    g = chmap.get(cid)
                    if g is None:
                        self._warn(f'{name}: messages on undeclared channel {cid}; skipped')
                    elif g >= 0:
                        add_row(log_time, g, k, pos - base)
                    elif add is None:
                        self._count_unreadable(g, 1)
                elif op == _OP_SCHEMA:
                    sid, schema = _parse_schema(buf, body, rec_end)
                    schemas[sid] = schema
                elif op == _OP_CHANNEL:
                    self._register(chmap, _parse_channel(buf, body, rec_end), schemas)
            except (_CorruptError, struct.error):
                self._warn(f'{name}: unreadable record(s); skipped')
            pos = rec_end

    def _scan_file(self, file_no: int, mapped: MappedFile) -> bool:
        """Index the file by reading it record by record; False when it ends without a footer."""
        buf, size = mapped.view, mapped.size
        chmap: dict[int, int] = {}
        schemas: dict[int, _Schema] = {}
        outside = self._raw_chunk(file_no)
        pos = len(MCAP_MAGIC)
        while pos + 9 <= size:
            op = buf[pos]
            (length,) = _U64(buf, pos + 1)
            rec_end = pos + 9 + length
            if op == _OP_CHUNK:
                try:
                    head = _chunk_head(buf, pos, size)
                except (_CorruptError, struct.error):
                    return False
                partial = rec_end > size
                chunk = Chunk(
                    file_no,
                    pos,
                    head.data_start,
                    head.data_len,
                    head.compression,
                    head.uncompressed_size,
                    partial,
                )
                self._scan_chunk(self._add_chunk(chunk), chmap, schemas)
                if partial:
                    return False
            elif rec_end > size:
                return False
            elif op == _OP_FOOTER:
                return buf[rec_end : rec_end + len(MCAP_MAGIC)] == MCAP_MAGIC
            elif op in (_OP_MESSAGE, _OP_SCHEMA, _OP_CHANNEL):
                self._scan_records(buf, pos, rec_end, 0, outside, chmap, schemas)
            pos = rec_end
        return False
