"""The GPU backends never run on the CPU: onnxruntime's session providers are checked.

onnxruntime-gpu lists the CUDA / TensorRT providers even where they cannot load, and then runs
on the CPU with only a warning. These tests fake exactly that at the onnxruntime boundary: the
build list says the GPU provider is there, the real session created from a real model file
reports the CPU provider only.
"""

from __future__ import annotations

import pytest
from backends.gpu.gpufakes import GPU_A, GPU_B, fake_gpu_build, fake_loader, torch_on_the_cpu
from backends.gpu.gpuhelpers import has

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu.availability import check_session_providers
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.backends.gpu.tensorrt import TensorrtBackend, trt_cache_dir
from replaybench.errors import BackendError, BackendUnavailableError


def test_cuda_refuses_a_session_that_fell_back_to_the_cpu(monkeypatch, tiny_model, driver):
    torch = pytest.importorskip('torch')
    driver([GPU_A, GPU_B])
    torch_on_the_cpu(monkeypatch, torch)
    seen = fake_gpu_build(monkeypatch, ['CPUExecutionProvider'], placement={})
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort', device=1))
    with pytest.raises(BackendUnavailableError) as err:
        backend.open()
    message = str(err.value)
    assert 'CUDAExecutionProvider' in message
    assert 'CPUExecutionProvider' in message
    assert 'refusing to run on the CPU' in message
    assert seen.providers[0] == [('CUDAExecutionProvider', {'device_id': 1, 'use_tf32': 0})]


def test_cuda_auto_picks_one_engine_and_never_switches_after_it_fails(
    monkeypatch, tiny_model, driver
):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    seen = fake_gpu_build(monkeypatch, ['CPUExecutionProvider'], placement={})
    backend = CudaBackend(BackendOptions(model=tiny_model))
    with pytest.raises(BackendUnavailableError) as err:
        backend.open()
    message = str(err.value)
    assert message.startswith(
        'cuda: engine ort (auto: onnxruntime has CUDAExecutionProvider): onnxruntime did not '
        'enable CUDAExecutionProvider'
    )
    assert message.endswith('(not switching engines: pass --engine torch to try it)')
    assert len(seen.providers) == 1
    assert backend.engine_name == ''


@pytest.mark.skipif(not has('torch'), reason='torch is not installed')
def test_a_gpu_session_without_a_cuda_torch_is_refused_too(monkeypatch, tiny_model):
    import torch

    if torch.cuda.is_available():
        pytest.skip('torch can use CUDA here')
    fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort'))
    with pytest.raises(BackendUnavailableError, match='torch'):
        backend.open()


def test_tensorrt_refuses_a_session_without_its_provider(monkeypatch, tiny_model, tmp_path, driver):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    fake_loader(monkeypatch, {'libnvinfer.so.10': 101300, 'libnvonnxparser.so.10': None})
    seen = fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])
    cache = tmp_path / 'engines'
    options = BackendOptions(model=tiny_model, precision='fp16', extra={'trt_cache': str(cache)})
    backend = TensorrtBackend(options)
    with pytest.raises(BackendUnavailableError) as err:
        backend.open()
    assert 'did not enable TensorrtExecutionProvider' in str(err.value)
    assert 'CUDAExecutionProvider' in str(err.value)
    (name, trt), (cuda, _) = seen.providers[-1]
    assert (name, cuda) == ('TensorrtExecutionProvider', 'CUDAExecutionProvider')
    assert trt['trt_fp16_enable'] is True
    assert trt['trt_engine_cache_enable'] is True
    assert backend.engine_key is not None
    assert trt['trt_engine_cache_path'] == str(cache / backend.engine_key.digest())
    assert (cache / backend.engine_key.digest() / 'key.json').is_file()


def test_tensorrt_without_libnvinfer_says_so_before_building_a_session(
    monkeypatch, tiny_model, driver
):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    fake_loader(monkeypatch, {})
    seen = fake_gpu_build(monkeypatch, ['TensorrtExecutionProvider'])
    with pytest.raises(BackendUnavailableError, match=r'libnvinfer\.so\.10, libnvonnxparser'):
        TensorrtBackend(BackendOptions(model=tiny_model)).open()
    assert seen.providers == []


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
        (BackendOptions(precision='int4'), 'unknown --precision'),
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


def _gpu_listed(monkeypatch):
    """onnxruntime's build lists the GPU providers (as onnxruntime-gpu does); sessions are real."""
    import onnxruntime

    monkeypatch.setattr(
        onnxruntime,
        'get_available_providers',
        lambda: ['CUDAExecutionProvider', 'CPUExecutionProvider'],
    )


def test_a_cuda_provider_that_cannot_load_is_blamed_on_the_libraries_it_lacks(
    monkeypatch, tiny_model, driver
):
    # a real session: onnxruntime leaves the model to the CPU and, with CPU fallback disabled,
    # fails with "... assigned to the default CPU EP ..."; the backend names what is missing
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    _gpu_listed(monkeypatch)
    fake_loader(monkeypatch, {'libcudart.so.13': 13000})
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort'))
    with pytest.raises(BackendUnavailableError) as err:
        backend.open()
    message = str(err.value)
    assert 'onnxruntime could not load CUDAExecutionProvider' in message
    assert 'libcublasLt.so.13, libcublas.so.13, libcudnn.so.9, not found' in message
    assert 'assigned to the default CPU EP' in message  # onnxruntime's own words, kept
    assert 'would run part of' not in message


def test_with_every_library_there_the_loader_says_why_the_provider_library_does_not_load(
    monkeypatch, tiny_model, driver, tmp_path
):
    from replaybench.backends.gpu import availability

    torch = pytest.importorskip('torch')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    _gpu_listed(monkeypatch)
    provider = tmp_path / 'libonnxruntime_providers_cuda.so'
    provider.write_bytes(b'')
    monkeypatch.setattr(availability, 'ort_provider_library', lambda name: provider)
    fake_loader(
        monkeypatch,
        {
            'libcudart.so.13': 13000,
            'libcublasLt.so.13': None,
            'libcublas.so.13': None,
            'libcudnn.so.9': 90100,
        },
    )
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort'))
    with pytest.raises(BackendUnavailableError) as err:
        backend.open()
    message = str(err.value)
    assert (
        f'libonnxruntime_providers_cuda.so does not load: {provider}: cannot open shared object '
        'file' in message
    )


def test_an_onnxruntime_without_the_provider_library_is_named_as_the_cpu_build(monkeypatch):
    from replaybench.backends.gpu import availability

    fake_loader(
        monkeypatch,
        {
            'libcudart.so.13': 13000,
            'libcublasLt.so.13': None,
            'libcublas.so.13': None,
            'libcudnn.so.9': 90100,
        },
    )
    library = availability.ort_provider_library('CUDAExecutionProvider')
    assert library is not None
    assert library.name == 'libonnxruntime_providers_cuda.so'
    assert library.parent.name == 'capi'
    if library.is_file():
        pytest.skip('this onnxruntime is a GPU build')
    problem = availability.ort_provider_load_problem('CUDAExecutionProvider')
    assert problem is not None
    assert problem.startswith(
        'onnxruntime has no libonnxruntime_providers_cuda.so (not an onnxruntime-gpu build)'
    )
    assert availability.ort_provider_load_problem('CPUExecutionProvider') is None
