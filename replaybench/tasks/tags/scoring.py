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

A wrong tag size scales a tag's distance and nothing else. Per tag id with at least
``SIZE_HINT_MIN`` posed detections, when the ratios of detected to true distance all lie
within ``SIZE_HINT_SPREAD`` of their median and the median is more than ``SIZE_HINT_OFF`` from 1,
the id gets a ``TagSizeHint`` ("tag 14: distances are 1.37x the truth: is its size 0.16 m
rather than 0.22 m?"), in run.json's ``tag_accuracy.size_hints`` and on the terminal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.fiducials.pose import rotation_error_deg
from replaybench.results.columns import TAG_SUMMARY_COLUMNS
from replaybench.results.model import TagAccuracy, TagSizeHint

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from replaybench.fiducials.types import TagDetection
    from replaybench.results.model import RunResult

__all__ = [
    'SIZE_HINT_MIN',
    'SIZE_HINT_OFF',
    'SIZE_HINT_SPREAD',
    'TAG_FRAME_COLUMNS',
    'TAG_SUMMARY_COLUMNS',
    'FrameTagScore',
    'TagAccuracy',
    'score_frame',
    'size_hints',
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


#: A size hint needs this many posed detections of the id, ...
SIZE_HINT_MIN = 3
#: ... their distance ratios within this fraction of the median, ...
SIZE_HINT_SPREAD = 0.03
#: ... and the median this far from 1 (the poses' own noise is under 1 % on the fixtures).
SIZE_HINT_OFF = 0.05


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
    #: per matched tag with both poses: (id, detected / true distance, size solved with)
    scales: tuple[tuple[int, float, float], ...] = ()

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
    scales: list[tuple[int, float, float]] = []
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
                if det.size_m is not None:
                    found_rng = math.hypot(*det.pose.position)
                    scales.append((det.tag_id, found_rng / rng, det.size_m))
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
        tuple(scales),
    )


def _size_text(value: float) -> str:
    return f'{float(f"{value:.2g}"):g}'


def size_hints(scores: Iterable[FrameTagScore]) -> tuple[TagSizeHint, ...]:
    """The ids whose distances one factor explains (see the module's description), by id."""
    by_id: dict[int, list[tuple[float, float]]] = {}
    for score in scores:
        for tag_id, ratio, size in score.scales:
            by_id.setdefault(tag_id, []).append((ratio, size))
    hints = []
    for tag_id, seen in sorted(by_id.items()):
        sizes = {size for _, size in seen}
        if len(seen) < SIZE_HINT_MIN or len(sizes) != 1:
            continue
        ratios = [r for r, _ in seen]
        scale = float(np.median(ratios))
        spread = max(abs(r / scale - 1) for r in ratios)
        if spread > SIZE_HINT_SPREAD or abs(scale - 1) <= SIZE_HINT_OFF:
            continue
        (size,) = sizes
        suggested = size / scale
        line = (
            f'tag {tag_id}: distances are {scale:.2f}x the truth: is its size '
            f'{_size_text(suggested)} m rather than {_size_text(size)} m?'
        )
        hints.append(
            TagSizeHint(tag_id, len(seen), scale, spread * 100, size, round(suggested, 6), line)
        )
    return tuple(hints)


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
        size_hints=size_hints(frames),
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
    """For the terminal: one line per tag backend saying which tag sizes it used and where
    they came from; one per (backend, topic) with tag accuracy, and its size hints."""
    lines = []
    for entry in run.backends:
        where = entry.info.get('tag_sizes_from')
        if where is None:
            continue
        per_id = entry.info.get('tag_sizes_m') or {}
        ids = ', '.join(f'{k}={v:g}' for k, v in per_id.items())
        sizes = f'{entry.info.get("tag_size_m", 0):g} m' + (f' ({ids})' if ids else '')
        lines.append(f'tags: {entry.name}: tag sizes {sizes} from {where}')
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
        lines += [f'tags: {row.backend} {row.topic}: {hint.line}' for hint in acc.size_hints]
    return lines
