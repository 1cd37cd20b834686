"""The GPU backends' own control flow (open, warm-up, stages, info, close) with CPU stand-ins.

These tests do NOT exercise a GPU: NumPy + SciPy stand in for CuPy, torch on the CPU for torch
on CUDA, onnxruntime's CPU provider for its CUDA provider, and the driver queries are answered
by the test. They check what the backends do around the device code: the order of the steps,
the stage timings, the recorded facts and the detections, which must equal the CPU backends'.
"""

from __future__ import annotations

import contextlib
import importlib.util
import sys
import types
from typing import Any

import numpy as np
import onnxruntime
import pytest
from backends.gpu.gpuhelpers import FIXTURE_BAGS

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu import cuda as cuda_module
from replaybench.backends.gpu import hsv_cuda as hsv_cuda_module
from replaybench.backends.gpu._cuda import DeviceFacts
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.backends.gpu.hsv_cuda import HsvCudaBackend
from replaybench.backends.hsv import HsvBackend
from replaybench.backends.onnx_cpu import OnnxCpuBackend
from replaybench.errors import BackendUnavailableError
from replaybench.types import Frame

FACTS = DeviceFacts(0, 'stand-in', 1 << 30, 'test driver', '12.4')


class _Stream:
    """A CUDA stream stand-in: a context manager with ``synchronize``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.synchronized = 0

    def synchronize(self) -> None:
        self.synchronized += 1

    def __enter__(self) -> _Stream:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


class _DeviceArray(np.ndarray):  # type: ignore[type-arg]
    """A NumPy array with CuPy's ``set`` / ``get``."""

    def set(self, array: np.ndarray, stream: Any = None) -> None:
        self[...] = array

    def get(self, stream: Any = None) -> np.ndarray:
        return np.asarray(self).copy()


def _fake_cupy() -> tuple[Any, Any, Any]:
    numpy_like = types.SimpleNamespace(
        **{k: getattr(np, k) for k in dir(np) if not k.startswith('_')}
    )
    numpy_like.empty = lambda shape, dtype=None: np.empty(shape, dtype).view(_DeviceArray)
    numpy_like.stack = lambda arrays, axis=0: np.stack(arrays, axis).view(_DeviceArray)
    numpy_like.zeros = lambda shape, dtype=float: np.zeros(shape, dtype).view(_DeviceArray)
    numpy_like.__version__ = 'numpy stand-in'
    numpy_like.cuda = types.SimpleNamespace(
        Device=lambda index: contextlib.nullcontext(),
        Stream=_Stream,
        runtime=types.SimpleNamespace(runtimeGetVersion=lambda: 12040),
    )
    cupyx = types.SimpleNamespace(empty_pinned=lambda shape, dtype=None: np.empty(shape, dtype))
    ndimage = pytest.importorskip('scipy.ndimage', reason='scipy is not installed')
    return numpy_like, cupyx, ndimage


def test_hsv_cuda_runs_its_steps_and_finds_what_hsv_finds(monkeypatch, scene):
    cupy, cupyx, ndimage = _fake_cupy()
    modules = {'cupy': cupy, 'cupyx': cupyx, 'cupyx.scipy.ndimage': ndimage}
    monkeypatch.setattr(hsv_cuda_module.importlib, 'import_module', modules.__getitem__)
    monkeypatch.setattr(hsv_cuda_module, 'driver_problem', lambda device: None)
    monkeypatch.setattr(hsv_cuda_module, 'device_facts', lambda index: FACTS)
    s = scene(seed=2).rect('red', 10, 20, 60, 50).disc('blue', 200, 120, 30)
    frames = [s.frame('rgb8'), s.frame('bgr8', seq=1), s.frame('mono8', seq=2)]

    backend = HsvCudaBackend(BackendOptions())
    backend.open()
    results = [backend.detect(frame) for frame in frames]
    info = backend.info()
    backend.close()

    reference = HsvBackend()
    reference.open()
    for frame, result in zip(frames, results, strict=True):
        assert result.detections == reference.detect(frame).detections
        stages = result.stages
        for value in (stages.h2d_ns, stages.preprocess_ns, stages.infer_ns, stages.d2h_ns):
            assert value is not None
            assert value >= 0
    assert [d.label for d in results[0].detections] == ['red', 'blue']
    assert info['engine'] == 'cupy'
    assert info['device_name'] == 'stand-in'
    assert info['cuda_version'] == '12.4'


class _CudaNamespace:
    """``torch.cuda`` stand-in: streams and device contexts that do nothing."""

    Stream = _Stream

    @staticmethod
    def stream(stream: Any) -> Any:
        return contextlib.nullcontext()

    @staticmethod
    def device(device: Any) -> Any:
        return contextlib.nullcontext()


def _fixture_frame() -> Frame:
    from replaybench.decode import decode_image, message_kind
    from replaybench.sources import open_source

    with open_source(FIXTURE_BAGS / 'rgb8_raw.mcap') as source:
        raw = next(m for m in source.messages() if message_kind(m.msgtype) == 'image')
        img = decode_image(raw)
    return Frame(raw.topic, raw.seq, 0, 0, '', np.array(img.image), img.encoding, img.encoding)


def _torch_on_the_cpu(monkeypatch: pytest.MonkeyPatch, torch: Any) -> None:
    """CudaBackend gets CPU torch with a ``torch.cuda`` stand-in and the test's device facts."""
    stand_in = types.SimpleNamespace(**{k: getattr(torch, k) for k in dir(torch) if k[0] != '_'})
    stand_in.cuda = _CudaNamespace
    stand_in.version = types.SimpleNamespace(cuda='12.4')
    stand_in.__version__ = torch.__version__
    monkeypatch.setattr(CudaBackend, '_torch_device', lambda self: (stand_in, torch.device('cpu')))
    monkeypatch.setattr(cuda_module, 'device_facts', lambda index: FACTS)


def _detect_with_both(options: BackendOptions, frame: Frame) -> tuple[Any, dict[str, Any], Any]:
    """(cuda's result, cuda's info, onnx-cpu's detections) for one frame."""
    backend = CudaBackend(options)
    backend.open()
    result = backend.detect(frame)
    info = backend.info()
    backend.close()
    reference = OnnxCpuBackend(BackendOptions(model=options.model, conf=options.conf, threads=1))
    reference.open()
    expected = reference.detect(frame).detections
    assert len(expected) >= 1
    assert [d.label for d in result.detections] == [d.label for d in expected]
    return result, info, expected


def test_cuda_opens_runs_and_records_its_engine(monkeypatch, yolox_nano):
    torch = pytest.importorskip('torch')
    real_session = onnxruntime.InferenceSession

    class Session(real_session):  # type: ignore[misc, valid-type]
        def __init__(self, path: str, options: Any = None, providers: Any = None) -> None:
            options.intra_op_num_threads = 1
            super().__init__(path, options, providers=['CPUExecutionProvider'])

        def get_providers(self) -> list[str]:
            return ['CUDAExecutionProvider', 'CPUExecutionProvider']

    gpu = ['CUDAExecutionProvider', 'CPUExecutionProvider']
    monkeypatch.setattr(onnxruntime, 'get_available_providers', lambda: gpu)
    monkeypatch.setattr(onnxruntime, 'InferenceSession', Session)
    _torch_on_the_cpu(monkeypatch, torch)

    options = BackendOptions(model=yolox_nano, conf=0.05)
    result, info, expected = _detect_with_both(options, _fixture_frame())
    for ours, theirs in zip(result.detections, expected, strict=True):
        assert abs(ours.score - theirs.score) <= 0.03
    assert result.stages.h2d_ns is not None
    assert result.stages.d2h_ns is not None
    assert info['engine'] == 'ort'
    assert info['providers'][0] == 'CUDAExecutionProvider'
    assert info['precision'] == 'fp32'
    assert info['device_name'] == 'stand-in'
    assert info['family'] == 'yolox'


def _bundled_model() -> Any:
    from replaybench.detector.spec import DEFAULT_MODEL

    if not DEFAULT_MODEL.is_file():
        pytest.skip(f'{DEFAULT_MODEL} is not installed')
    return DEFAULT_MODEL


@pytest.mark.parametrize('which', ['bundled', 'yolox_nano'])
def test_cuda_torch_engine_converts_the_model_and_finds_what_onnx_cpu_finds(
    monkeypatch, request, which
):
    torch = pytest.importorskip('torch')
    if importlib.util.find_spec('onnx2torch') is None:
        pytest.skip('onnx2torch is not installed (make install)')
    model = _bundled_model() if which == 'bundled' else request.getfixturevalue('yolox_nano')
    _torch_on_the_cpu(monkeypatch, torch)

    options = BackendOptions(model=model, conf=0.05, engine='torch')
    result, info, expected = _detect_with_both(options, _fixture_frame())
    for ours, theirs in zip(result.detections, expected, strict=True):
        # the device letterbox resizes with torch, onnx-cpu with OpenCV: near, not equal
        assert abs(ours.score - theirs.score) <= 0.01
        for a, b in zip(ours[3:], theirs[3:], strict=True):
            assert abs(a - b) <= 0.5
    assert info['engine'] == 'torch'
    assert info['precision'] == 'fp32'
    assert info['onnx2torch']


def test_cuda_torch_engine_without_torchvision_refuses_a_model_with_nms_nodes(
    monkeypatch, tiny_model
):
    torch = pytest.importorskip('torch')
    onnx = pytest.importorskip('onnx')
    if importlib.util.find_spec('onnx2torch') is None:
        pytest.skip('onnx2torch is not installed (make install)')
    if importlib.util.find_spec('torchvision') is not None:
        pytest.skip('torchvision is installed here')
    proto = onnx.load(str(tiny_model))
    for name, value in (('boxes', np.zeros((1, 1, 4), np.float32)), ('scores', np.ones((1, 1, 1)))):
        tensor = onnx.numpy_helper.from_array(value.astype(np.float32), name)
        proto.graph.node.append(onnx.helper.make_node('Constant', [], [name], value=tensor))
    proto.graph.node.append(
        onnx.helper.make_node('NonMaxSuppression', ['boxes', 'scores'], ['selected'])
    )
    onnx.save(proto, str(tiny_model))
    stand_in = types.SimpleNamespace(__version__=torch.__version__, cuda=_CudaNamespace)
    monkeypatch.setattr(CudaBackend, '_torch_device', lambda self: (stand_in, torch.device('cpu')))

    backend = CudaBackend(BackendOptions(model=tiny_model, engine='torch'))
    with pytest.raises(BackendUnavailableError, match=r'NonMaxSuppression.*torchvision'):
        backend.open()
    assert 'torchvision' not in sys.modules
