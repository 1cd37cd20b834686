"""MCAP files: ros2 (cdr), ros1 and protobuf channels.

Indexed files are read from their summary and MessageIndex records only; a message's ``data``
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
from replaybench.types import SkippedTopic

from ._common import MappedFile, decompress_chunk, normalize_msgtype, zero_tail_start
from ._table import Channel, Chunk, TableSource

if TYPE_CHECKING:
    from collections.abc import Sequence

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


def _read_summary(buf: memoryview, start: int, size: int) -> _Summary:
    end = size - _FOOTER_TAIL
    if not len(MCAP_MAGIC) <= start <= end:
        msg = 'summary offset outside the file'
        raise _CorruptError(msg)
    schemas: dict[int, _Schema] = {}
    channels: dict[int, _ChannelRecord] = {}
    chunk_records: list[int] = []
    chunk_ends: list[int] = []
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
            chunk_records.append(body)
            chunk_ends.append(rec_end)
        elif op == _OP_STATISTICS and length >= 8:
            message_count = int(_U64(buf, body)[0])
        pos = rec_end
    return _Summary(start, schemas, channels, chunk_records, chunk_ends, message_count)


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
        try:
            for file_no, file in enumerate(self.files):
                mapped = MappedFile(file)
                self._maps.append(mapped)
                self._index_file(file_no, mapped)
            self._finish()
        except BaseException:
            self.close()
            raise

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

    def _scan_chunk(self, k: int, chmap: dict[int, int], schemas: dict[int, _Schema]) -> None:
        """Index the records of chunk ``k`` by reading them."""
        ck = self._chunks[k]
        mapped = self._maps[ck.file_no]
        if not ck.compression:
            end = ck.data_start + ck.data_len
            self._scan_records(mapped.view, ck.data_start, end, ck.data_start, k, chmap, schemas)
            return
        data = self._chunk_bytes(k)
        if data is None:
            return
        view = memoryview(data)
        try:
            self._scan_records(view, 0, len(view), 0, k, chmap, schemas)
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
    ) -> None:
        """Index the Schema / Channel / Message records in ``buf[start:end]``.

        Message offsets are stored relative to ``base`` (the start of the chunk's records, or 0
        for messages outside chunks, whose offsets are file positions).
        """
        name = self.files[self._chunks[k].file_no].name
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
                        self._add_row(log_time, g, k, pos - base)
                    else:
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
