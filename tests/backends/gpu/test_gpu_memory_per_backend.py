"""GPU memory per backend: every backend is opened before the first pass and NVML reports the
whole device, so a backend's ``gpu_mem_mb_peak`` also holds the backends opened after it.
``gpu_mem_mb_pass_peak`` is the backend's peak above the device memory at the start of its own
pass (``gpu_mem_mb_start``); run.json says so (``gpu_mem_basis``). And hsv-cuda gives its pool
back on the GPU it ran on, so the next backend does not start above it.

The device is a counter of MiB in use that the stand-in backends move as a GPU library would
(a model loaded in ``open``, the allocator growing on the first frame, everything returned in
``close``); NVML (``fake_nvml``) and the CUDA driver (``FakeLibcuda``) read it; CuPy is NumPy +
SciPy (``fake_cupy``). The replay, the sampler and run.json are real.
"""

from __future__ import annotations

import importlib
import json
import sys
import time
from typing import Any

import pytest
from backends.gpu.gpufakes import GPU_A, GPU_B, fake_cupy, fake_nvml
from backends.gpu.gpuhelpers import FIXTURE_BAGS

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu.hsv_cuda import HsvCudaBackend
from replaybench.replay.resources import GPU_MEM_BASIS, ResourceSampler
from replaybench.replay.runner import RunConfig, run_benchmark

BASE_MIB = 1024


@pytest.fixture
def cupy(monkeypatch):
    cupy, cupyx, ndimage = fake_cupy()
    modules = {'cupy': cupy, 'cupyx': cupyx, 'cupyx.scipy.ndimage': ndimage}
    real = importlib.import_module

    def import_module(name: str, package: str | None = None) -> object:
        return modules[name] if name in modules else real(name, package)

    monkeypatch.setattr(importlib, 'import_module', import_module)
    return cupy


def test_the_pass_peak_is_the_peak_above_the_device_memory_at_the_start(monkeypatch, driver):
    driver([GPU_A])
    readings = iter([3000, 3100, 3400, 3200])
    last = [3000]

    def used(_gpu: Any) -> int:
        last[0] = next(readings, last[0])
        return last[0] << 20

    monkeypatch.setitem(sys.modules, 'pynvml', fake_nvml([GPU_A], used=used))
    with ResourceSampler(interval_s=0.01, gpu_index=0) as sampler:
        time.sleep(0.06)
    summary = sampler.summary()
    assert summary['gpu_mem_mb_start'] == pytest.approx(3000)
    assert summary['gpu_mem_mb_peak'] == pytest.approx(3400)
    assert summary['gpu_mem_mb_pass_peak'] == pytest.approx(400)
    assert summary['gpu_mem_basis'] == GPU_MEM_BASIS


def test_without_nvml_there_is_no_pass_peak_and_no_basis(monkeypatch):
    monkeypatch.setitem(sys.modules, 'pynvml', None)
    with ResourceSampler(interval_s=0.01, gpu_index=0) as sampler:
        time.sleep(0.02)
    summary = sampler.summary()
    assert summary['gpu_mem_mb_start'] is None
    assert summary['gpu_mem_mb_pass_peak'] is None
    assert summary['gpu_mem_basis'] is None


class _Device:
    """MiB in use on the one fake GPU."""

    used = BASE_MIB


class _Loaded(HsvCudaBackend):
    """hsv-cuda that also holds ``model_mib`` from ``open`` and grows by ``frames_mib`` on its
    first frame, all returned in ``close``."""

    model_mib = 0
    frames_mib = 0

    def open(self) -> None:
        super().open()
        _Device.used += self.model_mib
        self._grown = False

    def detect(self, frame: Any) -> Any:
        if not self._grown:
            _Device.used += self.frames_mib
            self._grown = True
        return super().detect(frame)

    def close(self) -> None:
        super().close()
        _Device.used -= self.model_mib + (self.frames_mib if self._grown else 0)
        self._grown = False


class _Small(_Loaded):
    model_mib, frames_mib = 100, 50


class _Large(_Loaded):
    model_mib, frames_mib = 2000, 300


@pytest.mark.usefixtures('cupy')
def test_each_backend_in_a_run_gets_its_own_pass_peak_in_run_json(monkeypatch, tmp_path, driver):
    driver([GPU_A])
    _Device.used = BASE_MIB
    monkeypatch.setitem(
        sys.modules, 'pynvml', fake_nvml([GPU_A], used=lambda g: _Device.used << 20)
    )
    made = {'hsv-cuda': _Small, 'cuda': _Large}
    config = RunConfig(
        inputs=[FIXTURE_BAGS / 'rgb8_raw.mcap'],
        backends=['hsv-cuda', 'cuda'],
        out_dir=tmp_path / 'run',
        max_frames=3,
        report=False,
    )
    outcome = run_benchmark(config, backend_factory=lambda name, options: made[name](options))
    assert outcome.run_dir is not None
    run = json.loads((outcome.run_dir / 'run.json').read_text(encoding='utf-8'))
    summaries = {b['name']: b['resources']['summary'] for b in run['backends']}
    small, large = summaries['hsv-cuda'], summaries['cuda']
    # the first pass starts with both backends open: the device figure holds the large model
    assert small['gpu_mem_mb_start'] == pytest.approx(BASE_MIB + 100 + 2000)
    assert small['gpu_mem_mb_peak'] == pytest.approx(BASE_MIB + 100 + 2000 + 50)
    assert small['gpu_mem_mb_pass_peak'] == pytest.approx(50)
    # the second starts after the first closed
    assert large['gpu_mem_mb_start'] == pytest.approx(BASE_MIB + 2000)
    assert large['gpu_mem_mb_pass_peak'] == pytest.approx(300)
    assert small['gpu_mem_basis'] == large['gpu_mem_basis'] == GPU_MEM_BASIS
    assert _Device.used == BASE_MIB


def test_hsv_cuda_gives_its_pool_back_on_the_gpu_it_ran_on(cupy, driver, scene):
    driver([GPU_A, GPU_B])
    backend = HsvCudaBackend(BackendOptions(device=1))
    backend.open()
    backend.detect(scene(seed=2).rect('green', 10, 10, 50, 40).frame('bgr8'))
    backend.close()
    device_pool, pinned_pool = cupy.pools
    assert device_pool.freed_on == [1]
    assert pinned_pool.freed == 1
    assert cupy.state.device == 0  # the current device is the caller's again


def test_hsv_cuda_copies_its_tables_on_its_own_stream_on_its_gpu(cupy, driver):
    driver([GPU_A, GPU_B])
    backend = HsvCudaBackend(BackendOptions(device=1))
    backend.open()
    stream = backend._stream
    copies = list(cupy.state.copies)
    backend.close()
    assert len(copies) >= 3  # two HSV tables and the morphology kernel, then the warm-up's
    assert all(device == 1 for device, _ in copies)
    assert all(s is stream for _, s in copies)
