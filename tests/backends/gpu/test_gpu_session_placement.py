"""No CPU inside a GPU session: ``session.disable_cpu_ep_fallback``, the providers checked after
creation and after the first inference, node placement recorded and checked, TensorRT refused
where it took no node; ``--engine auto`` decides once and says what it decided.

onnxruntime is faked only where it reports what a GPU build would (``gpufakes.fake_gpu_build``:
providers and the provider of each node); the session itself is a real CPU session of a real
model file, and its real node placement is what gets renamed.
"""

from __future__ import annotations

import onnxruntime
import pytest
from backends.gpu.gpufakes import GPU_A, fake_gpu_build, fake_loader, torch_on_the_cpu

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu import engine_lines
from replaybench.backends.gpu.availability import check_placement, ep_node_counts
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.backends.gpu.tensorrt import TensorrtBackend
from replaybench.errors import BackendUnavailableError
from replaybench.results.io import from_json
from replaybench.results.model import RunResult

torch = pytest.importorskip('torch')
GPU_SESSION = ['CUDAExecutionProvider', 'CPUExecutionProvider']


@pytest.fixture
def gpu(monkeypatch, driver):
    """One fake GPU, torch's CUDA calls answered on the CPU."""
    driver([GPU_A])
    return torch_on_the_cpu(monkeypatch, torch)


@pytest.mark.usefixtures('gpu')
def test_the_session_runs_every_node_on_the_gpu_provider_or_not_at_all(monkeypatch, tiny_model):
    seen = fake_gpu_build(monkeypatch, GPU_SESSION)
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort'))
    backend.open()
    info = backend.info()
    backend.close()
    options = seen.options[0]
    assert options.get_session_config_entry('session.disable_cpu_ep_fallback') == '1'
    assert options.get_session_config_entry('session.record_ep_graph_assignment_info') == '1'
    assert [p[0] for p in seen.providers[0]] == ['CUDAExecutionProvider']
    nodes = len(onnxruntime.InferenceSession(str(tiny_model)).get_provider_graph_assignment_info())
    assert info['ep_nodes'] == {'CUDAExecutionProvider': nodes}
    assert info['providers'] == GPU_SESSION


def test_onnxruntime_itself_refuses_the_cpu_provider_with_fallback_disabled(tiny_model):
    # why the GPU backends never list CPUExecutionProvider: onnxruntime rejects the pair
    options = onnxruntime.SessionOptions()
    options.add_session_config_entry('session.disable_cpu_ep_fallback', '1')
    with pytest.raises(Exception, match='disabled fallback to the CPU EP'):
        onnxruntime.InferenceSession(str(tiny_model), options, providers=['CPUExecutionProvider'])


def test_a_session_with_nodes_placed_on_the_cpu_is_refused(monkeypatch, tiny_model, gpu):
    # the providers look right; the placement (the real CPU one, not renamed) does not
    fake_gpu_build(monkeypatch, GPU_SESSION, placement={})
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort'))
    with pytest.raises(BackendUnavailableError) as err:
        backend.open()
    message = str(err.value)
    assert 'onnxruntime placed ' in message
    assert 'nodes on CPUExecutionProvider' in message
    assert message.endswith('refusing to run part of the model on the CPU')
    assert gpu.emptied == 1  # what was opened is released


@pytest.mark.usefixtures('gpu')
def test_the_providers_are_checked_again_after_the_first_inference(monkeypatch, tiny_model):
    seen = fake_gpu_build(monkeypatch, GPU_SESSION, after_run=['CPUExecutionProvider'])
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort'))
    with pytest.raises(BackendUnavailableError, match='refusing to run on the CPU'):
        backend.open()
    assert seen.runs == 1  # the warm-up inference ran, then the check refused


@pytest.mark.usefixtures('gpu')
def test_tensorrt_is_refused_where_it_took_no_node(monkeypatch, tiny_model, tmp_path):
    fake_loader(monkeypatch, {'libnvinfer.so.10': 101300, 'libnvonnxparser.so.10': None})
    reported = ['TensorrtExecutionProvider', *GPU_SESSION]
    fake_gpu_build(
        monkeypatch, reported, placement={'CPUExecutionProvider': 'CUDAExecutionProvider'}
    )
    options = BackendOptions(model=tiny_model, extra={'trt_cache': str(tmp_path)})
    with pytest.raises(BackendUnavailableError) as err:
        TensorrtBackend(options).open()
    assert 'TensorRT took none of the ' in str(err.value)
    assert 'CUDAExecutionProvider ' in str(err.value)


@pytest.mark.usefixtures('gpu')
def test_tensorrt_with_its_nodes_records_the_engine_key_and_placement(
    monkeypatch, tiny_model, tmp_path
):
    fake_loader(monkeypatch, {'libnvinfer.so.10': 101300, 'libnvonnxparser.so.10': None})
    reported = ['TensorrtExecutionProvider', *GPU_SESSION]
    fake_gpu_build(monkeypatch, reported)
    options = BackendOptions(model=tiny_model, extra={'trt_cache': str(tmp_path)})
    first = TensorrtBackend(options)
    first.open()
    info = first.info()
    first.close()
    assert set(info['ep_nodes']) == {'TensorrtExecutionProvider'}
    key = info['trt_engine_key']
    assert key['tensorrt'] == '10.13.0'
    assert key['gpu'] == 'Fake GPU A'
    assert key['compute_capability'] == '8.6'
    assert key['precision'] == 'tf32'  # fp32 asked, on compute capability 8.6
    assert key['input_shape'] == [1, 3, 32, 64]
    assert info['precision'] == 'tf32'
    assert 'NVIDIA_TF32_OVERRIDE=0' in info['precision_note']
    assert info['trt_engine_cached'] is False
    assert first.engine_key is not None
    (tmp_path / first.engine_key.digest() / 'model_ctx.engine').write_bytes(b'built')
    second = TensorrtBackend(options)
    second.open()
    assert second.info()['trt_engine_cached'] is True
    second.close()


@pytest.mark.usefixtures('gpu')
def test_auto_picks_torch_up_front_when_onnxruntime_lacks_the_provider(monkeypatch, tiny_model):
    monkeypatch.setattr(onnxruntime, 'get_available_providers', lambda: ['CPUExecutionProvider'])
    backend = CudaBackend(BackendOptions(model=tiny_model))
    engine, why = backend.choose_engine()
    assert engine == 'torch'
    assert why.startswith('auto: onnxruntime ')
    assert 'has no CUDAExecutionProvider' in why
    assert why.endswith('; onnx2torch is installed')
    backend.open()
    info = backend.info()
    backend.close()
    assert (info['engine'], info['engine_requested'], info['engine_choice']) == (
        'torch',
        'auto',
        why,
    )


def test_the_engine_that_ran_is_printed_from_run_json():
    run = from_json(
        RunResult,
        {
            'backends': [
                {'name': 'hsv', 'label': 'hsv', 'info': {'engine': 'opencv'}},
                {
                    'name': 'cuda',
                    'label': 'cuda',
                    'info': {
                        'engine': 'ort',
                        'engine_requested': 'auto',
                        'engine_choice': 'auto: onnxruntime has CUDAExecutionProvider',
                        'precision': 'fp32',
                    },
                },
                {
                    'name': 'tensorrt',
                    'label': 'tensorrt',
                    'info': {
                        'engine': 'ort',
                        'engine_requested': 'auto',
                        'engine_choice': 'auto: onnxruntime has TensorrtExecutionProvider',
                        'precision': 'tf32',
                        'precision_note': 'TensorRT builds fp32 layers with TF32',
                    },
                },
            ]
        },
    )
    assert engine_lines(run) == [
        'cuda: engine ort (auto: onnxruntime has CUDAExecutionProvider), precision fp32',
        (
            'tensorrt: engine ort (auto: onnxruntime has TensorrtExecutionProvider), precision '
            'tf32 (TensorRT builds fp32 layers with TF32)'
        ),
    ]


def test_placement_counts_come_from_onnxruntimes_assignment_info(tiny_model):
    options = onnxruntime.SessionOptions()
    options.add_session_config_entry('session.record_ep_graph_assignment_info', '1')
    session = onnxruntime.InferenceSession(str(tiny_model), options)
    counts = ep_node_counts(session)
    assert counts is not None
    assert set(counts) == {'CPUExecutionProvider'}
    assert counts['CPUExecutionProvider'] >= 1
    with pytest.raises(BackendUnavailableError, match=r'placed .* on CPUExecutionProvider'):
        check_placement(counts, 'CUDAExecutionProvider')
    unrecorded = onnxruntime.InferenceSession(str(tiny_model))
    assert ep_node_counts(unrecorded) is None
    check_placement(None, 'CUDAExecutionProvider')  # an older onnxruntime: nothing to check
