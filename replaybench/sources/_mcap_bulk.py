"""The chunk indexes of an MCAP summary read at once with array operations (``_bulk_index``):
the reader of a file that is not read lazily, where its index is regular. A file whose index is
not regular is read record by record (``McapTable._index_from_summary``), which gives the same
index or the same refusal."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ._mcap_records import _OP_CHUNK, _OP_MESSAGE_INDEX, _gather, _uint

if TYPE_CHECKING:
    import numpy.typing as npt

    from ._mcap_records import _Summary

__all__: list[str] = []


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
