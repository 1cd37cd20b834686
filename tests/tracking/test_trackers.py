"""The trackers over a scene of crossings with occlusions: ByteTrack keeps ids through them,
SORT and the IoU baseline switch; ids are deterministic."""

from __future__ import annotations

import numpy as np
import pytest

from replaybench.tracking import TrackFrame, TrackScores, box_iou_xywh, score_tracks
from replaybench.tracking.trackers import make_tracker

Scene = list[tuple[list[tuple[int, tuple[float, float, float, float]]], np.ndarray, np.ndarray]]


def _scene(seed: int, n_frames: int = 120) -> Scene:
    """Four pairs of objects crossing (one left to right, one right to left, 8 px apart in y);
    where they overlap the second is missed for 6 frames and seen with a low score (0.3) for
    5 frames on each side; detections jitter by 1 px (seeded)."""
    rng = np.random.default_rng(seed)
    objects = []
    for k in range(4):
        objects.append((2 * k, 20.0, 60.0 + 90 * k, 4.0))
        objects.append((2 * k + 1, 500.0, 68.0 + 90 * k, -4.0))
    frames: Scene = []
    for t in range(n_frames):
        truth, boxes, scores = [], [], []
        for oid, x0, y, vx in objects:
            x = x0 + vx * t
            if not 0 <= x <= 520:
                continue
            truth.append((oid, (x, y, 40.0, 80.0)))
            other = next(o for o in objects if o[0] == oid ^ 1)
            gap = abs(x - (other[1] + other[3] * t))
            if oid % 2 and gap < 24:
                continue
            jitter = rng.normal(0, 1.0, 4)
            boxes.append((x + jitter[0], y + jitter[1], x + 40 + jitter[2], y + 80 + jitter[3]))
            scores.append(0.3 if oid % 2 and gap < 44 else 0.9)
        frames.append((truth, np.array(boxes).reshape(-1, 4), np.array(scores)))
    return frames


def _run(name: str, scene: Scene) -> tuple[TrackScores, list[list[int]]]:
    tracker = make_tracker(name)
    sequence, ids = [], []
    for truth, boxes, scores in scene:
        tracks = tracker.update(boxes, scores)
        ids.append([t.id for t in tracks])
        gt = np.array([b for _, b in truth]).reshape(-1, 4)
        found = np.array(
            [[t.box[0], t.box[1], t.box[2] - t.box[0], t.box[3] - t.box[1]] for t in tracks]
        ).reshape(-1, 4)
        sequence.append(
            TrackFrame(
                np.array([i for i, _ in truth], dtype=np.int64),
                np.array([t.id for t in tracks], dtype=np.int64),
                box_iou_xywh(gt, found),
            )
        )
    return score_tracks(sequence), ids


@pytest.mark.parametrize('seed', [0, 1])
def test_bytetrack_keeps_ids_through_occlusions_and_both_trackers_beat_the_iou_baseline(
    seed: int,
) -> None:
    scene = _scene(seed)
    iou, _ = _run('iou', scene)
    sort, _ = _run('sort', scene)
    byte, _ = _run('bytetrack', scene)
    assert byte.idf1 >= sort.idf1 > iou.idf1
    assert byte.hota > sort.hota > iou.hota
    assert byte.id_switches < sort.id_switches
    assert byte.idf1 > 0.95


@pytest.mark.parametrize('name', ['iou', 'sort', 'bytetrack'])
def test_the_same_boxes_give_the_same_ids(name: str) -> None:
    scene = _scene(3)
    assert _run(name, scene)[1] == _run(name, scene)[1]


def test_a_tracker_reports_the_detection_it_matched_and_ids_from_1() -> None:
    tracker = make_tracker('sort', min_hits=1)
    boxes = np.array([[10.0, 10, 50, 90], [200, 10, 240, 90]])
    for step in range(3):
        shift = np.array([4.0 * step, 0, 4.0 * step, 0])
        tracks = tracker.update(boxes + shift, np.array([0.9, 0.8]))
    assert [(t.id, t.detection) for t in tracks] == [(1, 0), (2, 1)]


def test_an_unknown_tracker_or_parameter_is_refused() -> None:
    with pytest.raises(ValueError, match='known: iou, sort, bytetrack'):
        make_tracker('deepsort')
    with pytest.raises(ValueError, match="tracker 'sort'"):
        make_tracker('sort', nope=1)
