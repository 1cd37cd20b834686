"""The GPU backends never run on the CPU: onnxruntime's session providers are checked.

onnxruntime-gpu lists the CUDA / TensorRT providers even where they cannot load, and then runs
on the CPU with only a warning. These tests fake exactly that at the onnxruntime boundary: the
build list says the GPU provider is there, the real session created from a real model file
reports the CPU provider only.
"""

from __future__ import annotations

from typing import Any

import onnxruntime
import pytest
from backends.gpu.gpuhelpers import has

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu import tensorrt as tensorrt_module
from replaybench.backends.gpu.availability import check_session_providers
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.backends.gpu.tensorrt import TensorrtBackend, trt_cache_dir
from replaybench.errors import BackendError, BackendUnavailableError

GPU_PROVIDERS = ['TensorrtExecutionProvider', 'CUDAExecutionProvider', 'CPUExecutionProvider']


def _fake_gpu_build(monkeypatch: pytest.MonkeyPatch, reported: list[str]) -> list[Any]:
    """onnxruntime claims the GPU providers; every session it creates reports ``reported``."""
    real = onnxruntime.InferenceSession
    asked: list[Any] = []

    class Session(real):  # type: ignore[misc, valid-type]
        def __init__(self, path: str, options: Any = None, providers: Any = None) -> None:
            asked.append(providers)
            super().__init__(path, options, providers=['CPUExecutionProvider'])

        def get_providers(self) -> list[str]:
            return list(reported)

    monkeypatch.setattr(onnxruntime, 'get_available_providers', lambda: list(GPU_PROVIDERS))
    monkeypatch.setattr(onnxruntime, 'InferenceSession', Session)
    return asked


def test_cuda_refuses_a_session_that_fell_back_to_the_cpu(monkeypatch, tiny_model):
    asked = _fake_gpu_build(monkeypatch, ['CPUExecutionProvider'])
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort', device=1))
    with pytest.raises(BackendUnavailableError) as err:
        backend.open()
    message = str(err.value)
    assert 'CUDAExecutionProvider' in message
    assert 'CPUExecutionProvider' in message
    assert 'refusing to run on the CPU' in message
    assert asked[0][0] == ('CUDAExecutionProvider', {'device_id': 1})


def test_cuda_auto_reports_why_each_engine_is_unusable(monkeypatch, tiny_model):
    _fake_gpu_build(monkeypatch, ['CPUExecutionProvider'])
    backend = CudaBackend(BackendOptions(model=tiny_model))
    with pytest.raises(BackendUnavailableError) as err:
        backend.open()
    message = str(err.value)
    assert 'engine ort: onnxruntime did not enable CUDAExecutionProvider' in message
    assert 'engine torch:' in message


@pytest.mark.skipif(not has('torch'), reason='torch is not installed')
def test_a_gpu_session_without_a_cuda_torch_is_refused_too(monkeypatch, tiny_model):
    import torch

    if torch.cuda.is_available():
        pytest.skip('torch can use CUDA here')
    _fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort'))
    with pytest.raises(BackendUnavailableError, match='torch'):
        backend.open()


def test_tensorrt_refuses_a_session_without_its_provider(monkeypatch, tiny_model, tmp_path):
    asked = _fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])
    monkeypatch.setattr(tensorrt_module, 'tensorrt_problem', lambda: None)
    cache = tmp_path / 'engines'
    options = BackendOptions(model=tiny_model, precision='fp16', extra={'trt_cache': str(cache)})
    with pytest.raises(BackendUnavailableError) as err:
        TensorrtBackend(options).open()
    assert 'did not enable TensorrtExecutionProvider' in str(err.value)
    assert 'CUDAExecutionProvider' in str(err.value)
    name, trt = asked[0][0]
    assert name == 'TensorrtExecutionProvider'
    assert trt['trt_fp16_enable'] is True
    assert trt['trt_engine_cache_enable'] is True
    assert trt['trt_engine_cache_path'] == str(cache)
    assert cache.is_dir()


def test_tensorrt_without_libnvinfer_says_so_before_building_a_session(monkeypatch, tiny_model):
    asked = _fake_gpu_build(monkeypatch, ['TensorrtExecutionProvider'])
    monkeypatch.setattr(tensorrt_module, 'tensorrt_problem', lambda: 'TensorRT libraries missing')
    with pytest.raises(BackendUnavailableError, match='TensorRT libraries missing'):
        TensorrtBackend(BackendOptions(model=tiny_model)).open()
    assert asked == []


def test_the_session_check_wants_the_gpu_provider_first():
    class Session:
        def __init__(self, providers: list[str]) -> None:
            self.providers = providers

        def get_providers(self) -> list[str]:
            return self.providers

    ok = Session(['CUDAExecutionProvider', 'CPUExecutionProvider'])
    assert check_session_providers(ok, 'CUDAExecutionProvider') == ok.providers
    for providers in (
        ['CPUExecutionProvider'],
        [],
        ['CPUExecutionProvider', 'CUDAExecutionProvider'],
    ):
        with pytest.raises(BackendUnavailableError, match='refusing to run on the CPU'):
            check_session_providers(Session(providers), 'CUDAExecutionProvider')


@pytest.mark.parametrize(
    ('options', 'match'),
    [
        (BackendOptions(engine='tensorflow'), 'unknown --engine'),
        (BackendOptions(precision='int8'), 'unknown --precision'),
        (BackendOptions(conf=1.5), '--conf must be within 0..1'),
        (BackendOptions(model_family='detr'), 'unknown --model-family'),
        (BackendOptions(device=-1), '--device must be >= 0'),
        (BackendOptions(extra={'max_det': 'many'}), 'max_det must be an integer'),
        (BackendOptions(extra={'cuda_graph': 'maybe'}), 'cuda_graph must be on or off'),
        (BackendOptions(extra={'trt_cache': '/x'}), "unknown option 'trt_cache'"),
    ],
)
def test_bad_cuda_options_are_refused_when_constructed(options, match):
    with pytest.raises(BackendError, match=match):
        CudaBackend(options)


def test_tensorrt_offers_only_the_ort_engine_and_takes_a_cache_option(tmp_path):
    with pytest.raises(BackendError, match='--engine torch is not offered'):
        TensorrtBackend(BackendOptions(engine='torch'))
    options = BackendOptions(extra={'trt_cache': str(tmp_path)})
    assert trt_cache_dir(options) == tmp_path
    assert TensorrtBackend(options).info()['engine'] is None


def test_a_missing_model_is_a_backend_error_not_a_crash(tmp_path):
    with pytest.raises(BackendError, match='not found'):
        CudaBackend(BackendOptions(model=tmp_path / 'absent.onnx')).open()
