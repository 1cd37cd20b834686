"""ResourceSampler: CPU and memory of this process, optional NVML, its own cost."""

from __future__ import annotations

import sys
import time
import types
from typing import Any

import numpy as np
import pytest

from replaybench.replay import resources
from replaybench.replay.resources import ResourceSampler

SUMMARY_KEYS = {
    'cpu_percent_mean',
    'cpu_percent_max',
    'private_mb_peak',
    'private_mb_mean',
    'mapped_mb_peak',
    'rss_mb_peak',
    'rss_mb_mean',
    'gpu_util_mean',
    'gpu_mem_mb_peak',
    'gpu_power_w_mean',
    'samples',
    'interval_s',
    'overhead_ms_per_sample',
}
SERIES_KEYS = {
    't_s',
    'cpu_percent',
    'private_mb',
    'mapped_mb',
    'rss_mb',
    'gpu_util',
    'gpu_mem_mb',
    'gpu_power_w',
    'cpu_mhz',
    'gpu_throttle',
}


@pytest.fixture
def no_nvml(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make ``import pynvml`` fail, as on a machine without it."""
    monkeypatch.setitem(sys.modules, 'pynvml', None)


def _busy(seconds: float) -> None:
    end = time.perf_counter() + seconds
    x = 0
    while time.perf_counter() < end:
        x += 1


@pytest.mark.usefixtures('no_nvml')
def test_a_busy_loop_shows_as_cpu_use() -> None:
    wall0, cpu0 = time.perf_counter(), time.process_time()
    with ResourceSampler(interval_s=0.05) as sampler:
        _busy(0.3)
    # what this process really got: less than a core when other processes compete for it
    got = 100 * (time.process_time() - cpu0) / (time.perf_counter() - wall0)
    summary = sampler.summary()
    assert set(summary) >= SUMMARY_KEYS
    assert summary['cpu_percent_mean'] == pytest.approx(got, abs=10)
    assert summary['cpu_percent_mean'] > 50 or got < 60
    assert summary['cpu_percent_max'] >= summary['cpu_percent_mean']
    assert summary['samples'] >= 4


@pytest.mark.usefixtures('no_nvml')
def test_sleeping_uses_almost_no_cpu() -> None:
    with ResourceSampler(interval_s=0.05) as sampler:
        time.sleep(0.3)
    assert sampler.summary()['cpu_percent_mean'] < 20


@pytest.mark.usefixtures('no_nvml')
def test_allocating_200_mb_raises_the_peak_rss() -> None:
    with ResourceSampler(interval_s=0.02) as sampler:
        time.sleep(0.05)
        block = np.ones(200 * 1_000_000, dtype=np.uint8)  # written, so resident
        time.sleep(0.15)
        del block
        time.sleep(0.05)
    summary = sampler.summary()
    rss = [p['rss_mb'] for p in sampler.series() if p['rss_mb'] is not None]
    assert summary['rss_mb_peak'] - rss[0] >= 150
    assert summary['rss_mb_peak'] == pytest.approx(max(rss))
    assert min(rss) <= summary['rss_mb_mean'] <= summary['rss_mb_peak']


@pytest.mark.usefixtures('no_nvml')
def test_the_series_is_downsampled_to_max_samples() -> None:
    with ResourceSampler(interval_s=0.002, max_samples=20) as sampler:
        time.sleep(0.25)
    summary = sampler.summary()
    series = sampler.series()
    assert summary['samples'] > 40
    assert 2 <= len(series) <= 20
    assert all(set(p) == SERIES_KEYS for p in series)
    times = [float(p['t_s'] or 0.0) for p in series]
    assert times == sorted(times)
    assert times[-1] == pytest.approx(summary['duration_s'], abs=0.01)
    cpu = [p['cpu_percent'] for p in series if p['cpu_percent'] is not None]
    assert len(cpu) >= len(series) - 2
    assert np.median(cpu) < 50


@pytest.mark.usefixtures('no_nvml')
def test_without_nvml_the_gpu_fields_are_none() -> None:
    with ResourceSampler(interval_s=0.02) as sampler:
        time.sleep(0.05)
    summary = sampler.summary()
    for key in ('gpu_util_mean', 'gpu_mem_mb_peak', 'gpu_power_w_mean', 'gpu_name', 'gpu_index'):
        assert summary[key] is None
    assert all(p['gpu_util'] is None and p['gpu_mem_mb'] is None for p in sampler.series())


def _fake_nvml(*, fail_init: bool = False, power: bool = True) -> types.ModuleType:
    """An NVML stand-in with one device at 40 % util, 1536 MiB used, 75 W (no GPU here)."""
    module = types.ModuleType('pynvml')
    state: dict[str, Any] = {'shutdown': 0, 'index': None}

    class NVMLError(Exception):
        pass

    def init() -> None:
        if fail_init:
            msg = 'Driver Not Loaded'
            raise NVMLError(msg)

    def handle(index: int) -> str:
        state['index'] = index
        return f'gpu{index}'

    def power_usage(_handle: str) -> int:
        if not power:
            msg = 'Not Supported'
            raise NVMLError(msg)
        return 75_000  # mW

    module.NVMLError = NVMLError  # type: ignore[attr-defined]
    module.nvmlInit = init  # type: ignore[attr-defined]
    module.nvmlShutdown = lambda: state.__setitem__('shutdown', state['shutdown'] + 1)  # type: ignore[attr-defined]
    module.nvmlDeviceGetCount = lambda: 2  # type: ignore[attr-defined]
    module.nvmlDeviceGetHandleByIndex = handle  # type: ignore[attr-defined]
    module.nvmlDeviceGetName = lambda h: b'Fake GPU'  # type: ignore[attr-defined]
    module.nvmlDeviceGetUtilizationRates = lambda h: types.SimpleNamespace(gpu=40, memory=10)  # type: ignore[attr-defined]
    module.nvmlDeviceGetMemoryInfo = lambda h: types.SimpleNamespace(used=1536 << 20)  # type: ignore[attr-defined]
    module.nvmlDeviceGetPowerUsage = power_usage  # type: ignore[attr-defined]
    module.state = state  # type: ignore[attr-defined]
    return module


def test_nvml_readings_reach_the_summary_and_series(monkeypatch: pytest.MonkeyPatch) -> None:
    fake = _fake_nvml()
    monkeypatch.setitem(sys.modules, 'pynvml', fake)
    with ResourceSampler(interval_s=0.02, gpu_index=1) as sampler:
        time.sleep(0.08)
    summary = sampler.summary()
    assert fake.state['index'] == 1
    assert fake.state['shutdown'] == 1
    assert summary['gpu_index'] == 1
    assert summary['gpu_name'] == 'Fake GPU'
    assert summary['gpu_util_mean'] == pytest.approx(40.0)
    assert summary['gpu_mem_mb_peak'] == pytest.approx(1536.0)
    assert summary['gpu_power_w_mean'] == pytest.approx(75.0)
    assert all(p['gpu_mem_mb'] == pytest.approx(1536.0) for p in sampler.series())


def test_nvml_that_fails_to_start_or_lacks_power_readings_is_not_an_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, 'pynvml', _fake_nvml(fail_init=True))
    with ResourceSampler(interval_s=0.02) as sampler:
        time.sleep(0.03)
    assert sampler.summary()['gpu_util_mean'] is None
    monkeypatch.setitem(sys.modules, 'pynvml', _fake_nvml(power=False))
    with ResourceSampler(interval_s=0.02) as sampler:
        time.sleep(0.03)
    summary = sampler.summary()
    assert summary['gpu_util_mean'] == pytest.approx(40.0)
    assert summary['gpu_power_w_mean'] is None


def test_a_gpu_index_beyond_the_devices_gives_no_gpu_fields(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, 'pynvml', _fake_nvml())
    with ResourceSampler(interval_s=0.02, gpu_index=5) as sampler:
        time.sleep(0.03)
    assert sampler.summary()['gpu_name'] is None


@pytest.mark.usefixtures('no_nvml')
def test_without_proc_the_rss_comes_from_getrusage(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Any
) -> None:
    pytest.importorskip('resource')
    monkeypatch.setattr(resources, 'PROC_SELF', tmp_path / 'no-proc')
    with ResourceSampler(interval_s=0.02) as sampler:
        _busy(0.1)
    summary = sampler.summary()
    assert summary['rss_source'] == 'getrusage_maxrss'
    assert summary['rss_mb_peak'] > 10
    assert summary['cpu_percent_mean'] > 0


@pytest.mark.usefixtures('no_nvml')
def test_the_sampler_measures_its_own_cost_and_it_is_small() -> None:
    with ResourceSampler() as sampler:  # the default interval
        time.sleep(0.6)
    summary = sampler.summary()
    assert summary['interval_s'] == resources.DEFAULT_INTERVAL_S
    assert 0 < summary['overhead_ms_per_sample'] < 20  # wall time: a busy machine stretches it
    assert 0 <= summary['overhead_cpu_percent'] < 2


@pytest.mark.usefixtures('no_nvml')
def test_summary_is_available_while_running_and_stop_is_idempotent() -> None:
    sampler = ResourceSampler(interval_s=0.02).start()
    try:
        time.sleep(0.06)
        live = sampler.summary()
        assert live['samples'] >= 2
        assert live['overhead_cpu_percent'] is None
    finally:
        sampler.stop()
    sampler.stop()
    assert sampler.summary()['samples'] >= live['samples']
    with pytest.raises(RuntimeError):
        sampler.start()


@pytest.mark.parametrize(('interval', 'max_samples'), [(0.0, 10), (-1.0, 10), (0.1, 1)])
def test_bad_settings_are_refused(interval: float, max_samples: int) -> None:
    with pytest.raises(ValueError, match='must be'):
        ResourceSampler(interval_s=interval, max_samples=max_samples)
