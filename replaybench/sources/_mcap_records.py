"""The MCAP format as the MCAP reader (``mcap.py``) reads it: opcodes, the records it parses one
at a time (schemas, channels, chunk indexes, chunk heads, the footer and the summary), the
schemas of a summary that lists none, and the helpers that read fields of many records at once
with numpy (``_mcap_bulk.py``, ``_mcap_lazy.py``)."""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ._common import decompress_chunk

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ['MCAP_MAGIC', 'mcap_payload']

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
