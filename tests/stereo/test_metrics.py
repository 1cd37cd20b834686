"""The disparity metrics reproduce the Middlebury and KITTI devkits' definitions.

The references are written here as the devkits state them, pixel by pixel: Middlebury's
``evaldisp.cpp`` (unknown truth is inf; an estimate of inf is invalid; ``bad`` counts the
valid estimates whose error exceeds ``badthresh``, ``invalid`` the others; "totalbad" is
their sum over all evaluated pixels, "avgErr" the mean error of the valid ones) and KITTI
2015's ``disp_error.m`` (truth > 0 is known; an outlier has error > 3 px and > 5 % of the
truth; the estimate as ``disp_read`` gives it, -1 for no estimate).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from replaybench.errors import StereoError
from replaybench.fixtures.stereo import rectified_camera_infos
from replaybench.stereo import DisparityCounts, score_disparity, stereo_pair

INF = math.inf


def evaldisp(disp, gtdisp, badthresh):
    """Middlebury evaldisp, no mask, no clipping or rounding: (totalbad share, avgErr)."""
    n = bad = invalid = 0
    serr = 0.0
    for y in range(gtdisp.shape[0]):
        for x in range(gtdisp.shape[1]):
            gt = gtdisp[y, x]
            if gt == INF:
                continue
            d = disp[y, x]
            valid = d != INF
            n += 1
            if valid:
                err = abs(d - gt)
                serr += err
                bad += err > badthresh
            else:
                invalid += 1
    return (bad + invalid) / n, serr / (n - invalid)


def kitti_d1(d_gt, d_est):
    """KITTI 2015 disp_error with tau = [3 0.05]."""
    n_err = n_total = 0
    for gt, est in zip(d_gt.reshape(-1), d_est.reshape(-1), strict=True):
        if gt > 0:
            n_total += 1
            e = abs(gt - est)
            n_err += e > 3 and e / abs(gt) > 0.05
    return n_err / n_total


TRUTH = np.array(
    [
        [10.0, 10.0, 80.0, 80.0, INF],
        [20.0, 20.0, 20.0, 100.0, 5.0],
        [30.0, 30.0, 30.0, 30.0, 40.0],
    ]
)
ESTIMATE = np.array(
    [
        [10.5, 11.5, 83.5, 84.5, 7.0],  # errors 0.5, 1.5, 3.5 (4.4 %), 4.5 (5.6 %), no truth
        [22.5, INF, 23.25, 100.0, 8.5],  # 2.5, missing, 3.25 (16 %), 0, 3.5 (70 %)
        [30.0, 29.0, 31.0, 32.0, 44.0],  # 0, 1, 1, 2, 4 (10 %)
    ]
)


def _ours(estimate, truth):
    est = np.where(np.isinf(estimate), np.nan, estimate)
    gt = np.where(np.isinf(truth), 0.0, truth)
    return score_disparity(est, gt).figures()


def test_bad_n_and_epe_are_middleburys_totalbad_and_avgerr_on_a_hand_made_pair():
    ours = _ours(ESTIMATE, TRUTH)
    for threshold, share in ((1, ours.bad1), (2, ours.bad2), (3, ours.bad3)):
        want, avg = evaldisp(ESTIMATE, TRUTH, threshold)
        assert share == pytest.approx(want)
        assert ours.epe == pytest.approx(avg)
    # by hand: 14 pixels with truth, 13 estimates, errors summing to 27.25
    assert ours.epe == pytest.approx(27.25 / 13)
    assert ours.bad1 == pytest.approx(9 / 14)  # 8 errors > 1 and the missing one
    assert ours.bad3 == pytest.approx(6 / 14)
    assert ours.density == pytest.approx(13 / 14)


def test_d1_all_is_kittis_outlier_rule_with_a_missing_estimate_an_outlier():
    ours = _ours(ESTIMATE, TRUTH)
    kitti_truth = np.where(np.isinf(TRUTH), 0.0, TRUTH)
    kitti_estimate = np.where(np.isinf(ESTIMATE), -1.0, ESTIMATE)  # disp_read's no estimate
    assert ours.d1_all == pytest.approx(kitti_d1(kitti_truth, kitti_estimate))
    # 3.5 at 80 (4.4 %) is no outlier, 4.5 at 80 is; with 3.25, 3.5, 4 and the missing one: 5
    assert ours.d1_all == pytest.approx(5 / 14)


def test_the_references_agree_on_random_disparities_with_holes():
    rng = np.random.default_rng(3)
    # truth above 2 px: KITTI's -1 for no estimate is an outlier there, as ours always is
    truth = rng.uniform(2.5, 60, (30, 40))
    truth[rng.random(truth.shape) < 0.2] = INF
    # clipped at 0 as evaldisp clips: below min_disparity 0 is no estimate here, not in KITTI
    estimate = np.maximum(truth + rng.normal(0, 3, truth.shape), 0.0)
    estimate[rng.random(truth.shape) < 0.1] = INF
    ours = _ours(estimate, truth)
    assert ours.bad2 == pytest.approx(evaldisp(estimate, truth, 2)[0])
    assert ours.epe == pytest.approx(evaldisp(estimate, truth, 2)[1])
    kitti_estimate = np.where(np.isinf(estimate), -1.0, estimate)
    assert ours.d1_all == pytest.approx(
        kitti_d1(np.where(np.isinf(truth), 0, truth), kitti_estimate)
    )


def test_zero_nan_and_inf_truth_are_unknown_and_estimates_below_min_disparity_are_none():
    truth = np.array([[0.0, np.nan, np.inf, 10.0, 10.0, 10.0]])
    estimate = np.array([[5.0, 5.0, 5.0, 10.0, -1.0, 3.0]])
    counts = score_disparity(estimate, truth, min_disparity=4)
    assert counts.truth == 3
    assert counts.estimated == 1  # -1 and 3 are below min_disparity 4: no match
    assert counts.figures().density == pytest.approx(1 / 3)


def test_a_runs_figures_are_pooled_over_all_pixels_not_a_mean_of_frames():
    one = score_disparity(np.array([[1.0, 1.0, 1.0, 5.0]]), np.ones((1, 4)))
    two = score_disparity(np.array([[1.0]]), np.ones((1, 1)))
    run = (DisparityCounts() + one + two).figures()
    assert run.bad2 == pytest.approx(1 / 5)  # the mean of the frames' would be 1/8
    assert run.epe == pytest.approx(4 / 5)


def test_abs_rel_compares_the_depths_the_pairs_geometry_gives():
    pair = stereo_pair(*rectified_camera_infos((160, 120), 0))
    truth = np.array([[16.0, 32.0, 8.0]])
    estimate = np.array([[20.0, 32.0, np.nan]])
    f = score_disparity(estimate, truth, pair=pair).figures()
    # depth is f B / d: 16 -> 20 px is 0.96 -> 0.768 m, |0.768 - 0.96| / 0.96 = 0.2
    assert f.abs_rel == pytest.approx((0.2 + 0.0) / 2)
    assert score_disparity(estimate, truth).figures().abs_rel is None


def test_a_disparity_and_truth_of_different_sizes_are_refused():
    with pytest.raises(StereoError, match='not one size'):
        score_disparity(np.zeros((2, 3)), np.zeros((3, 2)))
