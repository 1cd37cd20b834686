"""Agreement between two backends' detections on the same frames."""

from __future__ import annotations

import random
import time
from typing import TYPE_CHECKING, Any

import pytest

from replaybench.results.agreement import (
    MAX_DISAGREEING_FRAMES,
    Agreement,
    agreement,
    agreement_table,
)
from replaybench.types import Detection

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    Frames = Mapping[tuple[int, int], Sequence[Detection]]


def _det(label: str, x0: float, y0: float, x1: float, y1: float, score: float = 0.9) -> Detection:
    return Detection(0, label, score, x0, y0, x1, y1)


def _agree(a: Frames, b: Frames, **kwargs: Any) -> Agreement:
    return agreement(a, b, backend_a='a', backend_b='b', topic='/cam', **kwargs)


def test_identical_detections_agree_completely() -> None:
    frames = {
        (0, i): (_det('red', 10 * i, 5, 10 * i + 20, 40, 0.5 + i / 100), _det('blue', 0, 0, 8, 8))
        for i in range(12)
    }
    result = _agree(frames, dict(frames))
    assert result.frames == 12
    assert result.n_a == result.n_b == result.matched == 24
    assert result.matched_frac_a == 1.0
    assert result.matched_frac_b == 1.0
    assert result.mean_iou == pytest.approx(1.0)
    assert result.mean_abs_score_diff == 0.0
    assert result.disagreeing_frames == ()


def test_one_missing_box_is_unmatched_on_one_side_and_names_its_frame() -> None:
    a = {(0, 0): (_det('red', 0, 0, 10, 10),), (0, 1): (_det('red', 0, 0, 10, 10),)}
    b = {(0, 0): (_det('red', 0, 0, 10, 10),), (0, 1): ()}
    result = _agree(a, b)
    assert (result.n_a, result.n_b, result.matched) == (2, 1, 1)
    assert result.matched_frac_a == 0.5
    assert result.matched_frac_b == 1.0
    assert result.disagreeing_frames == ((0, 1),)


def test_boxes_of_different_classes_are_never_matched() -> None:
    a = {(0, 0): (_det('red', 0, 0, 10, 10),)}
    b = {(0, 0): (_det('blue', 0, 0, 10, 10),)}
    result = _agree(a, b)
    assert result.matched == 0
    assert result.matched_frac_a == 0.0
    assert result.matched_frac_b == 0.0
    assert result.mean_iou is None
    assert result.mean_abs_score_diff is None
    assert result.disagreeing_frames == ((0, 0),)


def test_a_shifted_box_has_the_iou_computed_by_hand() -> None:
    # 10x10 boxes shifted by 2 px in x: intersection 8*10 = 80, union 100 + 100 - 80 = 120
    a = {(0, 0): (_det('red', 0, 0, 10, 10, score=0.9),)}
    b = {(0, 0): (_det('red', 2, 0, 12, 10, score=0.6),)}
    result = _agree(a, b)
    assert result.matched == 1
    assert result.mean_iou == pytest.approx(80 / 120)
    assert result.mean_abs_score_diff == pytest.approx(0.3)
    # shifted by 4 px: 60 / 140 < 0.5, no match at the default threshold, one at 0.4
    b4 = {(0, 0): (_det('red', 4, 0, 14, 10),)}
    assert _agree(a, b4).matched == 0
    assert _agree(a, b4, iou=0.4).mean_iou == pytest.approx(60 / 140)


def test_greedy_matching_takes_the_highest_iou_first() -> None:
    # b0 overlaps a0 a little and a1 a lot; greedy must pair b0 with a1, leaving a0 for b1
    a = {(0, 0): (_det('red', 0, 0, 10, 10), _det('red', 1, 0, 11, 10))}
    b = {(0, 0): (_det('red', 1, 0, 11, 10), _det('red', 0, 0, 10, 10))}
    result = _agree(a, b)
    assert result.matched == 2
    assert result.mean_iou == pytest.approx(1.0)


def test_a_detection_is_used_at_most_once() -> None:
    a = {(0, 0): (_det('red', 0, 0, 10, 10), _det('red', 0, 0, 10, 10))}
    b = {(0, 0): (_det('red', 0, 0, 10, 10),)}
    result = _agree(a, b)
    assert result.matched == 1
    assert result.matched_frac_a == 0.5
    assert result.matched_frac_b == 1.0


def test_ties_are_broken_by_output_order_so_results_are_deterministic() -> None:
    # two identical candidates for one b box, with different scores: the first a box wins
    a = {(0, 0): (_det('red', 0, 0, 10, 10, 0.2), _det('red', 0, 0, 10, 10, 0.8))}
    b = {(0, 0): (_det('red', 0, 0, 10, 10, 0.3),)}
    assert _agree(a, b).mean_abs_score_diff == pytest.approx(0.1)


def test_only_frames_present_in_both_are_compared() -> None:
    a = {(0, 0): (_det('red', 0, 0, 10, 10),), (0, 1): (_det('red', 0, 0, 10, 10),)}
    b = {(0, 1): (_det('red', 0, 0, 10, 10),), (1, 0): (_det('red', 0, 0, 10, 10),)}
    result = _agree(a, b)
    assert result.frames == 1
    assert (result.n_a, result.n_b, result.matched) == (1, 1, 1)


def test_frames_without_detections_on_either_side_agree_and_have_no_fractions() -> None:
    result = _agree({(0, 0): ()}, {(0, 0): ()})
    assert result.frames == 1
    assert result.matched_frac_a is None
    assert result.matched_frac_b is None
    assert result.disagreeing_frames == ()


def test_worst_frames_come_first_and_are_capped() -> None:
    a = {
        (0, i): tuple(_det('red', 20 * k, 0, 20 * k + 10, 10) for k in range(i % 4))
        for i in range(40)
    }
    b = {(0, i): () for i in range(40)}
    result = _agree(a, b)
    worst = result.disagreeing_frames
    assert len(worst) == MAX_DISAGREEING_FRAMES
    counts = [len(a[k]) for k in worst]
    assert counts == sorted(counts, reverse=True)
    assert worst[0] == (0, 3)  # three unmatched boxes; ties in frame order
    assert worst[:3] == ((0, 3), (0, 7), (0, 11))


def test_agreement_table_pairs_every_backend_on_every_topic() -> None:
    box = (_det('red', 0, 0, 10, 10),)
    dets: dict[tuple[str, str], Frames] = {
        ('hsv', '/a'): {(0, 0): box},
        ('null', '/a'): {(0, 0): ()},
        ('onnx', '/a'): {(0, 0): box},
        ('hsv', '/b'): {(0, 0): box},
        ('onnx', '/b'): {(0, 0): box},
    }
    table = agreement_table(dets)
    pairs = [(r.topic, r.backend_a, r.backend_b) for r in table]
    assert pairs == [
        ('/a', 'hsv', 'null'),
        ('/a', 'hsv', 'onnx'),
        ('/a', 'null', 'onnx'),
        ('/b', 'hsv', 'onnx'),
    ]
    assert [r.matched for r in table] == [0, 1, 0, 1]


def _random_frames(n: int, seed: int) -> tuple[Frames, Frames]:
    rng = random.Random(seed)
    a: dict[tuple[int, int], tuple[Detection, ...]] = {}
    b: dict[tuple[int, int], tuple[Detection, ...]] = {}
    for f in range(n):
        da, db = [], []
        for _ in range(rng.randint(0, 5)):
            x, y = rng.uniform(0, 600), rng.uniform(0, 400)
            w, h = rng.uniform(10, 80), rng.uniform(10, 80)
            label = rng.choice(('red', 'blue', 'car'))
            da.append(_det(label, x, y, x + w, y + h, rng.random()))
            if rng.random() < 0.9:
                dx = rng.uniform(-6, 6)
                db.append(_det(label, x + dx, y, x + w + dx, y + h, rng.random()))
        a[(0, f)], b[(0, f)] = tuple(da), tuple(db)
    return a, b


def _naive(a: Frames, b: Frames, iou: float = 0.5) -> tuple[int, float]:
    """Per-frame reference: all same-label pairs, sorted by (-IoU, i, j), taken greedily."""
    matched, total_iou = 0, 0.0
    for key in sorted(set(a) & set(b)):
        pairs: list[tuple[float, int, int]] = []
        for i, p in enumerate(a[key]):
            for j, q in enumerate(b[key]):
                if p.label != q.label:
                    continue
                iw = max(0.0, min(p.x1, q.x1) - max(p.x0, q.x0))
                ih = max(0.0, min(p.y1, q.y1) - max(p.y0, q.y0))
                inter = iw * ih
                union = (p.x1 - p.x0) * (p.y1 - p.y0) + (q.x1 - q.x0) * (q.y1 - q.y0) - inter
                value = inter / union if union > 0 else 0.0
                if value >= iou:
                    pairs.append((-value, i, j))
        used_a: set[int] = set()
        used_b: set[int] = set()
        for neg, i, j in sorted(pairs):
            if i not in used_a and j not in used_b:
                used_a.add(i)
                used_b.add(j)
                matched += 1
                total_iou -= neg
    return matched, total_iou


def test_the_vectorised_matching_equals_a_per_frame_reference() -> None:
    a, b = _random_frames(400, seed=3)
    result = _agree(a, b)
    matched, total_iou = _naive(a, b)
    assert result.matched == matched
    assert result.mean_iou == pytest.approx(total_iou / matched)


def test_ten_thousand_frames_take_well_under_a_second() -> None:
    a, b = _random_frames(10_000, seed=1)
    cpu0 = time.process_time()  # CPU time: other processes on the machine do not count
    result = _agree(a, b)
    elapsed = time.process_time() - cpu0
    assert result.frames == 10_000
    assert result.matched > 0.8 * result.n_b
    assert elapsed < 1.0
