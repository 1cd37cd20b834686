"""COCO-style accuracy: hand-computed cases and a cross-check against pycocotools' COCOeval."""

from __future__ import annotations

import contextlib
import io
import time
from typing import Any

import numpy as np
import pytest

from replaybench.results.accuracy import (
    MAX_DETECTIONS,
    AccuracyResult,
    evaluate,
    frame_scores,
    resampled_map50,
)
from replaybench.types import Detection

LABELS = ('red', 'green', 'blue', 'yellow')


def det(label: str, x0: float, y0: float, x1: float, y1: float, score: float = 1.0) -> Detection:
    return Detection(LABELS.index(label) if label in LABELS else 99, label, score, x0, y0, x1, y1)


# --- hand-computed cases ---------------------------------------------------------------------


def test_one_perfect_match_scores_ap_one() -> None:
    gt = {0: [det('red', 10, 10, 50, 40)]}
    result = evaluate(gt, {0: [det('red', 10, 10, 50, 40, 0.7)]})
    # precision is TP / (TP + FP + eps) as in pycocotools, hence approx
    assert isinstance(result, AccuracyResult)
    assert result[:4] == pytest.approx((1.0, 1.0, 1.0, 1.0), abs=1e-12)
    assert result.ap50 == pytest.approx({'red': 1.0}, abs=1e-12)
    assert result.ap50_95 == pytest.approx({'red': 1.0}, abs=1e-12)
    assert (result.n_gt, result.n_det) == (1, 1)


def test_false_positive_scored_above_the_true_positive_halves_ap() -> None:
    gt = {'f': [det('red', 0, 0, 10, 10)]}
    dets = {'f': [det('red', 0, 0, 10, 10, 0.8), det('red', 50, 50, 60, 60, 0.9)]}
    result = evaluate(gt, dets)
    # ranks: FP (p=0, r=0), TP (p=0.5, r=1): envelope 0.5 at every recall point
    assert result.ap50['red'] == pytest.approx(0.5)
    assert result.map50_95 == pytest.approx(0.5)
    assert result.precision50 == pytest.approx(0.5)
    assert result.recall50 == 1.0
    assert (result.n_gt, result.n_det) == (1, 2)


def test_true_positive_scored_above_a_false_positive_keeps_ap_one() -> None:
    gt = {'f': [det('red', 0, 0, 10, 10)]}
    dets = {'f': [det('red', 0, 0, 10, 10, 0.9), det('red', 50, 50, 60, 60, 0.8)]}
    result = evaluate(gt, dets)
    assert result.ap50['red'] == pytest.approx(1.0, abs=1e-12)
    assert result.precision50 == 0.5


def test_empty_detection_set_scores_zero() -> None:
    gt = {0: [det('red', 0, 0, 10, 10)], 1: [det('blue', 5, 5, 20, 20)]}
    result = evaluate(gt, {})
    assert result.map50 == 0.0
    assert result.map50_95 == 0.0
    assert result.ap50 == {'blue': 0.0, 'red': 0.0}
    assert (result.precision50, result.recall50, result.n_det, result.n_gt) == (0.0, 0.0, 0, 2)


def test_iou_of_exactly_one_half_matches_at_050_only() -> None:
    gt = {0: [det('red', 0, 0, 10, 10)]}
    result = evaluate(gt, {0: [det('red', 0, 0, 10, 5, 0.9)]})  # inter 50, union 100
    assert result.ap50['red'] == pytest.approx(1.0, abs=1e-12)
    assert result.ap50_95['red'] == pytest.approx(0.1)


def test_iou_is_continuous_without_plus_one() -> None:
    gt = {0: [det('red', 0, 0, 10, 10)]}
    # IoU 49/100 with continuous boxes; the +1 convention would make it 60/121 > 0.49
    result = evaluate(gt, {0: [det('red', 0, 0, 10, 4.9, 0.9)]})
    assert result.ap50['red'] == 0.0


def test_greedy_matching_gives_each_detection_the_best_free_box() -> None:
    gt = {0: [det('red', 0, 0, 10, 10), det('red', 4, 0, 14, 10)]}
    dets = {0: [det('red', 3, 0, 13, 10, 0.9), det('red', 0, 0, 10, 10, 0.8)]}
    result = evaluate(gt, dets)
    assert result.ap50['red'] == pytest.approx(1.0, abs=1e-12)
    assert result.precision50 == 1.0


def test_classes_without_ground_truth_get_minus_one_and_stay_out_of_the_mean() -> None:
    gt = {0: [det('red', 0, 0, 10, 10)]}
    dets = {0: [det('red', 0, 0, 10, 10, 0.9), det('purple', 0, 0, 10, 10, 0.95)]}
    result = evaluate(gt, dets)
    assert result.ap50 == pytest.approx({'purple': -1.0, 'red': 1.0}, abs=1e-12)
    assert result.map50 == pytest.approx(1.0, abs=1e-12)
    assert result.precision50 == 0.5


def test_detections_of_frames_without_ground_truth_entry_are_not_scored() -> None:
    gt = {0: [det('red', 0, 0, 10, 10)]}
    dets = {0: [det('red', 0, 0, 10, 10, 0.5)], 7: [det('red', 0, 0, 10, 10, 0.9)]}
    result = evaluate(gt, dets)
    assert (result.map50, result.precision50, result.n_det) == pytest.approx((1.0, 1.0, 1))


def test_no_ground_truth_at_all_gives_minus_one_map() -> None:
    result = evaluate({0: []}, {0: [det('red', 0, 0, 10, 10, 0.5)]})
    assert (result.map50, result.map50_95, result.recall50, result.precision50) == (
        -1.0,
        -1.0,
        0.0,
        0.0,
    )


def test_ap_keeps_100_detections_per_frame_while_precision_counts_all() -> None:
    boxes = [(20.0 * i, 0.0, 20.0 * i + 10, 10.0) for i in range(150)]
    gt = {0: [det('red', *b) for b in boxes]}
    dets = {0: [det('red', *b, score=1.0 - i / 1000) for i, b in enumerate(boxes)]}
    result = evaluate(gt, dets)
    # recall reaches 100/150 with precision 1: recall points 0.00..0.66 score 1
    assert result.ap50['red'] == pytest.approx(67 / 101)
    assert result.recall50 == 1.0
    assert result.precision50 == 1.0


# --- cross-check against pycocotools ---------------------------------------------------------


def _random_case(
    seed: int, n_frames: int = 50
) -> tuple[dict[int, list[Detection]], dict[int, list[Detection]]]:
    rng = np.random.default_rng(seed)
    labels = [*LABELS, 'white']  # 'white' has ground truth but is never detected
    gt: dict[int, list[Detection]] = {}
    dets: dict[int, list[Detection]] = {}
    for frame in range(n_frames):
        truth: list[Detection] = []
        found: list[Detection] = []
        for label in labels:
            for _ in range(int(rng.integers(0, 4))):
                x0, y0 = rng.uniform(0, 560), rng.uniform(0, 400)
                w, h = rng.uniform(8, 80), rng.uniform(8, 80)
                truth.append(det(label, x0, y0, x0 + w, y0 + h))
                if label == 'white' or rng.random() < 0.2:  # miss
                    continue
                for _ in range(1 + int(rng.random() < 0.15)):  # sometimes a duplicate
                    jitter = rng.normal(0.0, 0.12 * min(w, h), 4)
                    bx0, by0 = x0 + jitter[0], y0 + jitter[1]
                    bx1 = max(bx0 + 1.0, x0 + w + jitter[2])
                    by1 = max(by0 + 1.0, y0 + h + jitter[3])
                    found.append(det(label, bx0, by0, bx1, by1, float(rng.uniform(0.05, 1.0))))
            for _ in range(int(rng.integers(0, 3))):  # false positives
                x0, y0 = rng.uniform(0, 560), rng.uniform(0, 400)
                w, h = rng.uniform(8, 80), rng.uniform(8, 80)
                found.append(det(label, x0, y0, x0 + w, y0 + h, float(rng.uniform(0.0, 0.9))))
        if frame % 10 == 3:  # a class seen only in detections
            found.append(det('purple', 10, 10, 40, 40, 0.66))
        if frame == 17:  # more than maxDets=100 detections of one class in one frame
            for i in range(130):
                x0, y0 = rng.uniform(0, 600), rng.uniform(0, 440)
                found.append(det('red', x0, y0, x0 + 30, y0 + 30, float(rng.uniform(0.0, 1.0))))
                if i % 3 == 0:
                    truth.append(det('red', x0 + 1, y0, x0 + 31, y0 + 30))
        order = rng.permutation(len(found))
        gt[frame] = truth
        dets[frame] = [found[i] for i in order]
    return gt, dets


def _cocoeval(
    gt: dict[int, list[Detection]], dets: dict[int, list[Detection]]
) -> tuple[float, float, dict[str, float], dict[str, float]]:
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    names = sorted({d.label for items in (*gt.values(), *dets.values()) for d in items})
    cat = {name: i + 1 for i, name in enumerate(names)}
    image_id = {frame: i + 1 for i, frame in enumerate(gt)}
    annotations: list[dict[str, Any]] = []
    for frame, items in gt.items():
        for d in items:
            w, h = d.x1 - d.x0, d.y1 - d.y0
            annotations.append(
                {
                    'id': len(annotations) + 1,
                    'image_id': image_id[frame],
                    'category_id': cat[d.label],
                    'bbox': [d.x0, d.y0, w, h],
                    'area': w * h,
                    'iscrowd': 0,
                }
            )
    results = [
        {
            'image_id': image_id[frame],
            'category_id': cat[d.label],
            'bbox': [d.x0, d.y0, d.x1 - d.x0, d.y1 - d.y0],
            'score': d.score,
        }
        for frame, items in dets.items()
        for d in items
    ]
    with contextlib.redirect_stdout(io.StringIO()):
        coco_gt = COCO()
        coco_gt.dataset = {
            'images': [{'id': i, 'width': 640, 'height': 480} for i in image_id.values()],
            'categories': [{'id': i, 'name': name} for name, i in cat.items()],
            'annotations': annotations,
        }
        coco_gt.createIndex()
        coco_dt = coco_gt.loadRes(results)
        ev = COCOeval(coco_gt, coco_dt, 'bbox')
        ev.evaluate()
        ev.accumulate()
        ev.summarize()
    precision = ev.eval['precision'][:, :, :, 0, -1]  # area 'all', maxDets 100
    ap50: dict[str, float] = {}
    ap50_95: dict[str, float] = {}
    for k, cat_id in enumerate(ev.params.catIds):
        name = names[cat_id - 1]
        p = precision[:, :, k]
        ap50[name] = float(np.mean(p[0])) if (p[0] > -1).any() else -1.0
        ap50_95[name] = float(np.mean(p)) if (p > -1).any() else -1.0
    return float(ev.stats[1]), float(ev.stats[0]), ap50, ap50_95


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_map_equals_pycocotools_on_random_jittered_detections(seed: int) -> None:
    gt, dets = _random_case(seed)
    result = evaluate(gt, dets)
    map50, map50_95, ap50, ap50_95 = _cocoeval(gt, dets)
    assert 0.2 < result.map50 < 0.95  # a case that exercises misses and false positives
    assert result.map50 == pytest.approx(map50, abs=1e-6)
    assert result.map50_95 == pytest.approx(map50_95, abs=1e-6)
    assert result.ap50.keys() == ap50.keys()
    for name in ap50:
        assert result.ap50[name] == pytest.approx(ap50[name], abs=1e-6), name
        assert result.ap50_95[name] == pytest.approx(ap50_95[name], abs=1e-6), name
    assert result.ap50['purple'] == -1.0
    assert result.ap50['white'] == 0.0


def test_precision_and_recall_count_matches_at_050_over_all_detections() -> None:
    gt, dets = _random_case(5, n_frames=20)
    result = evaluate(gt, dets)
    # brute force: greedy at IoU 0.5 per frame and class, every detection, score order
    tp = 0
    for frame, truth in gt.items():
        for label in {d.label for d in dets[frame]}:
            boxes = [g for g in truth if g.label == label]
            taken = [False] * len(boxes)
            ranked = sorted((d for d in dets[frame] if d.label == label), key=lambda d: -d.score)
            for d in ranked:
                best, best_iou = -1, 0.5
                for i, g in enumerate(boxes):
                    iw = min(d.x1, g.x1) - max(d.x0, g.x0)
                    ih = min(d.y1, g.y1) - max(d.y0, g.y0)
                    if taken[i] or iw <= 0 or ih <= 0:
                        continue
                    inter = iw * ih
                    union = (d.x1 - d.x0) * (d.y1 - d.y0) + (g.x1 - g.x0) * (g.y1 - g.y0) - inter
                    if inter / union >= best_iou:
                        best, best_iou = i, inter / union
                if best >= 0:
                    taken[best] = True
                    tp += 1
    n_det = sum(len(v) for v in dets.values())
    n_gt = sum(len(v) for v in gt.values())
    assert (result.n_det, result.n_gt) == (n_det, n_gt)
    assert result.precision50 == pytest.approx(tp / n_det)
    assert result.recall50 == pytest.approx(tp / n_gt)


def test_bag_sized_input_evaluates_well_under_a_second() -> None:
    rng = np.random.default_rng(7)
    gt: dict[int, list[Detection]] = {}
    dets: dict[int, list[Detection]] = {}
    for frame in range(5000):
        truth, found = [], []
        for label in LABELS:
            for _ in range(int(rng.integers(0, 3))):
                x0, y0 = rng.uniform(0, 600), rng.uniform(0, 400)
                truth.append(det(label, x0, y0, x0 + 40, y0 + 30))
                found.append(det(label, x0 + 2, y0 - 1, x0 + 41, y0 + 30, float(rng.random())))
            if rng.random() < 0.3:
                found.append(det(label, 5, 5, 25, 25, float(rng.random())))
        gt[frame], dets[frame] = truth, found
    start = time.perf_counter()
    result = evaluate(gt, dets)
    elapsed = time.perf_counter() - start
    assert result.n_gt > 15000
    assert result.map50 > 0.5
    assert elapsed < 1.0, f'{elapsed:.3f} s'


def test_resampled_map50_equals_evaluate_on_the_drawn_frames_ties_and_the_100_limit_included() -> (
    None
):
    rng = np.random.default_rng(7)
    labels = ('red', 'green', 'blue')
    gt: dict[int, tuple[Detection, ...]] = {}
    dets: dict[int, tuple[Detection, ...]] = {}
    for frame in range(8):
        boxes = []
        for _ in range(int(rng.integers(0, 5))):
            x, y = rng.uniform(0, 200, 2)
            boxes.append(Detection(0, str(rng.choice(labels)), 1.0, x, y, x + 30, y + 20))
        gt[frame] = tuple(boxes)
        found = [
            Detection(0, b.label, float(rng.choice([0.5, 0.7, 0.9])), b.x0 + 3, b.y0, b.x1, b.y1)
            for b in boxes
            if rng.random() < 0.8
        ]
        many = MAX_DETECTIONS + 5 if frame == 3 else int(rng.integers(0, 4))
        for _ in range(many):  # phantoms (frame 3: more than the limit of one class)
            x, y = rng.uniform(0, 200, 2)
            label = 'red' if frame == 3 else str(rng.choice(labels))
            found.append(Detection(0, label, float(rng.choice([0.5, 0.7])), x, y, x + 10, y + 10))
        dets[frame] = tuple(found)
    scores = frame_scores(gt, dets)
    keys = list(gt)
    for _ in range(200):
        picks = rng.integers(0, len(keys), len(keys))
        drawn_gt = {i: gt[keys[j]] for i, j in enumerate(picks.tolist())}
        drawn = {i: dets[keys[j]] for i, j in enumerate(picks.tolist())}
        assert resampled_map50(scores, picks) == evaluate(drawn_gt, drawn).map50
    assert resampled_map50(scores, np.arange(len(keys))) == evaluate(gt, dets).map50
