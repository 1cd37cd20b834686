"""Stereo models through the GPU engines (``cuda-stereo``, ``tensorrt-stereo``), with CPU
stand-ins.

These tests do NOT exercise a GPU: torch on the CPU stands in for torch on CUDA and
onnxruntime's CPU provider for its CUDA and TensorRT providers (``gpufakes``). The bundled
stereo model runs on the pairs of the stereo fixture (``write_stereo_mcap``); its disparities
must equal ``onnx-stereo``'s within a stated tolerance: 1e-4 px for the torch engine (measured:
at most 3.1e-5 px; onnx2torch's kernels sum in another order than onnxruntime's), 1e-5 px for
the ort engine where the image is resized (measured 7.6e-6 px at 640x480: torch's bilinear
resize against OpenCV's), and exactly where it is not (the network's own 320x240).
"""

from __future__ import annotations

import csv
import importlib.util
import json
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from backends.gpu.gpufakes import GPU_A, fake_gpu_build, fake_loader, torch_on_the_cpu
from backends.gpu.gpuhelpers import stereo_pairs
from typer.testing import CliRunner

from replaybench.backends import get_backend
from replaybench.backends.base import Availability, BackendOptions, backend_traits
from replaybench.backends.gpu.cuda_stereo import CudaStereoBackend
from replaybench.backends.gpu.tensorrt import TensorrtBackend
from replaybench.backends.gpu.tensorrt_stereo import TensorrtStereoBackend
from replaybench.backends.onnx_stereo import OnnxStereoBackend
from replaybench.cli import app
from replaybench.detector.spec import DEFAULT_MODEL
from replaybench.errors import BackendError
from replaybench.stereo import Disparity

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.types import FrameSet

TORCH_TOLERANCE_PX = 1e-4
ORT_RESIZED_TOLERANCE_PX = 1e-5
runner = CliRunner()


def _needs_onnx2torch() -> Any:
    torch = pytest.importorskip('torch')
    pytest.importorskip('onnx')
    if importlib.util.find_spec('onnx2torch') is None:
        pytest.skip('onnx2torch is not installed (make install)')
    return torch


@pytest.fixture(scope='module')
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    from replaybench.fixtures.stereo import write_stereo_mcap

    out = tmp_path_factory.mktemp('stereo-gpu')
    return {
        'rect': write_stereo_mcap(out / 'stereo.mcap', 2),
        'raw': write_stereo_mcap(out / 'stereo_raw.mcap', 2, raw=True),
        'large': write_stereo_mcap(out / 'stereo_640.mcap', 2, (640, 480)),
    }


def _disparities(backend: Any, sets: list[FrameSet]) -> tuple[list[Any], dict[str, Any]]:
    backend.open()
    try:
        results = [backend.detect(frame_set) for frame_set in sets]
        info = backend.info()
    finally:
        backend.close()
    return results, info


def _expected(sets: list[FrameSet]) -> list[np.ndarray]:
    results, _ = _disparities(OnnxStereoBackend(BackendOptions(threads=1)), sets)
    return [r.output.disparity for r in results]


def _check_against_onnx_stereo(results: list[Any], expected: list[np.ndarray], tol: float) -> None:
    for ours, theirs in zip(results, expected, strict=True):
        assert ours.detections == ()
        assert isinstance(ours.output, Disparity)
        assert ours.output.disparity.shape == theirs.shape
        assert ours.output.disparity.dtype == np.float32
        assert float(np.abs(ours.output.disparity - theirs).max()) <= tol
        for value in (ours.stages.h2d_ns, ours.stages.preprocess_ns, ours.stages.d2h_ns):
            assert value is not None
            assert value >= 0
    # the network's disparities vary over the image: equal disparities are no accident
    assert float(np.ptp(expected[0])) > 10


def test_the_gpu_stereo_backends_are_registered_as_stereo_backends_of_frame_sets():
    for name, cls in (
        ('cuda-stereo', CudaStereoBackend),
        ('tensorrt-stereo', TensorrtStereoBackend),
    ):
        assert get_backend(name) is cls  # type: ignore[comparison-overlap]
        traits = backend_traits(cls)
        assert (traits.task, traits.device, traits.takes_frame_sets) == ('stereo', 'cuda', True)
        assert cls.default_sync == 'exact'
    # tensorrt-stereo's availability and providers are tensorrt's, through the class order
    assert TensorrtStereoBackend.available.__func__ is TensorrtBackend.available.__func__  # type: ignore[attr-defined]
    assert TensorrtStereoBackend._providers is TensorrtBackend._providers


@pytest.mark.parametrize('bag', ['rect', 'raw', 'large'])
def test_the_torch_engine_gives_onnx_stereos_disparity_on_the_fixture_pairs(
    monkeypatch, bags, driver, bag
):
    torch = _needs_onnx2torch()
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    sets = stereo_pairs(bags[bag])

    results, info = _disparities(CudaStereoBackend(BackendOptions(engine='torch')), sets)
    _check_against_onnx_stereo(results, _expected(sets), TORCH_TOLERANCE_PX)
    width = sets[0].frames[0].image.shape[1]
    assert results[0].output.max_disparity == 60.0 * width / 320
    assert (info['task'], info['engine'], info['layout']) == ('stereo', 'torch', 'two-inputs')
    assert info['input_size'] == [320, 240]
    assert info['shape_folding']['shape_ops_left'] == 0
    assert info['rectified'] == [bag != 'raw']


@pytest.mark.parametrize(('bag', 'tolerance'), [('rect', 0.0), ('large', ORT_RESIZED_TOLERANCE_PX)])
def test_the_ort_engine_binds_both_images_and_gives_onnx_stereos_disparity(
    monkeypatch, bags, driver, bag, tolerance
):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    seen = fake_gpu_build(monkeypatch, ['CUDAExecutionProvider'])
    torch_on_the_cpu(monkeypatch, torch)
    sets = stereo_pairs(bags[bag])

    results, info = _disparities(CudaStereoBackend(BackendOptions(engine='ort')), sets)
    _check_against_onnx_stereo(results, _expected(sets), tolerance)
    assert info['engine'] == 'ort'
    assert info['providers'] == ['CUDAExecutionProvider']
    assert [p[0] for p in seen.providers[0]] == ['CUDAExecutionProvider']
    assert seen.runs == len(sets) + 1  # and the warm-up pair in open()


def _variant(tmp_path: Path, layout: str, channels: int) -> Path:
    """The bundled model behind a front of its own: ``six-channel`` (one ``[1, 2C, H, W]``
    input split into left and right) and/or colour (C 3, averaged to grey), so that its
    disparity is the network's own and differs between left and right."""
    onnx = pytest.importorskip('onnx')
    from onnx import TensorProto, helper

    from replaybench.backends.onnx_stereo import DEFAULT_STEREO_MODEL

    proto = onnx.load(str(DEFAULT_STEREO_MODEL))
    height, width = 240, 320
    front = []
    if layout == 'six-channel':
        inputs = [
            helper.make_tensor_value_info(
                'pair', TensorProto.FLOAT, [1, 2 * channels, height, width]
            )
        ]
        sides = ['pair_left', 'pair_right'] if channels == 3 else ['left', 'right']
        front.append(helper.make_node('Split', ['pair'], sides, axis=1))
    else:
        sides = ['in_left', 'in_right']
        inputs = [
            helper.make_tensor_value_info(name, TensorProto.FLOAT, [1, channels, height, width])
            for name in sides
        ]
    if channels == 3:
        for side, grey in zip(sides, ('left', 'right'), strict=True):
            front.append(helper.make_node('ReduceMean', [side], [grey], axes=[1], keepdims=1))
    nodes = [*front, *proto.graph.node]
    del proto.graph.node[:]
    proto.graph.node.extend(nodes)
    del proto.graph.input[:]
    proto.graph.input.extend(inputs)
    for prop in proto.metadata_props:
        if prop.key == 'replaybench.stereo_layout':
            prop.value = layout
        if prop.key == 'replaybench.channel_order':
            prop.value = 'grey' if channels == 1 else 'rgb'
    onnx.checker.check_model(proto)
    path = tmp_path / f'{layout}-{channels}.onnx'
    onnx.save(proto, str(path))
    return path


@pytest.mark.parametrize(
    ('layout', 'channels'), [('six-channel', 1), ('two-inputs', 3), ('six-channel', 3)]
)
@pytest.mark.parametrize('engine', ['ort', 'torch'])
def test_every_layout_and_channel_count_gives_onnx_stereos_disparity(
    monkeypatch, tmp_path, bags, driver, layout, channels, engine
):
    torch = _needs_onnx2torch() if engine == 'torch' else pytest.importorskip('torch')
    driver([GPU_A])
    fake_gpu_build(monkeypatch, ['CUDAExecutionProvider'])
    torch_on_the_cpu(monkeypatch, torch)
    model = _variant(tmp_path, layout, channels)
    sets = stereo_pairs(bags['large'])[:1]

    results, info = _disparities(
        CudaStereoBackend(BackendOptions(engine=engine, model=model)), sets
    )
    expected, _ = _disparities(OnnxStereoBackend(BackendOptions(model=model, threads=1)), sets)
    tolerance = TORCH_TOLERANCE_PX if engine == 'torch' else ORT_RESIZED_TOLERANCE_PX
    _check_against_onnx_stereo(results, [r.output.disparity for r in expected], tolerance)
    assert (info['layout'], info['channel_order']) == (layout, 'grey' if channels == 1 else 'rgb')
    assert [i['shape'][1] for i in info['inputs']] == (
        [2 * channels] if layout == 'six-channel' else [channels] * 2
    )


def test_tensorrt_stereo_builds_its_engine_key_from_the_stereo_input(
    monkeypatch, bags, driver, tmp_path
):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    fake_loader(monkeypatch, {'libnvinfer.so.10': 101300, 'libnvonnxparser.so.10': None})
    seen = fake_gpu_build(monkeypatch, ['TensorrtExecutionProvider', 'CUDAExecutionProvider'])
    sets = stereo_pairs(bags['rect'])[:1]
    options = BackendOptions(precision='fp16', extra={'trt_cache': str(tmp_path / 'engines')})

    results, info = _disparities(TensorrtStereoBackend(options), sets)
    _check_against_onnx_stereo(results, _expected(sets), 0.0)
    (gpu_session,) = [p for p in seen.providers if len(p) == 2]
    (name, trt), (cuda, _) = gpu_session
    assert (name, cuda) == ('TensorrtExecutionProvider', 'CUDAExecutionProvider')
    assert trt['trt_fp16_enable'] is True
    assert info['trt_engine_key']['input_shape'] == [1, 1, 240, 320]
    assert info['precision'] == 'fp16'
    assert info['ep_nodes'] == {
        'TensorrtExecutionProvider': info['ep_nodes']['TensorrtExecutionProvider']
    }


def test_a_model_that_is_no_stereo_model_or_an_fp16_ort_run_is_refused_in_one_line(
    monkeypatch, driver
):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    fake_gpu_build(monkeypatch, ['CUDAExecutionProvider'])
    torch_on_the_cpu(monkeypatch, torch)
    with pytest.raises(BackendError) as err:
        CudaStereoBackend(BackendOptions(engine='ort', model=DEFAULT_MODEL)).open()
    assert 'cuda-stereo: engine ort' in str(err.value)
    assert "input 'images' has 3 channels; layout six-channel takes 6" in str(err.value)
    assert '\n' not in str(err.value)
    with pytest.raises(BackendError, match=r'--precision fp16 needs an fp16 model'):
        CudaStereoBackend(BackendOptions(engine='ort', precision='fp16')).open()
    with pytest.raises(BackendError, match=r"unknown --model-family 'yolov8'; known: two-inputs"):
        CudaStereoBackend(BackendOptions(model_family='yolov8'))
    with pytest.raises(BackendError, match=r"unknown option 'max_det'"):
        CudaStereoBackend(BackendOptions(extra={'max_det': '5'}))


@pytest.mark.parametrize('name', ['cuda-stereo', 'tensorrt-stereo'])
def test_running_an_unavailable_gpu_stereo_backend_exits_2_with_the_reason(tmp_path, bags, name):
    status = get_backend(name).available()
    if status.ok:
        pytest.skip(f'{name} is available on this machine')
    out = tmp_path / 'run'
    result = runner.invoke(app, ['run', str(bags['rect']), '--backend', name, '--out', str(out)])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if 'not available' in line]
    assert lines == [f"replaybench: error: backend '{name}' is not available here: {status.reason}"]
    assert not out.exists()


def test_replaybench_run_with_cuda_stereo_scores_as_onnx_stereo_and_agrees_with_it(
    monkeypatch, tmp_path, bags, driver
):
    """``replaybench run --backend onnx-stereo --backend cuda-stereo`` end to end on the fake
    device (its availability answered as a GPU machine's; the engines are the real code)."""
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    fake_gpu_build(monkeypatch, ['CUDAExecutionProvider'])
    torch_on_the_cpu(monkeypatch, torch)
    monkeypatch.setattr(
        CudaStereoBackend, 'available', classmethod(lambda cls: Availability(ok=True))
    )
    out = tmp_path / 'run'
    args = ['run', str(bags['rect']), '--backend', 'onnx-stereo', '--backend', 'cuda-stereo']
    result = runner.invoke(app, [*args, '--engine', 'ort', '--out', str(out), '--no-report'])
    assert result.exit_code == 0, result.output

    rows = {r['backend']: r for r in csv.DictReader((out / 'summary.csv').open())}
    assert set(rows) == {'onnx_stereo', 'cuda_stereo'}
    for key in ('epe', 'bad2', 'density'):
        assert float(rows['cuda_stereo'][key]) == pytest.approx(float(rows['onnx_stereo'][key]))
    document = json.loads((out / 'run.json').read_text())
    (agreement,) = document['stereo_agreement']
    assert (agreement['backend_a'], agreement['backend_b']) == ('onnx_stereo', 'cuda_stereo')
    assert agreement['epe'] == 0.0
    assert agreement['density'] == 1.0
    frames = [
        r for r in csv.DictReader((out / 'frames.csv').open()) if r['backend'] == 'cuda_stereo'
    ]
    assert frames
    assert all(r['h2d_ms'] and r['d2h_ms'] and r['infer_ms'] for r in frames)
    (info,) = [b['info'] for b in document['backends'] if b['name'] == 'cuda-stereo']
    assert (info['engine'], info['task']) == ('ort', 'stereo')
