"""The hsv backend on synthetic frames drawn with OpenCV."""

from __future__ import annotations

import json
from typing import Any

import cv2
import numpy as np
import pytest

from replaybench.backends import Backend, BackendOptions
from replaybench.backends.hsv import DEFAULT_CLASSES, HsvBackend
from replaybench.types import Detection, Frame

Scene = Any  # the conftest fixture's class


def run(frame: Frame, **extra: str) -> tuple[Detection, ...]:
    backend = HsvBackend(BackendOptions(extra=extra))
    backend.open()
    try:
        return backend.detect(frame).detections
    finally:
        backend.close()


def boxes(detections: tuple[Detection, ...]) -> list[tuple[str, float, float, float, float]]:
    return [(d.label, d.x0, d.y0, d.x1, d.y1) for d in detections]


def test_hsv_backend_satisfies_the_backend_protocol() -> None:
    backend = HsvBackend()
    assert isinstance(backend, Backend)
    assert HsvBackend.available().ok


def test_each_default_colour_is_found_with_a_tight_box(scene: type[Scene]) -> None:
    s = scene(seed=1)
    s.rect('red', 10, 20, 60, 50).rect('green', 100, 30, 140, 90)
    s.rect('blue', 200, 10, 290, 40).rect('yellow', 30, 150, 110, 200)
    found = run(s.frame())
    assert boxes(found) == [
        ('red', 10, 20, 60, 50),
        ('green', 100, 30, 140, 90),
        ('blue', 200, 10, 290, 40),
        ('yellow', 30, 150, 110, 200),
    ]
    assert [d.class_index for d in found] == [0, 1, 2, 3]
    assert all(0.95 < d.score <= 1.0 for d in found)


def test_discs_get_boxes_within_a_pixel(scene: type[Scene]) -> None:
    found = run(scene(seed=2).disc('green', 160, 120, 30).frame())
    assert len(found) == 1
    box = np.array([found[0].x0, found[0].y0, found[0].x1, found[0].y1])
    assert np.abs(box - [130, 90, 191, 151]).max() <= 1


@pytest.mark.parametrize('encoding', ['bgr8', 'rgb8', 'rgba8', 'bgra8'])
def test_every_colour_encoding_gives_the_same_detections(scene: type[Scene], encoding: str) -> None:
    s = scene(seed=3).rect('red', 10, 10, 50, 40).disc('blue', 200, 150, 25)
    assert run(s.frame(encoding)) == run(s.frame('bgr8'))
    assert len(run(s.frame(encoding))) == 2


def test_grey_frames_have_no_colour_blobs(scene: type[Scene]) -> None:
    s = scene(seed=4, noise=12.0).rect('red', 10, 10, 50, 40)
    assert run(s.frame('mono8')) == ()
    assert run(scene(seed=4, noise=12.0).frame('bgr8')) == ()


def test_depth_encodings_are_accepted_and_find_nothing() -> None:
    depth = np.linspace(0.5, 4.0, 240 * 320, dtype=np.float32).reshape(240, 320)
    for image, encoding in ((depth, '32FC1'), ((depth * 1000).astype(np.uint16), 'mono16')):
        frame = Frame('/depth', 0, 0, 0, 'cam', image, encoding, encoding, is_depth=True)
        assert run(frame) == ()


def test_red_is_found_on_both_sides_of_the_hue_wrap(scene: type[Scene]) -> None:
    low_hue, high_hue = (0, 40, 230), (60, 0, 230)  # OpenCV hue about 5 and about 172
    hsv = cv2.cvtColor(np.array([[low_hue, high_hue]], dtype=np.uint8), cv2.COLOR_BGR2HSV)
    assert hsv[0, 0, 0] <= 10
    assert hsv[0, 1, 0] >= 170
    s = scene(seed=5).rect(low_hue, 20, 20, 80, 60).rect(high_hue, 180, 120, 260, 200)
    found = run(s.frame())
    assert sorted(boxes(found)) == [('red', 20, 20, 80, 60), ('red', 180, 120, 260, 200)]


def test_min_area_drops_small_blobs(scene: type[Scene]) -> None:
    s = scene(seed=6).rect('blue', 20, 20, 29, 29).rect('blue', 100, 100, 140, 140)
    assert boxes(run(s.frame())) == [('blue', 100, 100, 140, 140)]  # 8x8 contour area 64 < 100
    small = run(s.frame(), min_area='10')
    assert sorted(boxes(small)) == [('blue', 20, 20, 29, 29), ('blue', 100, 100, 140, 140)]


def test_morphology_removes_specks_and_fills_pinholes(scene: type[Scene]) -> None:
    s = scene(seed=7).rect('yellow', 50, 50, 120, 110)
    s.image[80, 85] = (120, 120, 120)  # a pinhole inside the blob
    s.rect('yellow', 200, 200, 202, 202)  # a 2x2 speck
    found = run(s.frame(), min_area='0')
    assert boxes(found) == [('yellow', 50, 50, 120, 110)]
    unfiltered = run(s.frame(), min_area='0', kernel='1')
    assert len(unfiltered) == 2


def test_scores_grow_with_fill(scene: type[Scene]) -> None:
    s = scene(seed=8).rect('green', 20, 20, 80, 80).disc('green', 160, 50, 30)
    s.poly('green', [(220, 20), (300, 20), (220, 100)])  # a right triangle: half its box
    found = run(s.frame())
    square, disc, triangle = (d.score for d in sorted(found, key=lambda d: d.x0))
    assert square > disc > triangle
    assert square == pytest.approx(1.0, abs=0.01)
    assert disc == pytest.approx(np.pi / 4, abs=0.03)
    assert 0.45 < triangle < 0.6


def test_scores_grow_with_saturation_above_the_threshold(scene: type[Scene]) -> None:
    pale, deep = (110, 110, 230), (0, 0, 230)  # red with S about 133 and 255
    s = scene(seed=9).rect(pale, 20, 20, 80, 80).rect(deep, 150, 20, 210, 80)
    found = run(s.frame())
    assert [d.x0 for d in found] == [150.0, 20.0]  # sorted by score within the class
    assert found[0].score > found[1].score > 0.5


def test_detections_are_sorted_by_class_score_then_position(scene: type[Scene]) -> None:
    s = scene(seed=10)
    for x in (250, 20, 140):
        s.rect('blue', x, 150, x + 40, 190).rect('red', x, 20, x + 40, 60)
    found = run(s.frame())
    keys = [(d.class_index, -d.score, d.y0, d.x0) for d in found]
    assert keys == sorted(keys)
    assert [d.label for d in found] == ['red'] * 3 + ['blue'] * 3
    assert [d.x0 for d in found[:3]] == [20.0, 140.0, 250.0]


def test_two_runs_give_identical_results(scene: type[Scene]) -> None:
    s = scene(seed=11, width=640, height=480)
    rng = np.random.default_rng(11)
    for i in range(20):
        colour = DEFAULT_CLASSES[i % 4].name
        x, y = int(rng.integers(0, 580)), int(rng.integers(0, 420))
        s.disc(colour, x + 30, y + 30, int(rng.integers(8, 30)))
    frame = s.frame()
    first = HsvBackend()
    first.open()
    again = [first.detect(frame).detections for _ in range(3)]
    second = HsvBackend()
    second.open()
    assert again[0] == again[1] == again[2] == second.detect(frame).detections
    assert len(again[0]) >= 8


def test_stage_times_are_measured_in_nanoseconds(scene: type[Scene]) -> None:
    backend = HsvBackend()
    backend.open()
    result = backend.detect(scene().rect('red', 10, 10, 50, 50).frame())
    stages = result.stages
    for value in (stages.preprocess_ns, stages.infer_ns, stages.postprocess_ns):
        assert isinstance(value, int)
        assert 0 < value < 10**9
    assert stages.h2d_ns is None
    assert stages.d2h_ns is None


def test_frame_size_changes_reallocate_work_buffers(scene: type[Scene]) -> None:
    backend = HsvBackend()
    backend.open()
    small = scene(width=160, height=120).rect('red', 10, 10, 50, 50).frame()
    large = scene(width=640, height=480).rect('red', 500, 400, 560, 450).frame()
    assert boxes(backend.detect(small).detections) == [('red', 10, 10, 50, 50)]
    assert boxes(backend.detect(large).detections) == [('red', 500, 400, 560, 450)]
    assert boxes(backend.detect(small).detections) == [('red', 10, 10, 50, 50)]


def test_open_sets_opencv_threads_and_close_restores_them() -> None:
    before = cv2.getNumThreads()
    backend = HsvBackend(BackendOptions(threads=1))
    backend.open()
    assert cv2.getNumThreads() == 1
    backend.close()
    assert cv2.getNumThreads() == before


def test_info_lists_classes_and_thresholds_as_json() -> None:
    backend = HsvBackend(BackendOptions(extra={'kernel': '3'}))
    backend.open()
    info = json.loads(json.dumps(backend.info()))
    assert [c['name'] for c in info['classes']] == ['red', 'green', 'blue', 'yellow']
    assert info['classes'][0]['ranges'] == [
        [[0, 100, 70], [10, 255, 255]],
        [[170, 100, 70], [180, 255, 255]],
    ]
    assert info['detector'] == {
        'min_area': 100.0,
        'kernel': 3,
        'open_iterations': 1,
        'close_iterations': 1,
    }
    assert info['opencv'] == cv2.__version__


def test_a_wrongly_shaped_frame_is_a_backend_error() -> None:
    from replaybench.errors import BackendError

    frame = Frame('/t', 3, 0, 0, 'cam', np.zeros((10, 10), np.uint8), 'bgr8', 'bgr8')
    with pytest.raises(BackendError, match=r'/t#3: expected HxWx3 uint8'):
        run(frame)
