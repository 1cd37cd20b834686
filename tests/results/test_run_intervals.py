"""Every run report carries 95 % intervals and stability warnings: run.json, summary.csv,
report.html and the terminal; the drift, CV and throttling rules."""

from __future__ import annotations

import csv
import json
import math
import sys
import time
import types
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bagtools import image_msg, noise_frames, write_mcap

from replaybench.backends.base import Availability, BackendOptions
from replaybench.backends.busywait import BusyBackend, spin_options
from replaybench.backends.gpu import _cuda
from replaybench.cli import app
from replaybench.comparison import compare_runs
from replaybench.replay import Rate, VirtualClock, resources
from replaybench.replay.resources import ResourceSampler
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.report import render_report
from replaybench.results.bootstrap import percentile_interval
from replaybench.results.intervals import (
    CV_LIMIT,
    DRIFT_MIN_FRAMES,
    drift,
    measured_series,
    throttle_warnings,
    with_intervals,
)
from replaybench.results.recorded_latency import RECORDED_COLUMNS
from replaybench.results.records import FrameRecord, FramesCsvWriter, read_frames_csv
from replaybench.results.stats import INTERVAL_COLUMNS, SUMMARY_CSV_COLUMNS, summarize
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.types import Frame

NS = 1_000_000_000
CI_KEYS = {
    'latency_ms_p50': ('latency_ms_p50_ci_low', 'latency_ms_p50_ci_high'),
    'latency_ms_p99': ('latency_ms_p99_ci_low', 'latency_ms_p99_ci_high'),
    'throughput_fps': ('throughput_fps_ci_low', 'throughput_fps_ci_high'),
}


def _bag(path: Path, n: int) -> Path:
    frames = noise_frames(n)
    t0 = 1_700_000_000 * NS
    write_mcap(
        path,
        [
            (
                '/cam/image_raw',
                t0 + i * NS // 30,
                image_msg(t0 + i * NS // 30, frames[i]),
                'sensor_msgs/msg/Image',
            )
            for i in range(n)
        ],
    )
    return path


class ScheduledService:
    """A backend of declared service times on the virtual clock: ``times[seq % len(times)]``."""

    name: ClassVar[str] = 'service'
    description: ClassVar[str] = 'declared service times'

    def __init__(self, clock: VirtualClock, times: Sequence[float]) -> None:
        self.clock = clock
        self.times = list(times)

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Frame) -> BackendResult:
        service = self.times[frame.seq % len(self.times)]
        self.clock.advance(service)
        return BackendResult((), StageTimes(infer_ns=round(service * 1e9)))

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


class SlowerSecondHalf(BusyBackend):
    """The busy backend on a schedule: ``busy_ms`` per frame, ``factor`` times that from frame
    ``switch`` on."""

    def __init__(self, options: BackendOptions, switch: int, factor: float) -> None:
        super().__init__(options)
        self.switch = switch
        self.factor = factor
        self.base_s = self._seconds

    def detect(self, frame: Frame) -> BackendResult:
        self._seconds = self.base_s * (self.factor if frame.seq >= self.switch else 1.0)
        return super().detect(frame)


def _csv_rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline='') as f:
        return list(csv.DictReader(f))


def _run_json(run_dir: Path) -> dict[str, Any]:
    loaded: dict[str, Any] = json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))
    return loaded


def _row(run: dict[str, Any], backend: str) -> dict[str, Any]:
    return next(r for r in run['summary'] if r['backend'] == backend)


# --------------------------------------------------------------------------- whole runs


def test_a_40_frame_run_has_intervals_around_its_estimates_everywhere_and_compare_agrees(
    tmp_path: Path,
) -> None:
    bag = _bag(tmp_path / 'cam.mcap', 40)
    out = tmp_path / 'run'
    run_benchmark(RunConfig(inputs=[bag], backends=['null', 'hsv'], out_dir=out, warmup=2))
    run = _run_json(out)
    csv_rows = {r['backend']: r for r in _csv_rows(out / 'summary.csv')}
    html = render_report(out).read_text(encoding='utf-8')
    comparison = compare_runs([out])
    for backend in ('null', 'hsv'):
        row = _row(run, backend)
        assert row['measured'] == 38
        assert not any('measured frames' in w for w in row['warnings'])
        for point, (low, high) in CI_KEYS.items():
            assert row[low] is not None, (backend, point)
            assert row[high] is not None, (backend, point)
            assert row[low] <= row[point] <= row[high], (backend, point)
            # summary.csv: the same numbers, the columns at the end
            assert csv_rows[backend][low] == f'{row[low]:.4f}'
            assert csv_rows[backend][high] == f'{row[high]:.4f}'
        assert csv_rows[backend]['warnings'] == '; '.join(row['warnings'])
        # compare RUN's own interval of the row is the same computation on frames.csv
        [compared] = [r for r in comparison.rows if r.backend == backend]
        assert compared.metrics['median_ms'].value_ci == (
            row['latency_ms_p50_ci_low'],
            row['latency_ms_p50_ci_high'],
        )
        assert compared.metrics['p99_ms'].value_ci == (
            row['latency_ms_p99_ci_low'],
            row['latency_ms_p99_ci_high'],
        )
        assert compared.metrics['fps'].value_ci == (
            row['throughput_fps_ci_low'],
            row['throughput_fps_ci_high'],
        )
    hsv = _row(run, 'hsv')
    lo, hi = hsv['latency_ms_p50_ci_low'], hsv['latency_ms_p50_ci_high']
    digits = 3 if hsv['latency_ms_p50'] < 1 else 2
    assert f'<span class="muted ci">{lo:.{digits}f}–{hi:.{digits}f}</span>' in html
    # the segmentation and recorded-latency columns, added later, come after them
    warnings_at = SUMMARY_CSV_COLUMNS.index('warnings')
    assert list(SUMMARY_CSV_COLUMNS[warnings_at - 6 : warnings_at + 1]) == [
        *INTERVAL_COLUMNS,
        'warnings',
    ]
    assert RECORDED_COLUMNS[0] in SUMMARY_CSV_COLUMNS[warnings_at:]


def test_a_10_frame_run_has_empty_intervals_and_says_there_are_too_few_frames(
    tmp_path: Path,
) -> None:
    bag = _bag(tmp_path / 'cam.mcap', 10)
    out = tmp_path / 'run'
    result = CliRunner().invoke(
        app, ['run', str(bag), '--backend', 'null', '--warmup', '0', '--out', str(out)]
    )
    assert result.exit_code == 0, result.output
    row = _row(_run_json(out), 'null')
    assert row['measured'] == 10
    for low, high in CI_KEYS.values():
        assert row[low] is None
        assert row[high] is None
    too_few = '10 measured frames: fewer than 20, no 95 % interval'
    assert row['warnings'][0] == too_few
    [csv_row] = _csv_rows(out / 'summary.csv')
    assert all(csv_row[name] == '' for name in INTERVAL_COLUMNS)
    assert csv_row['warnings'].split('; ')[0] == too_few
    assert f'replaybench: warning: null /cam/image_raw: {too_few}' in result.stderr
    html = (out / 'report.html').read_text(encoding='utf-8')
    banner = html[html.index('<div class="banner"') :]
    assert too_few in banner[: banner.index('</div>')]


def test_a_busy_backend_that_slows_down_in_the_second_half_is_flagged_as_drifting(
    tmp_path: Path,
) -> None:
    bag = _bag(tmp_path / 'cam.mcap', 60)
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['busy'], out_dir=tmp_path / 'run', warmup=0),
        backend_factory=lambda name, options: SlowerSecondHalf(
            BackendOptions(extra=spin_options(3.0)), switch=30, factor=3.0
        ),
    )
    [summary] = outcome.summaries
    drifts = [w for w in summary.warnings if w.startswith('latency drift: ')]
    assert len(drifts) == 1, summary.warnings
    assert outcome.run_dir is not None
    written = _row(_run_json(outcome.run_dir), 'busy')['warnings']
    assert drifts == [w for w in written if 'drift' in w]


def test_a_busy_backend_of_constant_cost_is_not_flagged_as_drifting(tmp_path: Path) -> None:
    bag = _bag(tmp_path / 'cam.mcap', 60)
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['busy'],
            out_dir=tmp_path / 'run',
            warmup=0,
            report=False,
            options=BackendOptions(extra=spin_options(4.0)),
        )
    )
    [summary] = outcome.summaries
    assert summary.latency_ms_p50_ci_low is not None
    # the busy-wait spins wall time: other processes that take the CPU stretch it, and that is
    # real drift of the measured latency; judge the rule only when the spins held
    assert outcome.run_dir is not None
    spins = [
        float(r['infer_ms'])
        for r in _csv_rows(outcome.run_dir / 'frames.csv')
        if r['status'] == 'ok' and r['warmup'] == '0'
    ]
    halves = (np.median(spins[:30]), np.median(spins[30:]))
    if max(halves) > 1.05 * min(halves):
        pytest.skip(f'other processes stretched the 4 ms busy-wait (medians {halves} ms)')
    assert not [w for w in summary.warnings if 'drift' in w], summary.warnings


def test_a_backend_of_constant_cost_on_the_virtual_clock_has_no_drift_and_a_step_has(
    tmp_path: Path,
) -> None:
    def warnings(name: str, times: Sequence[float]) -> tuple[str, ...]:
        clock = VirtualClock()
        outcome = run_benchmark(
            RunConfig(
                inputs=[_bag(tmp_path / f'{name}.mcap', 40)],
                backends=['service'],
                out_dir=tmp_path / name,
                warmup=0,
                report=False,
            ),
            clock=clock,
            backend_factory=lambda _name, _options: ScheduledService(clock, times),
        )
        return outcome.summaries[0].warnings

    assert warnings('constant', [0.004]) == ()
    # 4 ms for frames 0-19, 5 ms for 20-39: +25 %, and CV 0.5 / 4.5 = 0.111
    stepped = warnings('stepped', [0.004] * 20 + [0.005] * 20)
    assert [w.split(':')[0] for w in stepped] == ['unstable latency', 'latency drift']
    assert stepped[1].startswith('latency drift: second-half median 5 ms vs first-half 4 ms, +25 %')


def test_a_spread_of_service_times_gives_the_cv_warning_and_an_even_one_none(
    tmp_path: Path,
) -> None:
    def run(name: str, times: Sequence[float]) -> tuple[str, ...]:
        clock = VirtualClock()
        outcome = run_benchmark(
            RunConfig(
                inputs=[_bag(tmp_path / f'{name}.mcap', 30)],
                backends=['service'],
                out_dir=tmp_path / name,
                rate=Rate('max'),
                warmup=0,
                report=False,
            ),
            clock=clock,
            backend_factory=lambda _name, _options: ScheduledService(clock, times),
        )
        return outcome.summaries[0].warnings

    # 1 ms and 3 ms alternating: mean 2, standard deviation 1
    spread = run('spread', [0.001, 0.003])
    assert f'unstable latency: CV 0.500 > {CV_LIMIT:g}' in spread
    assert not [w for w in spread if 'drift' in w]
    even = run('even', [0.002])
    assert not [w for w in even if 'CV' in w or 'drift' in w or 'frames' in w]


# --------------------------------------------------------------------------- the rules


def _records(
    latencies: Sequence[float], backend: str = 'b', topic: str = '/t'
) -> list[FrameRecord]:
    records, done = [], 0.0
    for seq, latency in enumerate(latencies):
        start = done
        done = start + latency / 1e3
        records.append(
            FrameRecord(
                0, backend, topic, seq, seq, seq, 'ok', '', False, False, start, start, done,
                0.0, 0.0, 0.0, latency, 0.0, None, None, latency, 0,
            )
        )  # fmt: skip
    return records


def test_drift_needs_a_change_beyond_10_percent_that_the_exact_interval_confirms() -> None:
    rng = np.random.default_rng(3)
    steady = 10.0 + rng.normal(0.0, 0.2, 60)
    assert drift(steady) is not None
    assert not drift(steady).significant  # type: ignore[union-attr]
    stepped = np.concatenate((steady[:30], steady[30:] * 1.25))
    found = drift(stepped)
    assert found is not None
    assert found.significant
    assert found.method == 'between-block'
    assert found.ratio == pytest.approx(1.25, rel=0.05)
    # significant but small: 5 % is not drift
    small = np.concatenate((steady[:30], steady[30:] * 1.05))
    assert not drift(small).significant  # type: ignore[union-attr]
    # large but not significant: two halves that overlap completely
    noisy = np.tile([1.0, 3.0], 10)
    assert not drift(noisy).significant  # type: ignore[union-attr]
    # 4 against 4 frames is the least that can be judged, frame by frame
    assert drift([1.0] * (DRIFT_MIN_FRAMES - 1)) is None
    short = drift([1.0, 1.01, 1.02, 1.03, 2.0, 2.01, 2.02, 2.03])
    assert short is not None
    assert short.significant
    assert short.method == 'per-frame'


def test_with_intervals_fills_in_every_row_and_reads_the_same_series_back_from_frames_csv(
    tmp_path: Path,
) -> None:
    latencies = [1.0 + 0.123456789 * (i % 7) for i in range(25)]
    records = _records(latencies) + _records(latencies[:5], backend='short')
    annotated = with_intervals(summarize(records), records)
    by_backend = {s.backend: s for s in annotated}
    assert by_backend['b'].latency_ms_p50_ci_low is not None
    assert by_backend['short'].latency_ms_p50_ci_low is None
    assert by_backend['short'].warnings[0].startswith('5 measured frames: fewer than 20')
    writer = FramesCsvWriter(tmp_path / 'frames.csv')
    writer.write_many(records)
    writer.close()
    back = read_frames_csv(tmp_path / 'frames.csv')
    mine = measured_series([r for r in records if r.backend == 'b'])
    theirs = measured_series([r for r in back if r.backend == 'b'])
    assert np.array_equal(mine.latency_ms, theirs.latency_ms)
    assert mine.intervals_s is not None
    assert theirs.intervals_s is not None
    assert np.array_equal(mine.intervals_s, theirs.intervals_s)


@pytest.mark.parametrize(
    ('summary', 'expected'),
    [
        (
            {'cpu_mhz_max': 3000.0, 'cpu_mhz_min': 2500.0},
            ['CPU throttling: busy CPU frequency fell 17 %'],
        ),
        ({'cpu_mhz_max': 3000.0, 'cpu_mhz_min': 2800.0}, []),
        ({'cpu_mhz_max': 3000.0, 'cpu_mhz_min': 2700.0}, []),  # exactly 10 %: not more
        ({'cpu_mhz_max': None, 'cpu_mhz_min': None, 'cpu_freq_source': None}, []),
        ({'cpu_throttle_events': 3}, ['CPU throttling: 3 thermal throttle event(s)']),
        ({'cpu_throttle_events': 0}, []),
        (
            {'gpu_throttle_reasons': ['sw_thermal_slowdown']},
            ['GPU throttling: sw_thermal_slowdown'],
        ),
        ({'gpu_throttle_reasons': []}, []),
        ({}, []),
    ],
)
def test_throttling_is_flagged_from_the_resource_summary(
    summary: dict[str, Any], expected: list[str]
) -> None:
    found = throttle_warnings(summary)
    assert len(found) == len(expected)
    for line, start in zip(found, expected, strict=True):
        assert line.startswith(start)


def _fake_cpus(root: Path, khz: int, core: int, package: int) -> None:
    for cpu in (0, 1):
        (root / f'cpu{cpu}' / 'cpufreq').mkdir(parents=True, exist_ok=True)
        (root / f'cpu{cpu}' / 'thermal_throttle').mkdir(parents=True, exist_ok=True)
        (root / f'cpu{cpu}' / 'cpufreq' / 'scaling_cur_freq').write_text(f'{khz}\n')
        (root / f'cpu{cpu}' / 'thermal_throttle' / 'core_throttle_count').write_text(f'{core}\n')
        (root / f'cpu{cpu}' / 'thermal_throttle' / 'package_throttle_count').write_text(
            f'{package}\n'
        )


def _fake_nvml(reasons: int) -> types.ModuleType:
    module = types.ModuleType('pynvml')
    module.nvmlInit = lambda: None  # type: ignore[attr-defined]
    module.nvmlShutdown = lambda: None  # type: ignore[attr-defined]
    module.nvmlDeviceGetCount = lambda: 1  # type: ignore[attr-defined]
    module.nvmlDeviceGetHandleByIndex = lambda i: object()  # type: ignore[attr-defined]
    module.nvmlDeviceGetName = lambda h: 'Fake GPU'  # type: ignore[attr-defined]
    module.nvmlDeviceGetUtilizationRates = lambda h: types.SimpleNamespace(gpu=50)  # type: ignore[attr-defined]
    module.nvmlDeviceGetMemoryInfo = lambda h: types.SimpleNamespace(used=1 << 30)  # type: ignore[attr-defined]
    module.nvmlDeviceGetPowerUsage = lambda h: 100_000  # type: ignore[attr-defined]
    module.nvmlDeviceGetCurrentClocksThrottleReasons = lambda h: reasons  # type: ignore[attr-defined]
    return module


def test_the_sampler_records_cpu_frequency_thermal_events_and_gpu_throttle_reasons(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(resources, 'SYS_CPU', tmp_path)
    monkeypatch.setattr(resources, 'BUSY_CPU_PERCENT', 0.0)  # every sample counts, busy or not
    monkeypatch.setattr(_cuda, 'load_libcuda', lambda: None)
    monkeypatch.setitem(sys.modules, 'pynvml', _fake_nvml(0x1 | 0x20))  # idle + SW thermal
    monkeypatch.setattr('os.sched_getaffinity', lambda pid: {0, 1})
    _fake_cpus(tmp_path, 3_000_000, core=5, package=2)
    with ResourceSampler(interval_s=0.02, gpu_index=0) as sampler:
        time.sleep(0.1)
        _fake_cpus(tmp_path, 2_400_000, core=6, package=3)
        time.sleep(0.1)
    summary = sampler.summary()
    assert summary['cpu_freq_source'] == 'cpufreq'
    assert summary['cpu_mhz_max'] == 3000.0
    assert summary['cpu_mhz_min'] == 2400.0
    assert summary['cpu_throttle_events'] == 2 + 1  # one more core event on each CPU, one package
    assert summary['gpu_throttle_reasons'] == ['sw_thermal_slowdown']
    series = sampler.series()
    assert {p['cpu_mhz'] for p in series} >= {3000.0}
    assert any(p['gpu_throttle'] == 0x21 for p in series)
    found = throttle_warnings(summary)
    assert [w.split(':')[0] for w in found] == ['CPU throttling'] * 2 + ['GPU throttling']


def test_without_cpufreq_cpu_throttling_cannot_be_judged_and_gives_no_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(resources, 'SYS_CPU', tmp_path / 'none')
    monkeypatch.setitem(sys.modules, 'pynvml', None)
    with ResourceSampler(interval_s=0.02) as sampler:
        time.sleep(0.05)
    summary = sampler.summary()
    assert summary['cpu_freq_source'] is None
    assert summary['cpu_mhz_min'] is None
    assert summary['cpu_mhz_max'] is None
    assert summary['cpu_throttle_events'] is None
    assert summary['gpu_throttle_reasons'] is None
    assert all(p['cpu_mhz'] is None for p in sampler.series())
    assert throttle_warnings(summary) == []


# ---------------------------------------------------------- estimates inside their intervals


def _record(seq: int, latency_ms: float) -> FrameRecord:
    release = seq * 0.01
    return FrameRecord(
        0, 'null', '/cam', seq, seq, seq, 'ok', '', False, False,
        release, release, release + latency_ms / 1000.0, latency_ms=latency_ms,
    )  # fmt: skip


def test_the_summary_and_its_intervals_come_from_the_values_frames_csv_holds() -> None:
    # 15.84 µs a frame: frames.csv holds 0.0158 ms. A p99 of the unrounded values (0.01584)
    # lay above the interval of the written ones ([0.0158, 0.0158]).
    records = [_record(seq, 0.01584) for seq in range(40)]
    [summary] = with_intervals(summarize(records), records)
    assert summary.latency_ms_p50 == summary.latency_ms_p99 == 0.0158
    for point, low, high in (
        (summary.latency_ms_p50, summary.latency_ms_p50_ci_low, summary.latency_ms_p50_ci_high),
        (summary.latency_ms_p99, summary.latency_ms_p99_ci_low, summary.latency_ms_p99_ci_high),
        (summary.throughput_fps, summary.throughput_fps_ci_low, summary.throughput_fps_ci_high),
    ):
        assert low is not None
        assert high is not None
        assert point is not None
        assert low <= point <= high


def test_an_interval_is_extended_to_an_estimate_it_would_leave_out() -> None:
    replicates = np.array([2.0, 2.1, 2.2, 2.3, 2.4])
    assert percentile_interval(replicates) == pytest.approx((2.01, 2.39))
    assert percentile_interval(replicates, point=1.5) == pytest.approx((1.5, 2.39))
    assert percentile_interval(replicates, point=3.0) == pytest.approx((2.01, 3.0))
    assert percentile_interval(replicates, point=2.2) == pytest.approx((2.01, 2.39))
    assert percentile_interval(replicates, point=math.nan) == pytest.approx((2.01, 2.39))
