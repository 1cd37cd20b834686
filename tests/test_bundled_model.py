"""The bundled blobs detector: its ONNX interface, metadata and accuracy on a fixture bag.

Runs the model with onnxruntime directly, with a minimal letterbox and decode of its own.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from replaybench.results.accuracy import evaluate
from replaybench.types import Detection

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / 'replaybench' / 'models' / 'blobs.onnx'
BAG = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
NAMES = ('red', 'green', 'blue', 'yellow')
SIZE = 320
# Measured on rgb8_raw.mcap (10 frames, this decoding): mAP@0.5 0.923, mAP@0.5:0.95 0.824,
# recall@0.5 0.918, precision@0.5 0.971 (docs/model.md); thresholds 0.05 below.
MIN_MAP50 = 0.87
MIN_MAP50_95 = 0.77
MIN_RECALL50 = 0.86
MIN_PRECISION50 = 0.92


@pytest.fixture(scope='module')
def session():
    ort = pytest.importorskip('onnxruntime')
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    return ort.InferenceSession(str(MODEL), options, providers=['CPUExecutionProvider'])


def _letterbox(bgr: np.ndarray) -> tuple[np.ndarray, float, int, int]:
    import cv2

    h, w = bgr.shape[:2]
    scale = min(SIZE / w, SIZE / h)
    nw, nh = round(w * scale), round(h * scale)
    rgb = np.ascontiguousarray(bgr[:, :, ::-1])
    if (nw, nh) != (w, h):
        rgb = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_LINEAR)
    px, py = (SIZE - nw) // 2, (SIZE - nh) // 2
    canvas = np.full((SIZE, SIZE, 3), 114, dtype=np.uint8)
    canvas[py : py + nh, px : px + nw] = rgb
    x = canvas.transpose(2, 0, 1)[None].astype(np.float32) / np.float32(255.0)
    return x, scale, px, py


def _decode(output: np.ndarray, scale: float, px: int, py: int, w: int, h: int) -> list[Detection]:
    pred = output[0].T
    cls = pred[:, 4:].argmax(axis=1)
    score = pred[np.arange(len(pred)), 4 + cls]
    keep = score >= 0.25
    pred, cls, score = pred[keep], cls[keep], score[keep]
    xyxy = np.concatenate([pred[:, :2] - pred[:, 2:4] / 2, pred[:, :2] + pred[:, 2:4] / 2], axis=1)
    order = np.argsort(-score, kind='stable')
    kept: list[int] = []
    for i in order:
        ok = True
        for j in kept:
            if cls[j] != cls[i]:
                continue
            ix = min(xyxy[i, 2], xyxy[j, 2]) - max(xyxy[i, 0], xyxy[j, 0])
            iy = min(xyxy[i, 3], xyxy[j, 3]) - max(xyxy[i, 1], xyxy[j, 1])
            inter = max(ix, 0.0) * max(iy, 0.0)
            area_i = (xyxy[i, 2] - xyxy[i, 0]) * (xyxy[i, 3] - xyxy[i, 1])
            area_j = (xyxy[j, 2] - xyxy[j, 0]) * (xyxy[j, 3] - xyxy[j, 1])
            if inter / (area_i + area_j - inter) > 0.45:
                ok = False
                break
        if ok:
            kept.append(int(i))
    dets = []
    for i in kept:
        x0, x1 = ((xyxy[i, [0, 2]] - px) / scale).clip(0, w)
        y0, y1 = ((xyxy[i, [1, 3]] - py) / scale).clip(0, h)
        if x1 > x0 and y1 > y0:
            c = int(cls[i])
            dets.append(Detection(c, NAMES[c], float(score[i]), x0, y0, x1, y1))
    return dets


def _bag_frames() -> list[tuple[tuple[str, int], np.ndarray, tuple[Detection, ...]]]:
    from replaybench.decode import decode_detections, decode_image, to_bgr8
    from replaybench.sources import open_source

    images, truth = {}, {}
    with open_source(BAG) as source:
        for msg in source.messages():
            if msg.msgtype.endswith('Detection2DArray'):
                gt = decode_detections(msg)
                truth[(gt.frame_id, gt.stamp_ns)] = gt.detections
            elif msg.msgtype.endswith('/Image'):
                decoded = decode_image(msg)
                bgr = to_bgr8(decoded.image, decoded.encoding)
                images[(decoded.frame_id, decoded.stamp_ns)] = np.ascontiguousarray(bgr)
    return [(key, image, truth[key]) for key, image in images.items()]


def test_bundled_model_is_a_small_onnx_file() -> None:
    assert MODEL.is_file(), f'{MODEL} missing: run python training/train_blobs.py'
    assert MODEL.stat().st_size < 5 * 1024 * 1024


def test_bundled_model_has_one_rgb_input_and_a_yolov8_output(session) -> None:
    (inp,) = session.get_inputs()
    assert inp.name == 'images'
    assert inp.shape == [1, 3, SIZE, SIZE]
    assert inp.type == 'tensor(float)'
    (out,) = session.get_outputs()
    assert out.name == 'output0'
    assert out.shape == [1, 4 + len(NAMES), (SIZE // 8) ** 2]
    assert out.type == 'tensor(float)'


def test_bundled_model_metadata_describes_its_preprocessing(session) -> None:
    meta = session.get_modelmeta().custom_metadata_map
    assert meta['replaybench.family'] == 'yolov8'
    assert meta['names'] == ','.join(NAMES)
    assert meta['replaybench.channel_order'] == 'rgb'
    assert float(meta['replaybench.scale']) == pytest.approx(1 / 255)
    assert meta['replaybench.pad_value'] == '114'
    assert meta['replaybench.letterbox_align'] == 'center'
    assert meta['replaybench.trained_on'].startswith('replaybench.fixtures.scene seeds ')


def test_bundled_model_outputs_scores_in_0_1_and_positive_box_sizes(session) -> None:
    rng = np.random.default_rng(0)
    x = rng.random((1, 3, SIZE, SIZE), dtype=np.float32)
    (out,) = session.run(['output0'], {'images': x})
    assert np.isfinite(out).all()
    assert (out[0, 2:4] >= 0).all()
    assert ((out[0, 4:] >= 0) & (out[0, 4:] <= 1)).all()


def test_bundled_model_finds_the_objects_of_the_held_out_fixture_bag(session) -> None:
    frames = _bag_frames()
    assert len(frames) >= 5
    gt, dets = {}, {}
    for key, bgr, truth in frames:
        x, scale, px, py = _letterbox(bgr)
        (out,) = session.run(['output0'], {'images': x})
        dets[key] = _decode(out, scale, px, py, bgr.shape[1], bgr.shape[0])
        gt[key] = truth
    result = evaluate(gt, dets)
    assert result.n_gt > 0
    assert result.map50 >= MIN_MAP50, result
    assert result.map50_95 >= MIN_MAP50_95, result
    assert result.recall50 >= MIN_RECALL50, result
    assert result.precision50 >= MIN_PRECISION50, result
