"""``run --repeat N``: interleaved passes, their warm-up, frames.csv's ``repeat`` column, the
per-pass statistics of run.json, and ``compare``'s verdicts between repeats.

Timings come from a virtual clock that a backend of declared service time advances, so every
latency is known exactly; nothing here reads the wall clock.
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'comparison'))

from bagtools import image_msg, noise_frames, write_mcap
from runbuilder import latencies, write_run

import replaybench as rb
from replaybench.backends.base import Availability
from replaybench.comparison import compare_runs, evaluate_gate
from replaybench.comparison.repeats import MIN_SINGLE_PASS_S, t_quantile
from replaybench.errors import UsageError
from replaybench.replay import VirtualClock
from replaybench.replay.runner import RunConfig, default_warmup, run_benchmark
from replaybench.results.records import FRAMES_CSV_COLUMNS, read_frames_csv
from replaybench.types import BackendResult, Frame, StageTimes

NS = 1_000_000_000
FRAMES = 40


class PassBackend:
    """Advances the virtual clock by its service time: ``pass_ms[k]`` in its k-th pass (a
    machine whose state changes between passes), times a small per-frame ripple."""

    name: ClassVar[str] = 'pass'
    description: ClassVar[str] = 'declared service time per pass'

    def __init__(
        self, clock: VirtualClock, label: str, pass_ms: list[float], calls: list[str]
    ) -> None:
        self.clock = clock
        self.label = label
        self.pass_ms = pass_ms
        self.calls = calls
        self.count = 0

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Frame) -> BackendResult:
        k = min(self.count // FRAMES, len(self.pass_ms) - 1)
        self.count += 1
        self.calls.append(self.label)
        ripple = 1.0 + 0.01 * math.sin(frame.seq)
        self.clock.advance(self.pass_ms[k] * ripple / 1e3)
        return BackendResult((), StageTimes())

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


def _bag(path: Path, n: int = FRAMES) -> Path:
    frames = noise_frames(n)
    t0 = 1_700_000_000 * NS
    write_mcap(
        path,
        [
            ('/cam/image_raw', t0 + i * NS // 30, image_msg(t0 + i * NS // 30, frames[i]),
             'sensor_msgs/msg/Image')
            for i in range(n)
        ],
    )  # fmt: skip
    return path


def _run(
    tmp_path: Path,
    name: str,
    passes: dict[str, list[float]],
    repeat: int,
    calls: list[str] | None = None,
) -> Path:
    bag = tmp_path / 'cam.mcap'
    if not bag.exists():
        _bag(bag)
    clock = VirtualClock()
    log = calls if calls is not None else []
    made = {label: PassBackend(clock, label, ms, log) for label, ms in passes.items()}
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=list(passes),
            out_dir=tmp_path / name,
            repeat=repeat,
            prefetch=0,
        ),
        clock=clock,
        backend_factory=lambda n, options: made[n],
    )
    assert outcome.run_dir is not None
    return outcome.run_dir


def test_repeated_passes_interleave_the_backends_and_each_pass_has_its_own_warmup(tmp_path):
    calls: list[str] = []
    run_dir = _run(tmp_path, 'run', {'a': [10.0], 'b': [20.0]}, repeat=3, calls=calls)
    runs = [calls[i] for i in range(0, len(calls), FRAMES)]
    assert runs == ['a', 'b', 'a', 'b', 'a', 'b']
    assert all(len(set(calls[i : i + FRAMES])) == 1 for i in range(0, len(calls), FRAMES))

    with (run_dir / 'frames.csv').open(newline='') as f:
        header = next(csv.reader(f))
    assert tuple(header) == FRAMES_CSV_COLUMNS
    assert 'repeat' in header
    records = read_frames_csv(run_dir / 'frames.csv')
    assert [(r.backend, r.repeat) for r in records[::FRAMES]] == [
        ('a', 0), ('b', 0), ('a', 1), ('b', 1), ('a', 2), ('b', 2)
    ]  # fmt: skip
    warm = default_warmup(FRAMES)
    for backend in 'ab':
        for k in range(3):
            mine = [r for r in records if r.backend == backend and r.repeat == k]
            assert [r.warmup for r in mine] == [True] * warm + [False] * (FRAMES - warm)
            assert mine[0].release_s == 0.0  # each pass's times count from its own start


def test_run_json_keeps_each_pass_and_the_summary_pools_them(tmp_path):
    run_dir = _run(tmp_path, 'run', {'a': [10.0, 20.0, 10.0]}, repeat=3)
    doc = json.loads((run_dir / 'run.json').read_text())
    assert doc['settings']['repeat'] == 3
    passes = doc['repeats']
    assert [(p['backend'], p['repeat']) for p in passes] == [('a', 0), ('a', 1), ('a', 2)]
    measured = FRAMES - default_warmup(FRAMES)
    assert [p['measured'] for p in passes] == [measured] * 3
    assert [round(p['latency_ms_p50']) for p in passes] == [10, 20, 10]
    (row,) = doc['summary']
    assert row['measured'] == 3 * measured
    # throughput: every measured frame over the sum of the passes' windows, not their span
    windows = sum(p['window_s'] for p in passes)
    assert row['throughput_fps'] == pytest.approx(3 * measured / windows, rel=1e-6)
    assert windows == pytest.approx(measured * 0.040, rel=0.02)


def test_detections_are_written_once_however_many_passes(tmp_path):
    from mcap.reader import make_reader

    run_dir = _run(tmp_path, 'run', {'a': [1.0]}, repeat=3)
    with (run_dir / 'outputs.mcap').open('rb') as f:
        topics = [c.topic for _, c, _ in make_reader(f).iter_messages()]
    assert sum(t.endswith('/detections') for t in topics) == FRAMES


def test_a_repeat_below_one_is_refused_in_one_line(tmp_path):
    with pytest.raises(UsageError, match='--repeat must be at least 1'):
        rb.run(_bag(tmp_path / 'cam.mcap'), backends='null', repeat=0)


def test_the_api_runs_repeats_in_memory(tmp_path):
    result = rb.run(_bag(tmp_path / 'cam.mcap'), backends=['null', 'busy'], repeat=2)
    assert result.settings.repeat == 2
    assert result.repeats is not None
    assert {(p.backend, p.repeat) for p in result.repeats} == {
        ('null', 0), ('null', 1), ('busy', 0), ('busy', 1)
    }  # fmt: skip
    assert sorted(set(result.frames['repeat'])) == [0, 1]


def test_an_old_frames_csv_without_the_repeat_column_reads_as_one_pass(tmp_path):
    run_dir = _run(tmp_path, 'run', {'a': [1.0]}, repeat=1)
    path = run_dir / 'frames.csv'
    rows = list(csv.reader(path.open(newline='')))
    with path.open('w', newline='') as f:
        csv.writer(f, lineterminator='\r\n').writerows(
            [row[: FRAMES_CSV_COLUMNS.index('repeat')] for row in rows]
        )
    assert {r.repeat for r in read_frames_csv(path)} == {0}


# -- compare between repeats -----------------------------------------------------------------

GATE = ['median_ms > +10%', 'mean_ms > +10%', 'fps < -10%']


def _verdicts(*dirs: Path, gate: list[str] = GATE) -> tuple[set[str], set[str], list[Any]]:
    comparison = compare_runs(list(dirs))
    results = evaluate_gate(comparison, gate)
    return {r.verdict for r in results}, {r.method for r in results}, results


def test_a_pass_slowed_by_background_load_does_not_fail_an_aa_pair_between_repeats(tmp_path):
    base = _run(tmp_path, 'base', {'a': [10.0, 10.1, 9.9]}, repeat=3)
    # same code; the machine was busy during one pass of the candidate (+40 %)
    cand = _run(tmp_path, 'cand', {'a': [14.0, 10.0, 10.05]}, repeat=3)
    verdicts, methods, _ = _verdicts(base, cand)
    assert methods == {'between-repeat 3/3'}
    assert 'failed' not in verdicts
    comparison = compare_runs([base, cand])
    row = next(r for r in comparison.rows if r.role == 'candidate')
    assert row.repeats == 3


def test_a_thirty_percent_regression_fails_between_repeats(tmp_path):
    base = _run(tmp_path, 'base', {'a': [10.0, 10.1, 9.9]}, repeat=3)
    cand = _run(tmp_path, 'cand', {'a': [13.0, 13.1, 12.9]}, repeat=3)
    verdicts, methods, results = _verdicts(base, cand)
    assert methods == {'between-repeat 3/3'}
    assert verdicts == {'failed'}
    assert 'typical repeat +30' in results[0].explanation


def test_between_repeats_the_interval_is_welchs_t_on_the_log_pass_values(tmp_path):
    base = _run(tmp_path, 'base', {'a': [10.0, 10.4, 9.7]}, repeat=3)
    cand = _run(tmp_path, 'cand', {'a': [11.0, 11.9, 11.2]}, repeat=3)
    comparison = compare_runs([base, cand])
    m = next(r for r in comparison.rows if r.role == 'candidate').metrics['median_ms']
    passes = {
        name: np.log([p.latency_ms_p50 or 0.0 for p in rb.load_run(d).repeats or ()])
        for name, d in (('x', base), ('y', cand))
    }
    x, y = passes['x'], passes['y']
    vx, vy = x.var(ddof=1) / 3, y.var(ddof=1) / 3
    df = (vx + vy) ** 2 / (vx**2 / 2 + vy**2 / 2)
    half = t_quantile(0.975, df) * math.sqrt(vx + vy)
    d = y.mean() - x.mean()
    assert m.method == 'between-repeat'
    assert m.typical_ratio == pytest.approx(math.exp(d))
    assert m.ratio_ci == pytest.approx((math.exp(d - half), math.exp(d + half)))


def test_one_run_with_repeats_against_one_without_compares_blocks(tmp_path):
    base = _run(tmp_path, 'base', {'a': [10.0]}, repeat=1)
    cand = _run(tmp_path, 'cand', {'a': [10.0, 10.0]}, repeat=2)
    _, methods, _ = _verdicts(base, cand)
    assert methods == {'between-block 4/4'}  # 36 and 72 measured frames: 4 blocks each


def test_t_quantiles_match_scipy() -> None:
    stats = pytest.importorskip('scipy.stats')
    for df in (1.0, 2.0, 2.7, 4.0, 30.0, 500.0):
        for p in (0.9, 0.975, 0.995, 0.025):
            assert t_quantile(p, df) == pytest.approx(stats.t.ppf(p, df), rel=1e-9)


# -- a short, unstable single pass cannot fail by itself -------------------------------------


def _single(tmp_path: Path, name: str, median_ms: float, cv: float) -> Path:
    values = latencies(300, median_ms, seed=hash(name) % 1000, cv=cv, rho=0.0)
    return write_run(tmp_path / name, {('busy', '/cam/image_raw'): values})


def test_a_short_unstable_single_pass_is_inconclusive_with_the_advice(tmp_path):
    # 300 frames of about 1 ms: 0.3 s, CV about 0.2
    base = _single(tmp_path, 'base', 1.0, cv=0.2)
    cand = _single(tmp_path, 'cand', 1.3, cv=0.2)
    verdicts, methods, results = _verdicts(base, cand, gate=['median_ms > +10%'])
    assert methods == {'between-block 10/10'}
    assert verdicts == {'inconclusive'}
    (result,) = results
    assert 'the whole CI is above +10%' in result.explanation
    assert f'under {MIN_SINGLE_PASS_S:g} s' in result.explanation
    assert '--repeat 3' in result.explanation
    comparison = compare_runs([base, cand])
    assert any('single pass of' in w for w in comparison.warnings)


def test_a_stable_or_long_single_pass_still_fails(tmp_path):
    stable = (_single(tmp_path, 'b1', 1.0, cv=0.02), _single(tmp_path, 'c1', 1.3, cv=0.02))
    long = (_single(tmp_path, 'b2', 20.0, cv=0.2), _single(tmp_path, 'c2', 26.0, cv=0.2))
    for base, cand in (stable, long):
        verdicts, _, _ = _verdicts(base, cand, gate=['median_ms > +10%'])
        assert verdicts == {'failed'}


def test_a_run_interrupted_in_its_first_pass_keeps_what_ran_and_a_valid_run_json(tmp_path):
    import threading

    bag = _bag(tmp_path / 'cam.mcap')
    clock = VirtualClock()
    stop = threading.Event()

    class Stopping(PassBackend):
        def detect(self, frame: Frame) -> BackendResult:
            if self.count == 20:
                stop.set()  # as Ctrl-C does through the command line's signal handler
            return super().detect(frame)

    made = {'a': Stopping(clock, 'a', [1.0], []), 'b': PassBackend(clock, 'b', [1.0], [])}
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['a', 'b'], out_dir=tmp_path / 'run', repeat=2),
        clock=clock,
        stop=stop,
        backend_factory=lambda n, options: made[n],
    )
    assert outcome.status == 'interrupted'
    doc = json.loads((tmp_path / 'run' / 'run.json').read_text())
    assert [b['name'] for b in doc['backends']] == ['a']
    assert {r.backend for r in read_frames_csv(tmp_path / 'run' / 'frames.csv')} == {'a'}


def test_the_report_charts_put_the_passes_one_after_the_other(tmp_path):
    from replaybench.results.repeats import one_timeline

    run_dir = _run(tmp_path, 'run', {'a': [10.0]}, repeat=3)
    records = read_frames_csv(run_dir / 'frames.csv')
    line = one_timeline(records)
    assert [r.repeat for r in line] == sorted(r.repeat for r in records)
    releases = [r.release_s for r in line]
    assert releases == sorted(releases)
    assert releases[-1] == pytest.approx(3 * FRAMES * 0.010 - 0.010, rel=0.02)
