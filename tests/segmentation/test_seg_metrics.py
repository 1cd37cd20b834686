"""Segmentation accuracy against values computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from replaybench.tasks.segmentation.scoring import class_name, confusion, scores


def test_iou_miou_and_pixel_accuracy_of_a_small_case_are_the_hand_computed_values() -> None:
    truth = np.array([[0, 0, 1, 1], [0, 0, 1, 1], [2, 2, 2, 2]], dtype=np.uint8)
    pred = np.array([[0, 1, 1, 1], [0, 0, 1, 0], [2, 2, 1, 1]], dtype=np.uint8)
    result = scores(confusion(pred, truth))
    # class 0: truth 4 px, predicted 4 px ((0,0), (1,0), (1,1), (1,3)), hits 3 -> 3 / (4 + 4 - 3)
    # class 1: truth 4, predicted 6 ((0,1), (0,2), (0,3), (1,2), (2,2), (2,3)), hits 3 -> 3 / 7
    # class 2: truth 4, predicted 2, hits 2 -> 2 / 4
    assert result.iou[0] == pytest.approx(3 / 5)
    assert result.iou[1] == pytest.approx(3 / 7)
    assert result.iou[2] == pytest.approx(2 / 4)
    assert set(result.iou) == {0, 1, 2}
    assert result.miou == pytest.approx((3 / 5 + 3 / 7 + 2 / 4) / 3)
    assert result.pixel_accuracy == pytest.approx(8 / 12)
    assert result.pixels == 12


def test_a_perfect_prediction_scores_one_and_absent_classes_have_no_iou() -> None:
    truth = np.array([[0, 3], [3, 3]], dtype=np.uint8)
    result = scores(confusion(truth.copy(), truth))
    assert result.iou == {0: 1.0, 3: 1.0}
    assert result.miou == 1.0
    assert result.pixel_accuracy == 1.0


def test_a_class_only_predicted_counts_with_iou_zero() -> None:
    truth = np.zeros((2, 2), dtype=np.uint8)
    pred = np.array([[0, 0], [0, 4]], dtype=np.uint8)
    result = scores(confusion(pred, truth))
    assert result.iou == {0: 0.75, 4: 0.0}
    assert result.miou == pytest.approx(0.375)


def test_ignored_truth_pixels_count_nowhere() -> None:
    truth = np.array([[1, 255], [1, 255]], dtype=np.uint8)
    pred = np.array([[1, 2], [1, 3]], dtype=np.uint8)
    result = scores(confusion(pred, truth))
    assert result.iou == {1: 1.0}
    assert result.pixels == 2


def test_frames_sum_their_matrices_rather_than_averaging_scores() -> None:
    a_truth = np.array([[1, 1, 1, 1]], dtype=np.uint8)
    a_pred = np.array([[1, 1, 1, 0]], dtype=np.uint8)
    b_truth = np.array([[0, 0, 0, 0]], dtype=np.uint8)
    b_pred = np.array([[0, 0, 0, 0]], dtype=np.uint8)
    total = confusion(a_pred, a_truth) + confusion(b_pred, b_truth)
    result = scores(total)
    # class 1: hits 3, union 4; class 0: hits 4, truth 4, pred 5 -> 4/5
    assert result.iou == {0: pytest.approx(0.8), 1: pytest.approx(0.75)}
    assert result.pixel_accuracy == pytest.approx(7 / 8)


def test_empty_and_mismatched_inputs() -> None:
    assert scores(np.zeros((256, 256), dtype=np.int64)).miou is None
    with pytest.raises(ValueError, match='mask shapes differ'):
        confusion(np.zeros((2, 2), np.uint8), np.zeros((2, 3), np.uint8))
    assert class_name(1, ('background', 'red')) == 'red'
    assert class_name(7, ('background',)) == '7'
