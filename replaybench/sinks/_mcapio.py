"""A chunked MCAP writer whose per-message cost is a few hundred nanoseconds.

It writes the file the ``mcap`` library's ``Writer`` writes with its defaults (chunks holding
their schemas, channels and messages, a MessageIndex per channel after each chunk, the summary
repeating schemas and channels, Statistics, ChunkIndex, an empty attachment index group, the
Metadata records and their MetadataIndex group, SummaryOffsets, chunk and summary CRCs) byte for
byte, so that every MCAP reader reads it as it reads the library's files. The records other than
Message are the library's own; only the per-message path is different: a Message record is one
``struct`` pack into the chunk buffer, and the chunk's indexes and the statistics are kept as
flat lists and settled per chunk, where the library builds a record object and updates the
statistics for every message.
"""

from __future__ import annotations

import struct
import zlib
from typing import TYPE_CHECKING, Any

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

if TYPE_CHECKING:
    from typing import BinaryIO

__all__ = ['MAGIC', 'McapWriter']

MAGIC = b'\x89MCAP0\r\n'

#: opcode, record length, channel id, sequence, log time, publish time
_MESSAGE = struct.Struct('<BQHIQQ')
_MESSAGE_FIXED = _MESSAGE.size - 9


def _record(record: Any) -> bytes:
    """One record of the ``mcap`` library, serialised."""
    builder: Any = RecordBuilder()
    record.write(builder)
    data: bytes = builder.end()
    return data


class McapWriter:
    """Write an MCAP to ``stream``: ``start``, ``register_schema``/``register_channel``,
    ``add_message``..., ``finish``. Chunks are zstd-compressed (``compression='zstd'``) or
    stored (``''``); a chunk is closed when its records pass ``chunk_size`` bytes.
    """

    def __init__(
        self, stream: BinaryIO, *, chunk_size: int = 1 << 20, compression: str = 'zstd'
    ) -> None:
        if compression not in {'zstd', ''}:
            msg = f'unsupported chunk compression {compression!r}'
            raise ValueError(msg)
        self._stream = stream
        self._chunk_size = chunk_size
        self._compression = compression
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._chunk = bytearray()
        # per channel in this chunk, in order of first message: [log_time, offset, ...]
        self._index: dict[int, list[int]] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._counts: dict[int, int] = {}  # messages per channel, in order of first message
        self._metadata_indexes: list[MetadataIndex] = []
        self._message_count = 0
        self._start_time = 0
        self._end_time = 0
        self._offset = 0  # bytes written to the stream

    def _emit(self, data: bytes) -> None:
        self._stream.write(data)
        self._offset += len(data)

    def start(self, profile: str, library: str) -> None:
        """Write the magic and the Header record."""
        self._emit(MAGIC + _record(Header(profile, library)))

    def _add_record(self, record: Schema | Channel) -> None:
        self._chunk += _record(record)
        if len(self._chunk) > self._chunk_size:
            self._finish_chunk()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """A new schema; its id (from 1)."""
        schema = Schema(id=len(self._schemas) + 1, data=data, encoding=encoding, name=name)
        self._schemas.append(schema)
        self._add_record(schema)
        return schema.id

    def register_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: dict[str, str] | None = None,
    ) -> int:
        """A new channel; its id (from 1)."""
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            metadata=dict(metadata or {}),
            schema_id=schema_id,
        )
        self._channels.append(channel)
        self._add_record(channel)
        return channel.id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A Metadata record, written at once (before the open chunk), and its index."""
        record = _record(Metadata(name=name, metadata=dict(data)))
        self._metadata_indexes.append(
            MetadataIndex(offset=self._offset, length=len(record), name=name)
        )
        self._emit(record)

    def add_message(
        self,
        channel_id: int,
        log_time: int,
        data: bytes | bytearray | memoryview,
        publish_time: int,
        sequence: int = 0,
    ) -> None:
        """Append a Message record to the open chunk.

        The record and then its index entry are each appended in one operation, so that a
        KeyboardInterrupt between any two lines leaves the chunk and its index consistent.
        """
        chunk = self._chunk
        offset = len(chunk)
        chunk += (
            _MESSAGE.pack(
                Opcode.MESSAGE,
                _MESSAGE_FIXED + len(data),
                channel_id,
                sequence,
                log_time,
                publish_time,
            )
            + data
        )
        index = self._index.get(channel_id)
        if index is None:
            self._index[channel_id] = [log_time, offset]
        else:
            index += (log_time, offset)
        if len(chunk) > self._chunk_size:
            self._finish_chunk()

    def _finish_chunk(self) -> None:
        """Write the open chunk and its message indexes; nothing when it holds no message."""
        if not self._index:
            return
        data = bytes(self._chunk)
        times = [t for index in self._index.values() for t in index[::2]]
        start, end = min(times), max(times)
        for channel_id, index in self._index.items():
            self._counts[channel_id] = self._counts.get(channel_id, 0) + len(index) // 2
        if self._message_count == 0:
            self._start_time = start
        else:
            self._start_time = min(self._start_time, start)
        self._end_time = max(self._end_time, end)
        self._message_count += len(times)

        if self._compression == 'zstd':
            import zstandard

            compressed = zstandard.compress(data)
        else:
            compressed = data
        chunk = _record(
            Chunk(
                compression=self._compression,
                data=compressed,
                message_end_time=end,
                message_start_time=start,
                uncompressed_crc=zlib.crc32(data),
                uncompressed_size=len(data),
            )
        )
        chunk_start = self._offset
        self._emit(chunk)
        chunk_length = self._offset - chunk_start

        offsets: dict[int, int] = {}
        indexes = bytearray()
        for channel_id, index in self._index.items():
            offsets[channel_id] = self._offset + len(indexes)
            n = len(index)
            indexes += struct.pack(
                f'<BQHI{n}Q', Opcode.MESSAGE_INDEX, 6 + 8 * n, channel_id, 8 * n, *index
            )
        self._emit(bytes(indexes))
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=end,
                chunk_start_offset=chunk_start,
                chunk_length=chunk_length,
                message_index_offsets=offsets,
                message_index_length=len(indexes),
                compression=self._compression,
                compressed_size=len(compressed),
                uncompressed_size=len(data),
            )
        )
        self._chunk = bytearray()
        self._index = {}

    def finish(self) -> None:
        """Close the open chunk, write DataEnd, the summary and the footer. Does not close the
        stream."""
        self._finish_chunk()
        self._emit(_record(DataEnd(0)))

        summary_start = self._offset
        summary: Any = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(
            opcode: Opcode,
            records: list[Schema] | list[Channel] | list[ChunkIndex] | list[MetadataIndex],
        ) -> None:
            begin = summary.count
            for record in records:
                record.write(summary)
            offsets.append(SummaryOffset(opcode, summary_start + begin, summary.count - begin))

        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        begin = summary.count
        Statistics(
            attachment_count=0,
            channel_count=len(self._channels),
            channel_message_counts=self._counts,
            chunk_count=len(self._chunk_indexes),
            message_count=self._message_count,
            message_end_time=self._end_time,
            message_start_time=self._start_time,
            metadata_count=len(self._metadata_indexes),
            schema_count=len(self._schemas),
        ).write(summary)
        offsets.append(
            SummaryOffset(Opcode.STATISTICS, summary_start + begin, summary.count - begin)
        )
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + summary.count
        for offset in offsets:
            offset.write(summary)
        data: bytes = summary.end()
        crc = zlib.crc32(data)
        crc = zlib.crc32(
            struct.pack('<BQQQ', Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start),
            crc,
        )
        self._emit(data)
        footer = Footer(
            summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc
        )
        self._emit(_record(footer) + MAGIC)
