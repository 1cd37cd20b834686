"""Item g: ``replaybench sweep`` on Ray against the same runs one after another.

Workload: ``inputs`` generated JPEG bags x two backends (hsv and onnx-cpu), ``--threads 1``,
no report: one cell is one ``run_benchmark`` of one bag through one backend.

* sequential: the cells as ``run_benchmark`` calls back to back in this process (no process
  start, models loaded again per cell as in a run), and as ``replaybench run`` processes one
  after another (what a shell loop does);
* sweep --pack on two Ray nodes: a cluster of two ``ray start`` nodes on this machine (one CPU
  each), joined with ``address``, cells placed by CPU (accuracy only); its start is timed apart;
* sweep on one node (the default placement, one timed cell at a time) on a local instance:
  its wall time per cell less the in-process run's is the per-cell cost of Ray (a worker
  process per cell, scheduling, files back to the driver, the driver's outputs).

Cells per minute are cells / wall time x 60. Run it with ``python -m benchmarks --items sweep``
(not part of the default suite: it starts Ray three times) or ``python -m benchmarks.bench_sweep``
(writes benchmarks/results/sweep.json).
"""

from __future__ import annotations

import contextlib
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
from typing import TYPE_CHECKING, Any

from benchmarks.core import Check, ItemResult, Measurement, ratio

if TYPE_CHECKING:
    from collections.abc import Iterator

    from benchmarks.core import Context

__all__ = ['BAGS', 'ITEM', 'run']

ITEM = 'g'
#: Bags of the suite this item reads: none, it writes its own small ones.
BAGS: tuple[str, ...] = ()
BACKENDS = ('hsv', 'onnx-cpu')
_NODE_IP = '127.0.0.2'


def _workload(ctx: Context) -> tuple[list[Path], int, tuple[int, int]]:
    from replaybench.fixtures.writer import write_mcap

    quick = ctx.settings.quick
    inputs, frames, size = (2, 20, (160, 120)) if quick else (4, 120, (640, 480))
    folder = ctx.tmp / 'sweep-bags'
    folder.mkdir(exist_ok=True)
    paths = [
        write_mcap(folder / f'bag{i}.mcap', frames=frames, size=size, encoding='jpeg', seed=i)
        for i in range(inputs)
    ]
    return paths, frames, size


def _sequential(paths: list[Path], out: Path) -> float:
    from replaybench.replay.runner import RunConfig, run_benchmark

    start = time.perf_counter()
    for n, path in enumerate(paths):
        for backend in BACKENDS:
            config = RunConfig(
                inputs=[path],
                backends=[backend],
                out_dir=out / f'{n}-{backend}',
                threads=1,
                report=False,
            )
            run_benchmark(config)
    return time.perf_counter() - start


def _processes(paths: list[Path], out: Path) -> float:
    start = time.perf_counter()
    for n, path in enumerate(paths):
        for backend in BACKENDS:
            command = [sys.executable, '-m', 'replaybench', 'run', str(path), '-b', backend]
            command += ['--threads', '1', '--no-report', '--out', str(out / f'{n}-{backend}')]
            subprocess.run(command, check=True, capture_output=True)
    return time.perf_counter() - start


def _sweep(paths: list[Path], out: Path, **options: Any) -> float:
    from replaybench.app.sweep import sweep

    start = time.perf_counter()
    result = sweep(paths, backends=BACKENDS, out=out, threads=1, report=False, **options)
    wall = time.perf_counter() - start
    if result.status != 'complete':
        msg = f'sweep {result.status}: {result.record["cells"]}'
        raise RuntimeError(msg)
    return wall


@contextlib.contextmanager
def two_nodes(temp: str) -> Iterator[tuple[str, dict[str, str]]]:
    """Two Ray nodes on this machine (one CPU and one node slot each), under ``ray start
    --block``; they are stopped by ending those two processes."""
    token = secrets.token_hex(32)
    env = {**os.environ, 'RAY_AUTH_MODE': 'token', 'RAY_AUTH_TOKEN': token}
    with socket.socket() as s:
        s.bind((_NODE_IP, 0))
        port = int(s.getsockname()[1])
    address = f'{_NODE_IP}:{port}'
    ray = str(Path(sys.executable).with_name('ray'))
    common = ['--block', '--node-ip-address', _NODE_IP, '--num-cpus', '1', '--num-gpus', '0']
    common += ['--resources', '{"replaybench_timed_slot": 1}', '--disable-usage-stats']
    head = [ray, 'start', '--head', '--port', str(port), '--include-dashboard', 'false']
    nodes = [
        subprocess.Popen(
            [*head, '--temp-dir', temp, *common],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
    ]
    try:
        _wait_nodes(address, env, 1)
        nodes.append(
            subprocess.Popen(
                [ray, 'start', '--address', address, *common],
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
            )
        )
        _wait_nodes(address, env, 2)
        yield address, {'RAY_AUTH_TOKEN': token}
    finally:
        for node in reversed(nodes):
            node.send_signal(signal.SIGTERM)
        for node in reversed(nodes):
            node.wait(timeout=120)


def _wait_nodes(address: str, env: dict[str, str], count: int) -> None:
    code = (
        'import logging, ray\n'
        f'ray.init(address={address!r}, logging_level=logging.ERROR)\n'
        'print(sum(1 for n in ray.nodes() if n["Alive"]))\n'
    )
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        found = subprocess.run(
            [sys.executable, '-c', code], env=env, capture_output=True, text=True, check=False
        )
        if found.stdout.strip() and int(found.stdout.strip()) >= count:
            return
        time.sleep(1)
    msg = f'the Ray cluster at {address} did not reach {count} node(s)'
    raise RuntimeError(msg)


@contextlib.contextmanager
def _environ(changes: dict[str, str]) -> Iterator[None]:
    before = {k: os.environ.get(k) for k in changes}
    os.environ.update(changes)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _per_minute(name: str, cells: int, walls: list[float], note: str) -> Measurement:
    return Measurement(name, 'cells/min', tuple(cells * 60.0 / w for w in walls), None, note)


def run(ctx: Context) -> ItemResult:
    try:
        import ray  # noqa: F401
    except ImportError:
        return ItemResult(ITEM, 'Sweep on Ray', [], [], [], 'Ray is not installed (sweep extra)')
    from replaybench.app.sweep import local_ray

    paths, frames, size = _workload(ctx)
    cells = len(paths) * len(BACKENDS)
    repeats = 1 if ctx.settings.quick else 2
    out = ctx.tmp / 'sweep-out'
    seq: list[float] = []
    procs: list[float] = []
    packed: list[float] = []
    single: list[float] = []
    for n in range(repeats):  # no Ray running
        seq.append(_sequential(paths, out / f'seq-{n}'))
        procs.append(_processes(paths, out / f'proc-{n}'))
    temp = tempfile.mkdtemp(prefix='rb-ray-')
    try:
        start = time.perf_counter()
        with two_nodes(temp) as (address, auth), _environ(auth):
            cluster_start = time.perf_counter() - start
            packed.extend(
                _sweep(paths, out / f'pack-{n}', address=address, pack=True) for n in range(repeats)
            )
        start = time.perf_counter()
        with local_ray(temp_dir=temp):
            local_start = time.perf_counter() - start
            single.extend(_sweep(paths, out / f'single-{n}') for n in range(repeats))
    finally:
        shutil.rmtree(temp, ignore_errors=True)
    workload = f'{len(paths)} bags x {", ".join(BACKENDS)}, {frames} frames {size[0]}x{size[1]}'
    m_seq = _per_minute('sequential run_benchmark', cells, seq, 'in this process')
    m_proc = _per_minute('sequential replaybench run', cells, procs, 'a process per cell')
    m_pack = _per_minute('sweep --pack, 2 Ray nodes', cells, packed, 'one CPU per node')
    m_single = _per_minute('sweep, 1 node, 1 timed cell', cells, single, 'local instance')
    per_cell = Measurement(
        'Ray cost per cell',
        's',
        tuple(s / cells - q / cells for s, q in zip(single, seq, strict=True)),
        None,
        'sweep wall per cell (1 node, cells one at a time) - run_benchmark wall per cell',
    )
    starts = [
        Measurement('Ray start, 2-node cluster', 's', (cluster_start,), None, 'ray start x2'),
        Measurement('Ray start, local instance', 's', (local_start,), None, 'ray.init'),
    ]
    checks: list[Check] = [
        ratio(ITEM, 'sweep --pack on 2 nodes vs sequential run_benchmark', m_pack, m_seq, None),
        ratio(ITEM, 'sweep --pack on 2 nodes vs sequential processes', m_pack, m_proc, None),
        ratio(ITEM, 'sweep on 1 node vs sequential run_benchmark', m_single, m_seq, None),
    ]
    notes = [
        f'Workload: {workload}, {cells} cells, --threads 1, no report.html.',
        (
            'Cells per minute exclude starting Ray (measured apart); every cell runs in a fresh '
            'Ray worker process (max_calls=1), as a standalone run does in its own process.'
        ),
    ]
    return ItemResult(
        ITEM,
        'Sweep on Ray vs sequential runs',
        [m_seq, m_proc, m_pack, m_single, per_cell, *starts],
        checks,
        notes,
    )


def main(argv: list[str] | None = None) -> int:
    """``python -m benchmarks.bench_sweep [--quick] [--out PATH]``."""
    import argparse

    from benchmarks.core import Context, Settings, pin_thread_env
    from replaybench.results.atomic import write_json_atomic
    from replaybench.results.machine import environment

    parser = argparse.ArgumentParser(prog='python -m benchmarks.bench_sweep')
    parser.add_argument('--quick', action='store_true', help='tiny bags (smoke test)')
    parser.add_argument(
        '--out',
        type=Path,
        default=Path(__file__).resolve().parent / 'results' / 'sweep.json',
        help='where the result goes',
    )
    args = parser.parse_args(argv)
    pin_thread_env()
    settings = Settings.tiny() if args.quick else Settings.full()
    with tempfile.TemporaryDirectory(prefix='replaybench-bench-') as tmp:
        ctx = Context(settings, Path(tmp), free_bytes=shutil.disk_usage(tmp).free)
        started = time.perf_counter()
        result = run(ctx)
    document = {
        'item': result.as_dict(),
        'mode': 'quick' if args.quick else 'full',
        'wall_s': time.perf_counter() - started,
        'environment': environment(),
        'load_average': os.getloadavg(),
    }
    write_json_atomic(args.out, document)
    for m in result.measurements:
        print(f'{m.name:<34} {m.median:10.3f} {m.unit:<10} ({m.note})')
    for c in result.checks:
        print(f'{c.name:<58} {c.value:6.2f}x  [{c.low:.2f} .. {c.high:.2f}]')
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
