"""Inputs that are not bags at all: FIFOs, character devices and folders without a bag.

A FIFO with no writer blocks ``open`` forever and ``/dev/zero`` never ends, so the file type
is checked before anything is opened. ``run`` and ``info`` are run as real processes with a
timeout: a hang fails the test instead of stalling the suite.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from replaybench.errors import SourceError
from replaybench.sources import open_source

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, 'PYTHONWARNINGS': 'ignore'}
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=10,
        check=False,
        cwd=REPO,
    )


def _fifo(tmp_path: Path) -> Path:
    path = tmp_path / 'camera.mcap'
    os.mkfifo(path)
    return path


def _empty_folder(tmp_path: Path) -> Path:
    path = tmp_path / 'no_bag_here'
    path.mkdir()
    return path


def _folder_of_notes(tmp_path: Path) -> Path:
    path = tmp_path / 'notes'
    path.mkdir()
    (path / 'readme.txt').write_text('not a bag\n')
    return path


def _fifo_named_metadata(tmp_path: Path) -> Path:
    path = tmp_path / 'bag' / 'metadata.yaml'
    path.parent.mkdir()
    os.mkfifo(path)
    return path


def _link_to_fifo(tmp_path: Path) -> Path:
    link = tmp_path / 'link.bag'
    link.symlink_to(_fifo(tmp_path))
    return link


INPUTS = {
    'fifo': (_fifo, 'is a FIFO, not a regular file'),
    'fifo-named-metadata.yaml': (_fifo_named_metadata, 'is a FIFO, not a regular file'),
    'link-to-a-fifo': (_link_to_fifo, 'is a FIFO, not a regular file'),
    'dev-null': (lambda _: Path('/dev/null'), 'is a character device, not a regular file'),
    'dev-zero': (lambda _: Path('/dev/zero'), 'is a character device, not a regular file'),
    'empty-folder': (_empty_folder, 'no bag in this folder'),
    'folder-without-a-bag': (_folder_of_notes, 'no bag in this folder'),
}


def _command(name: str, path: Path, tmp_path: Path) -> list[str]:
    if name == 'info':
        return ['info', str(path)]
    return ['run', str(path), '--backend', 'null', '--out', str(tmp_path / 'run'), '--no-report']


@pytest.mark.parametrize('command', ['run', 'info'])
@pytest.mark.parametrize('kind', list(INPUTS))
def test_a_path_that_is_not_a_bag_exits_2_at_once_with_one_line(tmp_path, command, kind):
    make, reason = INPUTS[kind]
    path = make(tmp_path)
    result = _cli(*_command(command, path, tmp_path))
    assert result.returncode == 2, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith('replaybench: error: ')
    assert reason in lines[0]
    assert str(path) in lines[0] or str(path.parent) in lines[0]
    assert 'Traceback' not in result.stderr
    assert result.stdout == ''
    assert not (tmp_path / 'run').exists()


def test_a_fifo_between_real_bags_stops_the_run_before_anything_is_written(tmp_path):
    result = _cli(
        'run', str(RAW), str(_fifo(tmp_path)), '--backend', 'null', '--out', str(tmp_path / 'run')
    )
    assert result.returncode == 2
    assert result.stderr.count('\n') == 1
    assert 'is a FIFO, not a regular file' in result.stderr
    assert not (tmp_path / 'run').exists()


def test_open_source_names_a_character_device_without_reading_it():
    with pytest.raises(SourceError, match='is a character device, not a regular file') as info:
        open_source('/dev/zero')
    assert '\n' not in str(info.value)
    assert info.value.__cause__ is None


def test_a_regular_bag_behind_a_symlink_still_opens(tmp_path):
    link = tmp_path / 'cam.mcap'
    link.symlink_to(RAW)
    with open_source(link) as source:
        assert source.format == 'mcap'
        assert source.topics()
