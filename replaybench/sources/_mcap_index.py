"""An MCAP source's channels and its index read at open (``McapTable``, the base of
``McapSource``): from a summary's chunk indexes read at once (``_index_from_bulk``) or record by
record (``_index_from_summary``), or by scanning the file's records (``_scan_file``)."""

from __future__ import annotations

import itertools
import struct
from typing import TYPE_CHECKING

import numpy as np

from replaybench.types import SkippedTopic

from ._common import MappedFile, normalize_msgtype
from ._mcap_records import (
    _GATHER_BELOW,
    _MESSAGE_HEAD,
    _OP_CHANNEL,
    _OP_CHUNK,
    _OP_FOOTER,
    _OP_MESSAGE,
    _OP_MESSAGE_INDEX,
    _OP_SCHEMA,
    _U16,
    _U32,
    _U64,
    MCAP_MAGIC,
    _chunk_head,
    _CorruptError,
    _data_schemas,
    _parse_channel,
    _parse_schema,
    mcap_payload,
)
from ._table import Channel, Chunk, TableSource

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    import numpy.typing as npt

    from replaybench.types import Serialization

    from ._mcap_bulk import _Bulk
    from ._mcap_records import _ChannelRecord, _ChunkHead, _ChunkIndex, _Schema, _Summary

__all__ = ['McapTable']

_SERIALIZATIONS: dict[str, Serialization] = {'cdr': 'cdr', 'ros1': 'ros1', 'protobuf': 'protobuf'}


class McapTable(TableSource):
    """The channels and the index of one or more ``.mcap`` files, read at open."""

    def __init__(self, path: Path, fmt: str, files: Sequence[Path]) -> None:
        super().__init__(path, fmt, files, mcap_payload)
        self._channel_warned: set[str] = set()
        #: topics of the channels in an unsupported encoding; chmap maps them to -2 - index
        self._unreadable_names: list[str] = []

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
