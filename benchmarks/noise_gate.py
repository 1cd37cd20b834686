"""Does the compare gate hold under noise? A/A and A/B pairs of runs under a seeded CPU hog.

    python -m benchmarks.noise_gate [--pairs 50] [--frames 300] [--clock wall] [--hsv-pairs 10]

A backend of known cost (``busy``: spins 10 ms a frame) is run as pairs of runs of
``--frames`` measured frames each, while a CPU hog — one spinning process per core, switched
on and off at random every 50 to 300 ms from a fixed seed — runs through all of them:

- **A/A**: the same 10 ms backend twice. Every gate condition should pass; a failure is a false
  alarm.
- **A/B**: 10 ms against 13 ms (+30 %). Every condition should fail.

Each pair is judged with ``--fail-if 'p50_ms > +10%'``, ``'mean_ms > +10%'``,
``'p99_ms > +10%'`` and ``'fps < -10%'`` by the gate (``compare_runs`` + ``evaluate_gate``), and,
for contrast, by the gate's previous method: a 95 % circular block-bootstrap interval of each
whole-run ratio, failing when it lies past the threshold. Then ``--hsv-pairs`` A/A pairs of the
``hsv`` backend on a 640x480 scene bag (a few milliseconds a frame, so that a run spans several
hog phases, as the busy runs do), under the same hog.

Runs are made in the order A, B, A' within a pair (A/A = A and A', A/B = A and B), so the two
runs of a pair are seconds apart. Writes benchmarks/results/noise_gate.json and prints
the counts. It takes minutes (``--pairs 50``: about 15 on an idle 2-core machine); the hog uses
every core, so other work on the machine slows it and adds its own noise: run it alone.
Not part of ``python -m benchmarks``: it measures the statistics, not the speed.
"""

from __future__ import annotations

import argparse
import datetime as dt
import multiprocessing
import os
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchmarks.core import pin_thread_env

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence
    from multiprocessing.process import BaseProcess

    import numpy as np
    import numpy.typing as npt

__all__ = ['CONDITIONS', 'DEFAULT_OUT', 'Hog', 'hog_phases', 'main']

DEFAULT_OUT = Path(__file__).resolve().parent / 'results' / 'noise_gate.json'
#: The gate judged on every pair.
CONDITIONS = ('p50_ms > +10%', 'mean_ms > +10%', 'p99_ms > +10%', 'fps < -10%')
_METRIC = {'p50_ms': 'median_ms', 'mean_ms': 'mean_ms', 'p99_ms': 'p99_ms', 'fps': 'fps'}
_WARMUP = 10
#: Hog phases last between these many seconds.
PHASE_S = (0.05, 0.3)


def hog_phases(seed: int) -> Callable[[], tuple[bool, float]]:
    """The hog's schedule: each call gives the next phase, ``(on, seconds)``; the first phase's
    state is drawn too. The same seed gives the same schedule in every process."""
    rng = random.Random(seed)
    state = {'on': rng.random() < 0.5}

    def next_phase() -> tuple[bool, float]:
        on = state['on']
        state['on'] = not on
        return on, rng.uniform(*PHASE_S)

    return next_phase


def _hog_worker(seed: int, t0: float) -> None:
    """Spin while the schedule says on, sleep while it says off, from ``t0`` (monotonic)."""
    phase = hog_phases(seed)
    edge = t0
    while True:
        on, seconds = phase()
        edge += seconds
        if on:
            while time.monotonic() < edge:
                pass
        else:
            left = edge - time.monotonic()
            if left > 0:
                time.sleep(left)


class Hog:
    """``workers`` processes switching on and off together on the seeded schedule."""

    def __init__(self, seed: int, workers: int) -> None:
        self.seed = seed
        self.workers = workers
        self.processes: list[BaseProcess] = []

    def __enter__(self) -> Hog:
        context = multiprocessing.get_context('spawn')
        t0 = time.monotonic() + 0.5  # time for the workers to start
        for _ in range(self.workers):
            process = context.Process(target=_hog_worker, args=(self.seed, t0), daemon=True)
            process.start()
            self.processes.append(process)
        time.sleep(max(0.0, t0 - time.monotonic()))
        return self

    def __exit__(self, *exc: object) -> None:
        for process in self.processes:
            process.terminate()
        for process in self.processes:
            process.join(timeout=5)


def _bag(path: Path, size: tuple[int, int], frames: int) -> Path:
    from benchmarks.data import BagSpec, scene_frames, warm_page_cache, write_bag

    write_bag(path, BagSpec(path.stem, size, frames, 'rgb8'), scene_frames(size, 8))
    warm_page_cache(path)
    return path


def _run(bag: Path, out: Path, backend: str, frames: int, extra: Mapping[str, str]) -> Path:
    from replaybench.backends.base import BackendOptions
    from replaybench.replay.runner import RunConfig, run_benchmark

    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=[backend],
            out_dir=out,
            max_frames=frames + _WARMUP,
            warmup=_WARMUP,
            threads=1,
            report=False,
            options=BackendOptions(threads=1, extra=extra),
        )
    )
    assert outcome.run_dir is not None
    return outcome.run_dir


def _series(run_dir: Path) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Measured latencies (ms) and completion-to-completion intervals (s), in replay order."""
    import numpy as np

    from replaybench.results.records import read_frames_csv

    records = sorted(read_frames_csv(run_dir / 'frames.csv'), key=lambda r: r.release_s)
    done = [r.done_s for r in records if r.status == 'ok']
    measured = [r for r in records if r.status == 'ok' and not r.warmup]
    latency = np.asarray([r.latency_ms for r in measured], dtype=np.float64)
    first = done.index(measured[0].done_s)
    previous = done[first - 1] if first else measured[0].start_s
    times = np.asarray([previous, *(r.done_s for r in measured)], dtype=np.float64)
    return latency, np.diff(times)


def _bootstrap_verdicts(base: Path, cand: Path, seed: int) -> dict[str, str]:
    """The previous gate: 95 % block-bootstrap interval of the whole-run ratio, per frame."""
    import numpy as np

    from replaybench.comparison.gate import parse_condition
    from replaybench.comparison.verdict import decide
    from replaybench.results.bootstrap import percentile_interval, replicates

    rng = np.random.default_rng(seed)
    rb = replicates(*_series(base), rng=rng)
    rc = replicates(*_series(cand), rng=rng)
    verdicts: dict[str, str] = {}
    for text in CONDITIONS:
        condition = parse_condition(text)
        name = {'median_ms': 'p50', 'p99_ms': 'p99', 'mean_ms': 'mean', 'fps': 'fps'}
        key = name[condition.metric]
        interval = None
        if rb is not None and rc is not None:
            b, c = getattr(rb, key), getattr(rc, key)
            if b is not None and c is not None:
                with np.errstate(divide='ignore', invalid='ignore'):
                    found = percentile_interval(c / b)
                if found is not None:
                    interval = ((found[0] - 1) * 100, (found[1] - 1) * 100)
        verdicts[text] = decide(None, interval, condition.op, condition.threshold)
    return verdicts


def _judge(base: Path, cand: Path, seed: int) -> dict[str, Any]:
    from replaybench.comparison import compare_runs, evaluate_gate

    comparison = compare_runs([base, cand], n_boot=1000, seed=seed)
    gate = evaluate_gate(comparison, list(CONDITIONS))
    row = next(r for r in comparison.rows if r.role == 'candidate')
    ratios = {}
    for text in CONDITIONS:
        metric = _METRIC[text.split()[0]]
        m = row.metrics[metric]
        ratios[metric] = {
            'whole_run': m.ratio,
            'typical': m.typical_ratio,
            'ci': list(m.ratio_ci) if m.ratio_ci else None,
        }
    return {
        'gate': {r.condition: r.verdict for r in gate},
        'bootstrap': _bootstrap_verdicts(base, cand, seed),
        'ratios': ratios,
        'flags': list(row.flags),
    }


def _counts(pairs: Sequence[dict[str, Any]], method: str) -> dict[str, dict[str, int]]:
    counts: dict[str, dict[str, int]] = {}
    for text in (*CONDITIONS, 'any'):
        tally = {'passed': 0, 'failed': 0, 'inconclusive': 0}
        for pair in pairs:
            verdicts = pair[method]
            if text == 'any':
                values = set(verdicts.values())
                verdict = next((v for v in ('failed', 'inconclusive') if v in values), 'passed')
            else:
                verdict = verdicts[text]
            tally[verdict] += 1
        counts[text] = tally
    return counts


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog='python -m benchmarks.noise_gate', description=__doc__)
    parser.add_argument('--pairs', type=int, default=50, help='A/A and A/B pairs (default 50)')
    parser.add_argument('--frames', type=int, default=300, help='measured frames per run')
    parser.add_argument('--cost-ms', type=float, default=10.0, help='A: busy ms per frame')
    parser.add_argument('--change', type=float, default=0.30, help='B: cost up by this fraction')
    parser.add_argument('--clock', choices=('wall', 'cpu'), default='wall', help='busy clock')
    parser.add_argument('--hsv-pairs', type=int, default=10, help='A/A pairs of hsv')
    parser.add_argument('--seed', type=int, default=14, help='the hog schedule')
    parser.add_argument('--workers', type=int, default=os.cpu_count() or 1, help='hog processes')
    parser.add_argument('--out', type=Path, default=DEFAULT_OUT)
    return parser.parse_args(argv)


def _log(line: str) -> None:
    print(f'[noise] {line}', file=sys.stderr, flush=True)


def _table(document: dict[str, Any]) -> str:
    header = (
        f'{"pairs":<22} {"method":<10} {"condition":<16} {"failed":>6} {"inconcl.":>8} '
        f'{"passed":>6}'
    )
    lines = [header]
    for name in ('aa', 'ab', 'hsv_aa'):
        block = document['results'][name]
        for method in ('gate', 'bootstrap'):
            for text, tally in block['counts'][method].items():
                lines.append(
                    f'{block["label"]:<22} {method:<10} {text:<16} {tally["failed"]:>6} '
                    f'{tally["inconclusive"]:>8} {tally["passed"]:>6}'
                )
    return '\n'.join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the experiment; returns the exit status."""
    from benchmarks.core import fix_threads
    from replaybench.backends.busywait import spin_options
    from replaybench.results.atomic import write_json_atomic
    from replaybench.results.machine import environment

    args = _parse(argv)
    threads = fix_threads()
    started = dt.datetime.now(dt.UTC)
    t0 = time.perf_counter()
    load_before = os.getloadavg()
    cost_b = args.cost_ms * (1.0 + args.change)
    aa: list[dict[str, Any]] = []
    ab: list[dict[str, Any]] = []
    hsv: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix='replaybench-noise-') as tmp:
        work = Path(tmp)
        busy_bag = _bag(work / 'small.mcap', (64, 48), args.frames + _WARMUP)
        hsv_bag = _bag(work / 'scene.mcap', (640, 480), args.frames + _WARMUP)

        def busy(name: str, ms: float) -> Path:
            return _run(busy_bag, work / name, 'busy', args.frames, spin_options(ms, args.clock))

        with Hog(args.seed, args.workers):
            for i in range(args.pairs):
                a = busy('a', args.cost_ms)
                b = busy('b', cost_b)
                a2 = busy('a2', args.cost_ms)
                aa.append({'pair': i, **_judge(a, a2, i)})
                ab.append({'pair': i, **_judge(a, b, i)})
                for folder in (a, b, a2):
                    shutil.rmtree(folder)
                _log(
                    f'pair {i + 1}/{args.pairs}: A/A {sorted(aa[-1]["gate"].values())} '
                    f'A/B {sorted(ab[-1]["gate"].values())}'
                )
            for i in range(args.hsv_pairs):
                a = _run(hsv_bag, work / 'h1', 'hsv', args.frames, {})
                a2 = _run(hsv_bag, work / 'h2', 'hsv', args.frames, {})
                hsv.append({'pair': i, **_judge(a, a2, i)})
                for folder in (a, a2):
                    shutil.rmtree(folder)
                _log(f'hsv pair {i + 1}/{args.hsv_pairs}: {sorted(hsv[-1]["gate"].values())}')

    def block(label: str, pairs: list[dict[str, Any]]) -> dict[str, Any]:
        return {
            'label': label,
            'pairs': pairs,
            'counts': {m: _counts(pairs, m) for m in ('gate', 'bootstrap')},
            'first4': {m: _counts(pairs[:4], m) for m in ('gate', 'bootstrap')},
        }

    clock = args.clock
    document = {
        'schema_version': 1,
        'experiment': 'noise_gate',
        'started_at': started.isoformat(),
        'wall_s': time.perf_counter() - t0,
        'command': [sys.executable, '-m', 'benchmarks.noise_gate', *(argv or sys.argv[1:])],
        'environment': environment(),
        'load_average': [list(load_before), list(os.getloadavg())],
        'threads': threads,
        'settings': {
            'pairs': args.pairs,
            'frames': args.frames,
            'warmup': _WARMUP,
            'cost_ms': [args.cost_ms, cost_b],
            'busy_clock': clock,
            'hsv_pairs': args.hsv_pairs,
            'hsv_bag': '640x480 rgb8 scene',
            'hog': {'seed': args.seed, 'workers': args.workers, 'phase_s': list(PHASE_S)},
            'conditions': list(CONDITIONS),
            'order': "A, B, A' per pair; A/A = (A, A'), A/B = (A, B)",
        },
        'results': {
            'aa': block(f'A/A busy {args.cost_ms:g} ms', aa),
            'ab': block(f'A/B {args.cost_ms:g} vs {cost_b:g} ms', ab),
            'hsv_aa': block('A/A hsv', hsv),
        },
    }
    write_json_atomic(args.out, document)
    print(_table(document))
    print(f'\nwrote {args.out}')
    return 0


if __name__ == '__main__':
    pin_thread_env()
    sys.exit(main())
