"""The GPU backends' own control flow (open, warm-up, stages, info, close) with CPU stand-ins.

These tests do NOT exercise a GPU: NumPy + SciPy stand in for CuPy, torch on the CPU for torch
on CUDA, onnxruntime's CPU provider for its CUDA provider, and a fake libcuda answers the driver
queries (``gpufakes``). They check what the backends do around the device code: the order of the
steps, the stage timings, the recorded facts and the detections, which must equal the CPU
backends'.
"""

from __future__ import annotations

import importlib.util
import sys
from typing import Any

import numpy as np
import pytest
from backends.gpu.gpufakes import GPU_A, fake_cupy, fake_gpu_build, torch_on_the_cpu
from backends.gpu.gpuhelpers import FIXTURE_BAGS

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.backends.gpu.hsv_cuda import HsvCudaBackend
from replaybench.backends.hsv import HsvBackend
from replaybench.backends.onnx_cpu import OnnxCpuBackend
from replaybench.errors import BackendUnavailableError
from replaybench.types import Frame


def test_hsv_cuda_runs_its_steps_and_finds_what_hsv_finds(monkeypatch, scene, driver):
    driver([GPU_A])
    cupy, cupyx, ndimage = fake_cupy()
    modules = {'cupy': cupy, 'cupyx': cupyx, 'cupyx.scipy.ndimage': ndimage}
    monkeypatch.setattr(importlib, 'import_module', modules.__getitem__)
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
    assert info['device_name'] == 'Fake GPU A'
    assert info['cuda_version'] == '13.0'


def _fixture_frame() -> Frame:
    from replaybench.decode import decode_image, message_kind
    from replaybench.sources import open_source

    with open_source(FIXTURE_BAGS / 'rgb8_raw.mcap') as source:
        raw = next(m for m in source.messages() if message_kind(m.msgtype) == 'image')
        img = decode_image(raw)
    return Frame(raw.topic, raw.seq, 0, 0, '', np.array(img.image), img.encoding, img.encoding)


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


def test_cuda_opens_runs_and_records_its_engine(monkeypatch, yolox_nano, driver):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])
    torch_on_the_cpu(monkeypatch, torch)

    options = BackendOptions(model=yolox_nano, conf=0.05)
    result, info, expected = _detect_with_both(options, _fixture_frame())
    for ours, theirs in zip(result.detections, expected, strict=True):
        assert abs(ours.score - theirs.score) <= 0.03
    assert result.stages.h2d_ns is not None
    assert result.stages.d2h_ns is not None
    assert info['engine'] == 'ort'
    assert info['providers'][0] == 'CUDAExecutionProvider'
    assert info['precision'] == 'fp32'
    assert info['device_name'] == 'Fake GPU A'
    assert info['family'] == 'yolox'


def _bundled_model() -> Any:
    from replaybench.detector.spec import DEFAULT_MODEL

    if not DEFAULT_MODEL.is_file():
        pytest.skip(f'{DEFAULT_MODEL} is not installed')
    return DEFAULT_MODEL


@pytest.mark.parametrize('which', ['bundled', 'yolox_nano'])
def test_cuda_torch_engine_converts_the_model_and_finds_what_onnx_cpu_finds(
    monkeypatch, request, which, driver
):
    torch = pytest.importorskip('torch')
    if importlib.util.find_spec('onnx2torch') is None:
        pytest.skip('onnx2torch is not installed (make install)')
    model = _bundled_model() if which == 'bundled' else request.getfixturevalue('yolox_nano')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)

    options = BackendOptions(model=model, conf=0.05, engine='torch')
    result, info, expected = _detect_with_both(options, _fixture_frame())
    for ours, theirs in zip(result.detections, expected, strict=True):
        # the device letterbox resizes with torch, onnx-cpu with OpenCV: near, not equal
        assert abs(ours.score - theirs.score) <= 0.01
        for a, b in zip(ours[3:7], theirs[3:7], strict=True):
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
    torch_on_the_cpu(monkeypatch, torch)

    backend = CudaBackend(BackendOptions(model=tiny_model, engine='torch'))
    with pytest.raises(BackendUnavailableError, match=r'NonMaxSuppression.*torchvision'):
        backend.open()
    assert 'torchvision' not in sys.modules
