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

Here: ``McapSource`` and how it reads a lazily indexed file. Its parts: the format's records
(``_mcap_records.py``), the channels and the index read at open, from a summary or by a scan
(``_mcap_index.py``, ``McapTable``), a summary's chunk indexes read at once with arrays
(``_mcap_bulk.py``) and read for the lazy reader (``_mcap_lazy.py``).
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from replaybench.errors import SourceError
from replaybench.types import RawMessage

from ._common import MappedFile, zero_tail_start
from ._mcap_bulk import _bulk_index as _bulk_index  # re-exported: _index_file looks it up here
from ._mcap_index import McapTable
from ._mcap_lazy import _lazy_index as _lazy_index  # likewise
from ._mcap_lazy import _LazyTable
from ._mcap_records import (
    _GATHER_BELOW,
    _OP_CHUNK,
    _OP_MESSAGE_INDEX,
    MCAP_MAGIC,
    _ascending,
    _chunk_indexes,
    _CorruptError,
    _gather,
    _read_footer,
    _read_summary,
    _sorted_unique,
    _uint,
    mcap_payload,
)
from ._table import U64_MAX, Chunk, clamp_time

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Iterator, Sequence

    import numpy.typing as npt

    from ._mcap_lazy import _Lazy
    from ._mcap_records import _Summary
    from ._table import Channel

__all__ = ['MCAP_MAGIC', 'McapSource', 'mcap_payload']


def _collect(rows: list[tuple[int, int, int, int]]) -> Callable[[int, int, int, int], None]:
    """A ``_scan_records`` ``add`` that appends its rows to ``rows``."""

    def add(log_time: int, channel: int, chunk: int, offset: int) -> None:
        rows.append((log_time, channel, chunk, offset))

    return add


#: chunks read at most at once by a lazily indexed source's reader (it starts with one)
_LAZY_BATCH = 128


class McapSource(McapTable):
    """One ``.mcap`` file, or the ``.mcap`` files of a rosbag2 directory replayed as one input."""

    def __init__(
        self, path: str | Path, files: Sequence[Path] | None = None, fmt: str = 'mcap'
    ) -> None:
        path = Path(path)
        super().__init__(path, fmt, files if files is not None else [path])
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
