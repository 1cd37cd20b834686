"""How closely two backends agree on the same frames, without ground truth.

Per frame present in both backends, detections of the same class label are paired greedily by
IoU: all candidate pairs with IoU >= the threshold, highest IoU first (ties: the earlier
detection of ``a``, then of ``b``, in the order the backend returned them), each detection used
at most once. IoU is the continuous one (no +1), as in ``replaybench.results.accuracy``.

A frame *disagrees* when some detection of either side is left unmatched; the worst frames are
those with the most unmatched detections (ties: frame order).
"""

from __future__ import annotations

from itertools import combinations
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

    from replaybench.types import Detection

__all__ = [
    'AGREEMENT_IOU',
    'MAX_DISAGREEING_FRAMES',
    'Agreement',
    'FrameKey',
    'agreement',
    'agreement_table',
]

#: IoU at which two backends' detections of the same label count as one (run.json records it
#: as ``settings.agreement_iou``).
AGREEMENT_IOU = 0.5

#: How many of the worst disagreeing frames an ``Agreement`` lists.
MAX_DISAGREEING_FRAMES = 20

#: A frame of a run: (input index, seq of the message within its topic).
FrameKey = tuple[int, int]


class Agreement(NamedTuple):
    """Agreement of backend ``a`` and backend ``b`` on one topic.

    ``frames`` counts the frames both processed; ``n_a`` / ``n_b`` their detections there;
    ``matched`` the pairs. Fractions and means are None when their denominator is 0.
    """

    backend_a: str
    backend_b: str
    topic: str
    frames: int
    n_a: int
    n_b: int
    matched: int
    matched_frac_a: float | None
    matched_frac_b: float | None
    mean_iou: float | None
    mean_abs_score_diff: float | None
    disagreeing_frames: tuple[FrameKey, ...]


class _Flat(NamedTuple):
    """One side's detections, sorted by (frame, label) with input order kept inside a group."""

    group: npt.NDArray[np.int64]  # frame * n_labels + label, ascending
    order: npt.NDArray[np.int64]  # position of each detection in the backend's own output
    frame: npt.NDArray[np.int64]
    score: npt.NDArray[np.float64]
    box: npt.NDArray[np.float64]  # x0, y0, x1, y1


def _grouped(
    frames: Mapping[FrameKey, Sequence[Detection]],
    keys: Sequence[FrameKey],
    labels: dict[str, int],
    n_labels: int,
) -> _Flat:
    counts = np.fromiter((len(frames[k]) for k in keys), dtype=np.int64, count=len(keys))
    dets = [det for key in keys for det in frames[key]]
    if not dets:
        empty = np.zeros(0, dtype=np.int64)
        return _Flat(empty, empty, empty, np.zeros(0), np.zeros((0, 4)))
    _, names, scores, x0, y0, x1, y1, _ = zip(*dets, strict=True)
    frame = np.repeat(np.arange(len(keys), dtype=np.int64), counts)
    label = np.fromiter((labels[n] for n in names), dtype=np.int64, count=len(dets))
    group = frame * n_labels + label
    order = np.argsort(group, kind='stable').astype(np.int64)
    box = np.stack([np.asarray(c, dtype=np.float64) for c in (x0, y0, x1, y1)], axis=1)
    return _Flat(
        group[order],
        order,
        frame[order],
        np.asarray(scores, dtype=np.float64)[order],
        box[order],
    )


def _candidate_pairs(a: _Flat, b: _Flat) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Every (i, j) with a[i] and b[j] in the same (frame, label) group, as index arrays."""
    if not len(a.group) or not len(b.group):
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    # for each a detection: the range of b detections of its group
    lo = np.searchsorted(b.group, a.group, side='left').astype(np.int64)
    hi = np.searchsorted(b.group, a.group, side='right').astype(np.int64)
    counts = hi - lo
    total = int(counts.sum())
    pair_a = np.repeat(np.arange(len(a.group), dtype=np.int64), counts)
    # offset of each pair inside its a detection's run: 0, 1, ..., count - 1
    run_start = np.repeat(np.cumsum(counts) - counts, counts)
    pair_b = np.repeat(lo, counts) + (np.arange(total, dtype=np.int64) - run_start)
    return pair_a, pair_b


def _iou(box_a: npt.NDArray[np.float64], box_b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Row-wise IoU of two (N, 4) xyxy arrays; 0 where the union is empty."""
    iw = np.minimum(box_a[:, 2], box_b[:, 2]) - np.maximum(box_a[:, 0], box_b[:, 0])
    ih = np.minimum(box_a[:, 3], box_b[:, 3]) - np.maximum(box_a[:, 1], box_b[:, 1])
    inter = np.clip(iw, 0.0, None) * np.clip(ih, 0.0, None)
    area_a = np.clip(box_a[:, 2] - box_a[:, 0], 0.0, None) * np.clip(
        box_a[:, 3] - box_a[:, 1], 0.0, None
    )
    area_b = np.clip(box_b[:, 2] - box_b[:, 0], 0.0, None) * np.clip(
        box_b[:, 3] - box_b[:, 1], 0.0, None
    )
    union = area_a + area_b - inter
    out = np.zeros(len(inter), dtype=np.float64)
    np.divide(inter, union, out=out, where=union > 0)
    return out


def _greedy(
    pair_a: npt.NDArray[np.int64],
    pair_b: npt.NDArray[np.int64],
    ious: npt.NDArray[np.float64],
    a: _Flat,
    b: _Flat,
) -> npt.NDArray[np.bool_]:
    """Which candidate pairs the greedy matching keeps."""
    # highest IoU first; ties by the detections' positions in the backends' own output
    rank = np.lexsort((b.order[pair_b], a.order[pair_a], -ious))
    pair_a, pair_b = pair_a[rank], pair_b[rank]
    keep = np.zeros(len(rank), dtype=np.bool_)
    # a pair whose two detections appear in no other candidate is kept without a contest
    count_a = np.bincount(pair_a, minlength=len(a.group))
    count_b = np.bincount(pair_b, minlength=len(b.group))
    alone = (count_a[pair_a] == 1) & (count_b[pair_b] == 1)
    keep[alone] = True
    used_a: set[int] = set()
    used_b: set[int] = set()
    for k in np.flatnonzero(~alone).tolist():
        i, j = int(pair_a[k]), int(pair_b[k])
        if i in used_a or j in used_b:
            continue
        used_a.add(i)
        used_b.add(j)
        keep[k] = True
    out = np.zeros(len(rank), dtype=np.bool_)
    out[rank] = keep
    return out


def agreement(
    a: Mapping[FrameKey, Sequence[Detection]],
    b: Mapping[FrameKey, Sequence[Detection]],
    *,
    backend_a: str,
    backend_b: str,
    topic: str,
    iou: float = AGREEMENT_IOU,
) -> Agreement:
    """Match ``a``'s and ``b``'s detections on the frames both have (see the module text)."""
    keys = sorted(k for k in a if k in b)
    names = {det.label for side in (a, b) for key in keys for det in side[key]}
    labels = {name: index for index, name in enumerate(sorted(names))}
    n_labels = max(len(labels), 1)
    fa, fb = _grouped(a, keys, labels, n_labels), _grouped(b, keys, labels, n_labels)
    pair_a, pair_b = _candidate_pairs(fa, fb)
    ious = _iou(fa.box[pair_a], fb.box[pair_b])
    close = ious >= iou
    pair_a, pair_b, ious = pair_a[close], pair_b[close], ious[close]
    kept = _greedy(pair_a, pair_b, ious, fa, fb)
    pair_a, pair_b, ious = pair_a[kept], pair_b[kept], ious[kept]
    matched = len(pair_a)
    n_a, n_b = len(fa.group), len(fb.group)

    unmatched = np.bincount(fa.frame, minlength=len(keys)) + np.bincount(
        fb.frame, minlength=len(keys)
    )
    unmatched -= 2 * np.bincount(fa.frame[pair_a], minlength=len(keys))
    bad = np.flatnonzero(unmatched > 0)
    worst = bad[np.argsort(-unmatched[bad], kind='stable')][:MAX_DISAGREEING_FRAMES]
    return Agreement(
        backend_a=backend_a,
        backend_b=backend_b,
        topic=topic,
        frames=len(keys),
        n_a=n_a,
        n_b=n_b,
        matched=matched,
        matched_frac_a=matched / n_a if n_a else None,
        matched_frac_b=matched / n_b if n_b else None,
        mean_iou=float(ious.mean()) if matched else None,
        mean_abs_score_diff=float(np.abs(fa.score[pair_a] - fb.score[pair_b]).mean())
        if matched
        else None,
        disagreeing_frames=tuple((int(keys[i][0]), int(keys[i][1])) for i in worst.tolist()),
    )


def agreement_table(
    detections: Mapping[tuple[str, str], Mapping[FrameKey, Sequence[Detection]]],
    *,
    iou: float = AGREEMENT_IOU,
) -> list[Agreement]:
    """``agreement`` for every pair of backends on every topic.

    ``detections`` maps (backend, topic) to that backend's detections per frame. Backends are
    paired in the order they first appear (a before b), topics in first-appearance order.
    """
    backends: list[str] = []
    topics: list[str] = []
    for backend, topic in detections:
        if backend not in backends:
            backends.append(backend)
        if topic not in topics:
            topics.append(topic)
    out = []
    for topic in topics:
        present = [name for name in backends if (name, topic) in detections]
        for name_a, name_b in combinations(present, 2):
            out.append(
                agreement(
                    detections[name_a, topic],
                    detections[name_b, topic],
                    backend_a=name_a,
                    backend_b=name_b,
                    topic=topic,
                    iou=iou,
                )
            )
    return out
