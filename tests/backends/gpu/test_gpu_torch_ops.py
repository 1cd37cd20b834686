"""The GPU detector's torch ops on the CPU, against the numpy detector they mirror.

Decoders, NMS and the mapping to source pixels get the same raw outputs as the numpy versions
and must give the same boxes within 1e-3 px (NMS: the same indices). Preprocessing may differ
from OpenCV's fixed-point resize by one intensity level. The whole pipeline runs with
onnxruntime's CPU provider through IO binding, as it does on the GPU with the CUDA provider.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np
import pytest
from backends.gpu.gpuhelpers import ASTRONAUT, FIXTURE_BAGS

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu import _torch_ops as ops
from replaybench.backends.gpu.cuda import DnnPipeline, OrtEngine, frame_input, to_detections
from replaybench.detector import decoders
from replaybench.detector.preprocess import Letterboxer, Transform, geometry
from replaybench.detector.preprocess import boxes_to_source as numpy_to_source
from replaybench.detector.spec import Preprocess, default_preprocess, grid_points, load_model_spec
from replaybench.types import Detection, Frame

if TYPE_CHECKING:
    from pathlib import Path

torch = pytest.importorskip('torch', reason='torch is not installed (pip install torch, CPU wheel)')

CPU = 'cpu'


def _image(rng: np.random.Generator, w: int, h: int, channels: int) -> np.ndarray:
    shape = (h, w) if channels == 1 else (h, w, channels)
    base = rng.integers(0, 256, shape, dtype=np.uint8)
    return cv2.GaussianBlur(base, (5, 5), 0)  # smooth, like camera images


@pytest.mark.parametrize(
    ('encoding', 'channels', 'layout'),
    [('bgr8', 3, 'bgr'), ('rgb8', 3, 'rgb'), ('bgra8', 4, 'bgra'), ('mono8', 1, 'y')],
)
@pytest.mark.parametrize(
    'pre',
    [
        default_preprocess('yolox', (64, 48)),
        default_preprocess('yolov8', (64, 64)),
        Preprocess(size=(40, 72), channel_order='bgr', mean=(0.4, 0.5, 0.6), std=(0.2, 0.25, 0.3)),
        Preprocess(size=(48, 48), letterbox=False),
    ],
    ids=['yolox', 'yolov8', 'mean-std', 'stretch'],
)
@pytest.mark.parametrize('src', [(120, 90), (31, 57), (64, 48)])
def test_letterbox_matches_the_opencv_letterboxer_within_one_level(
    encoding, channels, layout, pre, src
):
    width, height = src
    image = _image(np.random.default_rng(width), width, height, channels)
    expected, transform = Letterboxer(pre)(image, encoding)
    new_w, new_h, left, top, t = geometry(src[0], src[1], pre)
    assert t == transform
    out = torch.empty((1, 3, pre.size[1], pre.size[0]), dtype=torch.float32)
    pixels = torch.from_numpy(image)
    ops.letterbox_into(
        torch, out, pixels, layout, pre, (new_w, new_h, left, top), ops.normaliser(torch, pre, CPU)
    )
    one_level = max(pre.scale / s for s in pre.std) * 1.0001
    diff = np.abs(out.numpy() - expected)
    assert diff.max() <= one_level
    assert (diff > 1e-5).mean() < 0.25  # most values are exact


def _dense(rng: np.random.Generator, n: int, classes: int, size: tuple[int, int]) -> np.ndarray:
    """``[N, 5+C]`` rows: centres over the input, sizes, objectness and class scores."""
    out = np.empty((n, 5 + classes), np.float32)
    out[:, 0] = rng.uniform(0, size[0], n)
    out[:, 1] = rng.uniform(0, size[1], n)
    out[:, 2:4] = rng.uniform(2, 40, (n, 2))
    out[:, 4:] = rng.uniform(0, 1, (n, 1 + classes)) ** 3
    return out


def _same(numpy_out: tuple[np.ndarray, ...], torch_out: tuple[object, ...]) -> None:
    boxes, scores, classes = (t.numpy() for t in torch_out)  # type: ignore[attr-defined]
    assert boxes.shape == numpy_out[0].shape
    np.testing.assert_allclose(boxes, numpy_out[0], atol=1e-3, rtol=0)
    np.testing.assert_allclose(scores, numpy_out[1], atol=1e-6, rtol=0)
    np.testing.assert_array_equal(classes, numpy_out[2])


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_decoders_give_the_numpy_boxes_scores_and_classes(seed):
    rng = np.random.default_rng(seed)
    size = (96, 64)
    n = grid_points(size)
    raw = _dense(rng, n, 3, size)
    raw[:, 0:2] = rng.uniform(-0.5, 1.5, (n, 2))  # yolox: offsets within the cell
    raw[:, 2:4] = rng.uniform(-1, 2, (n, 2))  # yolox: log sizes
    grid, stride = ops.yolox_grid(torch, size, CPU)
    _same(
        decoders.decode_yolox(raw[None], size, conf=0.2),
        ops.decode_yolox(torch, torch.from_numpy(raw[None]), grid, stride, 0.2),
    )
    dense = _dense(rng, 500, 4, size)[None]
    _same(
        decoders.decode_yolov5(dense, conf=0.1),
        ops.decode_yolov5(torch, torch.from_numpy(dense), 0.1),
    )
    v8 = np.ascontiguousarray(np.delete(dense[0], 4, axis=1).T[None])
    _same(decoders.decode_yolov8(v8, conf=0.3), ops.decode_yolov8(torch, torch.from_numpy(v8), 0.3))


def _candidates(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    centres = rng.uniform(0, 200, (n, 2)).astype(np.float32)
    sizes = rng.uniform(5, 60, (n, 2)).astype(np.float32)
    boxes = np.concatenate((centres - sizes / 2, centres + sizes / 2), axis=1)
    boxes[n // 2 :: 7] = boxes[n // 2 - 1]  # exact duplicates
    scores = np.round(rng.uniform(0, 1, n), 2).astype(np.float32)  # many ties
    classes = rng.integers(0, 3, n).astype(np.int64)
    return boxes, scores, classes


@pytest.mark.parametrize('seed', range(6))
@pytest.mark.parametrize(('chunk', 'max_det'), [(2048, None), (7, None), (16, 25), (1, 10)])
def test_batched_nms_keeps_exactly_what_the_numpy_nms_keeps(seed, chunk, max_det):
    rng = np.random.default_rng(seed)
    boxes, scores, classes = _candidates(rng, 200)
    iou = [0.3, 0.45, 0.6, 0.0, 0.9, 0.5][seed]
    expected = decoders.nms(boxes, scores, classes, iou, max_det)
    kept = ops.batched_nms(
        torch,
        torch.from_numpy(boxes),
        torch.from_numpy(scores),
        torch.from_numpy(classes),
        iou,
        max_det,
        chunk=chunk,
    )
    assert kept.tolist() == expected.tolist()


def test_batched_nms_of_nothing_is_empty():
    empty = ops.batched_nms(
        torch, torch.zeros((0, 4)), torch.zeros(0), torch.zeros(0, dtype=torch.int64), 0.5
    )
    assert empty.shape == (0,)


def test_boxes_map_to_source_pixels_as_the_numpy_transform_does():
    rng = np.random.default_rng(5)
    boxes = rng.uniform(-20, 700, (50, 4)).astype(np.float32)
    for transform in (
        Transform(0.5, 10.0, 4.0, 1280, 720),
        Transform(0.3, 0.0, 17.5, 333, 97),
        Transform(640 / 300, 0.0, 0.0, 300, 200, 640 / 200),
    ):
        expected = numpy_to_source(boxes, transform)
        got = ops.boxes_to_source(torch, torch.from_numpy(boxes), transform).numpy()
        np.testing.assert_allclose(got, expected, atol=1e-3, rtol=0)


def test_downloaded_rows_become_detections_in_the_numpy_order():
    rows = np.array(
        [
            [1, 1, 5, 5, 0.5, 1],
            [0, 0, 4, 4, 0.9, 0],
            [3, 3, 3, 9, 0.95, 0],  # empty after clipping: dropped
            [2, 2, 6, 6, 0.5, 0],
            [2, 2, 6, 6, 0.7, 7],  # beyond the class names: the index as label
        ],
        np.float32,
    )
    found = to_detections(rows, ('a', 'b'))
    assert [d.label for d in found] == ['a', '7', 'a', 'b']
    assert [d.score for d in found] == pytest.approx([0.9, 0.7, 0.5, 0.5])


def _cpu_pipeline(model: Path, conf: float) -> tuple[DnnPipeline, OrtEngine]:
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = 1  # no spinning onnxruntime threads slowing torch down
    session = onnxruntime.InferenceSession(str(model), options, providers=['CPUExecutionProvider'])
    spec = load_model_spec(model, session=session)
    pipeline = DnnPipeline(torch, spec, torch.device(CPU), False, conf, 0.45, 300)
    return pipeline, OrtEngine(session, spec, pipeline.input, torch)


def _run(pipeline: DnnPipeline, engine: OrtEngine, frame: Frame) -> tuple[Detection, ...]:
    pixels, layout = frame_input(frame, 'test')
    transform = pipeline.preprocess(pipeline.upload(pixels), layout)
    arrays = pipeline.download(pipeline.postprocess(engine(), transform))
    return pipeline.detections(arrays, transform)


def _onnx_cpu(model: Path, conf: float, frame: Frame) -> tuple[Detection, ...]:
    from replaybench.backends.onnx_cpu import OnnxCpuBackend

    backend = OnnxCpuBackend(BackendOptions(model=model, conf=conf))
    backend.open()
    try:
        return backend.detect(frame).detections
    finally:
        backend.close()


def _iou(a: Detection, b: Detection) -> float:
    w = max(0.0, min(a.x1, b.x1) - max(a.x0, b.x0))
    h = max(0.0, min(a.y1, b.y1) - max(a.y0, b.y0))
    union = (a.x1 - a.x0) * (a.y1 - a.y0) + (b.x1 - b.x0) * (b.y1 - b.y0) - w * h
    return w * h / union if union > 0 else 0.0


def _assert_close(got: tuple[Detection, ...], expected: tuple[Detection, ...], conf: float) -> None:
    """Each detection has a same-label partner with IoU >= 0.9 and a score within 0.03.

    The inputs differ by at most one level (resize rounding), so a detection within 0.01 of
    the threshold may be on one side only.
    """
    for ours, theirs in ((got, expected), (expected, got)):
        for d in ours:
            partners = [e for e in theirs if e.label == d.label and _iou(d, e) >= 0.9]
            if not partners:
                assert d.score <= conf + 0.01, f'{d} has no partner'
                continue
            assert min(abs(d.score - e.score) for e in partners) <= 0.03, d


def test_the_pipeline_with_io_binding_gives_the_onnx_cpu_detections_of_a_tiny_model(tiny_model):
    image = np.zeros((48, 80, 3), np.uint8)
    frame = Frame('/c', 0, 0, 0, 'c', image, 'rgb8', 'rgb8')
    pipeline, engine = _cpu_pipeline(tiny_model, 0.25)
    got = _run(pipeline, engine, frame)
    expected = _onnx_cpu(tiny_model, 0.25, frame)
    assert len(expected) == 1
    assert got == expected  # constant outputs: identical numbers


def test_the_pipeline_finds_what_onnx_cpu_finds_with_yolox_nano(yolox_nano):
    if not ASTRONAUT.is_file():
        pytest.skip(f'{ASTRONAUT} not present')
    bgr = cv2.imread(str(ASTRONAUT))
    assert bgr is not None
    pipeline, engine = _cpu_pipeline(yolox_nano, 0.1)
    for encoding, image in (('bgr8', bgr), ('rgb8', cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))):
        frame = Frame('/c', 0, 0, 0, 'c', image, encoding, encoding)
        expected = _onnx_cpu(yolox_nano, 0.1, frame)
        assert any(d.label == 'person' and d.score > 0.8 for d in expected)
        _assert_close(_run(pipeline, engine, frame), expected, 0.1)


def test_the_pipeline_matches_onnx_cpu_on_every_fixture_frame(yolox_nano):
    """Boxes IoU >= 0.9, scores within 0.03 (measured: 259 boxes, IoU >= 0.95, 0.025)."""
    from replaybench.backends.onnx_cpu import OnnxCpuBackend
    from replaybench.decode import decode_image, message_kind
    from replaybench.sources import open_source

    conf = 0.05  # low: many detections to compare
    pipeline, engine = _cpu_pipeline(yolox_nano, conf)
    reference = OnnxCpuBackend(BackendOptions(model=yolox_nano, conf=conf, threads=1))
    reference.open()
    frames = compared = 0
    for bag in ('rgb8_raw.mcap', 'jpeg.mcap'):
        with open_source(FIXTURE_BAGS / bag) as source:
            for raw in source.messages():
                if message_kind(raw.msgtype) not in ('image', 'compressed_image'):
                    continue
                img = decode_image(raw)
                frame = Frame(raw.topic, raw.seq, 0, 0, '', img.image, img.encoding, img.encoding)
                expected = reference.detect(frame).detections
                _assert_close(_run(pipeline, engine, frame), expected, conf)
                frames += 1
                compared += len(expected)
                if frames % 8 == 0:
                    break
    assert frames == 16
    assert compared >= 40
