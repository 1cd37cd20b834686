"""`replaybench sweep` as a real process: its output and exit status with a failed cell, and
Ctrl-C in the middle of a sweep followed by a resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = pytest.mark.skipif(sys.platform == 'win32', reason='POSIX signals')


def _env(home: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith('RAY_')}
    return {**env, 'HOME': str(home)}


def test_a_failed_cell_gives_exit_1_one_line_per_failed_cell_and_leaves_no_ray_token(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    pytest.importorskip('ray', reason='the sweep extra (Ray) is not installed')
    out = tmp_path / 'sw'
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'replaybench',
            'sweep',
            str(bags['a']),
            str(bags['corrupt']),
            '--backend',
            'null',
            '--max-frames',
            '10',
            '--out',
            str(out),
        ],
        env=_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 1, proc.stderr[-3000:]
    errors = [line for line in proc.stderr.splitlines() if line.startswith('replaybench: error:')]
    assert len(errors) == 1, proc.stderr
    assert errors[0].startswith('replaybench: error: cell corrupt.null-')
    assert f'failed: {bags["corrupt"].resolve()}: ' in errors[0]
    assert 'Traceback' not in proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].split() == [
        'input',
        'backend',
        'params',
        'status',
        'fps',
        'p50',
        'ms',
        'p99',
        'ms',
        'mAP@.5',
        'node',
    ]
    assert lines[1].split()[:4] == ['a.mcap', 'null', '-', 'complete']
    assert lines[2].split()[:4] == ['corrupt.mcap', 'null', '-', 'failed']
    assert '1 of 2 cells complete (0 kept from an earlier run), 1 failed' in proc.stdout
    assert f'Report: {out / "sweep.html"}' in proc.stdout
    # the local instance ran with a token of its own: nothing in the home folder
    assert not (tmp_path / '.ray').exists()
    record = json.loads((out / 'sweep.json').read_text(encoding='utf-8'))
    assert record['command'][:2] == ['replaybench', 'sweep']
    assert record['engine']['mode'] == 'local'
    assert record['engine']['auth_mode'] == 'token'
    assert record['engine']['address'].startswith('127.0.0.2:')


def test_ctrl_c_stops_the_sweep_keeps_complete_cells_and_the_same_command_resumes(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    pytest.importorskip('ray', reason='the sweep extra (Ray) is not installed')
    out = tmp_path / 'sw'
    command = [
        sys.executable,
        '-m',
        'replaybench',
        'sweep',
        str(bags['a']),
        '--backend',
        'busy',
        '--param',
        'busy.busy_ms=100,101,102',
        '--max-frames',
        '30',
        '--out',
        str(out),
    ]
    process = subprocess.Popen(
        command,
        env=_env(tmp_path),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 300
        while not [p for p in (out / 'cells').glob('*') if not p.name.startswith('.')]:
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, 'no cell finished in time'
            time.sleep(0.1)
        process.send_signal(signal.SIGINT)
        _stdout, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == 130, stderr[-3000:]
    assert 'Traceback' not in stderr
    assert 'replaybench: interrupted: complete cells are kept; run again to resume' in stderr
    record = json.loads((out / 'sweep.json').read_text(encoding='utf-8'))
    assert record['status'] == 'interrupted'
    statuses = [c['status'] for c in record['cells']]
    assert statuses[0] == 'complete'
    assert 'complete' in statuses
    assert 'interrupted' in statuses
    done = [c for c in record['cells'] if c['status'] == 'complete']
    kept = {c['cell']: (out / c['run_dir'] / 'run.json').read_bytes() for c in done}
    assert not list((out / 'cells').glob('.*'))

    again = subprocess.run(
        command, env=_env(tmp_path), capture_output=True, text=True, timeout=600, check=False
    )
    assert again.returncode == 0, again.stderr[-3000:]
    record = json.loads((out / 'sweep.json').read_text(encoding='utf-8'))
    assert record['status'] == 'complete'
    assert [c['status'] for c in record['cells']] == ['complete'] * 3
    assert record['counts']['resumed'] == len(kept)
    for cell in record['cells']:
        if cell['cell'] in kept:
            assert cell['resumed'] is True
            assert (out / cell['run_dir'] / 'run.json').read_bytes() == kept[cell['cell']]
        else:
            assert cell['resumed'] is False
