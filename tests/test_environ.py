"""Importing replaybench and calling its API leave ``os.environ`` exactly as they found it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'

# a fresh interpreter: threadpoolctl and OpenCV set their variables when they first load
_SCRIPT = """
import json, os, sys, tempfile
from pathlib import Path

changes = {}

def check(step):
    now = dict(os.environ)
    diff = {k: now.get(k) for k in set(now) | set(before) if now.get(k) != before.get(k)}
    if diff:
        changes[step] = diff

before = dict(os.environ)
import replaybench as rb
check('import replaybench')
out = Path(tempfile.mkdtemp())
run = rb.run(sys.argv[1], backends=['hsv', 'onnx-cpu'], threads=1, max_frames=6)
check('rb.run in memory, --threads 1')
rb.run(sys.argv[1], backends=['null'], out=out / 'run', report=True, max_frames=6)
check('rb.run into a folder')
rb.load_run(out / 'run')
check('rb.load_run')
rb.compare(out / 'run', run)
check('rb.compare')
rb.peak(sys.argv[1], backend='null', max_hz=40, refine_steps=0, threads=1)
check('rb.peak')
print(json.dumps(changes))
"""


def test_importing_replaybench_and_every_api_call_leave_the_environment_as_found() -> None:
    env = {
        k: v for k, v in os.environ.items() if k not in {'KMP_DUPLICATE_LIB_OK', 'LD_LIBRARY_PATH'}
    }
    env['PYTHONPATH'] = str(REPO)
    proc = subprocess.run(
        [sys.executable, '-c', _SCRIPT, str(RAW)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout.splitlines()[-1]) == {}


def test_a_block_that_changes_the_environment_is_undone_when_it_ends() -> None:
    from replaybench._environ import kept_environ

    os.environ['REPLAYBENCH_TEST_KEPT'] = 'before'
    try:
        with kept_environ():
            os.environ['REPLAYBENCH_TEST_KEPT'] = 'changed'
            os.environ['REPLAYBENCH_TEST_ADDED'] = 'added'
            del os.environ['REPLAYBENCH_TEST_KEPT']
        assert os.environ['REPLAYBENCH_TEST_KEPT'] == 'before'
        assert 'REPLAYBENCH_TEST_ADDED' not in os.environ
    finally:
        os.environ.pop('REPLAYBENCH_TEST_KEPT', None)
