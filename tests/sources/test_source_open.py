from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from typing import TYPE_CHECKING

import pytest
from sourcebags import tie_plan, write_bag, write_mcap, write_rosbag2

from replaybench.errors import SourceError
from replaybench.sources import STORAGE_PLUGINS, Source, open_source

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

# -- unreadable inputs --------------------------------------------------------------------


def _assert_one_line_error(path: Path, pattern: str) -> SourceError:
    with pytest.raises(SourceError, match=pattern) as info:
        open_source(path)
    err = info.value
    assert '\n' not in str(err)
    assert str(path) in str(err)
    # what failed underneath is chained for `replaybench --debug`, never a second SourceError
    assert not isinstance(err.__cause__, SourceError)
    return err


def test_a_missing_path_is_a_source_error(tmp_path: Path) -> None:
    _assert_one_line_error(tmp_path / 'nothing.mcap', 'no such file')


@pytest.mark.parametrize('name', ['empty.mcap', 'empty.bag', 'empty.db3', 'empty'])
def test_an_empty_file_is_a_source_error(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.touch()
    _assert_one_line_error(path, 'empty')


@pytest.mark.parametrize(
    ('name', 'pattern'),
    [
        ('noise.mcap', 'not an MCAP file'),
        ('noise.bag', 'not a ROS 1 bag'),
        ('noise.db3', 'not a rosbag2 .db3'),
        ('noise.xyz', 'unrecognised format'),
    ],
)
def test_random_bytes_are_a_source_error(tmp_path: Path, name: str, pattern: str) -> None:
    path = tmp_path / name
    path.write_bytes(os.urandom(5000).replace(b'\x89', b'\x00'))
    _assert_one_line_error(path, pattern)


def test_a_text_file_named_mcap_is_a_source_error(tmp_path: Path) -> None:
    path = tmp_path / 'notes.mcap'
    path.write_text('these are not the frames you are looking for\n' * 20)
    _assert_one_line_error(path, 'not an MCAP file')


def test_a_directory_without_metadata_whose_db3_is_no_database_is_a_source_error(
    tmp_path: Path,
) -> None:
    (tmp_path / 'some.db3').write_bytes(b'SQLite format 3\x00')
    err = _assert_one_line_error(tmp_path, 'some.db3: .*not a database')
    assert err.__cause__ is not None  # the SQLite library's own error


def test_an_sqlite_file_that_is_no_rosbag2_is_a_source_error(tmp_path: Path) -> None:
    import sqlite3

    path = tmp_path / 'other.db3'
    with sqlite3.connect(path) as db:
        db.execute('CREATE TABLE things (x INTEGER)')
    db.close()
    err = _assert_one_line_error(path, 'cannot read rosbag2')
    assert err.__cause__ is not None  # the reader's own error


def test_a_zstd_compressed_bag_file_points_to_its_directory(tmp_path: Path) -> None:
    path = tmp_path / 'bag_0.mcap.zstd'
    path.write_bytes(b'\x28\xb5\x2f\xfd' + bytes(50))
    _assert_one_line_error(path, 'rosbag2 directory')


# -- dispatch -----------------------------------------------------------------------------


def test_storage_plugins_are_keyed_by_suffix() -> None:
    assert set(STORAGE_PLUGINS) == {'.mcap', '.db3', '.bag', ''}


@pytest.mark.parametrize(
    ('writer', 'fmt'),
    [
        (lambda p: write_mcap(p, tie_plan(4)), 'mcap'),
        (lambda p: write_bag(p, tie_plan(4)), 'rosbag1'),
    ],
)
def test_content_decides_the_reader_whatever_the_suffix(
    tmp_path: Path, writer: Callable[[Path], Path], fmt: str
) -> None:
    path = writer(tmp_path / 'recording.log')
    with open_source(path) as source:
        assert source.format == fmt
        assert len(list(source.messages())) == len(tie_plan(4))


def test_the_metadata_file_opens_its_bag_directory(tmp_path: Path) -> None:
    path = write_rosbag2(tmp_path / 'bag', tie_plan(4), 'sqlite3')
    with open_source(str(path / 'metadata.yaml')) as source:
        assert source.path == path
        assert source.format == 'rosbag2'


def test_every_source_satisfies_the_protocol(tmp_path: Path) -> None:
    paths = [
        write_mcap(tmp_path / 'a.mcap', tie_plan(3)),
        write_bag(tmp_path / 'b.bag', tie_plan(3)),
        write_rosbag2(tmp_path / 'c', tie_plan(3), 'sqlite3'),
        write_rosbag2(tmp_path / 'd', tie_plan(3), 'mcap'),
    ]
    for path in paths:
        source: Source = open_source(path)
        with source as entered:
            assert entered is source
            assert isinstance(source.warnings, list)
            assert source.truncated is False
            assert all(f.is_file() for f in source.files)
        with pytest.raises(SourceError, match='closed'):
            source.topics()


def test_importing_the_package_loads_no_reader_library() -> None:
    code = (
        'import sys, replaybench.sources as s; '
        "print(sorted(m for m in sys.modules if m.split('.')[0] in "
        "('mcap', 'rosbags', 'numpy', 'zstandard', 'lz4', 'ruamel')))"
    )
    out = subprocess.run(
        [sys.executable, '-c', code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == '[]'


# -- read-only ----------------------------------------------------------------------------

_OPENED: list[tuple[str, object, object]] = []
_WATCH: list[str] = []


def _audit(event: str, args: tuple[object, ...]) -> None:
    if event == 'open' and _WATCH and isinstance(args[0], str | bytes | os.PathLike):
        name = os.fsdecode(args[0])
        if name.startswith(_WATCH[0]):
            _OPENED.append((name, args[1], args[2]))


sys.addaudithook(_audit)


def _snapshot(root: Path) -> dict[str, tuple[int, int, str]]:
    return {
        str(p): (p.stat().st_mode, p.stat().st_mtime_ns, hashlib.sha256(p.read_bytes()).hexdigest())
        for p in sorted(root.rglob('*'))
        if p.is_file()
    }


def test_inputs_are_only_ever_opened_read_only(tmp_path: Path) -> None:
    plan = tie_plan(10)
    inputs = tmp_path / 'inputs'
    inputs.mkdir()
    paths = [
        write_mcap(inputs / 'a.mcap', plan, 'zstd', 300),
        write_bag(inputs / 'b.bag', plan, 'lz4', 300),
        write_rosbag2(inputs / 'c', plan, 'sqlite3'),
        write_rosbag2(inputs / 'd', plan, 'mcap'),
    ]
    cut = inputs / 'cut.mcap'
    cut.write_bytes(paths[0].read_bytes()[:-100])
    paths.append(cut)
    for p in inputs.rglob('*'):
        p.chmod(0o555 if p.is_dir() else 0o444)
    before = _snapshot(inputs)
    _OPENED.clear()
    _WATCH[:] = [str(inputs)]
    try:
        for path in paths:
            with open_source(path) as source:
                assert len(list(source.messages())) == len(plan)
                source.topics()
                list(source.messages(topics=['/a'], start_ns=plan[5][1]))
    finally:
        _WATCH.clear()
        after = _snapshot(inputs)
        for p in inputs.rglob('*'):
            p.chmod(0o755 if p.is_dir() else 0o644)
    assert after == before  # same files (no journal / wal), modes, mtimes and contents
    assert _OPENED, 'the audit hook saw no open() at all'
    for name, mode, flags in _OPENED:
        if isinstance(mode, str):
            assert set(mode) <= {'r', 'b', 't'}, (name, mode)
        if isinstance(flags, int):
            assert flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC) == 0, (name, flags)
