"""rosbag2: bag directories (metadata.yaml + .db3 or .mcap files) and bare ``.db3`` files.

A directory with uncompressed mcap storage is read file by file with the fast MCAP reader
(:class:`~replaybench.sources.mcap.McapSource`) and its files merged into one replay order.
sqlite3 storage and compressed bags are read with ``rosbags``: each file's stream is
re-ordered within equal timestamps (by topic) and the files are merged by
(log time, topic, file, position), so a split bag replays as one input.

A recording that was not closed is read whole:

- a ``.db3`` with a write-ahead log beside it (``x.db3-wal``) is read with its log
  (:class:`~replaybench.sources._sqlite.SqliteStorage`), never changing the files;
- a directory without ``metadata.yaml`` is read from its storage files when they are one
  ``.db3`` or ``.mcap`` file or the numbered files of one split bag (``name_0.db3``,
  ``name_1.db3``, ...); otherwise it is refused with the ways to go on.
"""

from __future__ import annotations

import contextlib
import heapq
import re
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any

from replaybench.errors import SourceError
from replaybench.types import RawMessage, SkippedTopic, TopicInfo

from ._common import decompress_message, normalize_msgtype
from ._table import Channel
from .mcap import McapSource

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Iterable, Iterator
    from types import TracebackType
    from typing import Self

    from rosbags.interfaces import Connection

__all__ = ['RosbagsSource', 'open_rosbag2']

#: (log time, topic, file number, position in file, channel, data)
_Item = tuple[int, str, int, int, Channel, bytes]


def _one_line(err: BaseException) -> str:
    text = ' '.join(str(err).split())
    return text or type(err).__name__


def _metadata(path: Path) -> dict[str, Any]:
    from ruamel.yaml import YAML

    meta = path / 'metadata.yaml'
    if not meta.is_file():
        msg = f'{path}: directory has no metadata.yaml (not a rosbag2 bag)'
        raise SourceError(msg)
    try:
        with meta.open('rb') as handle:
            doc = YAML(typ='safe').load(handle)
        info = doc['rosbag2_bagfile_information']
        if not isinstance(info, dict):
            raise TypeError
    except OSError as err:
        msg = f'{meta}: cannot read: {err.strerror or err}'
        raise SourceError(msg) from err
    except Exception as err:
        msg = f'{meta}: not valid rosbag2 metadata ({_one_line(err)})'
        raise SourceError(msg) from err
    return info


def open_rosbag2(path: str | Path) -> McapSource | RosbagsSource:
    """Open a rosbag2 directory (with or without ``metadata.yaml``) or a bare ``.db3`` file."""
    from ._sqlite import has_wal

    path = Path(path)
    files = [path]
    if path.is_dir():
        if not (path / 'metadata.yaml').is_file():
            return _open_unclosed(path)
        info = _metadata(path)
        try:
            files = [path / PurePath(name).name for name in info['relative_file_paths']]
            storage = str(info.get('storage_identifier', ''))
            mode = str(info.get('compression_mode', '') or '').lower()
            compression = str(info.get('compression_format', '') or '').lower()
        except (KeyError, TypeError) as err:
            msg = f'{path / "metadata.yaml"}: not valid rosbag2 metadata ({_one_line(err)})'
            raise SourceError(msg) from err
        if missing := [file.name for file in files if not file.is_file()]:
            msg = f'{path}: data files listed in metadata.yaml are missing: {", ".join(missing)}'
            raise SourceError(msg)
        if storage == 'mcap' and mode in ('', 'none', 'storage'):  # storage: compressed chunks
            return McapSource(path, files, fmt='rosbag2')
        plain = mode in ('', 'none') or (mode == 'message' and compression == 'zstd')
        logged = any(has_wal(file) for file in files)
        if storage == 'sqlite3' and plain and (logged or not _all_cdr(info)):
            # rosbags ignores write-ahead logs and refuses a whole bag for one non-CDR topic
            return _open_sqlite(path, files, message_compressed=mode == 'message')
    elif has_wal(path):
        return _open_sqlite(path, files)

    from rosbags.rosbag2 import Reader

    try:
        reader = Reader(path)
        reader.open()
    except Exception as err:
        msg = f'{path}: cannot read rosbag2 bag: {_one_line(err)}'
        raise SourceError(msg) from err
    opened = reader.storage
    storages = getattr(opened, 'storages', None)
    return RosbagsSource(
        path,
        files,
        list(storages) if storages is not None else [opened],
        close=reader.close,
        message_compressed=reader.compression_mode == 'message',
    )


def _all_cdr(info: dict[str, Any]) -> bool:
    """Whether metadata.yaml lists only topics in CDR (an unreadable list counts as all CDR)."""
    try:
        formats = {
            str(topic['topic_metadata']['serialization_format'])
            for topic in info.get('topics_with_message_count') or ()
        }
    except (KeyError, TypeError):
        return True
    return formats <= {'cdr'}


def _open_sqlite(
    path: Path, files: list[Path], *, message_compressed: bool = False, note: str = ''
) -> RosbagsSource:
    """Read ``.db3`` files with :class:`SqliteStorage` (write-ahead logs included)."""
    from ._sqlite import SqliteStorage

    storages: list[SqliteStorage] = []

    def close() -> None:
        for storage in storages:
            storage.close()

    try:
        for file in files:  # one by one: a later failure closes those already open
            storages.append(SqliteStorage(file))  # noqa: PERF401
    except BaseException:
        close()
        raise
    notes = [note] if note else []
    notes += [line for storage in storages for line in storage.notes]
    return RosbagsSource(
        path, files, storages, close=close, message_compressed=message_compressed, notes=notes
    )


#: The data files of a split rosbag2 bag: ``<name>_<n>.db3`` / ``.mcap``, n = 0, 1, 2, ...
_SPLIT_NAME = re.compile(r'(?P<name>.+)_(?P<n>[0-9]+)')
_STORAGE_SUFFIXES = ('.db3', '.mcap')


def _one_bag(found: list[Path]) -> list[Path] | None:
    """``found`` in replay order when it is one storage file or the files of one split bag."""
    if len(found) == 1:
        return found
    matches = [_SPLIT_NAME.fullmatch(file.stem) for file in found]
    if len({file.suffix for file in found}) != 1 or any(m is None for m in matches):
        return None
    numbered = sorted(
        (int(m['n']), m['name'], file) for m, file in zip(matches, found, strict=True) if m
    )
    if len({name for _, name, _ in numbered}) != 1:
        return None
    if [n for n, _, _ in numbered] != list(range(len(numbered))):
        return None
    return [file for _, _, file in numbered]


def _open_unclosed(path: Path) -> McapSource | RosbagsSource:
    """A rosbag2 directory without ``metadata.yaml``: the recorder was killed before writing it.

    Its storage files are read directly when they are one bag; otherwise SourceError says how
    to go on.
    """
    entries = sorted(path.iterdir())
    found = [p for p in entries if p.suffix in _STORAGE_SUFFIXES and p.is_file()]
    if not found:
        hint = ''
        if any(p.suffix == '.bag' for p in entries):
            hint = '; for a ROS 1 bag, pass the .bag file itself'
        elif any(p.name.endswith(('.db3.zstd', '.mcap.zstd')) for p in entries):
            hint = '; its compressed data files need their metadata.yaml (run `ros2 bag reindex`)'
        msg = f'{path}: no bag in this folder (no metadata.yaml, .db3 or .mcap file){hint}'
        raise SourceError(msg)
    files = _one_bag(found)
    names = ', '.join(p.name for p in found[:4]) + (', ...' if len(found) > 4 else '')
    if files is None:
        msg = (
            f'{path}: metadata.yaml is missing and the {len(found)} storage files ({names}) are '
            'not one split bag; pass one storage file, or run `ros2 bag reindex` on the folder'
        )
        raise SourceError(msg)
    note = (
        f'{path.name}: metadata.yaml is missing (the recording was not closed); '
        f'read {names} directly'
    )
    if files[0].suffix == '.mcap':
        source = McapSource(path, files, fmt='rosbag2')
        source._warn(note)
        return source
    return _open_sqlite(path, files, note=note)


def _ties_by_topic(items: Iterable[_Item]) -> Iterator[_Item]:
    """Re-order runs of equal log time by topic, keeping file order within a topic."""
    group: list[_Item] = []
    for item in items:
        if group and item[0] != group[0][0]:
            group.sort(key=lambda x: x[1])
            yield from group
            group.clear()
        group.append(item)
    group.sort(key=lambda x: x[1])
    yield from group


def _merge_key(item: _Item) -> tuple[int, str, int, int]:
    return item[0], item[1], item[2], item[3]


class RosbagsSource:
    """A rosbag2 bag read through ``rosbags`` (sqlite3 storage, compressed bags).

    ``storages``: one opened storage reader per data file (``rosbags``' readers or
    :class:`~replaybench.sources._sqlite.SqliteStorage`); ``close`` closes them all; ``notes``
    are warnings found while opening them.
    """

    def __init__(
        self,
        path: Path,
        files: list[Path],
        storages: list[Any],
        *,
        close: Callable[[], None],
        message_compressed: bool = False,
        notes: Iterable[str] = (),
    ) -> None:
        self.path = path
        self.format = 'rosbag2'
        self.files = files
        self._close_storages = close
        self._closed = False
        self._truncated = False
        self._warnings: list[str] = list(notes)
        #: (file name, topic) -> (messages that could not be decompressed, the first reason)
        self._skipped: dict[tuple[str, str], tuple[int, str]] = {}
        self._storages = storages
        self._message_compressed = message_compressed
        self._chmaps: list[dict[int, Channel]] = []
        #: per storage: connection id -> (topic, msgtype, serialization) of unsupported ones
        self._unsupported: list[dict[int, tuple[str, str, str]]] = []
        for sub in self._storages:
            chmap: dict[int, Channel] = {}
            unsupported: dict[int, tuple[str, str, str]] = {}
            for conn in sub.connections:
                msgtype = normalize_msgtype(conn.msgtype)
                fmt = getattr(conn.ext, 'serialization_format', 'cdr')
                if fmt != 'cdr':
                    self._warn(
                        f'topic {conn.topic}: serialization {fmt!r} is not supported; skipped'
                    )
                    unsupported[conn.id] = (conn.topic, msgtype, str(fmt))
                    continue
                chmap[conn.id] = Channel(conn.topic, msgtype, 'cdr', b'')
            self._chmaps.append(chmap)
            self._unsupported.append(unsupported)
        self._per_conn: dict[int, dict[int, tuple[int, int, int]]] = {}
        self._topics: list[TopicInfo] | None = None

    # -- Source API -----------------------------------------------------------------------

    @property
    def truncated(self) -> bool:
        """True when reading stopped at a damaged or cut file."""
        return self._truncated

    @property
    def warnings(self) -> list[str]:
        """Human-readable lines about truncation, skipped topics and skipped messages."""
        skipped = [
            f'{name}: {count} message(s) on {topic} could not be decompressed '
            f'(first: {first}); skipped'
            for (name, topic), (count, first) in self._skipped.items()
        ]
        return [*self._warnings, *skipped]

    def topics(self) -> list[TopicInfo]:
        """Topics sorted by name, with message counts and first / last log times."""
        self._check_open()
        if self._topics is None:
            stats: dict[str, list[int]] = {}
            first_channel: dict[str, Channel] = {}
            for i, sub in enumerate(self._storages):
                per_conn = self._conn_stats(i, sub)
                for cid, channel in self._chmaps[i].items():
                    first_channel.setdefault(channel.topic, channel)
                    acc = stats.setdefault(channel.topic, [0, 0, 0])
                    count, first, last = per_conn.get(cid, (0, 0, 0))
                    if count:
                        acc[1] = first if not acc[0] else min(acc[1], first)
                        acc[2] = last if not acc[0] else max(acc[2], last)
                        acc[0] += count
            self._topics = [
                TopicInfo(name, first_channel[name].msgtype, 'cdr', *stats[name])
                for name in sorted(stats)
            ]
        return list(self._topics)

    def skipped_topics(self) -> list[SkippedTopic]:
        """Topics in a serialization format other than CDR, with their message counts."""
        self._check_open()
        found: dict[str, SkippedTopic] = {}
        for i, sub in enumerate(self._storages):
            if not self._unsupported[i]:
                continue
            per_conn = self._conn_stats(i, sub)
            for cid, (topic, msgtype, fmt) in self._unsupported[i].items():
                count = per_conn.get(cid, (0, 0, 0))[0]
                before = found[topic].count if topic in found else 0
                reason = f'serialization {fmt!r} is not supported'
                found[topic] = SkippedTopic(topic, msgtype, fmt, before + count, reason)
        return [found[name] for name in sorted(found)]

    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[RawMessage]:
        """Messages in replay order; ``start_ns`` inclusive, ``end_ns`` exclusive (log time)."""
        self._check_open()
        wanted = None if topics is None else ({topics} if isinstance(topics, str) else set(topics))
        if start_ns is not None and end_ns is not None and end_ns <= start_ns:
            return iter(())
        streams: list[Iterator[_Item]] = []
        for i, sub in enumerate(self._storages):
            chmap = self._chmaps[i]
            conns = [
                conn
                for conn in sub.connections
                if conn.id in chmap and (wanted is None or chmap[conn.id].topic in wanted)
            ]
            if conns:
                streams.append(_ties_by_topic(self._read(i, sub, conns, start_ns, end_ns)))
        if not streams:
            return iter(())
        seq = self._counts_before(start_ns, wanted) if start_ns is not None else {}
        return self._generate(streams, seq)

    def close(self) -> None:
        """Close the underlying rosbags reader."""
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(Exception):
            self._close_storages()

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

    # -- internals ------------------------------------------------------------------------

    def _warn(self, line: str) -> None:
        if line not in self._warnings:
            self._warnings.append(line)

    def _undecompressed(self, i: int, topic: str, reason: str) -> None:
        key = (self._file_name(i), topic)
        count, first = self._skipped.get(key, (0, reason))
        self._skipped[key] = (count + 1, first)

    def _check_open(self) -> None:
        if self._closed:
            msg = f'{self.path}: source is closed'
            raise SourceError(msg)

    def _file_name(self, i: int) -> str:
        return self.files[i].name if i < len(self.files) else self.path.name

    def _generate(
        self, streams: list[Iterator[_Item]], seq: dict[str, int]
    ) -> Iterator[RawMessage]:
        merged = streams[0] if len(streams) == 1 else heapq.merge(*streams, key=_merge_key)
        for log_time, topic, _, _, channel, data in merged:
            n = seq.get(topic, 0)
            seq[topic] = n + 1
            yield RawMessage(topic, channel.msgtype, 'cdr', log_time, n, data, b'')

    def _read(
        self,
        i: int,
        sub: Any,
        conns: list[Connection],
        start_ns: int | None,
        end_ns: int | None,
    ) -> Iterator[_Item]:
        chmap = self._chmaps[i]
        dctx = _zstd_decompressor() if self._message_compressed else None
        n = 0
        try:
            for conn, log_time, data in sub.messages(conns, start_ns, end_ns):
                channel = chmap[conn.id]
                if dctx is not None:
                    try:
                        payload = decompress_message(data, dctx=dctx)
                    except ValueError as err:
                        self._undecompressed(i, channel.topic, str(err))
                        continue
                else:
                    payload = data
                if log_time < 0:  # sqlite stores signed times; log times are unsigned
                    self._warn(
                        f'{self._file_name(i)}: messages with negative timestamps; '
                        'replayed at log time 0'
                    )
                    log_time = 0
                yield log_time, channel.topic, i, n, channel, payload
                n += 1
        except Exception as err:  # noqa: BLE001  sqlite and rosbags errors: a warning
            if self._closed:
                return
            self._truncated = True
            self._warn(
                f'{self._file_name(i)}: read error after {n} messages ({_one_line(err)}); '
                'replaying the messages before it'
            )

    def _conn_stats(self, i: int, sub: Any) -> dict[int, tuple[int, int, int]]:
        if i not in self._per_conn:
            self._per_conn[i] = self._stats(i, sub)
        return self._per_conn[i]

    def _stats(self, i: int, sub: Any) -> dict[int, tuple[int, int, int]]:
        """Per connection id: (count, first log time, last log time)."""
        db = getattr(sub, 'dbconn', None)
        try:
            if db is not None:
                rows = db.execute(
                    'SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) '
                    'FROM messages GROUP BY topic_id'
                ).fetchall()
                return {int(r[0]): (int(r[1]), max(0, int(r[2])), max(0, int(r[3]))) for r in rows}
            stats: dict[int, tuple[int, int, int]] = {}
            for conn, time, _ in sub.messages(list(sub.connections)):
                log_time = max(0, time)
                count, first, last = stats.get(conn.id, (0, log_time, log_time))
                stats[conn.id] = (count + 1, min(first, log_time), max(last, log_time))
        except Exception as err:  # noqa: BLE001  sqlite and rosbags errors: a warning
            self._truncated = True
            self._warn(f'{self._file_name(i)}: cannot count messages ({_one_line(err)})')
            return {}
        return stats

    def _counts_before(self, start_ns: int, wanted: set[str] | None) -> dict[str, int]:
        """Messages per topic logged before ``start_ns`` (the seq of the first one yielded)."""
        counts: dict[str, int] = {}
        for i, sub in enumerate(self._storages):
            chmap = self._chmaps[i]
            per_conn: dict[int, int] = {}
            db = getattr(sub, 'dbconn', None)
            try:
                if db is not None:
                    rows = db.execute(
                        'SELECT topic_id, COUNT(*) FROM messages WHERE timestamp < ? '
                        'GROUP BY topic_id',
                        (start_ns,),
                    ).fetchall()
                    per_conn = {int(r[0]): int(r[1]) for r in rows}
                else:
                    conns = [
                        conn
                        for conn in sub.connections
                        if conn.id in chmap and (wanted is None or chmap[conn.id].topic in wanted)
                    ]
                    for conn, _, _ in sub.messages(conns, None, start_ns):
                        per_conn[conn.id] = per_conn.get(conn.id, 0) + 1
            except Exception as err:  # noqa: BLE001  sqlite and rosbags errors: a warning
                self._warn(f'{self._file_name(i)}: cannot count messages ({_one_line(err)})')
            for cid, count in per_conn.items():
                if cid in chmap:
                    topic = chmap[cid].topic
                    counts[topic] = counts.get(topic, 0) + count
        return counts


def _zstd_decompressor() -> Any:
    import zstandard

    return zstandard.ZstdDecompressor()
