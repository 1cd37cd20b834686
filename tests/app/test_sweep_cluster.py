"""A sweep joining a two-node Ray cluster on this machine (`ray start --head` and
`ray start --address`, one node slot each, token authentication), through the CLI."""

from __future__ import annotations

import itertools
import json
import os
import secrets
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


class Cluster:
    def __init__(self, address: str, token: str, home: Path) -> None:
        self.address = address
        self.token = token
        self.home = home


def _free_port() -> int:
    with socket.socket() as s:
        s.bind((NODE_IP, 0))
        return int(s.getsockname()[1])


def _node_count(address: str, env: dict[str, str]) -> int:
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
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cluster]:
    """Two Ray nodes on this machine, each with one ``replaybench_timed_slot`` and one CPU.

    The nodes run under ``ray start --block``: the finalizer ends those two processes (by
    their id), which stops each node's processes; ``ray stop`` would also stop every other
    Ray instance of this machine.
    """
    pytest.importorskip('ray', reason='the sweep extra (Ray) is not installed')
    home = tmp_path_factory.mktemp('home')
    temp = tempfile.mkdtemp(prefix='rb-ray-')  # Ray's socket paths must stay < 108 chars
    token = secrets.token_hex(32)
    env = {
        **os.environ,
        'HOME': str(home),
        'RAY_AUTH_MODE': 'token',
        'RAY_AUTH_TOKEN': token,
        'RAY_USAGE_STATS_ENABLED': '0',
    }
    port = _free_port()
    address = f'{NODE_IP}:{port}'
    common = [
        '--block',
        '--node-ip-address',
        NODE_IP,
        '--num-cpus',
        '1',
        '--num-gpus',
        '0',
        '--resources',
        '{"replaybench_timed_slot": 1}',
        '--disable-usage-stats',
    ]
    logs = Path(temp)
    nodes: list[subprocess.Popen[bytes]] = []
    try:
        with (logs / 'head.log').open('wb') as log:
            head = [
                str(RAY),
                'start',
                '--head',
                '--port',
                str(port),
                '--include-dashboard',
                'false',
            ]
            nodes.append(
                subprocess.Popen(
                    [*head, '--temp-dir', temp, *common],
                    env=env,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,
                )
            )
        deadline = time.monotonic() + 120
        while _node_count(address, env) < 1:
            assert time.monotonic() < deadline, (logs / 'head.log').read_text()[-2000:]
            time.sleep(1)
        with (logs / 'worker.log').open('wb') as log:
            nodes.append(
                subprocess.Popen(
                    [str(RAY), 'start', '--address', address, *common],
                    env=env,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,
                )
            )
        while _node_count(address, env) < 2:
            assert time.monotonic() < deadline, (logs / 'worker.log').read_text()[-2000:]
            time.sleep(1)
        yield Cluster(address, token, home)
    finally:
        for node in reversed(nodes):
            node.send_signal(signal.SIGTERM)
        for node in reversed(nodes):
            try:
                node.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(node.pid, signal.SIGKILL)
                node.wait()
        shutil.rmtree(temp, ignore_errors=True)


def test_a_sweep_joining_a_two_node_cluster_spreads_its_cells_over_both_nodes(
    cluster: Cluster, bags: dict[str, Path], tmp_path: Path
) -> None:
    home = tmp_path / 'home'
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith('RAY_')}
    # the token at hand, RAY_AUTH_MODE unset: the sweep joins in token mode by itself
    env |= {'HOME': str(home), 'RAY_AUTH_TOKEN': cluster.token}
    out = tmp_path / 'sw'
    args = [str(bags['a']), str(bags['b']), '--backend', 'null', '--backend', 'hsv']
    args += ['--address', cluster.address, '--out', str(out), '--max-frames', '20']
    args += ['--param', 'hsv.min_area=50,100']
    proc = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'sweep', *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert 'Traceback' not in proc.stderr
    assert '6 of 6 cells complete' in proc.stdout
    record = json.loads((out / 'sweep.json').read_text(encoding='utf-8'))
    engine = record['engine']
    assert engine['mode'] == 'cluster'
    assert engine['address'] == cluster.address
    assert engine['auth_mode'] == 'token'
    assert engine['resources']['replaybench_timed_slot'] == 2.0
    assert engine['resources']['CPU'] == 2.0
    node_ids = {n['node_id'] for n in engine['nodes'] if n['alive']}
    assert len(node_ids) == 2
    assert engine['head_node_id'] in node_ids
    cells = record['cells']
    assert len(cells) == 6
    assert {c['status'] for c in cells} == {'complete'}
    assert {c['node_id'] for c in cells} == node_ids  # both nodes ran cells
    for cell in cells:
        run = json.loads((out / cell['run_dir'] / 'run.json').read_text(encoding='utf-8'))
        assert run['sweep']['node_id'] == cell['node_id']
        assert run['sweep']['node_ip'] == '127.0.0.2'
        assert run['sweep']['concurrency']['max_cells_on_node'] == 1
    # at most one cell per node at a time
    spans = {
        node: sorted((c['started_at'], c['finished_at']) for c in cells if c['node_id'] == node)
        for node in node_ids
    }
    for mine in spans.values():
        assert all(a[1] <= b[0] for a, b in itertools.pairwise(mine))
    assert not (home / '.ray').exists()
