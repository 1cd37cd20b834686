"""A sweep joining a plain Ray cluster as it is: one `ray start --head` node started here with
two CPUs, no custom resource and no authentication, as KubeRay, `ray up` or a lab head node
would be. Timed cells still get the node to themselves (all its CPUs, node affinity), one at a
time, and a rosbag2 folder's sha256 in sweep.json is the one its cells' run.json record."""

from __future__ import annotations

import itertools
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from collections.abc import Iterator

pytestmark = pytest.mark.skipif(sys.platform != 'linux', reason='loopback address 127.0.0.2')

RAY = Path(sys.executable).with_name('ray')
NODE_IP = '127.0.0.2'  # loopback (Ray maps 127.0.0.1 itself to the machine's network address)


def _env(home: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith('RAY_')}
    return {**env, 'HOME': str(home), 'RAY_USAGE_STATS_ENABLED': '0'}


def _alive(address: str, env: dict[str, str]) -> int:
    code = (
        'import logging, ray\n'
        f'ray.init(address={address!r}, logging_level=logging.ERROR)\n'
        'print(sum(1 for n in ray.nodes() if n["Alive"]))\n'
    )
    proc = subprocess.run(
        [sys.executable, '-c', code], env=env, capture_output=True, text=True, timeout=120
    )
    return int(proc.stdout.strip() or 0)


@pytest.fixture(scope='module')
def plain_head(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """`ray start --head --num-cpus 2` and nothing else; its address. The node runs under
    ``--block``: ending that process (by its id) stops it, never another Ray of this machine."""
    pytest.importorskip('ray', reason='the sweep extra (Ray) is not installed')
    home = tmp_path_factory.mktemp('home')
    temp = tempfile.mkdtemp(prefix='rb-ray-')  # Ray's socket paths must stay < 108 chars
    with socket.socket() as s:
        s.bind((NODE_IP, 0))
        port = int(s.getsockname()[1])
    address = f'{NODE_IP}:{port}'
    env = _env(home)
    log = Path(temp) / 'head.log'
    command = [str(RAY), 'start', '--head', '--block', '--port', str(port)]
    command += ['--node-ip-address', NODE_IP, '--num-cpus', '2', '--num-gpus', '0']
    command += ['--include-dashboard', 'false', '--disable-usage-stats', '--temp-dir', temp]
    with log.open('wb') as out:
        head = subprocess.Popen(
            command, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
        )
    try:
        deadline = time.monotonic() + 120
        while _alive(address, env) < 1:
            assert head.poll() is None, log.read_text()[-2000:]
            assert time.monotonic() < deadline, log.read_text()[-2000:]
            time.sleep(1)
        yield address
    finally:
        head.send_signal(signal.SIGTERM)
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(head.pid, signal.SIGKILL)
            head.wait()
        shutil.rmtree(temp, ignore_errors=True)


def test_a_sweep_runs_on_a_plain_cluster_one_timed_cell_at_a_time_holding_the_whole_node(
    plain_head: str, bags: dict[str, Path], tmp_path: Path
) -> None:
    from replaybench.fixtures.writer import write_rosbag2

    folder = write_rosbag2(tmp_path / 'bag2', frames=12, size=(64, 48))
    out = tmp_path / 'sw'
    args = [str(bags['a']), str(folder), '--backend', 'null', '--backend', 'hsv']
    args += ['--address', plain_head, '--out', str(out), '--max-frames', '10', '--no-report']
    proc = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'sweep', *args],
        env=_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert 'Traceback' not in proc.stderr
    assert '4 of 4 cells complete' in proc.stdout
    record = json.loads((out / 'sweep.json').read_text(encoding='utf-8'))
    engine = record['engine']
    assert engine['mode'] == 'cluster'
    assert engine['auth_mode'] == 'disabled'
    assert 'replaybench_timed_slot' not in engine['resources']
    assert engine['resources']['CPU'] == 2.0
    assert engine['placement']['cpu_cells'] == (
        "one timed cell per node (all the node's CPUs, node affinity)"
    )
    cells = record['cells']
    assert {c['status'] for c in cells} == {'complete'}
    spans = sorted((c['started_at'], c['finished_at']) for c in cells)
    assert all(a[1] <= b[0] for a, b in itertools.pairwise(spans))  # never two at once
    by_input = {i['path']: i for i in record['inputs']}
    for cell in cells:
        run = json.loads((out / cell['run_dir'] / 'run.json').read_text(encoding='utf-8'))
        assert run['sweep']['concurrency'] == {'limit_per_node': 1, 'max_cells_on_node': 1}
        assert run['sweep']['placement'] == 'node-slot'
        # one definition of the digest: sweep.json and run.json agree, folder included
        assert run['inputs'][0]['sha256'] == by_input[cell['input']]['sha256']
        assert run['inputs'][0]['size_bytes'] == by_input[cell['input']]['size_bytes']
        assert not any('sha256' in w for w in run['inputs'][0]['warnings'])
    assert not (tmp_path / '.ray').exists()
