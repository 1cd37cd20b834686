"""Family decoders, NMS and postprocess on hand-computed output tensors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from replaybench.detector.decoders import (
    decode_nms,
    decode_yolov5,
    decode_yolov8,
    decode_yolox,
    nms,
    postprocess,
    yolox_grid,
)
from replaybench.detector.preprocess import Transform
from replaybench.detector.spec import ModelSpec, Preprocess
from replaybench.errors import BackendError
from replaybench.types import Detection

LN2 = math.log(2.0)


def _spec(family: str, names: tuple[str, ...], size: tuple[int, int] = (64, 32)) -> ModelSpec:
    return ModelSpec(
        path=Path('m.onnx'),
        sha256='0' * 64,
        input_name='images',
        output_names=('output',),
        family=family,
        preprocess=Preprocess(size=size),
        class_names=names,
        precision='fp32',
    )


def _yolox_output() -> np.ndarray:
    """Input 64x32: 8x4 cells at stride 8 (rows 0-31), 4x2 at 16 (32-39), 2x1 at 32 (40-41)."""
    out = np.zeros((1, 42, 7), np.float32)
    # stride 8, cell x=3 y=1 -> row 11
    out[0, 11] = [0.5, 0.25, 0.0, LN2, 0.8, 0.5, 1.0]
    # stride 16, cell x=2 y=1 -> row 32 + 1*4 + 2 = 38
    out[0, 38] = [0.0, 0.0, 0.0, 0.0, 0.5, 0.9, 0.1]
    # stride 32, cell x=1 y=0 -> row 41: objectness too low
    out[0, 41] = [0.0, 0.0, 0.0, 0.0, 0.2, 1.0, 1.0]
    return out


def test_yolox_grid_lists_cells_row_major_per_stride():
    grid, stride = yolox_grid((64, 32))
    assert grid.shape == (42, 2)
    assert grid[11].tolist() == [3.0, 1.0]
    assert stride[11, 0] == 8
    assert grid[38].tolist() == [2.0, 1.0]
    assert stride[38, 0] == 16
    assert grid[41].tolist() == [1.0, 0.0]
    assert stride[41, 0] == 32


def test_yolox_decoder_adds_the_grid_and_scales_by_stride():
    boxes, scores, classes = decode_yolox(_yolox_output(), (64, 32), conf=0.3)
    # row 11: cx=(0.5+3)*8=28, cy=(0.25+1)*8=10, w=e^0*8=8, h=e^ln2*8=16
    # row 38: cx=(0+2)*16=32, cy=(0+1)*16=16, w=h=16
    np.testing.assert_allclose(
        boxes, [[24, 2, 32, 18], [24, 2, 32, 18], [24, 8, 40, 24]], rtol=0, atol=1e-5
    )
    np.testing.assert_allclose(scores, [0.4, 0.8, 0.45], rtol=1e-6)
    assert classes.tolist() == [0, 1, 0]
    assert boxes.dtype == np.float32
    assert scores.dtype == np.float32
    assert classes.dtype == np.int64


def test_yolox_decoder_matches_check_model_decode_on_random_rows():
    rng = np.random.default_rng(3)
    out = rng.uniform(-1.0, 1.0, (1, 42, 7)).astype(np.float32)
    out[..., 4:] = rng.uniform(0, 1, (1, 42, 3))
    boxes, scores, classes = decode_yolox(out, (64, 32), conf=0.0)
    # check_model.py's decode: xy = (xy + grid) * stride, wh = exp(wh) * stride
    grids, strides = [], []
    for s in (8, 16, 32):
        xv, yv = np.meshgrid(np.arange(64 // s), np.arange(32 // s))
        grids.append(np.stack((xv, yv), 2).reshape(-1, 2))
        strides.append(np.full((grids[-1].shape[0], 1), s))
    pred = out[0].astype(np.float64)
    pred[:, :2] = (pred[:, :2] + np.concatenate(grids)) * np.concatenate(strides)
    pred[:, 2:4] = np.exp(pred[:, 2:4]) * np.concatenate(strides)
    xyxy = np.concatenate([pred[:, :2] - pred[:, 2:4] / 2, pred[:, :2] + pred[:, 2:4] / 2], 1)
    all_scores = pred[:, 4:5] * pred[:, 5:]
    rows, cols = np.nonzero(all_scores > 0)
    np.testing.assert_allclose(boxes, xyxy[rows], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(scores, all_scores[rows, cols], rtol=1e-5)
    assert classes.tolist() == cols.tolist()


def test_yolox_decoder_names_the_expected_row_count_when_the_size_is_wrong():
    with pytest.raises(BackendError, match=r'42 rows; a 64x64 input .* gives 84'):
        decode_yolox(_yolox_output(), (64, 64))


def test_yolov5_decoder_multiplies_objectness_and_class_scores():
    out = np.zeros((1, 3, 7), np.float32)
    out[0, 0] = [20, 10, 8, 4, 0.5, 0.5, 1.0]  # scores 0.25, 0.5
    out[0, 1] = [50, 40, 10, 20, 0.1, 1.0, 1.0]  # 0.1: below conf
    out[0, 2] = [5, 6, 2, 2, 1.0, 0.75, 0.0]  # 0.75
    boxes, scores, classes = decode_yolov5(out, conf=0.2)
    assert boxes.tolist() == [[16, 8, 24, 12], [16, 8, 24, 12], [4, 5, 6, 7]]
    assert scores.tolist() == [0.25, 0.5, 0.75]
    assert classes.tolist() == [0, 1, 0]


def test_yolov8_decoder_reads_channels_first_without_objectness():
    # [1, 4 + 2 classes, 3 candidates]
    out = np.array(
        [
            [
                [10, 30, 50],  # cx
                [20, 30, 40],  # cy
                [4, 8, 2],  # w
                [6, 8, 2],  # h
                [0.5, 0.1, 0.125],  # class 0
                [0.25, 0.75, 0.0],  # class 1
            ]
        ],
        np.float32,
    )
    boxes, scores, classes = decode_yolov8(out, conf=0.2)
    assert boxes.tolist() == [[8, 17, 12, 23], [8, 17, 12, 23], [26, 26, 34, 34]]
    assert scores.tolist() == [0.5, 0.25, 0.75]
    assert classes.tolist() == [0, 1, 1]


def test_dense_decoders_return_empty_arrays_when_nothing_passes():
    out = np.zeros((1, 6, 3), np.float32)
    boxes, scores, classes = decode_yolov8(out, conf=0.25)
    assert boxes.shape == (0, 4)
    assert scores.shape == (0,)
    assert classes.shape == (0,)


def test_nms_decoder_reads_one_output_with_six_columns():
    det = np.array(
        [[[1, 2, 11, 12, 0.9, 3], [5, 5, 9, 9, 0.2, 1], [0, 0, 4, 4, 0.6, 0]]], np.float32
    )
    boxes, scores, classes = decode_nms({'output0': det}, conf=0.25)
    assert boxes.tolist() == [[1, 2, 11, 12], [0, 0, 4, 4]]
    assert scores.tolist() == pytest.approx([0.9, 0.6])
    assert classes.tolist() == [3, 0]


def test_nms_decoder_reads_yolov7_seven_columns_of_batch_zero():
    det = np.array(
        [[0, 1, 2, 11, 12, 2, 0.8], [1, 0, 0, 5, 5, 0, 0.9], [0, 3, 3, 6, 6, 1, 0.5]],
        np.float32,
    )
    boxes, scores, classes = decode_nms({'output': det})
    assert boxes.tolist() == [[1, 2, 11, 12], [3, 3, 6, 6]]
    assert scores.tolist() == pytest.approx([0.8, 0.5])
    assert classes.tolist() == [2, 1]


def test_nms_decoder_reads_separate_outputs_up_to_the_detection_count():
    outputs = {
        'num_dets': np.array([[2]], np.int32),
        'det_boxes': np.array([[[0, 0, 2, 2], [1, 1, 3, 3], [9, 9, 9, 9]]], np.float32),
        'det_scores': np.array([[0.9, 0.4, 0.99]], np.float32),
        'det_classes': np.array([[4, 5, 6]], np.int32),
    }
    boxes, scores, classes = decode_nms(outputs, conf=0.3)
    assert boxes.tolist() == [[0, 0, 2, 2], [1, 1, 3, 3]]
    assert scores.tolist() == pytest.approx([0.9, 0.4])
    assert classes.tolist() == [4, 5]


def test_nms_decoder_reads_boxes_scores_labels_without_a_count():
    outputs: dict[str, np.ndarray] = {
        'boxes': np.array([[[0, 0, 2, 2], [1, 1, 3, 3]]], np.float32),
        'scores': np.array([[0.3, 0.7]], np.float32),
        'labels': np.array([[1, 0]], np.int64),
    }
    boxes, scores, classes = decode_nms(outputs)
    assert boxes.tolist() == [[0, 0, 2, 2], [1, 1, 3, 3]]
    assert scores.tolist() == pytest.approx([0.3, 0.7])
    assert classes.tolist() == [1, 0]


def test_nms_decoder_says_what_it_needs_for_unknown_outputs():
    with pytest.raises(BackendError, match='need boxes'):
        decode_nms({'a': np.zeros((1, 5, 4)), 'b': np.zeros((1, 5))})
    with pytest.raises(BackendError, match=r'\[K, 6\] or \[K, 7\]'):
        decode_nms({'a': np.zeros((1, 5, 5))})


def test_nms_suppresses_overlapping_boxes_of_the_same_class():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [20, 20, 30, 30]], np.float32)
    scores = np.array([0.8, 0.9, 0.7], np.float32)
    classes = np.array([0, 0, 0])
    # IoU(0, 1) = 90 / 110 = 0.818
    assert nms(boxes, scores, classes, 0.45).tolist() == [1, 2]
    assert nms(boxes, scores, classes, 0.85).tolist() == [1, 0, 2]


def test_nms_keeps_overlapping_boxes_of_different_classes():
    boxes = np.array([[0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 10]], np.float32)
    scores = np.array([0.5, 0.9, 0.6], np.float32)
    classes = np.array([2, 1, 2])
    assert nms(boxes, scores, classes, 0.45).tolist() == [1, 2]


def test_nms_keeps_a_box_whose_iou_equals_the_threshold():
    boxes = np.array([[0, 0, 10, 10], [5, 0, 15, 10]], np.float32)  # IoU = 50 / 150
    scores = np.array([0.9, 0.8], np.float32)
    assert nms(boxes, scores, np.array([0, 0]), 1 / 3).tolist() == [0, 1]
    assert nms(boxes, scores, np.array([0, 0]), 0.3).tolist() == [0]


def test_nms_breaks_score_ties_by_class_then_coordinates_whatever_the_input_order():
    boxes = np.array([[2, 0, 12, 10], [0, 0, 10, 10], [1, 0, 11, 10], [0, 0, 10, 10]], np.float32)
    scores = np.full(4, 0.5, np.float32)
    classes = np.array([0, 0, 0, 1])
    kept = nms(boxes, scores, classes, 0.45)
    assert kept.tolist() == [1, 3]  # class 0 first, then the smallest x0
    for perm in ([3, 2, 1, 0], [2, 0, 3, 1], [1, 3, 0, 2]):
        again = nms(boxes[perm], scores[perm], classes[perm], 0.45)
        assert boxes[perm][again].tolist() == boxes[kept].tolist()
        assert classes[perm][again].tolist() == classes[kept].tolist()


def test_nms_ties_on_identical_boxes_keep_the_first_input():
    boxes = np.array([[0, 0, 4, 4]] * 3, np.float32)
    kept = nms(boxes, np.full(3, 0.5, np.float32), np.zeros(3, np.int64), 0.5)
    assert kept.tolist() == [0]


def test_nms_stops_at_max_det_and_handles_no_boxes():
    boxes = np.array([[i * 10, 0, i * 10 + 5, 5] for i in range(5)], np.float32)
    scores = np.array([0.1, 0.5, 0.3, 0.4, 0.2], np.float32)
    assert nms(boxes, scores, np.zeros(5, np.int64), 0.5, max_det=2).tolist() == [1, 3]
    empty = nms(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64), 0.5)
    assert empty.tolist() == []


def test_postprocess_maps_to_source_pixels_labels_and_sorts():
    out = np.zeros((1, 4, 7), np.float32)
    out[0, 0] = [20, 14, 8, 4, 1.0, 0.6, 0.0]  # model box (16, 12, 24, 16)
    out[0, 1] = [21, 14, 8, 4, 1.0, 0.5, 0.0]  # same class, overlaps row 0 -> suppressed
    out[0, 2] = [40, 20, 16, 8, 1.0, 0.0, 0.6]  # model box (32, 16, 48, 24), same score
    out[0, 3] = [2, 2, 2, 2, 1.0, 0.9, 0.0]  # model box (1, 1, 3, 3): in the pad -> dropped
    spec = _spec('yolov5', ('cat', 'dog'))
    # source 120x40 into 64x32 centred: r = min(64/120, 32/40) = 0.5333; 64x21, top pad 5
    transform = Transform(64 / 120, 0.0, 5.0, 120, 40)
    dets = postprocess({'output': out}, spec, transform, conf=0.25, iou=0.45)
    r = 64 / 120
    assert [d.label for d in dets] == ['cat', 'dog']
    assert [d.class_index for d in dets] == [0, 1]
    assert dets[0].score == pytest.approx(0.6)
    assert (dets[0].x0, dets[0].y0, dets[0].x1, dets[0].y1) == pytest.approx(
        (16 / r, 7 / r, 24 / r, 11 / r), abs=1e-3
    )
    assert (dets[1].x0, dets[1].y0, dets[1].x1, dets[1].y1) == pytest.approx(
        (32 / r, 11 / r, 48 / r, 19 / r), abs=1e-3
    )
    assert all(isinstance(d, Detection) and isinstance(d.score, float) for d in dets)


def test_postprocess_labels_unknown_classes_by_index_and_skips_nms_for_nms_models():
    det = np.array([[[0, 0, 10, 10, 0.9, 7], [0, 0, 10, 10, 0.8, 7]]], np.float32)
    spec = _spec('nms', ())
    dets = postprocess({'output': det}, spec, Transform(1.0, 0, 0, 20, 20), conf=0.5, iou=0.45)
    assert [(d.label, d.class_index) for d in dets] == [('7', 7), ('7', 7)]
    assert [d.score for d in dets] == pytest.approx([0.9, 0.8])


def test_postprocess_clips_boxes_to_the_source_image():
    out = np.zeros((1, 1, 6), np.float32)
    out[0, 0] = [30, 16, 8, 40, 1.0, 1.0]  # model box (26, -4, 34, 36)
    dets = postprocess(
        {'output': out}, _spec('yolov5', ('a',)), Transform(1.0, 0, 0, 32, 32), 0.25, 0.45
    )
    assert (dets[0].x0, dets[0].y0, dets[0].x1, dets[0].y1) == (26.0, 0.0, 32.0, 32.0)
