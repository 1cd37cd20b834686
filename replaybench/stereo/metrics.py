"""Disparity accuracy against ground truth: EPE, bad-1/2/3, D1-all, density, depth AbsRel.

A truth pixel is known where its value is finite and not 0 (0, NaN and inf mean unknown, as
KITTI's 0 and Middlebury's inf do). An estimate is a pixel whose value is finite and at least
the matcher's (or the message's) ``min_disparity``: stereo_msgs/DisparityImage marks a
missing match with a value below ``min_disparity``, ``Matcher.compute`` with NaN.

- ``epe``: the mean absolute error over the pixels with truth AND an estimate (Middlebury's
  ``evaldisp`` "avgErr", its estimates not clipped to the range);
- ``bad1``/``bad2``/``bad3``: the share of the truth pixels whose error exceeds 1/2/3 px, a
  pixel without an estimate counting as bad (``evaldisp``'s "totalbad" at badthresh 1/2/3);
- ``d1_all``: KITTI 2015's outliers, error > 3 px AND > 5 % of the truth, over the truth
  pixels (the devkit's ``disp_error`` with ``tau = [3 0.05]``); a pixel without an estimate
  is an outlier (the devkit interpolates the estimate's holes before it scores them instead);
- ``density``: the share of the truth pixels that have an estimate;
- ``abs_rel``: the mean of ``|Z_est - Z_truth| / Z_truth`` over the pixels where both
  depths can be formed (``StereoPair.depth``: a positive disparity after the principal-point
  offset); only with the pair's geometry.

``DisparityCounts`` holds the sums, not the shares: counts add over frames, so a run's
figure is the figure over all the pixels of all its frames (pooled, as KITTI's evaluation
adds the erroneous and the valid pixels of every image), not a mean of per-frame figures.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.errors import StereoError

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.stereo.calibration import StereoPair

__all__ = ['DisparityCounts', 'StereoFigures', 'known_truth', 'score_disparity']

#: KITTI's D1 outlier: error above both (pixels, share of the truth).
D1_PIXELS, D1_SHARE = 3.0, 0.05


@dataclass(frozen=True, slots=True)
class StereoFigures:
    """The shares (0..1) and errors of one frame or one run; None where undefined (no truth
    pixel, no estimate on truth, no depth)."""

    epe: float | None
    bad1: float | None
    bad2: float | None
    bad3: float | None
    d1_all: float | None
    density: float | None
    abs_rel: float | None


def _share(part: float, whole: int) -> float | None:
    return part / whole if whole else None


@dataclass(frozen=True, slots=True)
class DisparityCounts:
    """The sums the figures are shares of (see the module): add them over frames with ``+``."""

    truth: int = 0
    estimated: int = 0
    abs_error_sum: float = 0.0
    bad1: int = 0
    bad2: int = 0
    bad3: int = 0
    d1: int = 0
    depth_pixels: int = 0
    abs_rel_sum: float = 0.0

    def __add__(self, other: DisparityCounts) -> DisparityCounts:
        return DisparityCounts(
            self.truth + other.truth,
            self.estimated + other.estimated,
            self.abs_error_sum + other.abs_error_sum,
            self.bad1 + other.bad1,
            self.bad2 + other.bad2,
            self.bad3 + other.bad3,
            self.d1 + other.d1,
            self.depth_pixels + other.depth_pixels,
            self.abs_rel_sum + other.abs_rel_sum,
        )

    def figures(self) -> StereoFigures:
        return StereoFigures(
            epe=_share(self.abs_error_sum, self.estimated),
            bad1=_share(self.bad1, self.truth),
            bad2=_share(self.bad2, self.truth),
            bad3=_share(self.bad3, self.truth),
            d1_all=_share(self.d1, self.truth),
            density=_share(self.estimated, self.truth),
            abs_rel=_share(self.abs_rel_sum, self.depth_pixels),
        )


def known_truth(truth: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.bool_]:
    """The pixels with truth: finite and not 0."""
    t = np.asarray(truth)
    known: npt.NDArray[np.bool_] = np.isfinite(t) & (t != 0)
    return known


def score_disparity(
    estimate: npt.NDArray[np.floating[Any]],
    truth: npt.NDArray[np.floating[Any]],
    *,
    min_disparity: float = 0.0,
    pair: StereoPair | None = None,
) -> DisparityCounts:
    """The counts of one frame: ``estimate`` and ``truth`` of one size, disparities of the left
    image in pixels; ``StereoError`` for different sizes."""
    est = np.asarray(estimate, dtype=np.float64)
    gt = np.asarray(truth, dtype=np.float64)
    if est.shape != gt.shape or est.ndim != 2:
        msg = f'the disparity is {est.shape[::-1]} and its truth {gt.shape[::-1]}: not one size'
        raise StereoError(msg)
    has_truth = known_truth(gt)
    with np.errstate(invalid='ignore'):
        has_estimate = np.isfinite(est) & (est >= min_disparity)
    both = has_truth & has_estimate
    error = np.abs(est[both] - gt[both])
    truth_values = np.abs(gt[both])
    missing = int(np.count_nonzero(has_truth)) - int(error.size)
    depth_pixels, abs_rel_sum = 0, 0.0
    if pair is not None:
        z_est = pair.depth(np.where(both, est, np.nan))
        z_gt = pair.depth(np.where(both, gt, np.nan))
        usable = np.isfinite(z_est) & np.isfinite(z_gt) & (z_gt > 0)
        zg, ze = z_gt[usable].astype(np.float64), z_est[usable].astype(np.float64)
        depth_pixels = int(zg.size)
        abs_rel_sum = float(np.sum(np.abs(ze - zg) / zg))
    return DisparityCounts(
        truth=int(np.count_nonzero(has_truth)),
        estimated=int(error.size),
        abs_error_sum=float(np.sum(error)),
        bad1=int(np.count_nonzero(error > 1.0)) + missing,
        bad2=int(np.count_nonzero(error > 2.0)) + missing,
        bad3=int(np.count_nonzero(error > 3.0)) + missing,
        d1=int(np.count_nonzero((error > D1_PIXELS) & (error > D1_SHARE * truth_values))) + missing,
        depth_pixels=depth_pixels,
        abs_rel_sum=abs_rel_sum,
    )
