"""The GPU backends on a real NVIDIA GPU against their CPU counterparts.

Every test here skips, with the reason, where the backend is not available (no GPU, no
onnxruntime-gpu / torch / CuPy). Tolerances: ``cuda`` / ``tensorrt`` fp32 against ``onnx-cpu``:
each detection has a same-label partner with IoU >= 0.9 and a score within 0.03, detections
within 0.01 of the threshold may be on one side only (the preprocessing differs from OpenCV's
fixed-point resize by at most one level). fp16: IoU >= 0.85, scores within 0.05, 0.05 of the
threshold. ``hsv-cuda`` against ``hsv``: IoU >= 0.9 for >= 95 % of the boxes of either.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import pytest
from backends.gpu.gpuhelpers import ASTRONAUT, FIXTURE_BAGS, has

from replaybench.backends import get_backend
from replaybench.backends.base import BackendOptions
from replaybench.errors import BackendUnavailableError
from replaybench.segmentation.spec import DEFAULT_SEG_MODEL
from replaybench.types import Detection, Frame

if TYPE_CHECKING:
    from pathlib import Path

INFO_KEYS = ('engine', 'providers', 'precision', 'device_name', 'driver', 'cuda_version')


def _needs(name: str) -> pytest.MarkDecorator:
    status = get_backend(name).available()
    return pytest.mark.skipif(not status.ok, reason=f'{name} unavailable: {status.reason}')


def _frames(limit: int = 8) -> list[Frame]:
    from replaybench.decode import decode_image, message_kind
    from replaybench.sources import open_source

    frames = []
    if ASTRONAUT.is_file():
        image = cv2.imread(str(ASTRONAUT))
        assert image is not None
        frames.append(Frame('/astronaut', 0, 0, 0, '', image, 'bgr8', 'bgr8'))
    for bag in ('rgb8_raw.mcap', 'jpeg.mcap', 'two_camera.mcap'):
        with open_source(FIXTURE_BAGS / bag) as source:
            for raw in source.messages():
                if message_kind(raw.msgtype) not in ('image', 'compressed_image'):
                    continue
                img = decode_image(raw)
                frames.append(Frame(raw.topic, raw.seq, 0, 0, '', img.image, img.encoding, ''))
                if len(frames) % limit == 0:
                    break
    return frames


def _detect_all(name: str, options: BackendOptions, frames: list[Frame]) -> list[Any]:
    backend = get_backend(name)(options)  # type: ignore[call-arg]
    backend.open()
    try:
        results = [backend.detect(frame) for frame in frames]
        info = backend.info()
    finally:
        backend.close()
    return [results, info]


def _iou(a: Detection, b: Detection) -> float:
    w = max(0.0, min(a.x1, b.x1) - max(a.x0, b.x0))
    h = max(0.0, min(a.y1, b.y1) - max(a.y0, b.y0))
    union = (a.x1 - a.x0) * (a.y1 - a.y0) + (b.x1 - b.x0) * (b.y1 - b.y0) - w * h
    return w * h / union if union > 0 else 0.0


def _assert_close(
    got: tuple[Detection, ...],
    expected: tuple[Detection, ...],
    conf: float,
    iou: float = 0.9,
    score: float = 0.03,
    margin: float = 0.01,
) -> None:
    for ours, theirs in ((got, expected), (expected, got)):
        for d in ours:
            partners = [e for e in theirs if e.label == d.label and _iou(d, e) >= iou]
            if not partners:
                assert d.score <= conf + margin, f'{d} has no partner'
                continue
            assert min(abs(d.score - e.score) for e in partners) <= score, d


def _compare_with_onnx_cpu(name: str, model: Path, **options: Any) -> dict[str, Any]:
    conf = 0.1
    frames = _frames()
    cpu, _ = _detect_all('onnx-cpu', BackendOptions(model=model, conf=conf), frames)
    gpu, info = _detect_all(name, BackendOptions(model=model, conf=conf, **options), frames)
    half = options.get('precision') == 'fp16'
    tolerance = {'iou': 0.85, 'score': 0.05, 'margin': 0.05} if half else {}
    for ours, theirs in zip(gpu, cpu, strict=True):
        _assert_close(ours.detections, theirs.detections, conf, **tolerance)
        stages = ours.stages
        for value in (
            stages.h2d_ns,
            stages.preprocess_ns,
            stages.infer_ns,
            stages.postprocess_ns,
            stages.d2h_ns,
        ):
            assert value is not None
            assert value > 0
    assert sum(len(r.detections) for r in cpu) >= 5
    for key in INFO_KEYS:
        assert info[key], key
    assert info['device_memory_bytes'] > 0
    return dict(info)


@_needs('cuda')
def test_cuda_with_onnxruntime_finds_what_onnx_cpu_finds(yolox_nano):
    info = _compare_with_onnx_cpu('cuda', yolox_nano, engine='ort')
    assert info['engine'] == 'ort'
    assert info['providers'][0] == 'CUDAExecutionProvider'


@_needs('cuda')
@pytest.mark.skipif(not has('onnx2torch'), reason='onnx2torch is not installed')
@pytest.mark.parametrize('precision', ['fp32', 'fp16'])
def test_cuda_with_torch_finds_what_onnx_cpu_finds(yolox_nano, precision):
    info = _compare_with_onnx_cpu('cuda', yolox_nano, engine='torch', precision=precision)
    assert info['engine'] == 'torch'
    assert info['precision'] == precision


@_needs('tensorrt')
@pytest.mark.parametrize('precision', ['fp32', 'fp16'])
def test_tensorrt_finds_what_onnx_cpu_finds(yolox_nano, precision, tmp_path):
    extra = {'trt_cache': str(tmp_path / 'trt')}
    info = _compare_with_onnx_cpu('tensorrt', yolox_nano, precision=precision, extra=extra)
    assert info['providers'][0] == 'TensorrtExecutionProvider'
    assert any((tmp_path / 'trt').iterdir())  # the built engine was cached


@_needs('cuda')
def test_cuda_gives_the_same_detections_for_the_same_frame(yolox_nano):
    frame = _frames()[0]
    results, _ = _detect_all('cuda', BackendOptions(model=yolox_nano), [frame] * 3)
    assert results[0].detections == results[1].detections == results[2].detections


@_needs('cuda')
def test_a_gpu_index_beyond_the_machine_is_refused(yolox_nano):
    backend = get_backend('cuda')(BackendOptions(model=yolox_nano, device=99))  # type: ignore[call-arg]
    with pytest.raises(BackendUnavailableError):
        backend.open()


@_needs('hsv-cuda')
def test_hsv_cuda_gives_the_hsv_detections_within_the_stated_tolerance():
    frames = _frames(limit=20)
    cpu, _ = _detect_all('hsv', BackendOptions(), frames)
    gpu, info = _detect_all('hsv-cuda', BackendOptions(), frames)
    hits = total = 0
    for ours, theirs in zip(gpu, cpu, strict=True):
        for a, b in ((ours.detections, theirs.detections), (theirs.detections, ours.detections)):
            total += len(a)
            hits += sum(any(x.label == y.label and _iou(x, y) >= 0.9 for y in b) for x in a)
        assert ours.stages.h2d_ns
        assert ours.stages.d2h_ns
    assert total >= 100
    assert hits / total >= 0.95
    identical = sum(o.detections == t.detections for o, t in zip(gpu, cpu, strict=True))
    assert identical == len(frames)  # what the CPU run of the same algorithm shows
    assert info['device_name']
    assert np.isfinite(info['device_memory_bytes'])


def _assert_device_spans_within_host_laps(results: list[Any]) -> None:
    """Each stage's device span (start to end event) lies within its host lap."""
    for result in results:
        s = result.stages
        for device, host in (
            (s.h2d_device_ns, s.h2d_ns),
            (s.preprocess_device_ns, s.preprocess_ns),
            (s.infer_device_ns, s.infer_ns),
            (s.d2h_device_ns, s.d2h_ns),
        ):
            assert device is not None
            assert host is not None
            assert 0 < device <= host
        assert s.postprocess_device_ns is not None
        assert s.postprocess_ns is not None
        assert 0 < s.postprocess_device_ns <= s.postprocess_ns


@_needs('cuda')
def test_cuda_device_spans_lie_within_the_host_stage_times(yolox_nano):
    results, _ = _detect_all('cuda', BackendOptions(model=yolox_nano, engine='ort'), _frames())
    _assert_device_spans_within_host_laps(results)


@_needs('hsv-cuda')
def test_hsv_cuda_device_spans_lie_within_the_host_stage_times():
    results, _ = _detect_all('hsv-cuda', BackendOptions(), _frames())
    _assert_device_spans_within_host_laps(results)


@_needs('cuda')
def test_the_cuda_provider_library_loads_on_a_machine_where_cuda_runs():
    from replaybench.backends.gpu.availability import ort_provider_load_problem

    assert ort_provider_load_problem('CUDAExecutionProvider') is None


@_needs('cuda')
@pytest.mark.skipif(not has('onnx2torch'), reason='onnx2torch is not installed')
def test_an_fp32_torch_engine_keeps_both_tf32_apis_readable_and_off(yolox_nano):
    import torch

    backend = get_backend('cuda')(BackendOptions(model=yolox_nano, engine='torch'))  # type: ignore[call-arg]
    backend.open()
    try:
        legacy = (torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32)
        cudnn: Any = torch.backends.cudnn
        modes = (cudnn.conv.fp32_precision, cudnn.rnn.fp32_precision)
        graph = backend.info()
    finally:
        backend.close()
    assert legacy == (False, False)
    assert modes == ('ieee', 'ieee')
    if graph['syncs_per_forward'] == 0:
        assert graph['cuda_graph'] == 'captured'
    else:
        assert graph['cuda_graph'].startswith('eager (the forward synchronises')


@_needs('hsv-cuda')
@_needs('cuda')
@pytest.mark.skipif(not has('pynvml'), reason='nvidia-ml-py (NVML) is not installed')
def test_each_gpu_backend_of_a_run_gets_its_own_pass_peak(yolox_nano, tmp_path):
    import json

    from replaybench.replay.runner import RunConfig, run_benchmark

    config = RunConfig(
        inputs=[FIXTURE_BAGS / 'rgb8_raw.mcap'],
        backends=['hsv-cuda', 'cuda'],
        options=BackendOptions(model=yolox_nano),
        out_dir=tmp_path / 'run',
        max_frames=20,
        report=False,
    )
    outcome = run_benchmark(config)
    assert outcome.run_dir is not None
    run = json.loads((outcome.run_dir / 'run.json').read_text(encoding='utf-8'))
    for backend in run['backends']:
        summary = backend['resources']['summary']
        assert summary['gpu_mem_mb_start'] is not None, backend['name']
        assert 0 <= summary['gpu_mem_mb_pass_peak'] <= summary['gpu_mem_mb_peak']
        assert summary['gpu_mem_basis']


def _seg_frames(tmp_path: Path) -> list[Frame]:
    """Frames of a fixture bag written with ground-truth masks (``fixtures --masks``)."""
    from replaybench.decode import decode_image, message_kind
    from replaybench.fixtures.writer import write_mcap
    from replaybench.sources import open_source

    frames = []
    with open_source(write_mcap(tmp_path / 'seg.mcap', 6, masks=True)) as source:
        for raw in source.messages():
            if raw.topic == '/camera/image_raw' and message_kind(raw.msgtype) == 'image':
                img = decode_image(raw)
                frames.append(Frame(raw.topic, raw.seq, 0, 0, '', img.image, img.encoding, ''))
    return frames


@_needs('cuda')
@pytest.mark.parametrize(
    ('name', 'engine'),
    [
        ('cuda', 'ort'),
        pytest.param(
            'cuda',
            'torch',
            marks=pytest.mark.skipif(not has('onnx2torch'), reason='onnx2torch is not installed'),
        ),
        pytest.param('tensorrt', 'auto', marks=_needs('tensorrt')),
    ],
)
def test_the_gpu_engines_label_the_bundled_segmentation_model_as_onnx_seg_does(
    name, engine, tmp_path
):
    # fp32 convolutions on the GPU sum in another order than on the CPU: a pixel whose two best
    # class scores are nearly equal may flip, so >= 99.9 % of the pixels must agree
    # (TensorRT builds fp32 layers with TF32 on Ampere and newer: >= 99.5 %)
    frames = _seg_frames(tmp_path)
    cpu, _ = _detect_all('onnx-seg', BackendOptions(threads=1), frames)
    extra = {'trt_cache': str(tmp_path / 'trt')} if name == 'tensorrt' else {}
    options = BackendOptions(model=DEFAULT_SEG_MODEL, engine=engine, extra=extra)
    gpu, info = _detect_all(name, options, frames)
    floor = 0.995 if name == 'tensorrt' else 0.999
    for ours, theirs in zip(gpu, cpu, strict=True):
        assert ours.mask is not None
        assert theirs.mask is not None
        assert ours.mask.labels.shape == theirs.mask.labels.shape
        assert (ours.mask.labels == theirs.mask.labels).mean() >= floor
        assert ours.stages.d2h_ns is not None
        assert ours.stages.postprocess_device_ns is not None
    assert (info['task'], info['layout']) == ('segmentation', 'logits-nchw')
    assert info['device_name']


#: ``cuda-stereo`` / ``tensorrt-stereo`` against ``onnx-stereo`` on the stereo fixture, in
#: pixels of disparity: (mean, max) absolute difference per pair
STEREO_TOLERANCE_PX = {'fp32': (1e-3, 0.05), 'fp16': (0.1, 2.0)}


@pytest.mark.parametrize(
    ('name', 'engine', 'precision'),
    [
        ('cuda-stereo', 'torch', 'fp32'),
        ('cuda-stereo', 'torch', 'fp16'),
        ('cuda-stereo', 'ort', 'fp32'),
        ('tensorrt-stereo', 'ort', 'fp32'),
    ],
)
def test_the_gpu_stereo_backends_give_onnx_stereos_disparity_on_the_device(
    tmp_path: Path, name: str, engine: str, precision: str
) -> None:
    status = get_backend(name).available()
    if not status.ok:
        pytest.skip(f'{name} unavailable: {status.reason}')
    if engine == 'torch' and not has('onnx2torch'):
        pytest.skip('onnx2torch is not installed')
    from backends.gpu.gpuhelpers import stereo_pairs

    from replaybench.fixtures.stereo import write_stereo_mcap

    sets = stereo_pairs(write_stereo_mcap(tmp_path / 'stereo.mcap', 3))
    options = BackendOptions(engine=engine, precision=precision)
    if name == 'tensorrt-stereo':
        options = BackendOptions(
            engine=engine, precision=precision, extra={'trt_cache': str(tmp_path / 'trt')}
        )
    try:
        ours, info = _detect_all(name, options, sets)  # type: ignore[arg-type]
    except BackendUnavailableError as exc:
        pytest.skip(f'{name}: {exc}')
    theirs, _ = _detect_all('onnx-stereo', BackendOptions(threads=1), sets)  # type: ignore[arg-type]
    mean_tol, max_tol = STEREO_TOLERANCE_PX[precision]
    for a, b in zip(ours, theirs, strict=True):
        difference = np.abs(a.output.disparity - b.output.disparity)
        assert float(difference.mean()) <= mean_tol
        assert float(difference.max()) <= max_tol
        assert a.stages.infer_device_ns is not None
        assert a.stages.h2d_device_ns is not None
    assert info['engine'] == engine
    assert info['task'] == 'stereo'
