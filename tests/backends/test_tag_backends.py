"""The apriltag and aruco backends on rendered tags with exact truth.

Tolerances, from what the detectors reach on these frames with their default options
(measured over 30 frames of each camera at 640x480, docs/fiducials.md) with room for the frames
chosen here: AprilTag 3 corners are within 0.28 px RMSE of the truth (0.14 mean), its poses
within 4.3 mm (under 1 % of the range) and 2.4 degrees; ArUco's with AprilTag refinement
within 0.33 px, 5.6 mm and 1.4 degrees, with its default sub-pixel refinement 0.29 px RMSE and
18.8 mm at most (benchmarks/tag_refine.py). A tag's pose has a two-fold ambiguity that noisier
corners reach (with decimation 2 ArUco's corners were within 1.03 px and a few poses off by 26
degrees), so rotation is also checked by the median.
"""

from __future__ import annotations

import statistics
from typing import TYPE_CHECKING

import numpy as np
import pytest

from replaybench.backends import backend_table, get_backend
from replaybench.backends.base import BackendOptions
from replaybench.errors import BackendError
from replaybench.fiducials import TagResult, rotation_error_deg
from replaybench.fixtures.tags import render_tag_frame, tag_camera_info
from replaybench.types import Frame

if TYPE_CHECKING:
    from pathlib import Path

FIXTURE_SIZES = {'tag_size': '0.16', 'tag_sizes': '14=0.2,3=0.1'}
FRAMES = 30
#: unoccluded frames, sharp, blurred and noisy ones among them
INDICES = (0, 2, 4, 9, 13, 23)


def _frame(index: int, distortion: str = 'plumb_bob', *, with_info: bool = True):
    info = tag_camera_info((640, 480), distortion, 0)  # type: ignore[arg-type]
    rendered = render_tag_frame(info, index, FRAMES)
    frame = Frame(
        '/camera/image_raw',
        index,
        0,
        0,
        'camera_optical_frame',
        rendered.image,
        'mono8',
        'mono8',
        camera_info=info if with_info else None,
    )
    return frame, rendered


def _open(name: str, **extra: str):
    backend = get_backend(name)(BackendOptions(extra={**FIXTURE_SIZES, **extra}))  # type: ignore[call-arg]
    backend.open()
    return backend


def _errors(
    name: str, distortion: str, **extra: str
) -> tuple[list[float], list[float], list[float]]:
    backend = _open(name, **extra)
    corner, translation, rotation = [], [], []
    for index in INDICES:
        frame, rendered = _frame(index, distortion)
        result = backend.detect(frame)
        assert isinstance(result, TagResult)
        assert [t.tag_id for t in result.tags] == [t.tag_id for t in rendered.truth]
        for found, truth in zip(result.tags, rendered.truth, strict=True):
            assert found.pose is not None
            assert truth.pose is not None
            diff = np.subtract(found.corners, truth.corners)
            corner.append(float(np.sqrt(np.mean(np.sum(diff**2, axis=1)))))
            distance = float(np.linalg.norm(truth.pose.position))
            gap = np.subtract(found.pose.position, truth.pose.position)
            translation.append(float(np.linalg.norm(gap)) / distance)
            rotation.append(rotation_error_deg(found.pose, truth.pose))
    backend.close()
    return corner, translation, rotation


@pytest.mark.parametrize('distortion', ['plumb_bob', 'equidistant'])
def test_apriltag_finds_every_tag_with_its_corners_and_pose(distortion: str) -> None:
    corner, translation, rotation = _errors('apriltag', distortion)
    assert max(corner) < 0.5
    assert max(translation) < 0.015
    assert max(rotation) < 6.0
    assert statistics.median(rotation) < 1.0


@pytest.mark.parametrize('refine', ['subpix', 'apriltag'])
@pytest.mark.parametrize('distortion', ['plumb_bob', 'equidistant'])
def test_aruco_finds_every_tag_with_its_corners_and_pose(distortion: str, refine: str) -> None:
    corner, translation, rotation = _errors('aruco', distortion, refine=refine)
    assert max(corner) < 0.6
    assert max(translation) < 0.02
    assert max(rotation) < 6.0
    assert statistics.median(rotation) < 1.0


def test_arucos_apriltag_refinement_gives_closer_corners_than_its_default_subpix() -> None:
    # measured over 50 fixture frames: 0.16 against 0.29 px RMSE (docs/fiducials.md)
    subpix, _, _ = _errors('aruco', 'plumb_bob')
    apriltag, _, _ = _errors('aruco', 'plumb_bob', refine='apriltag')
    assert statistics.fmean(apriltag) < 0.8 * statistics.fmean(subpix)


@pytest.mark.parametrize('name', ['apriltag', 'aruco'])
def test_each_tag_also_comes_as_a_box_labelled_family_and_id(name: str) -> None:
    frame, rendered = _frame(0)
    result = _open(name).detect(frame)
    assert [d.label for d in result.detections] == [f'tag36h11:{t.tag_id}' for t in rendered.truth]
    for box, tag in zip(result.detections, result.tags, strict=True):
        # boxes in Detection's convention (the origin at the top-left pixel's corner)
        xs, ys = [c[0] + 0.5 for c in tag.corners], [c[1] + 0.5 for c in tag.corners]
        assert (box.x0, box.y0, box.x1, box.y1) == (min(xs), min(ys), max(xs), max(ys))
        assert box.class_index == tag.tag_id
    assert result.camera_frame == 'camera_optical_frame'
    assert result.note == ''
    assert result.stages.preprocess_ns is not None
    assert result.stages.infer_ns is not None
    assert result.stages.postprocess_ns is not None


@pytest.mark.parametrize('name', ['apriltag', 'aruco'])
def test_a_frame_without_camera_info_gets_corners_and_ids_but_no_pose(name: str) -> None:
    frame, rendered = _frame(0, with_info=False)
    backend = _open(name)
    result = backend.detect(frame)
    assert [t.tag_id for t in result.tags] == [t.tag_id for t in rendered.truth]
    assert all(t.pose is None for t in result.tags)
    assert 'no CameraInfo' in result.note
    assert backend.info()['frames_without_pose'] == 1


def test_the_tag_size_of_each_id_scales_its_distance() -> None:
    frame, _ = _frame(0)
    sized = {t.tag_id: t for t in _open('apriltag').detect(frame).tags}
    backend = get_backend('apriltag')(BackendOptions(extra={'tag_size': '0.16'}))  # type: ignore[call-arg]
    backend.open()
    result = backend.detect(frame)
    assert isinstance(result, TagResult)
    uniform = {t.tag_id: t for t in result.tags}
    for tag_id, size in ((0, 0.16), (3, 0.10), (14, 0.20)):
        a, b = sized[tag_id].pose, uniform[tag_id].pose
        assert a is not None
        assert b is not None
        assert sized[tag_id].size_m == size
        assert np.allclose(np.multiply(b.position, size / 0.16), a.position, rtol=1e-6)


@pytest.mark.parametrize('name', ['apriltag', 'aruco'])
def test_max_tags_keeps_that_many(name: str) -> None:
    frame, _ = _frame(0)
    assert len(_open(name, max_tags='2').detect(frame).tags) == 2


@pytest.mark.parametrize(
    ('name', 'extra', 'message'),
    [
        ('apriltag', {'family': 'tag99h1'}, 'unknown tag family'),
        ('aruco', {'family': 'tagCircle21h7'}, 'unknown tag family'),
        ('aruco', {'tag_sizes': '14=big'}, 'tag size'),
        ('apriltag', {'decimation': '0.5'}, 'decimation'),
        ('aruco', {'decimation': '2'}, "acts with refine 'apriltag' only"),
        ('aruco', {'decimation': '2', 'refine': 'none'}, "refine is 'none'"),
        ('aruco', {'max_tags': '0'}, 'max_tags'),
        ('aruco', {'colour': 'red'}, "unknown option 'colour'"),
    ],
)
def test_bad_tag_options_are_refused_naming_the_option(
    name: str, extra: dict[str, str], message: str
) -> None:
    with pytest.raises(BackendError, match=message):
        get_backend(name)(BackendOptions(extra=extra))  # type: ignore[call-arg]


def test_aruco_takes_a_decimation_where_its_refinement_uses_it() -> None:
    backend = get_backend('aruco')(BackendOptions(extra={'decimation': '2', 'refine': 'apriltag'}))  # type: ignore[call-arg]
    assert backend.info()['decimation'] == 2.0


def test_an_aruco_dictionary_family_detects_its_own_markers() -> None:
    import cv2

    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_1000)
    image = np.full((300, 300), 255, dtype=np.uint8)
    image[70:230, 70:230] = cv2.aruco.generateImageMarker(dictionary, 417, 160)
    frame = Frame('/c', 0, 0, 0, 'c', image, 'mono8', 'mono8')
    result = _open('aruco', family='aruco_5x5_1000').detect(frame)
    assert [t.tag_id for t in result.tags] == [417]
    assert np.allclose(
        result.tags[0].corners,
        [(69.5, 69.5), (229.5, 69.5), (229.5, 229.5), (69.5, 229.5)],
        atol=0.6,
    )


def test_both_tag_backends_are_listed_and_available() -> None:
    rows = {row.name: row for row in backend_table()}
    for name in ('apriltag', 'aruco'):
        assert rows[name].origin == 'built-in'
        assert rows[name].availability.ok, rows[name].availability.reason


def test_replaying_apriltag_twice_in_one_process_leaves_the_heap_intact(tmp_path: Path) -> None:
    """pupil-apriltags' own Detector.__del__ frees the tag families before the detector, whose
    destruction then writes into them; with glibc's heap checks on, the second run of a process
    aborted. The backend frees them in the right order."""
    import os
    import subprocess
    import sys

    script = (
        'import sys, replaybench as rb\n'
        'from replaybench.fixtures.tags import write_tag_mcap\n'
        'bag = write_tag_mcap(sys.argv[1] + "/t.mcap", 2)\n'
        'for i in range(3):\n'
        '    rb.run(bag, backends="apriltag", out=sys.argv[1] + f"/r{i}", max_frames=1)\n'
        'print("done")\n'
    )
    env = {**os.environ, 'MALLOC_CHECK_': '3'}
    done = subprocess.run(
        [sys.executable, '-c', script, str(tmp_path)],
        capture_output=True, text=True, env=env, check=False, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == 'done'
