"""``replaybench --debug``: a one-line error also shows the traceback of what caused it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

BAG = Path(__file__).resolve().parents[1] / 'fixtures' / 'bags' / 'bgr8_rosbag2'


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', *args],
        capture_output=True,
        text=True,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
        timeout=300,
        check=False,
    )


@pytest.fixture
def broken_bag(tmp_path: Path) -> Path:
    """A rosbag2 folder whose metadata.yaml does not parse (the YAML parser's error is the
    cause of the SourceError)."""
    bag = tmp_path / 'bag'
    shutil.copytree(BAG, bag)
    (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: [unclosed\n')
    return bag


def test_a_bad_input_with_debug_prints_the_cause_traceback_then_the_one_line(
    broken_bag: Path, tmp_path: Path
) -> None:
    result = _cli('--debug', 'run', str(broken_bag), '-b', 'hsv', '--out', str(tmp_path / 'run'))
    assert result.returncode == 2
    assert result.stdout == ''
    assert 'Traceback (most recent call last):' in result.stderr
    assert 'The above exception was the direct cause of the following exception' in result.stderr
    assert 'ruamel.yaml' in result.stderr  # the parser's error, chained to the SourceError
    last = result.stderr.splitlines()[-1]
    assert last.startswith('replaybench: error: ')
    assert 'metadata.yaml: not valid rosbag2 metadata' in last
    assert not (tmp_path / 'run').exists()


def test_a_bad_input_without_debug_prints_the_one_line_only(
    broken_bag: Path, tmp_path: Path
) -> None:
    result = _cli('run', str(broken_bag), '-b', 'hsv', '--out', str(tmp_path / 'run'))
    assert result.returncode == 2
    assert 'Traceback' not in result.stderr
    (line,) = result.stderr.splitlines()
    assert line.startswith('replaybench: error: ')
    assert 'metadata.yaml: not valid rosbag2 metadata' in line
