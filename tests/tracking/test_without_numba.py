"""Without the tracking extra's Numba, a tracked backend is refused in one line naming the
extra (exit 2), and the untracked rows of the same command line are not what fails.

Numba is installed in the test environment, so the runs are subprocesses whose ``PYTHONPATH``
starts with a ``numba`` package that raises ``ImportError``, as a missing package would.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'fixtures' / 'bags' / 'jpeg.mcap'


@pytest.fixture
def no_numba(tmp_path: Path) -> dict[str, str]:
    blocker = tmp_path / 'blocker' / 'numba'
    blocker.mkdir(parents=True)
    (blocker / '__init__.py').write_text(
        "raise ImportError('No module named numba (blocked by the test)')\n", encoding='utf-8'
    )
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(blocker.parent), str(REPO), *filter(None, [env.get('PYTHONPATH')])]
    )
    return env


def _replaybench(env: dict[str, str], *args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', *map(str, args)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


def test_a_tracker_without_numba_is_one_line_naming_the_extra_and_exit_2(
    no_numba: dict[str, str], tmp_path: Path
) -> None:
    done = _replaybench(
        no_numba, 'run', BAG, '--backend', 'hsv', '--tracker', 'sort', '--out', tmp_path / 'run'
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert lines[-1].startswith('replaybench: error: the trackers need Numba')
    assert 'pip install "replaybench[tracking]"' in lines[-1]
    assert 'Traceback' not in done.stderr


def test_the_same_run_without_a_tracker_needs_no_numba(
    no_numba: dict[str, str], tmp_path: Path
) -> None:
    done = _replaybench(
        no_numba,
        'run',
        BAG,
        '--backend',
        'hsv',
        '--max-frames',
        '5',
        '--out',
        tmp_path / 'run',
        '--no-report',
    )
    assert done.returncode == 0, done.stderr
    assert (tmp_path / 'run' / 'summary.csv').is_file()
