"""Peak-rate sweep: peaks checkable by hand with a virtual clock and declared service times."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path
from typing import Any, ClassVar

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bagtools import image_msg, noise_frames, write_mcap

from replaybench.app.peak import (
    PEAK_SCHEMA_VERSION,
    PeakResult,
    Trial,
    find_peak_rate,
    trial_verdict,
)
from replaybench.backends.base import Availability, BackendOptions
from replaybench.errors import UsageError
from replaybench.replay import VirtualClock
from replaybench.results.records import FrameRecord
from replaybench.types import BackendResult, Frame, StageTimes

NS = 1_000_000_000
OPTIONS = BackendOptions()


class ServiceTimeBackend:
    """Takes exactly ``service_s`` of virtual time per frame."""

    name: ClassVar[str] = 'service'
    description: ClassVar[str] = 'declared service time'

    def __init__(self, clock: VirtualClock, service_s: float) -> None:
        self.clock = clock
        self.service_s = service_s

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Frame) -> BackendResult:
        self.clock.advance(self.service_s)
        return BackendResult((), StageTimes(infer_ns=round(self.service_s * 1e9)))

    def info(self) -> dict[str, Any]:
        return {'service_s': self.service_s}

    def close(self) -> None:
        pass


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('bag') / 'cam.mcap'
    frames = noise_frames(60, width=16, height=12)
    t0 = 1_700_000_000 * NS
    stamps = [t0 + i * NS // 30 for i in range(len(frames))]
    write_mcap(
        path,
        [
            ('/cam/image_raw', t, image_msg(t, f), 'sensor_msgs/msg/Image')
            for t, f in zip(stamps, frames, strict=True)
        ],
    )
    return path


def _sweep(bag: Path, out: Path, service_s: float, **kwargs: Any) -> PeakResult:
    clock = VirtualClock()
    backend = ServiceTimeBackend(clock, service_s)
    return find_peak_rate(
        bag,
        'service',
        out,
        options=OPTIONS,
        clock=clock,
        backend_factory=lambda name, options: backend,
        **kwargs,
    )


@pytest.mark.parametrize('service_s', [0.020, 0.021, 0.033])
def test_without_drops_allowed_the_peak_is_just_under_the_service_rate(
    bag: Path, tmp_path: Path, service_s: float
) -> None:
    result = _sweep(bag, tmp_path / 'peak', service_s, max_drop=0.0, report=False)
    capacity = 1 / service_s
    peak = json.loads((tmp_path / 'peak' / 'peak.json').read_text())
    resolution = peak['resolution_hz']
    assert result.peak_hz is not None
    assert resolution is not None
    assert 0 < resolution <= capacity / 2**4 * 1.05  # start rate / 2**refine_steps
    # a queue of depth 1 only drops once the backlog reaches one period: over the 54 frames
    # after warm-up that happens just above the service rate, never below it
    assert capacity - resolution <= result.peak_hz <= capacity * (1 + 1 / 54)
    assert peak['first_failing_hz'] == pytest.approx(result.peak_hz + resolution)
    assert all(t.dropped == 0 for t in result.trials if t.ok)
    assert all(t.dropped > 0 for t in result.trials if not t.ok)


def test_the_sweep_starts_at_the_probe_rate_doubles_then_bisects(bag: Path, tmp_path: Path) -> None:
    result = _sweep(bag, tmp_path / 'peak', 0.02, max_drop=0.0, report=False)
    # probe: 50 frames/s; 50 Hz passes, 100 fails, then 75, 62.5, 56.25, 53.125 all fail;
    # a second trial at 50 Hz confirms it
    assert [t.rate_hz for t in result.trials] == [50.0, 100.0, 75.0, 62.5, 56.25, 53.125, 50.0]
    assert [t.ok for t in result.trials] == [True] + [False] * 5 + [True]
    assert result.trials[-1].attempt == 2
    assert result.confirmed
    assert result.peak_hz == 50.0
    assert result.status == 'complete'


def test_a_drop_tolerance_lets_the_rate_go_past_the_service_rate(bag: Path, tmp_path: Path) -> None:
    strict = _sweep(bag, tmp_path / 'strict', 0.021, max_drop=0.0, report=False)
    loose = _sweep(bag, tmp_path / 'loose', 0.021, max_drop=0.15, report=False)
    assert strict.peak_hz is not None
    assert loose.peak_hz is not None
    assert loose.peak_hz > strict.peak_hz
    # about 1 - service rate / rate of the frames are dropped above the service rate
    assert loose.peak_hz <= (1 / 0.021) / (1 - 0.15) * 1.05
    ok = [t for t in loose.trials if t.ok]
    failed = [t for t in loose.trials if not t.ok]
    assert all(t.drop_fraction <= 0.15 for t in ok)
    assert all(t.drop_fraction > 0.15 for t in failed)
    assert max(t.rate_hz for t in ok) == loose.peak_hz < min(t.rate_hz for t in failed)


def test_a_failing_start_rate_is_halved_until_a_trial_passes(bag: Path, tmp_path: Path) -> None:
    clock = VirtualClock()
    made: list[ServiceTimeBackend] = []

    def factory(_name: str, _options: BackendOptions) -> ServiceTimeBackend:
        # the max-rate probe sees a 10 ms backend, every trial a 20 ms one
        made.append(ServiceTimeBackend(clock, 0.010 if not made else 0.020))
        return made[-1]

    result = find_peak_rate(
        bag,
        'service',
        tmp_path / 'peak',
        options=OPTIONS,
        max_drop=0.0,
        clock=clock,
        backend_factory=factory,
        report=False,
    )
    assert [t.rate_hz for t in result.trials] == [100.0, 50.0, 75.0, 62.5, 56.25, 53.125, 50.0]
    assert result.peak_hz == 50.0


def test_an_unreachable_p99_bound_leaves_no_peak_after_halving_to_the_lowest_rate(
    bag: Path, tmp_path: Path
) -> None:
    result = _sweep(bag, tmp_path / 'peak', 0.02, p99_bound_ms=15.0, min_hz=5.0, report=False)
    assert result.peak_hz is None
    assert [t.rate_hz for t in result.trials] == [50.0, 25.0, 12.5, 6.25, 5.0]
    assert all(t.dropped == 0 and t.p99_ms == pytest.approx(20.0) for t in result.trials[1:])
    assert not any(t.ok for t in result.trials)


def test_a_p99_bound_above_the_service_time_does_not_change_the_peak(
    bag: Path, tmp_path: Path
) -> None:
    result = _sweep(bag, tmp_path / 'peak', 0.02, max_drop=0.0, p99_bound_ms=25.0, report=False)
    assert result.peak_hz == 50.0
    assert result.p99_bound_ms == 25.0


def test_the_highest_rate_caps_the_search(bag: Path, tmp_path: Path) -> None:
    result = _sweep(bag, tmp_path / 'peak', 0.001, max_hz=120.0, report=False)
    assert [t.rate_hz for t in result.trials] == [120.0, 120.0]
    assert result.peak_hz == 120.0
    peak = json.loads((tmp_path / 'peak' / 'peak.json').read_text())
    assert peak['limit_reached'] is True
    assert peak['first_failing_hz'] is None


def test_peak_json_lists_every_trial_and_each_trial_replays_distinct_frames_once(
    bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / 'peak'
    result = _sweep(bag, out, 0.02, trial_frames=25, refine_steps=2)
    peak = json.loads((out / 'peak.json').read_text())
    assert peak['schema_version'] == PEAK_SCHEMA_VERSION
    assert peak['kind'] == 'peak'
    assert peak['backend'] == 'service'
    assert peak['settings']['trial_frames'] == 25
    assert peak['settings']['queue_depth'] == 1
    assert peak['start']['from'] == 'max-rate probe'
    assert peak['start']['probe_fps'] == pytest.approx(50.0)
    assert peak['start']['recorded_hz'] == pytest.approx(30.0)
    assert peak['input']['sha256']
    # a rate search's trials have no copies (``peak --cameras``): peak.json leaves the key out
    assert all(
        t.copies is None and 'copies' not in row
        for t, row in zip(result.trials, peak['trials'], strict=True)
    )
    assert [tuple(t.values()) for t in peak['trials']] == [tuple(t)[:-1] for t in result.trials]
    assert peak['peak_hz'] == result.peak_hz
    for trial in [*result.trials, None]:
        run_dir = out / (trial.run_dir if trial else 'trials/max')
        with (run_dir / 'frames.csv').open(newline='') as f:
            rows = list(csv.DictReader(f))
        assert sorted(int(r['seq']) for r in rows) == list(range(25))
        run = json.loads((run_dir / 'run.json').read_text())
        assert run['settings']['queue_depth'] == 1
        if trial:
            assert run['settings']['rate'] == f'{trial.rate_hz:g}hz'
    assert (out / 'peak.html').is_file()
    assert not (out / 'trials' / 'max' / 'report.html').exists()


def test_a_real_clock_sweep_with_the_null_backend_writes_its_files(
    bag: Path, tmp_path: Path
) -> None:
    seen: list[Trial] = []
    out = tmp_path / 'peak'
    result = find_peak_rate(
        bag,
        'null',
        out,
        options=OPTIONS,
        trial_frames=12,
        min_hz=40.0,
        max_hz=80.0,
        refine_steps=1,
        progress=seen.append,
    )
    assert result.trials
    assert seen == list(result.trials)
    assert all(40.0 <= t.rate_hz <= 80.0 for t in result.trials)
    assert result.peak_hz is None or result.peak_hz in {t.rate_hz for t in result.trials if t.ok}
    assert (out / 'peak.json').is_file()
    assert 'replaybench peak rate' in (out / 'peak.html').read_text(encoding='utf-8')


def test_a_non_empty_output_folder_needs_force(bag: Path, tmp_path: Path) -> None:
    out = tmp_path / 'peak'
    _sweep(bag, out, 0.001, max_hz=60.0, report=False)
    with pytest.raises(UsageError, match='not empty'):
        _sweep(bag, out, 0.001, max_hz=60.0, report=False)
    again = _sweep(bag, out, 0.001, max_hz=30.0, force=True, report=False)
    assert again.peak_hz == 30.0
    assert not (out / 'trials' / '60.000hz').exists()


@pytest.mark.parametrize(
    ('kwargs', 'message'),
    [
        ({'max_drop': 1.0}, 'max-drop'),
        ({'max_drop': -0.1}, 'max-drop'),
        ({'p99_bound_ms': 0.0}, 'p99-ms'),
        ({'trial_frames': 0}, 'trial-frames'),
        ({'min_hz': 0.0}, 'lowest rate'),
        ({'min_hz': 0.0004}, 'lowest rate'),
        ({'min_hz': 10.0, 'max_hz': 5.0}, 'below the lowest'),
        ({'refine_steps': -1}, 'refinement'),
    ],
)
def test_bad_settings_are_refused_before_anything_runs(
    bag: Path, tmp_path: Path, kwargs: dict[str, Any], message: str
) -> None:
    with pytest.raises(UsageError, match=message):
        _sweep(bag, tmp_path / 'peak', 0.02, **kwargs)
    assert not (tmp_path / 'peak').exists()


def _rec(seq: int, status: str, warmup: bool, release: float, latency: float | None) -> FrameRecord:
    return FrameRecord(
        0, 'b', '/cam', seq, seq, None, status, '', warmup, status == 'dropped', release,  # type: ignore[arg-type]
        latency_ms=latency,
    )  # fmt: skip


def test_drops_during_warm_up_do_not_count_against_a_trial() -> None:
    records = [
        _rec(0, 'ok', True, 0.0, 900.0),  # a slow first call ...
        _rec(1, 'dropped', False, 0.1, None),  # ... pushes frames out while it runs
        _rec(2, 'dropped', False, 0.2, None),
        _rec(3, 'ok', True, 0.3, 10.0),
        _rec(4, 'ok', False, 0.4, 10.0),  # first measured frame
        _rec(5, 'dropped', False, 0.5, None),
        _rec(6, 'ok', False, 0.6, 12.0),
        _rec(7, 'ok', False, 0.7, 11.0),
    ]
    frames, dropped, p99, ok = trial_verdict(records, max_drop=0.25, p99_bound_ms=None)
    assert (frames, dropped) == (4, 1)
    assert p99 == pytest.approx(11.98)  # [10, 11, 12] at rank 0.99 * 2 = 1.98
    assert ok
    assert not trial_verdict(records, max_drop=0.2, p99_bound_ms=None)[3]
    assert not trial_verdict(records, max_drop=0.25, p99_bound_ms=11.5)[3]
    assert trial_verdict(records, max_drop=0.25, p99_bound_ms=12.0)[3]


def test_a_trial_that_measured_nothing_fails() -> None:
    records = [_rec(0, 'ok', True, 0.0, 5.0), _rec(1, 'dropped', False, 0.1, None)]
    assert trial_verdict(records, max_drop=0.5, p99_bound_ms=None) == (2, 1, None, False)


def test_an_interrupted_sweep_keeps_the_finished_trials_and_says_so(
    bag: Path, tmp_path: Path
) -> None:
    clock = VirtualClock()

    class Interrupting(ServiceTimeBackend):
        calls = 0

        def detect(self, frame: Frame) -> BackendResult:
            Interrupting.calls += 1
            if Interrupting.calls == 60 + 60 + 30:  # during the second trial
                raise KeyboardInterrupt
            return super().detect(frame)

    backend = Interrupting(clock, 0.02)
    out = tmp_path / 'peak'
    result = find_peak_rate(
        bag,
        'service',
        out,
        options=OPTIONS,
        max_drop=0.0,
        clock=clock,
        backend_factory=lambda name, options: backend,
    )
    assert result.status == 'interrupted'
    assert [t.rate_hz for t in result.trials] == [50.0, 100.0]
    assert not result.trials[1].ok  # an interrupted trial never passes
    assert result.peak_hz == 50.0
    peak = json.loads((out / 'peak.json').read_text())
    assert peak['status'] == 'interrupted'
    assert 'The sweep was interrupted' in (out / 'peak.html').read_text(encoding='utf-8')
