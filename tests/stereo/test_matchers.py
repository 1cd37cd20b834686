"""SGBM and BM with stereo_image_proc's parameters; float disparity, NaN where no match."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from stereodata import motorcycle

from replaybench.errors import UsageError
from replaybench.fixtures.stereo import render_stereo
from replaybench.stereo import Matcher, StereoParams, score_disparity, to_mono8


def test_the_defaults_are_those_of_stereo_image_procs_disparity_node():
    p = StereoParams()
    assert (p.prefilter_size, p.prefilter_cap, p.correlation_window_size) == (9, 31, 15)
    assert (p.min_disparity, p.disparity_range, p.texture_threshold) == (0, 64, 10)
    assert (p.speckle_size, p.speckle_range, p.disp12_max_diff) == (100, 4, 0)
    assert (p.uniqueness_ratio, p.p1, p.p2, p.full_dp) == (15, 200, 400, False)
    assert p.max_disparity == 63.0


def test_parameters_are_taken_by_stereo_image_procs_and_opencvs_names():
    m = Matcher.from_mapping(
        'sgbm', {'disparities': 32, 'block_size': 5, 'P1': 8, 'P2': 32, 'uniqueness': 5}
    )
    assert (m.params.disparity_range, m.params.correlation_window_size) == (32, 5)
    assert (m.params.p1, m.params.p2, m.params.uniqueness_ratio) == (8, 32, 5)
    with pytest.raises(UsageError, match="unknown bm parameter 'blocksize'"):
        Matcher.from_mapping('bm', {'blocksize': 5})
    with pytest.raises(UsageError, match='whole number'):
        Matcher.from_mapping('sgbm', {'P1': 1.5})


@pytest.mark.parametrize(
    ('kind', 'values', 'message'),
    [
        ('sgbm', {'disparities': 40}, 'not a positive multiple of 16'),
        ('bm', {'block_size': 4}, 'is not odd in 5..255'),
        ('bm', {'prefilter_size': 3}, 'prefilter_size 3'),
        ('sgbm', {'prefilter_cap': 0}, 'prefilter_cap 0'),
        ('sgbm', {'speckle_range': -1}, 'speckle_range -1 is negative'),
    ],
)
def test_parameters_opencv_would_refuse_are_one_line(kind, values, message):
    with pytest.raises(UsageError, match=message):
        Matcher.from_mapping(kind, values)


def test_the_valid_window_is_the_one_disparity_node_computes():
    assert StereoParams().valid_window(320, 240) == (70, 7, 225, 242)
    assert StereoParams(min_disparity=-8).valid_window(320, 240) == (62, 7, 225, 249)


@pytest.mark.parametrize('kind', ['sgbm', 'bm'])
def test_the_disparity_is_opencvs_over_16_with_nan_where_opencv_marks_no_match(kind):
    view = render_stereo((320, 240), 0)
    m = Matcher(kind, StereoParams(min_disparity=2))
    fixed = m.compute_fixed(view.left, view.right)
    disparity = m.compute(view.left, view.right)
    invalid = fixed < 2 * 16
    assert invalid.any()
    assert np.isnan(disparity[invalid]).all()
    assert np.array_equal(disparity[~invalid], fixed[~invalid] / np.float32(16))
    assert disparity.dtype == np.float32


def test_sgbm_on_the_rectified_fixture_finds_its_planes():
    view = render_stereo((320, 240), 1)
    figures = score_disparity(Matcher('sgbm').compute(view.left, view.right), view.disparity)
    f = figures.figures()
    assert f.epe is not None
    assert f.epe < 0.5
    assert f.density is not None
    assert f.density > 0.7  # the left 71 px (range + border) cannot be matched
    assert f.bad2 is not None
    assert f.bad2 < 1.0 - f.density + 0.03  # almost every matched pixel within 2 px


def test_colour_images_are_made_grey_as_cv_bridge_makes_them():
    rgb = np.zeros((2, 2, 3), np.uint8)
    rgb[..., 0] = 255
    assert to_mono8(rgb, 'rgb8')[0, 0] == 76
    assert to_mono8(rgb[..., ::-1].copy(), 'bgr8')[0, 0] == 76
    assert to_mono8(np.full((2, 2), 0x1234, np.uint16), 'mono16')[0, 0] == 0x12
    with pytest.raises(UsageError, match='not 32FC1'):
        to_mono8(np.zeros((2, 2), np.float32), '32FC1')


def test_sgbm_on_middlebury_motorcycle_is_opencvs_stereosgbm_at_the_same_parameters():
    left, right, truth = motorcycle()
    grey_left, grey_right = to_mono8(left, 'bgr8'), to_mono8(right, 'bgr8')
    ours = Matcher('sgbm').compute(grey_left, grey_right)
    direct = cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=64,
        blockSize=15,
        P1=200,
        P2=400,
        disp12MaxDiff=0,
        preFilterCap=31,
        uniquenessRatio=15,
        speckleWindowSize=100,
        speckleRange=4,
        mode=cv2.STEREO_SGBM_MODE_SGBM,
    ).compute(grey_left, grey_right)
    theirs = np.where(direct < 0, np.nan, direct / 16.0).astype(np.float32)
    assert np.array_equal(ours, theirs, equal_nan=True)
    ours_f = score_disparity(ours, truth).figures()
    theirs_f = score_disparity(theirs, truth).figures()
    assert ours_f == theirs_f
    print(f'motorcycle sgbm: EPE {ours_f.epe:.3f} px, bad-2 {ours_f.bad2:.4f}')
    assert ours_f.epe is not None
    assert ours_f.epe < 2.0
    assert ours_f.bad2 is not None
    assert ours_f.bad2 < 0.3
