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

import struct
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from replaybench.errors import SourceError
from replaybench.types import SkippedTopic

from ._common import MappedFile, decompress_chunk, normalize_msgtype, zero_tail_start
from ._table import Channel, Chunk, TableSource

if TYPE_CHECKING:
    from collections.abc import Sequence

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
    chunk_indexes: list[_ChunkIndex]
    message_count: int | None


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
    chunk_indexes: list[_ChunkIndex] = []
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
        elif op == _OP_CHUNK_INDEX:
            chunk_indexes.append(_parse_chunk_index(buf, body, rec_end))
        elif op == _OP_STATISTICS and length >= 8:
            message_count = int(_U64(buf, body)[0])
        pos = rec_end
    return _Summary(start, schemas, channels, chunk_indexes, message_count)


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
            except (_CorruptError, struct.error) as err:
                self._warn(f'{mapped.path.name}: summary unreadable ({err}); scanned the file')
            else:
                if self._index_from_summary(file_no, mapped, summary):
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

    def _index_from_summary(self, file_no: int, mapped: MappedFile, summary: _Summary) -> bool:
        """Index from the summary; False (nothing added) when the index cannot be trusted."""
        if not summary.chunk_indexes:
            return False
        ids = {cid for ci in summary.chunk_indexes for cid in ci.index_offsets}
        if any(cid not in summary.channels for cid in ids):
            return False
        buf, size = mapped.view, mapped.size
        chmap: dict[int, int] = {}
        channels_before = len(self._channels)
        schemas = summary.schemas
        missing = {ch.schema_id for ch in summary.channels.values() if ch.schema_id} - set(schemas)
        if missing:  # channels in the summary, their schemas only in the data section
            schemas = {**_data_schemas(buf, summary.start, missing), **schemas}
        for record in summary.channels.values():
            self._register(chmap, record, schemas)
        plans: list[tuple[int, _ChunkHead, list[tuple[int, int, int]] | None]] = []
        indexed = 0
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_pos):
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
                pairs = np.frombuffer(mapped.map, '<u8', count=2 * count, offset=offset)
                pairs = pairs.reshape(count, 2)
                self._add_rows(pairs[:, 0].astype(np.uint64), g, k, pairs[:, 1].astype(np.int64))
                del pairs
        return True

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
