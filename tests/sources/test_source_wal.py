"""rosbag2 .db3 files in WAL mode whose writer died before a checkpoint (issue 13, item 1).

The write-ahead log is part of the database: replaybench replays exactly the rows sqlite returns
when it opens the files normally (``walbags.sqlite_rows``, plain ``sqlite3`` on a copy), and
leaves the .db3, -wal and -shm files byte-identical, also in a read-only folder.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from typer.testing import CliRunner
from walbags import (
    CAMERA,
    PERIOD,
    T0,
    Step,
    image_payloads,
    immutable_rows,
    killed_before_checkpoint,
    sqlite_rows,
    write_wal_bag,
)

from replaybench.cli import app
from replaybench.sources import open_source

REPO = Path(__file__).resolve().parents[2]


def snapshot(folder: Path) -> dict[str, str]:
    """Every file of ``folder`` and its sha256 (a file that appears or changes shows)."""
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def replayed(path: Path, **window: int) -> list[tuple[int, bytes]]:
    with open_source(path) as source:
        return [(m.log_time_ns, bytes(m.data)) for m in source.messages([CAMERA], **window)]


def camera_rows(out: Path) -> list[dict[str, str]]:
    with (out / 'frames.csv').open(newline='') as handle:
        return [row for row in csv.DictReader(handle) if row['topic'] == CAMERA]


@pytest.mark.parametrize('bare', [False, True], ids=['folder', 'db3'])
@pytest.mark.parametrize('metadata', [True, False], ids=['metadata', 'no-metadata'])
@pytest.mark.parametrize('shm', [True, False], ids=['shm', 'no-shm'])
@pytest.mark.parametrize('in_db3', [32, 0, -1], ids=['32-in-db3', 'tables-in-db3', 'all-in-wal'])
def test_a_db3_killed_before_a_checkpoint_replays_every_row_sqlite_returns(
    tmp_path, in_db3, shm, metadata, bare
):
    folder = killed_before_checkpoint(tmp_path / 'bag', 45, in_db3, shm=shm, metadata=metadata)
    db3 = folder / 'bag.db3'
    expected = sqlite_rows(db3)
    assert len(expected) == 45
    assert immutable_rows(db3) == max(in_db3, 0)  # what a reader that ignores the log sees
    before = snapshot(folder)

    with open_source(db3 if bare else folder) as source:
        got = [(m.log_time_ns, bytes(m.data)) for m in source.messages()]
        counts = {t.name: t.count for t in source.topics()}
        warnings = source.warnings
        truncated = source.truncated

    assert got == expected
    assert counts == {CAMERA: 45}
    assert any('bag.db3-wal' in line and 'not closed' in line for line in warnings), warnings
    assert not truncated
    assert snapshot(folder) == before


def test_a_partly_checkpointed_log_replays_the_rows_of_the_db3_and_of_the_log(tmp_path):
    # a reader pinned the snapshot after 10 frames: the checkpoint copied only those pages, and
    # the .db3 alone is not even a consistent database (sqlite sizes it when a checkpoint ends)
    steps = [Step('insert', 10), Step('pin'), Step('insert', 20), Step('checkpoint')]
    steps += [Step('unpin'), Step('insert', 15)]
    folder = write_wal_bag(tmp_path / 'bag', image_payloads(45), steps, shm=False)
    db3 = folder / 'bag.db3'
    assert immutable_rows(db3) < 45
    expected = sqlite_rows(db3)
    assert len(expected) == 45
    assert replayed(folder) == expected


def test_a_replay_window_over_a_write_ahead_log_keeps_the_seq_of_the_whole_bag(tmp_path):
    folder = killed_before_checkpoint(tmp_path / 'bag', 45, 20)
    expected = sqlite_rows(folder / 'bag.db3')
    start, end = T0 + 30 * PERIOD, T0 + 40 * PERIOD
    with open_source(folder) as source:
        got = list(source.messages([CAMERA], start_ns=start, end_ns=end))
    assert [(m.log_time_ns, bytes(m.data)) for m in got] == expected[30:40]
    assert [m.seq for m in got] == list(range(30, 40))


def test_run_replays_all_45_frames_of_a_db3_whose_log_was_not_checkpointed(tmp_path):
    folder = killed_before_checkpoint(tmp_path / 'bag', 45, 32)
    before = snapshot(folder)
    out = tmp_path / 'out'
    args = ['run', str(folder), '--backend', 'null', '--no-report', '--out', str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    rows = camera_rows(out)
    assert [int(r['log_time_ns']) for r in rows] == [t for t, _ in sqlite_rows(folder / 'bag.db3')]
    assert {r['status'] for r in rows} == {'ok'}
    run = json.loads((out / 'run.json').read_text())
    assert run['counts']['frames'] == 45
    assert any('bag.db3-wal' in w for w in run['inputs'][0]['warnings'])
    assert snapshot(folder) == before


def _read_only_prefix() -> list[str]:
    """A command prefix under which read-only permission bits hold (root ignores them)."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which('setpriv')
    if setpriv is None:
        pytest.skip('running as root without setpriv: read-only permissions would not hold')
    return [setpriv, '--bounding-set=-dac_override,-dac_read_search']


@pytest.mark.parametrize('shm', [True, False], ids=['shm', 'no-shm'])
def test_a_db3_with_its_log_in_a_read_only_folder_is_replayed_whole_and_left_untouched(
    tmp_path, shm
):
    folder = killed_before_checkpoint(tmp_path / 'bag', 45, 10, shm=shm)
    for path in folder.iterdir():
        path.chmod(0o444)
    folder.chmod(0o555)
    before = snapshot(folder)
    out = tmp_path / 'out'
    command = [sys.executable, '-m', 'replaybench', 'run', str(folder), '--backend', 'null']
    command += ['--no-report', '--out', str(out)]
    try:
        done = subprocess.run(
            [*_read_only_prefix(), *command],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
    finally:
        folder.chmod(0o755)
    assert done.returncode == 0, done.stderr
    assert 'Traceback' not in done.stderr
    assert len(camera_rows(out)) == 45
    assert snapshot(folder) == before


def test_without_the_unix_none_vfs_a_private_copy_is_read_and_removed(tmp_path, monkeypatch):
    from replaybench.sources import _sqlite

    monkeypatch.setattr(_sqlite, '_VFS', 'no-such-vfs')
    private = tmp_path / 'tmp'
    private.mkdir()
    monkeypatch.setattr(tempfile, 'tempdir', str(private))
    folder = killed_before_checkpoint(tmp_path / 'bag', 45, 5, shm=False)
    before = snapshot(folder)
    with open_source(folder) as source:
        got = [(m.log_time_ns, bytes(m.data)) for m in source.messages()]
        warnings = source.warnings
        assert len(list(private.iterdir())) == 1
    assert got == sqlite_rows(folder / 'bag.db3')
    assert any('private copy' in line for line in warnings), warnings
    assert list(private.iterdir()) == []
    assert snapshot(folder) == before


def test_an_empty_write_ahead_log_is_read_like_no_log(tmp_path):
    folder = killed_before_checkpoint(tmp_path / 'bag', 12, 12, shm=False)
    (folder / 'bag.db3-wal').write_bytes(b'')
    with open_source(folder) as source:
        got = [(m.log_time_ns, bytes(m.data)) for m in source.messages()]
        warnings = source.warnings
    assert got == sqlite_rows(folder / 'bag.db3')
    assert len(got) == 12
    assert not any('-wal' in line for line in warnings)
