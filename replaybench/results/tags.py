"""Tag accuracy against ground truth: recall, wrong and phantom ids, corner and pose errors.

Per frame with truth, each truth tag is matched to a detected tag of the same family and id
whose centre lies inside the truth's corner quadrilateral (the nearest such one). A detected
tag left over is a **wrong id** when its centre lies inside some truth tag's quadrilateral (it
is on a real tag but decoded another id), a **phantom** otherwise. Over the matched tags:

* ``corner_rmse_px``: root mean square of the distances of the four corners (canonical order);
* ``trans_err_m``: mean distance between the detected and the true position; ``trans_err_pct``
  the mean of that distance over the true range (distance from the camera), in %;
* ``rot_err_deg``: mean angle of the rotation between the detected and the true orientation.

Poses count only where both have one (a frame without CameraInfo has none). ``recall`` is
matched / truth tags. Everything is a point estimate: no interval.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.fiducials.pose import rotation_error_deg
from replaybench.results.columns import TAG_SUMMARY_COLUMNS
from replaybench.results.model import TagAccuracy

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from replaybench.fiducials.types import TagDetection
    from replaybench.results.model import RunResult

__all__ = [
    'TAG_FRAME_COLUMNS',
    'TAG_SUMMARY_COLUMNS',
    'FrameTagScore',
    'TagAccuracy',
    'score_frame',
    'summary_columns',
    'tag_accuracy',
    'tag_lines',
]

#: frames.csv columns of a tag backend (empty for other backends), after the existing ones.
TAG_FRAME_COLUMNS: tuple[str, ...] = (
    'tags',
    'tag_truth',
    'tag_matched',
    'tag_wrong_ids',
    'tag_phantoms',
    'tag_corner_rmse_px',
    'tag_trans_err_m',
    'tag_rot_err_deg',
)


@dataclass(frozen=True, slots=True)
class FrameTagScore:
    """One frame's tags against its truth; the per-tag errors kept for the summary."""

    found: int
    truth: int
    matched: int
    wrong_ids: int
    phantoms: int
    corner_sq_px: tuple[float, ...]  # per matched tag: mean squared corner distance
    trans_err_m: tuple[float, ...]
    trans_err_rel: tuple[float, ...]
    rot_err_deg: tuple[float, ...]

    def columns(self) -> dict[str, Any]:
        """The frame's TAG_FRAME_COLUMNS values."""
        return {
            'tags': self.found,
            'tag_truth': self.truth,
            'tag_matched': self.matched,
            'tag_wrong_ids': self.wrong_ids,
            'tag_phantoms': self.phantoms,
            'tag_corner_rmse_px': _rms(self.corner_sq_px),
            'tag_trans_err_m': _mean(self.trans_err_m),
            'tag_rot_err_deg': _mean(self.rot_err_deg),
        }


def _mean(values: Sequence[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _rms(mean_squares: Sequence[float]) -> float | None:
    return math.sqrt(float(np.mean(mean_squares))) if mean_squares else None


def _inside(point: tuple[float, float], quad: Sequence[tuple[float, float]]) -> bool:
    """Whether ``point`` lies inside the (convex or not) quadrilateral ``quad``."""
    x, y = point
    inside = False
    n = len(quad)
    for i in range(n):
        x0, y0 = quad[i]
        x1, y1 = quad[(i + 1) % n]
        if (y0 > y) != (y1 > y):
            cross = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
            if x < cross:
                inside = not inside
    return inside


def score_frame(found: Sequence[TagDetection], truth: Sequence[TagDetection]) -> FrameTagScore:
    """Match one frame's detected tags to its truth (see the module's description)."""
    left = list(range(len(found)))
    corner: list[float] = []
    trans: list[float] = []
    rel: list[float] = []
    rot: list[float] = []
    matched = 0
    for gt in truth:
        candidates = [
            i
            for i in left
            if found[i].tag_id == gt.tag_id
            and found[i].family == gt.family
            and _inside(found[i].center, gt.corners)
        ]
        if not candidates:
            continue
        best = min(candidates, key=lambda i: math.dist(found[i].center, gt.center))
        left.remove(best)
        det = found[best]
        matched += 1
        diff = np.subtract(det.corners, gt.corners)
        corner.append(float(np.mean(np.sum(diff * diff, axis=1))))
        if det.pose is not None and gt.pose is not None:
            gap = math.dist(det.pose.position, gt.pose.position)
            trans.append(gap)
            rng = math.hypot(*gt.pose.position)
            if rng > 0:
                rel.append(gap / rng)
            rot.append(rotation_error_deg(det.pose, gt.pose))
    wrong = sum(1 for i in left if any(_inside(found[i].center, gt.corners) for gt in truth))
    return FrameTagScore(
        len(found),
        len(truth),
        matched,
        wrong,
        len(left) - wrong,
        tuple(corner),
        tuple(trans),
        tuple(rel),
        tuple(rot),
    )


def tag_accuracy(scores: Iterable[FrameTagScore]) -> TagAccuracy:
    """The summary of a (backend, topic)'s frame scores."""
    frames = list(scores)
    corner = [v for s in frames for v in s.corner_sq_px]
    trans = [v for s in frames for v in s.trans_err_m]
    rel = [v for s in frames for v in s.trans_err_rel]
    rot = [v for s in frames for v in s.rot_err_deg]
    n_truth = sum(s.truth for s in frames)
    matched = sum(s.matched for s in frames)
    return TagAccuracy(
        frames=len(frames),
        n_truth=n_truth,
        n_found=sum(s.found for s in frames),
        matched=matched,
        recall=matched / n_truth if n_truth else None,
        wrong_ids=sum(s.wrong_ids for s in frames),
        phantoms=sum(s.phantoms for s in frames),
        corner_rmse_px=_rms(corner),
        trans_err_m=_mean(trans),
        trans_err_pct=float(np.mean(rel)) * 100 if rel else None,
        rot_err_deg=_mean(rot),
        rot_err_deg_p95=float(np.percentile(rot, 95)) if rot else None,
        rot_err_deg_max=max(rot) if rot else None,
        trans_err_m_max=max(trans) if trans else None,
        poses=len(rot),
    )


def summary_columns(accuracy: TagAccuracy | None) -> dict[str, Any]:
    """The ``TAG_SUMMARY_COLUMNS`` values of a (backend, topic)'s tag accuracy (None: all
    None)."""
    if accuracy is None:
        return dict.fromkeys(TAG_SUMMARY_COLUMNS)
    return {
        'tag_recall': accuracy.recall,
        'tag_wrong_ids': accuracy.wrong_ids,
        'tag_phantoms': accuracy.phantoms,
        'tag_corner_rmse_px': accuracy.corner_rmse_px,
        'tag_trans_err_m': accuracy.trans_err_m,
        'tag_trans_err_pct': accuracy.trans_err_pct,
        'tag_rot_err_deg': accuracy.rot_err_deg,
    }


def _f(value: float | None, spec: str) -> str:
    return '-' if value is None else format(value, spec)


def tag_lines(run: RunResult) -> list[str]:
    """One line per (backend, topic) with tag accuracy, for the terminal."""
    lines = []
    for row in run.summary_rows:
        acc = row.tag_accuracy
        if acc is None:
            continue
        lines.append(
            f'tags: {row.backend} {row.topic}: recall {_f(acc.recall, ".3f")} '
            f'({acc.matched}/{acc.n_truth}), wrong ids {acc.wrong_ids}, phantoms {acc.phantoms}, '
            f'corner RMSE {_f(acc.corner_rmse_px, ".3f")} px, translation '
            f'{_f(acc.trans_err_m, ".4f")} m ({_f(acc.trans_err_pct, ".2f")} % of range), '
            f'rotation {_f(acc.rot_err_deg, ".2f")} deg (p95 {_f(acc.rot_err_deg_p95, ".2f")})'
        )
    return lines
