"""Tag poses from corners: exact on synthetic projections through distorted cameras."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from replaybench.errors import DecodeError, UsageError
from replaybench.fiducials import (
    TagPose,
    camera_model,
    object_corners,
    parse_tag_sizes,
    rotation_error_deg,
    solve_tag_pose,
    undistort_pixels,
)
from replaybench.fiducials.pose import matrix_to_quaternion, quaternion_to_matrix
from replaybench.types import CameraInfo

K = (600.0, 0.0, 322.5, 0.0, 605.0, 241.25, 0.0, 0.0, 1.0)
PLUMB_BOB = (-0.28, 0.09, 0.0012, -0.0008, -0.012)
EQUIDISTANT = (0.08, -0.02, 0.004, -0.001)


def _info(model: str, d: tuple[float, ...], k: tuple[float, ...] = K) -> CameraInfo:
    return CameraInfo(0, 'cam_optical', 640, 480, model, d, k, (), ())


def _project(info: CameraInfo, pose_r: np.ndarray, t: np.ndarray, size: float) -> np.ndarray:
    rvec, _ = cv2.Rodrigues(pose_r)
    k = np.asarray(info.k).reshape(3, 3)
    obj = object_corners(size)
    if info.distortion_model == 'equidistant':
        pts, _ = cv2.fisheye.projectPoints(obj.reshape(-1, 1, 3), rvec, t, k, np.asarray(info.d))
    else:
        pts, _ = cv2.projectPoints(obj, rvec, t, k, np.asarray(info.d))
    return np.asarray(pts, dtype=np.float64).reshape(4, 2)


def _poses() -> list[tuple[np.ndarray, np.ndarray]]:
    # squarely facing (a half turn about x: the hardest case for OpenCV's IPPE), turned in the
    # image plane, then random tilts
    out = [
        (np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 2.0])),
        (np.diag([-1.0, 1.0, -1.0]), np.array([0.1, 0.05, 1.5])),
        (np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), np.array([0, 0, 1.0])),
    ]
    rng = np.random.default_rng(7)
    for _ in range(25):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = math.radians(rng.uniform(0, 50))
        # facing the camera: 180 deg about x (tag z towards the camera), then a tilt
        tilt, _ = cv2.Rodrigues(axis * angle)
        r = tilt @ np.diag([1.0, -1.0, -1.0])
        t = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(0.8, 2.5)])
        out.append((r, t))
    return out


@pytest.mark.parametrize(
    ('model', 'd'),
    [('plumb_bob', PLUMB_BOB), ('equidistant', EQUIDISTANT), ('plumb_bob', ()), ('', ())],
)
def test_a_pose_solved_from_projected_corners_is_the_pose_they_were_projected_from(
    model: str, d: tuple[float, ...]
) -> None:
    info = _info(model, d)
    camera = camera_model(info)
    for r, t in _poses():
        corners = _project(info, r, t, 0.16)
        pose = solve_tag_pose(corners, 0.16, camera)
        assert pose is not None
        truth = TagPose(tuple(t), matrix_to_quaternion(r))
        # exact data: only the solver's numerical error is left (measured: under 1e-4 deg
        # over 2,500 views; 1e-6 m at up to 2.5 m)
        assert np.allclose(pose.position, t, atol=1e-6)
        assert rotation_error_deg(pose, truth) < 1e-3


def test_corners_given_in_another_order_give_a_wrong_pose_without_an_error() -> None:
    info = _info('plumb_bob', PLUMB_BOB)
    camera = camera_model(info)
    r, t = _poses()[0]
    corners = _project(info, r, t, 0.16)
    truth = TagPose(tuple(t), matrix_to_quaternion(r))
    rolled = solve_tag_pose(np.roll(corners, 1, axis=0), 0.16, camera)
    assert rolled is not None
    assert abs(rotation_error_deg(rolled, truth) - 90.0) < 1e-3


def test_solving_with_the_distortion_ignored_gives_a_measurably_wrong_pose() -> None:
    info = _info('plumb_bob', PLUMB_BOB)
    r, t = np.diag([1.0, -1.0, -1.0]), np.array([0.35, 0.25, 1.0])
    corners = _project(info, r, t, 0.16)
    right = solve_tag_pose(corners, 0.16, camera_model(info))
    wrong = solve_tag_pose(corners, 0.16, camera_model(_info('plumb_bob', ())))
    assert right is not None
    assert wrong is not None
    assert np.allclose(right.position, t, atol=1e-6)
    assert np.linalg.norm(np.subtract(wrong.position, t)) > 0.02


def test_undistorted_pixels_reproject_to_the_distorted_ones() -> None:
    for model, d in (('plumb_bob', PLUMB_BOB), ('equidistant', EQUIDISTANT)):
        info = _info(model, d)
        camera = camera_model(info)
        grid = np.array([[x, y] for x in (5.0, 160.0, 320.0, 635.0) for y in (5.0, 240.0, 475.0)])
        ideal = undistort_pixels(camera, grid)
        k = camera.matrix
        normalised = np.c_[(ideal - k[:2, 2]) / np.diag(k)[:2], np.ones(len(grid))]
        if model == 'equidistant':
            back, _ = cv2.fisheye.projectPoints(
                normalised.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, np.asarray(d)
            )
        else:
            back, _ = cv2.projectPoints(normalised, np.zeros(3), np.zeros(3), k, np.asarray(d))
        assert np.abs(back.reshape(-1, 2) - grid).max() < 1e-6


def test_quaternions_and_matrices_convert_both_ways() -> None:
    for r, _ in _poses():
        q = matrix_to_quaternion(r)
        assert q[3] >= 0
        assert np.allclose(quaternion_to_matrix(q), r, atol=1e-12)
    identity = TagPose((0, 0, 1), (0.0, 0.0, 0.0, 1.0))
    turned = TagPose((0, 0, 1), (0.0, 0.0, math.sin(0.5e-4), math.cos(0.5e-4)))
    assert rotation_error_deg(identity, turned) == pytest.approx(math.degrees(1e-4), rel=1e-9)


def test_tag_sizes_parse_per_id_with_a_default() -> None:
    sizes = parse_tag_sizes('0.16', '14=0.2, 3=0.1')
    assert (sizes.size(14), sizes.size(3), sizes.size(0)) == (0.2, 0.1, 0.16)
    assert parse_tag_sizes().size(5) == 0.22


@pytest.mark.parametrize(
    ('default', 'per_id', 'message'),
    [
        ('-1', None, '--tag-size'),
        ('big', None, '--tag-size'),
        (None, '14:0.2', 'ID=METRES'),
        (None, '14=0.2,14=0.3', 'given twice'),
        (None, '3=0', '--tag-sizes'),
    ],
)
def test_bad_tag_sizes_are_refused_naming_the_option(
    default: str | None, per_id: str | None, message: str
) -> None:
    with pytest.raises(UsageError, match=message):
        parse_tag_sizes(default, per_id)


@pytest.mark.parametrize(
    ('info', 'message'),
    [
        (_info('plumb_bob', PLUMB_BOB, k=(0.0,) * 9), 'not a calibrated camera matrix'),
        (_info('kannala_brandt8', (0.1,) * 8), 'not supported'),
        (_info('equidistant', (0.1,)), 'needs 4 coefficients'),
        (_info('plumb_bob', (0.1, 0.2, 0.3)), '3 coefficients'),
    ],
)
def test_a_camera_info_that_cannot_give_a_pose_is_refused_in_one_line(
    info: CameraInfo, message: str
) -> None:
    with pytest.raises(DecodeError, match=message):
        camera_model(info)
