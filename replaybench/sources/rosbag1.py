"""ROS 1 bags (format 2.0): chunks uncompressed, bz2 or lz4.

An indexed bag is indexed with ``rosbags.rosbag1.Reader`` (connections and per-message
(time, chunk, offset) entries); payloads are then read from the memory-mapped file (zero
copy for uncompressed chunks) or from the chunk decompressed once.

A bag whose index is missing (recording not closed) or cut off is scanned record by record:
the scan keeps per-message metadata only, replays every complete message before the cut in
the same deterministic order as an indexed bag, and sets ``truncated``. A bag that ends in
zeros where its data or index should be (its last blocks lost to a power cut) is read as cut
where the zeros begin: no message is built from the zeroed bytes.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from replaybench.errors import SourceError

from ._common import MappedFile, normalize_msgtype, normalize_topic, zero_tail_start
from ._table import Channel, Chunk, TableSource

__all__ = ['ROSBAG_MAGIC', 'Rosbag1Source', 'ros1_payload']

ROSBAG_MAGIC = b'#ROSBAG V2.0\n'

_OP_MSGDATA = 0x02
_OP_BAGHEADER = 0x03
_OP_CHUNK = 0x05
_OP_CONNECTION = 0x07
_OP_EQ = (0x6F, 0x70, 0x3D)  # b'op='

_U32 = struct.Struct('<I').unpack_from
_U64 = struct.Struct('<Q').unpack_from
_TIME = struct.Struct('<II').unpack_from


class _CorruptError(ValueError):
    """A record that does not parse."""


def _fields(buf: memoryview, start: int, end: int) -> dict[str, bytes]:
    """The ``name=value`` fields of a record header in ``buf[start:end]``."""
    out: dict[str, bytes] = {}
    pos = start
    while pos < end:
        if pos + 4 > end:
            msg = 'header field cut short'
            raise _CorruptError(msg)
        (n,) = _U32(buf, pos)
        pos += 4
        if pos + n > end:
            msg = 'header field runs past its header'
            raise _CorruptError(msg)
        name, sep, value = bytes(buf[pos : pos + n]).partition(b'=')
        if not sep:
            msg = 'header field without "="'
            raise _CorruptError(msg)
        out[name.decode('latin-1')] = value
        pos += n
    return out


def _op(fields: dict[str, bytes]) -> int:
    value = fields.get('op', b'')
    return value[0] if len(value) == 1 else -1


def _op_of(buf: memoryview, start: int, end: int) -> int:
    """The ``op`` field of a record header, or -1."""
    pos = start
    while pos + 4 <= end:
        (n,) = _U32(buf, pos)
        pos += 4
        if n == 4 and pos + 4 <= end and (buf[pos], buf[pos + 1], buf[pos + 2]) == _OP_EQ:
            return buf[pos + 3]
        pos += n
    return -1


def ros1_payload(buf: memoryview, pos: int) -> memoryview | None:
    """The data of the message-data record at ``pos`` (connection records before it skipped)."""
    size = len(buf)
    while pos >= 0 and pos + 4 <= size:
        (hlen,) = _U32(buf, pos)
        hend = pos + 4 + hlen
        if hend + 4 > size:
            return None
        op = _op_of(buf, pos + 4, hend)
        (dlen,) = _U32(buf, hend)
        dend = hend + 4 + dlen
        if dend > size:
            return None
        if op == _OP_MSGDATA:
            return buf[hend + 4 : dend]
        if op != _OP_CONNECTION:
            return None
        pos = dend
    return None


class Rosbag1Source(TableSource):
    """A ROS 1 ``.bag`` file; msgtypes use ROS 2 spelling, serialization ``'ros1'``."""

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        super().__init__(path, 'rosbag1', [path], ros1_payload)
        try:
            mapped = MappedFile(path)
            self._maps.append(mapped)
            self._index(mapped)
            self._finish()
        except BaseException:
            self.close()
            raise

    def _index(self, mapped: MappedFile) -> None:
        buf, size = mapped.view, mapped.size
        head = bytes(buf[: len(ROSBAG_MAGIC)])
        if head != ROSBAG_MAGIC:
            if head.startswith(b'#ROSBAG V'):
                version = head[9:].split(b'\n', 1)[0].decode('latin-1', 'replace')
                msg = f'{self.path}: ROS bag version {version} is not supported (only 2.0)'
            else:
                msg = f'{self.path}: not a ROS 1 bag (no #ROSBAG V2.0 magic)'
            raise SourceError(msg)
        index_pos = self._bag_header(buf, size)
        # A zero-filled tail (last blocks lost to a power cut) is where the file was cut. An
        # index always holds non-zero bytes: zeros from before index_pos mean it is gone.
        end = zero_tail_start(buf, size)
        reason = ''
        if index_pos == 0:
            reason = 'bag is not indexed (recording was not closed)'
        elif index_pos == size and self._declares_nothing(buf, size):
            return  # closed without a connection or a chunk: an empty bag, not a cut one
        elif index_pos >= size:
            reason = 'bag index is missing (file cut short)'
        elif end <= index_pos:
            reason = 'bag index is zeroed'
        else:
            try:
                self._index_with_rosbags(mapped)
            except Exception as err:  # noqa: BLE001  rosbags on a damaged index: a reason
                self._channels.clear()
                self._chunks.clear()
                self._parts.clear()
                reason = f'bag index unreadable ({err})'
            else:
                return
        cut = end < size  # the zeros a readable index may end with never get here
        if cut:
            mapped.cut(end)
        complete = self._scan(mapped) and not cut
        if index_pos == 0 or index_pos >= size or not complete:
            self._truncated = True
            where = ''
            if cut:
                where = f'; file is cut short at byte {end} (the last {size - end} bytes are zeros)'
            self._warn(
                f'{self.path.name}: {reason}{where}; replaying every complete message before '
                'the cut'
            )
        else:
            self._warn(f'{self.path.name}: {reason}; scanned the file')

    def _bag_header(self, buf: memoryview, size: int) -> int:
        """``index_pos`` of the bag header record; SourceError for encrypted bags."""
        pos = len(ROSBAG_MAGIC)
        try:
            (hlen,) = _U32(buf, pos)
            fields = _fields(buf, pos + 4, min(pos + 4 + hlen, size))
        except (struct.error, _CorruptError):
            return 0
        if fields.get('op') != bytes([_OP_BAGHEADER]):
            return 0
        if fields.get('encryptor'):
            name = fields['encryptor'].decode('latin-1')
            msg = f'{self.path}: encrypted bags ({name}) are not supported'
            raise SourceError(msg)
        value = fields.get('index_pos', b'')
        return int(_U64(value, 0)[0]) if len(value) == 8 else 0

    def _declares_nothing(self, buf: memoryview, size: int) -> bool:
        """Whether the bag header counts no connection and no chunk (a closed, empty bag)."""
        pos = len(ROSBAG_MAGIC)
        try:
            (hlen,) = _U32(buf, pos)
            fields = _fields(buf, pos + 4, min(pos + 4 + hlen, size))
        except (struct.error, _CorruptError):
            return False
        return fields.get('conn_count') == bytes(4) and fields.get('chunk_count') == bytes(4)

    def _index_with_rosbags(self, mapped: MappedFile) -> None:
        from rosbags.rosbag1 import Reader

        reader = Reader(self.path)
        reader.open()
        try:
            chmap = {
                conn.id: self._add_channel(
                    Channel(conn.topic, normalize_msgtype(conn.msgtype), 'ros1', b'')
                )
                for conn in reader.connections
            }
            kmap: dict[int, int] = {}
            for chunk_pos in sorted(reader.chunks):
                info = reader.chunks[chunk_pos]
                compression, usize = self._chunk_header(mapped, chunk_pos)
                kmap[chunk_pos] = self._add_chunk(
                    Chunk(0, chunk_pos, info.datapos, info.datasize, compression, usize, False)
                )
            # What the chunk infos count must be what the index lists (and no chunk holds
            # nothing): a zeroed tail can leave the index readable with its last counts gone.
            listed = {
                (kmap.get(info.pos, -1), cid): count
                for info in reader.chunk_infos
                for cid, count in info.connection_counts.items()
            }
            indexed: dict[tuple[int, int], int] = {}
            for conn in reader.connections:
                entries = reader.indexes.get(conn.id, [])
                if not entries:
                    continue
                n = len(entries)
                times = np.fromiter((e.time for e in entries), np.uint64, n)
                chunks = np.fromiter((kmap[e.chunk_pos] for e in entries), np.int32, n)
                offsets = np.fromiter((e.offset for e in entries), np.int64, n)
                for k in np.unique(chunks).tolist():
                    mask = chunks == k
                    indexed[int(k), conn.id] = int(np.count_nonzero(mask))
                    self._add_rows(times[mask], chmap[conn.id], int(k), offsets[mask])
            # (a bag without any message is empty, not damaged: rosbags writes its connections
            # into a chunk that counts none)
            empty_chunk = not all(info.connection_counts for info in reader.chunk_infos)
            if indexed != listed or (empty_chunk and indexed):
                msg = (
                    f'chunk infos count {sum(listed.values())} messages, '
                    f'the index lists {sum(indexed.values())}'
                )
                raise ValueError(msg)
        finally:
            reader.close()

    @staticmethod
    def _chunk_header(mapped: MappedFile, pos: int) -> tuple[str, int]:
        buf = mapped.view
        (hlen,) = _U32(buf, pos)
        fields = _fields(buf, pos + 4, pos + 4 + hlen)
        compression = fields['compression'].decode('latin-1')
        return compression if compression != 'none' else '', int(_U32(fields['size'], 0)[0])

    # -- scanning -------------------------------------------------------------------------

    def _scan(self, mapped: MappedFile) -> bool:
        """Index the bag record by record; False when it ends inside a record."""
        buf, size = mapped.view, mapped.size
        chmap: dict[int, int] = {}
        outside = self._raw_chunk(0)
        pos = len(ROSBAG_MAGIC)
        while pos < size:
            if pos + 4 > size:
                return False
            (hlen,) = _U32(buf, pos)
            hend = pos + 4 + hlen
            if hend + 4 > size:
                return False
            try:
                fields = _fields(buf, pos + 4, hend)
            except _CorruptError:
                self._warn(f'{self.path.name}: unreadable record at byte {pos}; stopped there')
                return False
            (dlen,) = _U32(buf, hend)
            dstart = hend + 4
            dend = dstart + dlen
            op = _op(fields)
            if op == _OP_CHUNK:
                compression = fields.get('compression', b'none').decode('latin-1')
                size_field = fields.get('size', b'')
                usize = int(_U32(size_field, 0)[0]) if len(size_field) == 4 else 0
                partial = dend > size
                k = self._add_chunk(
                    Chunk(
                        0,
                        pos,
                        dstart,
                        min(dlen, size - dstart),
                        compression if compression != 'none' else '',
                        usize,
                        partial,
                    )
                )
                self._scan_chunk(k, chmap)
                if partial:
                    return False
            elif dend > size:
                return False
            elif op in (_OP_CONNECTION, _OP_MSGDATA):
                self._scan_records(buf, pos, dend, 0, outside, chmap)
            pos = dend
        return True

    def _scan_chunk(self, k: int, chmap: dict[int, int]) -> None:
        ck = self._chunks[k]
        view = self._maps[0].view
        if not ck.compression:
            end = ck.data_start + ck.data_len
            self._scan_records(view, ck.data_start, end, ck.data_start, k, chmap)
            return
        data = self._chunk_bytes(k)
        if data is None:
            return
        inner = memoryview(data)
        try:
            self._scan_records(inner, 0, len(inner), 0, k, chmap)
        finally:
            inner.release()

    def _scan_records(
        self,
        buf: memoryview,
        start: int,
        end: int,
        base: int,
        k: int,
        chmap: dict[int, int],
    ) -> None:
        """Index connection and message-data records in ``buf[start:end]``."""
        pos = start
        while pos + 4 <= end:
            (hlen,) = _U32(buf, pos)
            hend = pos + 4 + hlen
            if hend + 4 > end:
                return
            (dlen,) = _U32(buf, hend)
            dend = hend + 4 + dlen
            if dend > end:
                return
            try:
                fields = _fields(buf, pos + 4, hend)
                op = _op(fields)
                if op == _OP_CONNECTION:
                    conn = int(_U32(fields['conn'], 0)[0])
                    if conn not in chmap:
                        info = _fields(buf, hend + 4, dend)
                        topic = normalize_topic(fields['topic'].decode())
                        msgtype = normalize_msgtype(info['type'].decode())
                        chmap[conn] = self._add_channel(Channel(topic, msgtype, 'ros1', b''))
                elif op == _OP_MSGDATA:
                    conn = int(_U32(fields['conn'], 0)[0])
                    sec, nsec = _TIME(fields['time'], 0)
                    if conn in chmap:
                        self._add_row(sec * 1_000_000_000 + nsec, chmap[conn], k, pos - base)
                    else:
                        self._warn(
                            f'{self.path.name}: messages on undeclared connection {conn}; skipped'
                        )
            except (_CorruptError, KeyError, struct.error, UnicodeDecodeError):
                self._warn(f'{self.path.name}: unreadable record(s); skipped')
            pos = dend
