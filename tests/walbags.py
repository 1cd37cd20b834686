"""rosbag2 sqlite bags left behind by a recorder that died before sqlite checkpointed its log.

A bag is written whole with ``rosbags``' Writer, then rebuilt with ``sqlite3`` in WAL mode
(``wal_autocheckpoint=0``) step by step: inserts (one transaction each, like a recorder),
checkpoints, readers that pin a snapshot. The ``.db3``, ``-wal`` (and ``-shm``) files are copied
while the writing connection is still open, which is what a killed writer leaves on disk.

The oracle, :func:`sqlite_rows`, opens a copy of those files with plain ``sqlite3`` the normal
way (sqlite recovers the log) and returns the rows it holds; it never calls replaybench.
"""

from __future__ import annotations

import functools
import shutil
import sqlite3
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np
from bagtools import TS, image_msg
from rosbags.rosbag2 import Writer

CAMERA = '/camera/image_raw'
IMAGE = 'sensor_msgs/msg/Image'
T0 = 1_700_000_000 * 1_000_000_000
PERIOD = 33_000_000


def image_payloads(n: int, width: int = 32, height: int = 24) -> list[tuple[int, bytes]]:
    """``n`` (log time, CDR Image) pairs, 33 ms apart; every frame's pixels differ."""
    out = []
    for i in range(n):
        t = T0 + i * PERIOD
        pixels = np.full((height, width, 3), i % 256, np.uint8)
        out.append((t, bytes(TS.serialize_cdr(image_msg(t, pixels), IMAGE))))
    return out


class Step(NamedTuple):
    """One thing the recorder's database connection did.

    ``insert``: the next ``n`` messages, one commit each; ``checkpoint``: ``PRAGMA
    wal_checkpoint(mode)``; ``pin``: another connection starts reading (its snapshot limits what
    a checkpoint may copy); ``unpin``: that reader ends.
    """

    kind: str
    n: int = 0
    mode: str = 'PASSIVE'


def write_wal_bag(
    folder: Path,
    payloads: list[tuple[int, bytes]],
    steps: list[Step],
    *,
    shm: bool = True,
    metadata: bool = True,
) -> Path:
    """The rosbag2 folder ``folder`` holding ``{folder.name}.db3`` and its ``-wal``.

    The schema and the topics are created first, in the log; the messages follow ``steps``
    (messages no step inserts are never written). ``shm`` keeps the ``-shm`` file beside them;
    ``metadata`` keeps the ``metadata.yaml`` ``rosbags`` wrote for the whole bag.
    """
    scratch = Path(tempfile.mkdtemp(prefix='walbag', dir=folder.parent))
    try:
        full = scratch / folder.name
        full.mkdir()
        whole, meta = _whole_bag(tuple(payloads))
        source = full / f'{folder.name}.db3'
        source.write_bytes(whole)
        (full / 'metadata.yaml').write_text(meta.replace('whole.db3', source.name))
        work = scratch / 'work'
        work.mkdir()
        db3 = work / source.name
        db = sqlite3.connect(db3, isolation_level=None)
        readers: list[sqlite3.Connection] = []
        try:
            db.execute('PRAGMA journal_mode=WAL')
            db.execute('PRAGMA wal_autocheckpoint=0')
            db.execute('PRAGMA synchronous=OFF')  # the log's content does not depend on it
            db.execute('ATTACH DATABASE ? AS src', (str(source),))
            schema = db.execute(
                'SELECT type, name, sql FROM src.sqlite_master WHERE sql IS NOT NULL ORDER BY '
                "type = 'index', rowid"
            ).fetchall()
            db.execute('BEGIN')
            for kind, name, sql in schema:
                db.execute(sql)
                if kind == 'table' and name != 'messages':
                    db.execute(f'INSERT INTO main.{name} SELECT * FROM src.{name}')
            db.execute('COMMIT')
            rows = db.execute('SELECT topic_id, timestamp, data FROM src.messages ORDER BY id')
            pending = rows.fetchall()
            db.execute('DETACH DATABASE src')
            done = 0
            for step in steps:
                if step.kind == 'insert':
                    for topic_id, t, data in pending[done : done + step.n]:
                        db.execute(
                            'INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)',
                            (topic_id, t, data),
                        )
                    done = min(len(pending), done + step.n)
                elif step.kind == 'checkpoint':
                    db.execute(f'PRAGMA wal_checkpoint({step.mode})')
                elif step.kind == 'pin':
                    reader = sqlite3.connect(db3, isolation_level=None)
                    reader.execute('BEGIN')
                    reader.execute('SELECT count(*) FROM messages').fetchall()
                    readers.append(reader)
                elif step.kind == 'unpin' and readers:
                    readers.pop().close()
            folder.mkdir()
            suffixes = ['', '-wal', '-shm'] if shm else ['', '-wal']
            for suffix in suffixes:
                name = db3.name + suffix
                if (work / name).exists():
                    shutil.copyfile(work / name, folder / name)
            if metadata:
                shutil.copyfile(full / 'metadata.yaml', folder / 'metadata.yaml')
        finally:
            for reader in readers:
                reader.close()
            db.close()
    finally:
        shutil.rmtree(scratch)
    return folder


@functools.cache
def _whole_bag(payloads: tuple[tuple[int, bytes], ...]) -> tuple[bytes, str]:
    """The .db3 bytes and metadata.yaml text ``rosbags`` writes for the payloads (once)."""
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / 'whole'
        with Writer(bag, version=9) as writer:
            conn = writer.add_connection(CAMERA, IMAGE, typestore=TS)
            for t, data in payloads:
                writer.write(conn, t, data)
        return (bag / 'whole.db3').read_bytes(), (bag / 'metadata.yaml').read_text()


def killed_before_checkpoint(
    folder: Path, frames: int = 45, in_db3: int = 32, *, shm: bool = True, metadata: bool = True
) -> Path:
    """``frames`` camera frames, the first ``in_db3`` checkpointed into the .db3, the rest only
    in its log (``in_db3=0``: the .db3 holds the empty tables; ``-1``: not even those)."""
    steps = [Step('insert', in_db3), Step('checkpoint', mode='TRUNCATE')] if in_db3 >= 0 else []
    steps.append(Step('insert', frames - max(in_db3, 0)))
    return write_wal_bag(folder, image_payloads(frames), steps, shm=shm, metadata=metadata)


def sqlite_rows(db3: Path, topic: str = CAMERA) -> list[tuple[int, bytes]]:
    """(log time, data) of ``topic``'s messages as sqlite returns them when it opens a copy of
    ``db3`` and its ``-wal`` / ``-shm`` files normally (ordered by log time, then row id)."""
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / db3.name
        for suffix in ('', '-wal', '-shm'):
            if Path(f'{db3}{suffix}').exists():
                shutil.copyfile(f'{db3}{suffix}', f'{copy}{suffix}')
        db = sqlite3.connect(copy)
        try:
            rows = db.execute(
                'SELECT messages.timestamp, messages.data FROM messages JOIN topics '
                'ON messages.topic_id = topics.id WHERE topics.name = ? '
                'ORDER BY messages.timestamp, messages.id',
                (topic,),
            ).fetchall()
        except sqlite3.DatabaseError:
            rows = []
        finally:
            db.close()
    return [(int(t), bytes(data)) for t, data in rows]


def immutable_rows(db3: Path, topic: str = CAMERA) -> int:
    """How many of ``topic``'s messages sqlite sees when it ignores the log (``immutable=1``);
    0 when the .db3 alone is no readable database."""
    db = sqlite3.connect(f'file:{db3}?immutable=1', uri=True)
    try:
        (count,) = db.execute(
            'SELECT count(*) FROM messages JOIN topics ON messages.topic_id = topics.id '
            'WHERE topics.name = ?',
            (topic,),
        ).fetchone()
    except sqlite3.DatabaseError:
        count = 0
    finally:
        db.close()
    return int(count)
