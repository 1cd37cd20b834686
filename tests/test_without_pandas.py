"""The default install has no pandas: the command line never imports it, and the Python API's
tables say which extra they need.

pandas is installed in the test environment, so each test runs replaybench in a subprocess
whose ``PYTHONPATH`` starts with a ``pandas`` package that records the attempt and raises
``ImportError``, as a missing package would.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'


@pytest.fixture
def no_pandas(tmp_path: Path) -> tuple[dict[str, str], Path]:
    """An environment in which ``import pandas`` fails, and the file each attempt is logged to."""
    blocker = tmp_path / 'blocker' / 'pandas'
    blocker.mkdir(parents=True)
    log = tmp_path / 'pandas-imports.log'
    (blocker / '__init__.py').write_text(
        'import os, traceback\n'
        "with open(os.environ['PANDAS_IMPORT_LOG'], 'a') as f:\n"
        '    f.write("".join(traceback.format_stack()) + "\\n")\n'
        "raise ImportError('No module named pandas (blocked by the test)')\n",
        encoding='utf-8',
    )
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(blocker.parent), str(REPO), *filter(None, [env.get('PYTHONPATH')])]
    )
    env['PANDAS_IMPORT_LOG'] = str(log)
    return env, log


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


def test_the_blocker_makes_pandas_unimportable(no_pandas: tuple[dict[str, str], Path]) -> None:
    env, log = no_pandas
    done = subprocess.run(
        [sys.executable, '-c', 'import pandas'],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 1
    assert 'blocked by the test' in done.stderr
    assert log.exists()


def test_run_info_compare_and_report_work_without_pandas(
    no_pandas: tuple[dict[str, str], Path], tmp_path: Path
) -> None:
    env, log = no_pandas
    a, b = tmp_path / 'a', tmp_path / 'b'
    for out in (a, b):
        done = _replaybench(env, 'run', BAG, '--backend', 'hsv', '--backend', 'null', '--out', out)
        assert done.returncode == 0, done.stderr
        assert (out / 'frames.csv').is_file()
        assert (out / 'report.html').is_file()
    done = _replaybench(env, 'info', BAG)
    assert done.returncode == 0, done.stderr
    done = _replaybench(env, 'compare', a, b)
    assert done.returncode == 0, done.stderr
    assert 'hsv' in done.stdout
    done = _replaybench(env, 'compare', a, b, '--out', tmp_path / 'cmp')
    assert done.returncode == 0, done.stderr
    assert (tmp_path / 'cmp' / 'comparison.csv').is_file()
    (a / 'report.html').unlink()
    done = _replaybench(env, 'report', a)
    assert done.returncode == 0, done.stderr
    assert (a / 'report.html').is_file()
    assert not log.exists(), log.read_text(encoding='utf-8')


_API = """
import replaybench as rb
from replaybench.errors import MissingDependencyError

res = rb.run({bag!r}, backends=['hsv', 'null'], max_frames=4)
print('status', res.status, len(res.frame_records), len(res.summary_rows))
cmp = rb.compare(res, res)
print('rows', len(cmp.table_rows), cmp.table_columns[:2])
for name, get in [('frames', lambda: res.frames), ('summary', lambda: res.summary),
                  ('table', lambda: cmp.table)]:
    try:
        get()
    except MissingDependencyError as err:
        assert isinstance(err, ImportError)
        print(name, 'raises:', err)
"""


def test_the_api_runs_without_pandas_and_its_tables_name_the_extra(
    no_pandas: tuple[dict[str, str], Path],
) -> None:
    env, _ = no_pandas
    done = subprocess.run(
        [sys.executable, '-c', _API.format(bag=str(BAG))],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == 'status complete 8 2'
    assert lines[1] == "rows 4 ('run', 'run_index')"  # 2 runs x 2 backends
    hint = "pip install 'replaybench[pandas]'"
    assert [ln.split(' raises: ')[0] for ln in lines[2:]] == ['frames', 'summary', 'table']
    assert all(ln.endswith(hint) for ln in lines[2:]), lines
