"""Message table shared by the MCAP and ROS 1 readers.

A reader indexes its files into one row of metadata per message (log time, channel, chunk,
offset); payloads stay in the memory-mapped file, or in a decompressed chunk, until the
message is yielded. Rows are sorted once by (log time, topic, file, position in file), which
gives the replay order and every message's per-topic ``seq``.
"""

from __future__ import annotations

from array import array
from collections import OrderedDict
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from replaybench.errors import SourceError
from replaybench.types import RawMessage, SkippedTopic, TopicInfo

from ._common import decompress_chunk

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Iterator, Sequence
    from pathlib import Path
    from types import TracebackType
    from typing import Self

    import numpy.typing as npt

    from replaybench.types import Serialization

    from ._common import MappedFile

    PayloadReader = Callable[[memoryview, int], memoryview | None]

__all__ = ['CACHE_BYTES', 'U64_MAX', 'Channel', 'Chunk', 'TableSource', 'clamp_time']

#: Decompressed chunks kept at most (bytes); at least two chunks are kept whatever their size.
CACHE_BYTES = 256 << 20
_BATCH = 1024


U64_MAX = 2**64 - 1


def clamp_time(time_ns: int) -> int:
    """``time_ns`` within the range of a log time (uint64)."""
    return min(max(time_ns, 0), U64_MAX)


def _column(n: int, value: int | npt.NDArray[np.int32]) -> npt.NDArray[np.int32]:
    """``n`` int32 values: ``value`` repeated, or ``value`` itself when it is an array."""
    if isinstance(value, np.ndarray):
        return value
    return np.full(n, value, np.int32)


class Chunk(NamedTuple):
    """Where the payloads of a group of messages live.

    ``pos`` is the file position of the chunk record, or -1 for a pseudo-chunk that stands for
    the whole file (messages outside chunks; their offsets are file positions).
    """

    file_no: int
    pos: int
    data_start: int
    data_len: int
    compression: str
    uncompressed_size: int
    partial: bool


class Channel(NamedTuple):
    """A connection / channel: what its messages are."""

    topic: str
    msgtype: str
    serialization: Serialization
    schema: bytes


class _Table(NamedTuple):
    time: npt.NDArray[np.uint64]
    channel: npt.NDArray[np.int32]
    chunk: npt.NDArray[np.int32]
    offset: npt.NDArray[np.int64]
    seq: npt.NDArray[np.int64]


class TableSource:
    """A source whose messages are indexed up front (metadata only) and sorted once."""

    def __init__(self, path: Path, fmt: str, files: Sequence[Path], payload: PayloadReader) -> None:
        self.path = path
        self.format = fmt
        self.files = list(files)
        self._payload = payload
        self._maps: list[MappedFile] = []
        self._channels: list[Channel] = []
        self._chunks: list[Chunk] = []
        self._raw_chunks: dict[int, int] = {}
        self._warnings: list[str] = []
        self._truncated = False
        self._closed = False
        self._cache: OrderedDict[int, memoryview] = OrderedDict()
        self._cache_bytes = 0
        self._bad_chunks: set[int] = set()
        self._chunk_regions: tuple[list[tuple[memoryview, int] | None], bool] | None = None
        #: rows added in bulk: (times, channel, chunk, offsets); channel and chunk are one value
        #: for every row of the part, or an array of one per row
        self._parts: list[
            tuple[
                npt.NDArray[np.uint64],
                int | npt.NDArray[np.int32],
                int | npt.NDArray[np.int32],
                npt.NDArray[np.int64],
            ]
        ] = []
        self._rows_time = array('Q')
        self._rows_channel = array('i')
        self._rows_chunk = array('i')
        self._rows_offset = array('q')
        self._table = _Table(
            np.empty(0, np.uint64),
            np.empty(0, np.int32),
            np.empty(0, np.int32),
            np.empty(0, np.int64),
            np.empty(0, np.int64),
        )
        self._topics: list[TopicInfo] = []
        #: topic -> its messages in an encoding that cannot be read (counted by the reader)
        self._unreadable: dict[str, SkippedTopic] = {}

    # -- building -------------------------------------------------------------------------

    def _warn(self, line: str) -> None:
        if line not in self._warnings:
            self._warnings.append(line)

    def _add_channel(self, channel: Channel) -> int:
        self._channels.append(channel)
        return len(self._channels) - 1

    def _add_chunk(self, chunk: Chunk) -> int:
        self._chunks.append(chunk)
        return len(self._chunks) - 1

    def _raw_chunk(self, file_no: int) -> int:
        """The pseudo-chunk for messages stored outside chunks in file ``file_no``."""
        if file_no not in self._raw_chunks:
            size = self._maps[file_no].size
            self._raw_chunks[file_no] = self._add_chunk(
                Chunk(file_no, -1, 0, size, '', size, False)
            )
        return self._raw_chunks[file_no]

    def _add_row(self, log_time: int, channel: int, chunk: int, offset: int) -> None:
        self._rows_time.append(log_time)
        self._rows_channel.append(channel)
        self._rows_chunk.append(chunk)
        self._rows_offset.append(offset)

    def _add_rows(
        self,
        times: npt.NDArray[np.uint64],
        channel: int | npt.NDArray[np.int32],
        chunk: int | npt.NDArray[np.int32],
        offsets: npt.NDArray[np.int64],
    ) -> None:
        self._parts.append((times, channel, chunk, offsets))

    def _finish(self) -> None:
        """Sort the collected rows into replay order and compute seq and topic statistics."""
        times = [part[0] for part in self._parts]
        channels = [_column(len(part[0]), part[1]) for part in self._parts]
        chunks = [_column(len(part[0]), part[2]) for part in self._parts]
        offsets = [part[3] for part in self._parts]
        times.append(np.frombuffer(self._rows_time, np.uint64))
        channels.append(np.frombuffer(self._rows_channel, np.int32))
        chunks.append(np.frombuffer(self._rows_chunk, np.int32))
        offsets.append(np.frombuffer(self._rows_offset, np.int64))
        time = np.concatenate(times).astype(np.uint64, copy=False)
        channel = np.concatenate(channels).astype(np.int32, copy=False)
        chunk = np.concatenate(chunks).astype(np.int32, copy=False)
        offset = np.concatenate(offsets).astype(np.int64, copy=False)
        self._parts.clear()
        self._rows_time = array('Q')
        self._rows_channel = array('i')
        self._rows_chunk = array('i')
        self._rows_offset = array('q')

        names = sorted({ch.topic for ch in self._channels})
        rank = {name: i for i, name in enumerate(names)}
        channel_rank = np.array([rank[ch.topic] for ch in self._channels] or [0], np.int64)
        topic = channel_rank[channel]
        chunk_file = np.array([ck.file_no for ck in self._chunks] or [0], np.int64)[chunk]
        chunk_pos = np.array([ck.pos for ck in self._chunks] or [0], np.int64)[chunk]
        outside = chunk_pos < 0
        # File order: (file, chunk position, offset in chunk); messages outside chunks by position.
        file_pos = np.where(outside, offset, chunk_pos)
        in_chunk = np.where(outside, 0, offset)
        order = np.lexsort((in_chunk, file_pos, chunk_file, topic, time))
        time, channel, chunk, offset, topic = (
            time[order],
            channel[order],
            chunk[order],
            offset[order],
            topic[order],
        )
        n = len(time)
        counts = np.bincount(topic, minlength=len(names)) if n else np.zeros(len(names), np.int64)
        by_topic = np.argsort(topic, kind='stable')
        starts = np.cumsum(counts) - counts
        seq = np.empty(n, np.int64)
        seq[by_topic] = np.arange(n, dtype=np.int64) - np.repeat(starts, counts)
        self._table = _Table(time, channel, chunk, offset, seq)

        first = np.zeros(len(names), np.int64)
        last = np.zeros(len(names), np.int64)
        if n:
            present, first_idx = np.unique(topic, return_index=True)
            first[present] = time[first_idx].astype(np.int64)
            present_rev, last_idx_rev = np.unique(topic[::-1], return_index=True)
            last[present_rev] = time[n - 1 - last_idx_rev].astype(np.int64)
        self._topics = self._topic_infos(names, counts.tolist(), first.tolist(), last.tolist())

    def _topic_infos(
        self, names: list[str], counts: list[int], first: list[int], last: list[int]
    ) -> list[TopicInfo]:
        """The topics ``names`` (sorted) with their counts and first / last log times."""
        infos: list[TopicInfo] = []
        for i, name in enumerate(names):
            kinds = {(ch.msgtype, ch.serialization) for ch in self._channels if ch.topic == name}
            ch = next(ch for ch in self._channels if ch.topic == name)
            if len(kinds) > 1:
                self._warn(f'topic {name}: several message types; listed as {ch.msgtype}')
            infos.append(
                TopicInfo(
                    name, ch.msgtype, ch.serialization, int(counts[i]), int(first[i]), int(last[i])
                )
            )
        return infos

    # -- Source API -----------------------------------------------------------------------

    @property
    def truncated(self) -> bool:
        """True when a file was found cut short (or its index missing)."""
        return self._truncated

    @property
    def warnings(self) -> list[str]:
        """Human-readable lines about truncation and skipped records."""
        return list(self._warnings)

    def topics(self) -> list[TopicInfo]:
        """Topics sorted by name, with message counts and first / last log times."""
        self._check_open()
        return list(self._topics)

    def skipped_topics(self) -> list[SkippedTopic]:
        """Topics held in an encoding that cannot be read, with their message counts."""
        self._check_open()
        return [self._unreadable[name] for name in sorted(self._unreadable)]

    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[RawMessage]:
        """Messages in replay order; ``start_ns`` inclusive, ``end_ns`` exclusive (log time)."""
        self._check_open()
        table = self._table
        n = len(table.time)
        # np.uint64 keys: a Python int against uint64 times is compared as float64, which
        # cannot tell nanoseconds apart at today's epoch times
        lo = (
            0 if start_ns is None else int(table.time.searchsorted(np.uint64(clamp_time(start_ns))))
        )
        hi = n if end_ns is None else int(table.time.searchsorted(np.uint64(clamp_time(end_ns))))
        if end_ns is not None and end_ns > U64_MAX:
            hi = n
        if hi <= lo:
            return iter(())
        selection: npt.NDArray[np.int64] | None = None
        if topics is not None:
            wanted = {topics} if isinstance(topics, str) else set(topics)
            keep = np.array([ch.topic in wanted for ch in self._channels] or [False], np.bool_)
            selection = lo + np.flatnonzero(keep[table.channel[lo:hi]])
            if not len(selection):
                return iter(())
        return self._generate(lo, hi, selection)

    def close(self) -> None:
        """Release the mappings; messages still referenced stay valid until dropped."""
        if self._closed:
            return
        self._closed = True
        self._chunk_regions = None
        self._cache.clear()
        self._cache_bytes = 0
        for mapped in self._maps:
            mapped.close()
        self._maps.clear()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f'{type(self).__name__}({str(self.path)!r})'

    # -- iteration ------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._closed:
            msg = f'{self.path}: source is closed'
            raise SourceError(msg)

    def _generate(
        self, lo: int, hi: int, selection: npt.NDArray[np.int64] | None
    ) -> Iterator[RawMessage]:
        table = self._table
        channels = self._channels
        payload = self._payload
        regions, compressed = self._regions()
        # Drop a decompressed chunk from the cache right after its last message is yielded.
        chunk_ids = table.chunk[lo:hi] if selection is None else table.chunk[selection]
        last_use: dict[int, int] = {}
        if compressed:
            rev_unique, rev_first = np.unique(chunk_ids[::-1], return_index=True)
            last_pos = len(chunk_ids) - 1 - rev_first
            last_use = {
                int(k): int(p)
                for k, p in zip(rev_unique.tolist(), last_pos.tolist(), strict=True)
                if regions[int(k)] is None
            }
        total = hi - lo if selection is None else len(selection)
        position = 0
        for b0 in range(0, total, _BATCH):
            rows: slice | npt.NDArray[np.int64]
            if selection is None:
                rows = slice(lo + b0, min(lo + b0 + _BATCH, hi))
            else:
                rows = selection[b0 : b0 + _BATCH]
            times = table.time[rows].tolist()
            chans = table.channel[rows].tolist()
            chunks = table.chunk[rows].tolist()
            offsets = table.offset[rows].tolist()
            seqs = table.seq[rows].tolist()
            for j in range(len(times)):
                if self._closed:
                    msg = f'{self.path}: source closed during iteration'
                    raise SourceError(msg)
                k = chunks[j]
                region = regions[k]
                if region is None:
                    buf = self._decompressed(k)
                    data = payload(buf, offsets[j]) if len(buf) else None
                else:
                    data = payload(region[0], region[1] + offsets[j])
                ch = channels[chans[j]]
                if data is None:
                    self._skipped(k, ch.topic)
                else:
                    yield RawMessage(
                        ch.topic, ch.msgtype, ch.serialization, times[j], seqs[j], data, ch.schema
                    )
                if last_use and last_use.get(k) == position:
                    self._evict(k)
                position += 1

    def _regions(self) -> tuple[list[tuple[memoryview, int] | None], bool]:
        """Per chunk, for an uncompressed one a (buffer, base) pair, None for one that must be
        decompressed; and whether there is any of those. Made once, on the first read."""
        if self._chunk_regions is None:
            regions: list[tuple[memoryview, int] | None] = [
                (self._maps[ck.file_no].view, ck.data_start) if not ck.compression else None
                for ck in self._chunks
            ]
            self._chunk_regions = (regions, any(region is None for region in regions))
        return self._chunk_regions

    def _chunk_at(self, k: int) -> Chunk:
        """Chunk ``k``."""
        return self._chunks[k]

    def _skipped(self, k: int, topic: str) -> None:
        if k in self._bad_chunks:
            return
        ck = self._chunk_at(k)
        where = f'chunk at byte {ck.pos}' if ck.pos >= 0 else 'data section'
        name = self._file_name(ck)
        self._warn(f'{name}: unreadable message record(s) on {topic} in {where}; skipped')

    def _file_name(self, ck: Chunk) -> str:
        return self.files[ck.file_no].name if ck.file_no < len(self.files) else self.path.name

    def _chunk_bytes(self, k: int) -> bytes | None:
        """Compressed chunk ``k`` decompressed; None (warned once) when it cannot be."""
        ck = self._chunk_at(k)
        try:
            return decompress_chunk(
                self._maps[ck.file_no].view,
                ck.data_start,
                ck.data_len,
                ck.compression,
                ck.uncompressed_size,
                partial=ck.partial,
            )
        except ValueError as err:
            if k not in self._bad_chunks:
                self._bad_chunks.add(k)
                name = self._file_name(ck)
                self._warn(f'{name}: chunk at byte {ck.pos} cannot be decompressed ({err})')
            return None

    def _decompressed(self, k: int) -> memoryview:
        buf = self._cache.get(k)
        if buf is not None:
            self._cache.move_to_end(k)
            return buf
        buf = memoryview(self._chunk_bytes(k) or b'')
        self._cache[k] = buf
        self._cache_bytes += len(buf)
        while len(self._cache) > 2 and self._cache_bytes > CACHE_BYTES:
            _, old = self._cache.popitem(last=False)
            self._cache_bytes -= len(old)
        return buf

    def _evict(self, k: int) -> None:
        buf = self._cache.pop(k, None)
        if buf is not None:
            self._cache_bytes -= len(buf)
