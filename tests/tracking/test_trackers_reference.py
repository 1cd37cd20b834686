"""The trackers report what their frozen reference (tracking/frozen_trackers.py, the trackers
before their filters became elementwise 2x2 blocks) reports: the same ids and matched boxes in
every frame, the boxes within 1e-6 px, over seeded random scenes (births, deaths, occlusions,
crossings, low-score boxes, clutter, boxes in shuffled order) and over hsv's boxes on the
tracking fixture and on the 50-object grid of benchmarks/bench_tracking.py."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from tracking import frozen_trackers

from replaybench.tracking import trackers

Sequence = list[tuple[np.ndarray, np.ndarray]]

PARAMS: list[tuple[str, dict[str, float]]] = [
    ('iou', {}),
    ('sort', {}),
    ('sort', {'max_age': 4, 'min_hits': 1, 'iou_threshold': 0.2}),
    ('sort', {'det_thresh': 0.4, 'max_age': 2}),
    ('bytetrack', {}),
    ('bytetrack', {'track_buffer': 5, 'match_thresh': 0.7}),
    ('bytetrack', {'track_thresh': 0.6, 'low_thresh': 0.2, 'track_buffer': 2}),
]


def _random_scene(seed: int, n_frames: int = 80) -> Sequence:
    """Objects born and dying at random frames, moving at constant velocity (some towards each
    other, so that they cross), each hidden now and then for 1 to 6 frames and seen with a
    low score (0.15 to 0.5) now and then; clutter boxes; 1 px jitter; each frame's boxes in a
    shuffled order."""
    rng = np.random.default_rng(seed)
    objects = []
    for _ in range(int(rng.integers(15, 35))):
        born = int(rng.integers(0, n_frames - 5))
        objects.append(
            {
                'born': born,
                'dies': born + int(rng.integers(5, n_frames)),
                'x': rng.uniform(0, 600),
                'y': rng.uniform(0, 440),
                'vx': rng.choice([-1, 1]) * rng.uniform(0, 6),
                'vy': rng.normal(0, 1.5),
                'w': rng.uniform(12, 60),
                'h': rng.uniform(12, 90),
                'hidden_until': -1,
            }
        )
    frames: Sequence = []
    for t in range(n_frames):
        boxes, scores = [], []
        for o in objects:
            if not o['born'] <= t < o['dies']:
                continue
            if t <= o['hidden_until']:
                continue
            if rng.random() < 0.04:
                o['hidden_until'] = t + int(rng.integers(1, 7))
                continue
            dt = t - o['born']
            x, y = o['x'] + o['vx'] * dt, o['y'] + o['vy'] * dt
            j = rng.normal(0, 1.0, 4)
            boxes.append((x + j[0], y + j[1], x + o['w'] + j[2], y + o['h'] + j[3]))
            scores.append(rng.uniform(0.15, 0.5) if rng.random() < 0.15 else rng.uniform(0.6, 1))
        for _ in range(int(rng.poisson(1.5))):
            x, y = rng.uniform(0, 620), rng.uniform(0, 460)
            boxes.append((x, y, x + rng.uniform(5, 30), y + rng.uniform(5, 30)))
            scores.append(rng.uniform(0.05, 0.7))
        order = rng.permutation(len(boxes))
        frames.append(
            (
                np.array(boxes, dtype=np.float64).reshape(-1, 4)[order],
                np.array(scores, dtype=np.float64)[order],
            )
        )
    return frames


def _hsv_boxes(scene: Any, n_frames: int) -> Sequence:
    """hsv's boxes and scores on the frames a fixture scene renders."""
    from replaybench.backends.hsv import HsvBackend
    from replaybench.types import Frame

    hsv = HsvBackend()
    hsv.open()
    frames: Sequence = []
    for i in range(n_frames):
        image, _ = scene.render(i)
        found = hsv.detect(Frame('/camera', i, i, i, 'camera', image, 'bgr8', 'bgr8')).detections
        frames.append(
            (
                np.array([d[3:7] for d in found], dtype=np.float64).reshape(-1, 4),
                np.array([d[2] for d in found], dtype=np.float64),
            )
        )
    hsv.close()
    return frames


def _assert_same(name: str, params: dict[str, float], frames: Sequence) -> int:
    """Each frame's tracks of the tracker and of its reference: the same ids and detections,
    boxes within 1e-6 px. The number of tracks reported over the frames."""
    new = trackers.make_tracker(name, **params)
    old = frozen_trackers.make_tracker(name, **params)
    reported = 0
    for n, (boxes, scores) in enumerate(frames):
        got = new.update(boxes.copy(), scores.copy())
        want = old.update(boxes.copy(), scores.copy())
        assert [(t.id, t.detection) for t in got] == [(t.id, t.detection) for t in want], n
        if want:
            np.testing.assert_allclose(
                np.array([t.box for t in got]), np.array([t.box for t in want]), rtol=0, atol=1e-6
            )
        reported += len(want)
    return reported


@pytest.mark.parametrize('seed', range(8))
@pytest.mark.parametrize(('name', 'params'), PARAMS)
def test_each_tracker_reports_its_references_tracks_on_random_scenes(
    name: str, params: dict[str, float], seed: int
) -> None:
    assert _assert_same(name, params, _random_scene(seed)) > 100


def test_the_trackers_report_their_references_tracks_on_hsvs_boxes_of_the_fixtures() -> None:
    repo = str(Path(__file__).resolve().parents[2])
    if repo not in sys.path:  # the benchmarks package, however pytest was started
        sys.path.insert(0, repo)
    from benchmarks.bench_tracking import OBJECTS, grid_scene
    from replaybench.fixtures.tracks import TRACKS_FRAMES, TrackScene

    crossings = _hsv_boxes(TrackScene(), TRACKS_FRAMES)
    grid = _hsv_boxes(grid_scene(), 40)
    assert min(len(b) for b, _ in grid) >= OBJECTS - 10
    for name, params in PARAMS:
        assert _assert_same(name, params, crossings) > 200
        assert _assert_same(name, params, grid) > 1000


def test_frames_without_boxes_and_a_tracker_fed_nothing_report_no_tracks() -> None:
    empty = (np.zeros((0, 4)), np.zeros(0))
    frames = _random_scene(99, 30)
    frames[5:9] = [empty] * 4
    frames.insert(0, empty)
    for name, params in PARAMS:
        _assert_same(name, params, frames)
        assert trackers.make_tracker(name, **params).update(*empty) == []


@pytest.mark.parametrize('name', ['iou', 'sort', 'bytetrack'])
def test_a_tracked_backends_detections_are_its_references_tracks_on_the_fixture(name: str) -> None:
    from replaybench.backends.base import BackendOptions
    from replaybench.backends.hsv import HsvBackend
    from replaybench.backends.tracked import tracked_class
    from replaybench.fixtures.tracks import TRACKS_FRAMES, TrackScene
    from replaybench.types import Detection, Frame

    made: Any = tracked_class(f'hsv+{name}', HsvBackend, name)
    backend = made(BackendOptions())
    backend.open()
    hsv = HsvBackend()
    hsv.open()
    reference = frozen_trackers.make_tracker(name)
    scene = TrackScene()
    reported = 0
    for i in range(TRACKS_FRAMES):
        image, _ = scene.render(i)
        frame = Frame('/camera', i, i, i, 'camera', image, 'bgr8', 'bgr8')
        got = backend.detect(frame).detections
        found = hsv.detect(frame).detections
        tracks = reference.update(
            np.array([d[3:7] for d in found]).reshape(-1, 4), np.array([d[2] for d in found])
        )
        want = [
            Detection(*found[t.detection][:3], *t.box, str(t.id))
            for t in tracks
            if t.detection is not None
        ]
        assert [d[:3] + d[7:] for d in got] == [d[:3] + d[7:] for d in want], i
        assert all(type(d) is Detection for d in got)
        np.testing.assert_allclose(
            np.array([d[3:7] for d in got]).reshape(-1, 4),
            np.array([d[3:7] for d in want]).reshape(-1, 4),
            rtol=0,
            atol=1e-6,
        )
        reported += len(got)
    backend.close()
    assert reported > 200


def test_a_track_without_a_box_of_its_frame_is_not_reported_as_a_detection() -> None:
    from replaybench.backends.tracked import _tracked
    from replaybench.types import Detection

    found = (Detection(0, 'red', 0.9, 1, 2, 3, 4), Detection(1, 'green', 0.8, 5, 6, 7, 8))
    columns = list(zip(*found, strict=True))
    boxes = [[10.0, 20.0, 30.0], [11.0, 21.0, 31.0], [12.0, 22.0, 32.0], [13.0, 23.0, 33.0]]
    got = _tracked(([4, 5, 6], boxes, [1, -1, 0]), columns)
    assert got == (
        Detection(1, 'green', 0.8, 10.0, 11.0, 12.0, 13.0, '4'),
        Detection(0, 'red', 0.9, 30.0, 31.0, 32.0, 33.0, '6'),
    )
    assert _tracked(([4], [[1.0], [2.0], [3.0], [4.0]], [-1]), columns) == ()
    assert _tracked(([], [[], [], [], []], []), []) == ()
