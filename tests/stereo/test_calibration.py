"""A stereo pair's geometry and rectification from its two CameraInfo."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pytest
from stereodata import euroc_camera_infos, euroc_pair

from replaybench.errors import StereoError
from replaybench.fixtures.stereo import (
    raw_camera_infos,
    rectified_camera_infos,
    render_raw,
    render_stereo,
)
from replaybench.stereo import Matcher, score_disparity, stereo_pair
from replaybench.stereo.calibration import _maps

if TYPE_CHECKING:
    from replaybench.types import CameraInfo

SIZE = (160, 120)


def test_a_rectified_pair_is_used_as_it_is_and_gives_focal_length_and_baseline_from_the_right_p():
    pair = stereo_pair(*rectified_camera_infos(SIZE, 0))
    assert pair.rectified
    assert pair.focal_px == 128.0
    assert pair.baseline == pytest.approx(0.12)
    assert pair.cx_offset == 0.0
    left, right = np.zeros((120, 160), np.uint8), np.ones((120, 160), np.uint8)
    out = pair.rectifier().rectify(left, right)
    assert out[0] is left
    assert out[1] is right


def test_a_distorted_or_rotated_pair_is_rectified_unless_its_topics_say_it_is_rectified():
    left, right = raw_camera_infos(SIZE, 0)
    assert not stereo_pair(left, right).rectified
    assert stereo_pair(left, right, rectified=True).rectified
    assert not stereo_pair(*rectified_camera_infos(SIZE, 0), rectified=False).rectified


def test_depth_is_f_times_b_over_the_disparity_less_the_principal_point_offset():
    left, right = rectified_camera_infos(SIZE, 0)
    p = list(right.p)
    p[2] += 4.0  # cx_right = cx_left + 4: Middlebury's doffs
    pair = stereo_pair(left, replace(right, p=tuple(p)))
    assert pair.cx_offset == -4.0
    depth = pair.depth(np.array([[12.0, np.nan, -4.0]]))
    assert depth[0, 0] == pytest.approx(128.0 * 0.12 / 16.0)
    assert np.isnan(depth[0, 1])
    assert np.isnan(depth[0, 2])
    assert pair.disparity_of_depth(depth)[0, 0] == pytest.approx(12.0)


@pytest.mark.parametrize(
    ('change', 'message'),
    [
        ('missing', 'the right camera of the stereo pair has no CameraInfo'),
        ('size', 'different sizes: 160x120'),
        ('no_baseline', 'P has no baseline (Tx is 0)'),
        ('swapped', 'left and right swapped?'),
        ('no_p', 'P is not a projection matrix'),
    ],
)
def test_a_pair_that_cannot_be_used_is_one_line_with_exit_status_2(change, message):
    left, right_info = rectified_camera_infos(SIZE, 0)
    right: CameraInfo | None = right_info
    if change == 'missing':
        right = None
    elif change == 'size':
        right = replace(right_info, width=320)
    elif change == 'no_baseline':
        right = replace(right_info, p=left.p)
    elif change == 'swapped':
        p = list(right_info.p)
        p[3] = -p[3]
        right = replace(right_info, p=tuple(p))
    else:
        right = replace(right_info, p=(0.0,) * 12)
    with pytest.raises(StereoError) as err:
        stereo_pair(left, right)
    assert message in str(err.value)
    assert '\n' not in str(err.value)
    assert err.value.exit_code == 2


def _camera(model: str) -> CameraInfo:
    """The raw fixture's left camera, with a fisheye model for ``equidistant``."""
    info = raw_camera_infos(SIZE, 0)[0]
    if model == 'equidistant':
        info = replace(info, distortion_model='equidistant', d=(0.05, -0.01, 0.002, 0.0))
    return info


def _opencv_maps(info: CameraInfo, kind: int) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's own rectification maps of a camera, of type ``kind``."""
    k = np.array(info.k).reshape(3, 3)
    r = np.array(info.r).reshape(3, 3)
    p = np.array(info.p).reshape(3, 4)[:, :3]
    if info.distortion_model == 'equidistant':
        return cv2.fisheye.initUndistortRectifyMap(
            k, np.array(info.d).reshape(1, 4), r, p, SIZE, kind
        )
    return cv2.initUndistortRectifyMap(k, np.array(info.d), r, p, SIZE, kind)


@pytest.mark.parametrize('model', ['plumb_bob', 'equidistant'])
def test_the_maps_are_opencvs_initundistortrectifymap_of_k_d_r_and_p(model):
    info = _camera(model)
    want = _opencv_maps(info, cv2.CV_16SC2)
    got = _maps(info)
    assert np.array_equal(got[0], want[0])
    assert np.array_equal(got[1], want[1])


def test_rectifying_the_raw_fixture_gives_the_rectified_fixture_and_matching_needs_it():
    size = (320, 240)
    raw, rect = render_raw(size, 2), render_stereo(size, 2)
    pair = stereo_pair(*raw_camera_infos(size, 0))
    left, right = pair.rectifier().rectify(raw.left, raw.right)
    inner = (slice(12, -12), slice(12, -12))
    assert np.median(np.abs(left.astype(int) - rect.left)[inner]) <= 2
    assert np.median(np.abs(right.astype(int) - rect.right)[inner]) <= 2
    sgbm = Matcher('sgbm')
    rectified = score_disparity(sgbm.compute(left, right), rect.disparity).figures()
    unrectified = score_disparity(sgbm.compute(raw.left, raw.right), rect.disparity).figures()
    assert rectified.epe is not None
    assert rectified.epe < 0.6
    assert unrectified.epe is not None
    assert unrectified.epe > 3 * rectified.epe


def test_an_image_not_of_its_camera_infos_size_is_refused():
    pair = stereo_pair(*raw_camera_infos(SIZE, 0))
    with pytest.raises(StereoError, match='the left image is 80x60, its CameraInfo says 160x120'):
        pair.rectifier().rectify(np.zeros((60, 80), np.uint8), np.zeros((120, 160), np.uint8))


def test_euroc_pairs_rectified_from_their_real_calibration_have_matching_rows():
    left_info, right_info = euroc_camera_infos()
    pair = stereo_pair(left_info, right_info)
    assert not pair.rectified
    assert pair.baseline == pytest.approx(0.110, abs=0.002)  # the VI-Sensor's 11 cm
    rectifier = pair.rectifier()
    orb = cv2.ORB.create(1500)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)

    def dy(left, right):
        kl, dl = orb.detectAndCompute(left, None)
        kr, dr = orb.detectAndCompute(right, None)
        pairs = [(kl[m.queryIdx].pt, kr[m.trainIdx].pt) for m in matcher.match(dl, dr)]
        # a match far off in x (beyond the disparities a 11 cm baseline can give) is wrong
        good = [(a, b) for a, b in pairs if -2.0 <= a[0] - b[0] <= 120.0]
        return np.array([abs(a[1] - b[1]) for a, b in good])

    raw_left, raw_right = euroc_pair(40)
    rect_dy = dy(*rectifier.rectify(raw_left, raw_right))
    raw_dy = dy(raw_left, raw_right)
    assert rect_dy.size > 100
    assert np.median(rect_dy) < 1.0
    assert np.median(rect_dy) < np.median(raw_dy)


@pytest.mark.parametrize('model', ['plumb_bob', 'equidistant'])
def test_float_maps_are_opencvs_32_bit_maps_and_rectify_as_bilinear_sampling_at_them(model):
    info = _camera(model)
    want = _opencv_maps(info, cv2.CV_32FC1)
    got = _maps(info, 'float')
    assert got[0].dtype == np.float32
    assert np.array_equal(got[0], want[0])
    assert np.array_equal(got[1], want[1])
    # each output pixel is the bilinear sample of the image at its map position (float64 here)
    image = render_raw(SIZE, 1).left
    out = cv2.remap(image, *got, cv2.INTER_LINEAR)
    x, y = got[0].astype(np.float64), got[1].astype(np.float64)
    inside = (x >= 0) & (y >= 0) & (x < SIZE[0] - 1) & (y < SIZE[1] - 1)
    x0, y0 = np.floor(x[inside]).astype(int), np.floor(y[inside]).astype(int)
    fx, fy = x[inside] - x0, y[inside] - y0
    v = image.astype(np.float64)
    top = v[y0, x0] * (1 - fx) + v[y0, x0 + 1] * fx
    bottom = v[y0 + 1, x0] * (1 - fx) + v[y0 + 1, x0 + 1] * fx
    reference = top * (1 - fy) + bottom * fy
    assert inside.mean() > 0.8
    assert np.abs(out[inside] - reference).max() <= 1.0


def test_float_and_fixed_maps_rectify_a_pair_alike_but_not_byte_for_byte():
    raw = render_raw(SIZE, 1)
    pair = stereo_pair(*raw_camera_infos(SIZE, 0))
    fixed = pair.rectifier().rectify(raw.left, raw.right)
    floating = pair.rectifier('float').rectify(raw.left, raw.right)
    for a, b in zip(fixed, floating, strict=True):
        diff = np.abs(a.astype(int) - b)
        assert diff.any()  # the fixed-point maps round positions to 1/32 px
        assert np.median(diff) == 0
        assert diff.mean() < 0.5


def test_a_rectify_maps_value_other_than_fixed_or_float_is_one_line_and_exit_2():
    from replaybench.stereo import rectify_maps

    assert rectify_maps(None, 'sgbm') == 'fixed'
    assert rectify_maps(' Float ', 'sgbm') == 'float'
    with pytest.raises(StereoError) as err:
        rectify_maps('half', 'sgbm')
    assert str(err.value) == "sgbm: rectify_maps must be one of fixed, float, not 'half'"
    assert err.value.exit_code == 2
    pair = stereo_pair(*raw_camera_infos(SIZE, 0))
    with pytest.raises(StereoError, match='rectify_maps must be one of fixed, float'):
        pair.rectifier('half')
