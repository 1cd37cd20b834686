"""Availability of the GPU backends: cheap checks, clear reasons, no heavy imports."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
from backends.gpu.gpuhelpers import has

from replaybench.backends import backend_table, get_backend
from replaybench.backends.gpu import _cuda, availability
from replaybench.backends.gpu._cuda import StageClock, cache_dir, device_facts, driver_problem
from replaybench.errors import BackendUnavailableError

GPU_BACKENDS = ('cuda', 'tensorrt', 'hsv-cuda')
NO_DRIVER = driver_problem() is not None
no_gpu_only = pytest.mark.skipif(not NO_DRIVER, reason='this machine has an NVIDIA GPU')


def _without(monkeypatch: pytest.MonkeyPatch, *modules: str) -> None:
    """Make ``find_spec`` report ``modules`` as not installed."""
    real = importlib.util.find_spec

    def find_spec(name: str, package: str | None = None) -> object:
        if name.split('.')[0] in modules:
            return None
        return real(name, package)

    monkeypatch.setattr(importlib.util, 'find_spec', find_spec)


def test_the_three_gpu_backends_are_registered_with_descriptions():
    rows = {row.name: row for row in backend_table()}
    for name in GPU_BACKENDS:
        assert rows[name].origin == 'built-in'
        assert rows[name].description
        assert get_backend(name).name == name
        status = rows[name].availability
        assert status.ok or status.reason, f'{name} unavailable without a reason'


@no_gpu_only
def test_without_a_driver_every_gpu_backend_names_the_missing_gpu_first():
    assert driver_problem() == 'no NVIDIA GPU/driver found (libcuda not loadable)'
    for name in GPU_BACKENDS:
        status = get_backend(name).available()
        assert not status.ok
        assert status.reason.startswith('no NVIDIA GPU/driver found (libcuda not loadable)')


@no_gpu_only
def test_device_facts_refuse_without_a_driver():
    with pytest.raises(BackendUnavailableError, match='libcuda'):
        device_facts(0)


def test_a_cpu_onnxruntime_build_is_told_to_install_onnxruntime_gpu():
    import onnxruntime

    if 'CUDAExecutionProvider' in onnxruntime.get_available_providers():
        pytest.skip('this onnxruntime build has the CUDA provider')
    problem = availability.ort_provider_problem('CUDAExecutionProvider')
    assert problem is not None
    assert 'has no CUDAExecutionProvider' in problem
    assert 'install onnxruntime-gpu' in problem
    assert 'docs/gpu.md' in problem


def test_a_faked_gpu_provider_list_passes_the_build_check(monkeypatch):
    import onnxruntime

    providers = ['TensorrtExecutionProvider', 'CUDAExecutionProvider', 'CPUExecutionProvider']
    monkeypatch.setattr(onnxruntime, 'get_available_providers', lambda: providers)
    assert availability.ort_provider_problem('CUDAExecutionProvider') is None
    assert availability.ort_provider_problem('TensorrtExecutionProvider') is None


def test_missing_cupy_is_named_with_the_install_command(monkeypatch):
    _without(monkeypatch, 'cupy')
    status = availability.hsv_cuda_availability()
    assert not status.ok
    assert "cupy not installed: pip install 'replaybench[gpu]'" in status.reason
    assert availability.cupy_problem() == "cupy not installed: pip install 'replaybench[gpu]'"


def test_missing_torch_and_onnx2torch_are_named_for_cuda(monkeypatch):
    import onnxruntime

    monkeypatch.setattr(onnxruntime, 'get_available_providers', lambda: ['CPUExecutionProvider'])
    _without(monkeypatch, 'torch', 'onnx2torch')
    reason = availability.cuda_availability().reason
    assert 'torch is not installed' in reason
    assert 'onnx2torch is not installed' in reason
    assert availability.torch_problem() == "torch is not installed: pip install 'replaybench[gpu]'"


@pytest.mark.skipif(not has('torch'), reason='torch is not installed')
def test_a_cpu_only_torch_build_is_not_taken_for_a_gpu_one():
    import torch

    if torch.version.cuda is not None:
        pytest.skip('torch here is a CUDA build')
    problem = availability.torch_problem()
    assert problem is not None
    assert 'CPU-only build' in problem


def test_missing_tensorrt_libraries_are_named():
    if availability.tensorrt_problem() is None:
        pytest.skip('libnvinfer loads on this machine')
    assert 'TensorRT' in (availability.tensorrt_problem() or '')
    assert 'TensorRT' in availability.tensorrt_availability().reason


def test_a_missing_driver_library_is_reported_not_raised(monkeypatch):
    monkeypatch.setattr(_cuda, '_library_names', lambda: ['libdoes-not-exist-replaybench.so'])
    _cuda.load_libcuda.cache_clear()
    _cuda._device_count.cache_clear()
    try:
        assert _cuda.load_libcuda() is None
        assert driver_problem() == 'no NVIDIA GPU/driver found (libcuda not loadable)'
        assert driver_problem(3) == 'no NVIDIA GPU/driver found (libcuda not loadable)'
    finally:
        _cuda.load_libcuda.cache_clear()
        _cuda._device_count.cache_clear()


def test_importing_and_asking_the_gpu_backends_imports_neither_torch_nor_cupy():
    code = (
        'import sys\n'
        'from replaybench.backends import get_backend\n'
        'for name in ("cuda", "tensorrt", "hsv-cuda"):\n'
        '    get_backend(name)\n'
        'heavy = [m for m in ("torch", "cupy", "onnx2torch", "cv2") if m in sys.modules]\n'
        'print(heavy)\n'
    )
    if not NO_DRIVER:  # with a GPU, available() may import torch / cupy to ask them
        code = code.replace('get_backend(name)', 'get_backend(name)  # no available()')
    else:
        code = code.replace('get_backend(name)', 'get_backend(name).available()')
    out = subprocess.run(
        [sys.executable, '-c', code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == '[]'


def test_the_engine_cache_follows_xdg_cache_home(monkeypatch, tmp_path):
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path))
    assert cache_dir('trt') == tmp_path / 'replaybench' / 'trt'
    monkeypatch.setenv('XDG_CACHE_HOME', 'relative/ignored')
    monkeypatch.setenv('HOME', str(tmp_path / 'home'))
    assert cache_dir('trt') == Path(tmp_path / 'home' / '.cache' / 'replaybench' / 'trt')


def test_a_stage_clock_synchronises_before_every_reading():
    calls: list[str] = []
    clock = StageClock(lambda: calls.append('sync'))
    clock.start()
    clock.begin()
    first = clock.lap()
    clock.begin()
    second = clock.lap()
    assert calls == ['sync', 'sync', 'sync']
    assert first >= 0
    assert second >= 0
