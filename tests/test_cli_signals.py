"""Ctrl-C and SIGTERM sent to a real `replaybench run` process."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bagtools import image_msg, noise_frames, write_mcap

pytestmark = pytest.mark.skipif(sys.platform == 'win32', reason='POSIX signals')

NS = 1_000_000_000
FRAMES = 300  # 10 s at the recorded rate: the signals always arrive mid-replay


def _bag(path: Path) -> Path:
    frames = noise_frames(12)
    t0 = 1_700_000_000 * NS
    write_mcap(
        path,
        [
            (
                '/cam/image_raw',
                t0 + i * NS // 30,
                image_msg(t0 + i * NS // 30, frames[i % 12]),
                'sensor_msgs/msg/Image',
            )
            for i in range(FRAMES)
        ],
    )
    return path


def _start(tmp_path: Path, *args: str, backend: str = 'null') -> subprocess.Popen[str]:
    """`replaybench run` at the recorded rate; returns once the replay has begun."""
    bag = _bag(tmp_path / 'cam.mcap')
    out = tmp_path / 'run'
    # a backend whose close() takes a minute, registered the way a built-in one is
    (tmp_path / 'slowclose.py').write_text(
        textwrap.dedent(
            """
            import time
            from replaybench.backends.null import NullBackend

            class SlowClose(NullBackend):
                name = 'slow-close'

                def close(self):
                    time.sleep(60)
            """
        )
    )
    driver = textwrap.dedent(
        f"""
        import sys
        sys.path.insert(0, {str(tmp_path)!r})
        from replaybench.backends import BUILTIN_BACKENDS
        BUILTIN_BACKENDS['slow-close'] = 'slowclose:SlowClose'
        from replaybench.cli import main
        sys.argv = ['replaybench', *sys.argv[1:]]
        main()
        """
    )
    command = ['run', str(bag), '--backend', backend, '--rate', 'recorded', '--out', str(out)]
    process = subprocess.Popen(
        [sys.executable, '-c', driver, *command, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
    )
    deadline = time.monotonic() + 60
    # the run is written beside --out and swapped in when it ends
    while not list(tmp_path.glob('.run.tmp-*/frames.csv.part')):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, 'the run did not start'
        time.sleep(0.05)
    time.sleep(1.0)  # about 30 frames replayed
    return process


def _finish(process: subprocess.Popen[str], within_s: float) -> tuple[int, str]:
    began = time.monotonic()
    _, stderr = process.communicate(timeout=within_s + 30)
    assert time.monotonic() - began < within_s, 'the process did not stop promptly'
    return process.returncode, stderr


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT], ids=['SIGTERM', 'Ctrl-C'])
def test_an_interrupt_ends_the_run_with_outputs_finalized_and_exit_130(tmp_path, sig):
    from mcap.reader import make_reader

    process = _start(tmp_path)
    process.send_signal(sig)
    code, stderr = _finish(process, within_s=20)
    assert code == 130
    assert 'Traceback' not in stderr
    assert 'interrupted' in stderr
    out = tmp_path / 'run'
    run = json.loads((out / 'run.json').read_text())
    assert run['status'] == 'interrupted'
    with (out / 'frames.csv').open(newline='') as f:
        rows = list(csv.DictReader(f))
    assert 0 < len(rows) < FRAMES
    assert [int(row['seq']) for row in rows] == list(range(len(rows)))
    with (out / 'outputs.mcap').open('rb') as f:
        messages = [m for _, ch, m in make_reader(f).iter_messages() if 'replaybench' in ch.topic]
    assert len(messages) == len(rows)
    assert (out / 'report.html').is_file()
    assert not list(out.glob('*.part'))
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'run', 'slowclose.py']


def test_a_second_ctrl_c_stops_at_once_without_waiting_for_the_outputs(tmp_path):
    process = _start(tmp_path, backend='slow-close')
    process.send_signal(signal.SIGINT)
    time.sleep(1.0)  # the replay has ended; the backend is closing (for a minute)
    assert process.poll() is None
    process.send_signal(signal.SIGINT)
    code, stderr = _finish(process, within_s=20)
    assert code == 130
    assert 'Traceback' not in stderr
    assert 'interrupted again' in stderr
    # unfinished outputs are not kept: no run folder, nothing beside it
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'slowclose.py']
