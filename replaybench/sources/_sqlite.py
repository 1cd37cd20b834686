"""rosbag2 sqlite3 storage files read with their write-ahead log.

``rosbags`` opens a ``.db3`` file ``immutable``: sqlite then ignores a ``-wal`` file beside it,
and a recording whose writer died before a checkpoint loses every message still in the log.
:class:`SqliteStorage` reads a ``.db3`` the way sqlite reads it when it opens the database
normally, log included, without changing a byte of the files:

- no ``-wal`` (or an empty one): opened ``immutable``, as ``rosbags`` does;
- a ``-wal``: opened read-only through sqlite's ``unix-none`` VFS in exclusive locking mode.
  sqlite then builds the log's index in memory instead of in the ``-shm`` file (which is neither
  read, written nor created) and never checkpoints, so this works in a read-only folder too;
- a ``-wal`` and no ``unix-none`` VFS: the ``.db3`` and its log are copied into a private
  temporary folder and opened there; the storage's ``notes`` say so.

The storage has the attributes and the ``messages`` query of ``rosbags``' sqlite3 reader, so
:class:`~replaybench.sources.rosbag2.RosbagsSource` reads both alike.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple, cast
from urllib.parse import quote

import apsw

from replaybench.errors import SourceError

if TYPE_CHECKING:
    from collections.abc import Collection, Iterator

__all__ = ['SqliteStorage', 'StorageTopic', 'has_wal', 'wal_path']

#: The sqlite VFS without file locks: with it, exclusive locking mode needs no ``-shm`` file.
_VFS = 'unix-none'


def wal_path(db3: Path) -> Path:
    """The write-ahead log sqlite keeps beside ``db3``."""
    return db3.with_name(db3.name + '-wal')


def has_wal(db3: Path) -> bool:
    """Whether ``db3`` has a non-empty write-ahead log beside it (frames not yet in the file)."""
    try:
        return wal_path(db3).stat().st_size > 0
    except OSError:
        return False


def _uri(path: Path, query: str) -> str:
    return f'file:{quote(str(path.absolute()))}?{query}'


class _Ext(NamedTuple):
    serialization_format: str


class StorageTopic(NamedTuple):
    """A row of the ``topics`` table (the fields ``rosbags``' connections have)."""

    id: int
    topic: str
    msgtype: str
    msgcount: int
    ext: _Ext


class SqliteStorage:
    """One rosbag2 ``.db3`` file, read-only, its write-ahead log included."""

    dbconn: apsw.Connection

    def __init__(self, path: Path) -> None:
        self.path = path
        self.notes: list[str] = []
        self.connections: list[StorageTopic] = []
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        wal = wal_path(path)
        logged = has_wal(path)
        try:
            if not logged:
                self.dbconn = self._connect(path, 'immutable=1')
            elif _VFS in apsw.vfs_names():
                self.dbconn = self._connect(path, 'mode=ro', vfs=_VFS)
                # before the first read: keeps the log's index in memory, no -shm
                self.dbconn.execute('PRAGMA locking_mode=EXCLUSIVE')
                self.dbconn.config(apsw.SQLITE_DBCONFIG_NO_CKPT_ON_CLOSE, 1)
            else:
                self.dbconn = self._private_copy(path, wal)
            self._read_topics()
        except apsw.Error as err:
            self.close()
            log = f' with its write-ahead log {wal.name}' if logged else ''
            msg = f'{path}: cannot read the sqlite database{log}: {err}'
            raise SourceError(msg) from err
        except BaseException:
            self.close()
            raise
        if logged:
            self.notes.insert(
                0,
                f'{path.name}: the recording was not closed; its write-ahead log {wal.name} '
                'was read with it',
            )

    @staticmethod
    def _connect(path: Path, query: str, vfs: str | None = None) -> apsw.Connection:
        flags = apsw.SQLITE_OPEN_READONLY | apsw.SQLITE_OPEN_URI
        return apsw.Connection(_uri(path, query), flags=flags, vfs=vfs)

    def _private_copy(self, path: Path, wal: Path) -> apsw.Connection:
        """Open a copy of ``path`` and its log in a private folder, as sqlite opens it normally."""
        self._tmp = tempfile.TemporaryDirectory(prefix='replaybench-db3-')
        copy = Path(self._tmp.name) / path.name
        shutil.copyfile(path, copy)
        shutil.copyfile(wal, wal_path(copy))
        self.notes.append(
            f'{path.name}: read from a private copy in a temporary folder (sqlite needs a '
            f'writable -shm file to read {wal.name})'
        )
        flags = apsw.SQLITE_OPEN_READWRITE | apsw.SQLITE_OPEN_URI
        return apsw.Connection(_uri(copy, 'mode=rw'), flags=flags)

    def _read_topics(self) -> None:
        tables = {
            str(row[0])
            for row in self.dbconn.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table' AND name IN "
                "('messages', 'topics')"
            )
        }
        if tables != {'messages', 'topics'}:
            msg = f'{self.path}: not a rosbag2 database (no messages and topics tables)'
            raise SourceError(msg)
        rows = self.dbconn.execute(
            'SELECT topics.id, topics.name, topics.type, topics.serialization_format, '
            'count(messages.id) FROM topics LEFT JOIN messages ON topics.id == messages.topic_id '
            'GROUP BY topics.id ORDER BY topics.id'
        ).fetchall()
        self.connections = [
            StorageTopic(
                cast('int', cid), str(name), str(msgtype), cast('int', count), _Ext(str(fmt))
            )
            for cid, name, msgtype, fmt, count in rows
        ]

    def messages(
        self,
        connections: Collection[StorageTopic],
        start: int | None = None,
        stop: int | None = None,
    ) -> Iterator[tuple[StorageTopic, int, bytes]]:
        """(topic, log time, data) in log-time order: the query of ``rosbags``' reader."""
        ids = tuple({conn.id for conn in connections})
        query = [
            'SELECT topics.id,messages.timestamp,messages.data',
            'FROM messages JOIN topics ON messages.topic_id=topics.id',
            f'WHERE topics.id IN ({",".join("?" for _ in ids)})',
        ]
        args: list[int] = list(ids)
        if start is not None:
            query.append('AND messages.timestamp >= ?')
            args.append(start)
        if stop is not None:
            query.append('AND messages.timestamp < ?')
            args.append(stop)
        query.append('ORDER BY timestamp')
        by_id = {conn.id: conn for conn in self.connections}
        for cid, timestamp, data in self.dbconn.execute(' '.join(query), args):
            yield by_id[cid], timestamp, data

    def close(self) -> None:
        """Close the database (and remove a private copy)."""
        conn = getattr(self, 'dbconn', None)
        if conn is not None:
            with contextlib.suppress(apsw.Error):
                conn.close()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
