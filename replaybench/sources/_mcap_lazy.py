"""A regular MCAP summary's chunk indexes read as arrays without reading any chunk
(``_lazy_index``): what ``McapSource`` needs to read a single file lazily, each chunk and its
MessageIndex records when a reader reaches it (``McapSource._lazy_rows``)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ._mcap_records import MCAP_MAGIC, _ascending, _gather, _sorted_unique, _strided_uint, _uint

if TYPE_CHECKING:
    import numpy.typing as npt

    from ._mcap_records import _Summary

__all__: list[str] = []


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
