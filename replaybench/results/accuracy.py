"""COCO-style detection accuracy, matching pycocotools' ``COCOeval`` for boxes.

Semantics (``iouType='bbox'``, one area range "all", no crowd regions, ``maxDets=100``):

* classes are ``Detection.label``; frames are the keys of ``gt`` (detections of other frames
  are not scored);
* per frame and class, detections are sorted by score (descending, stable) and the first 100
  kept; each, in that order, takes the still unmatched ground truth box with the highest IoU
  >= the threshold (ties: the later box, as pycocotools does);
* IoU is the continuous one of COCO (no +1): boxes are ``[x0, y0, x1, y1]`` pixel floats;
* per class, detections of all frames sorted by score give the precision/recall curve; its
  precision envelope sampled at 101 recall points 0, 0.01, ..., 1 averages to AP, for IoU
  thresholds 0.50, 0.55, ..., 0.95;
* classes without ground truth get AP -1 and are left out of the means (pycocotools does the
  same); with no ground truth at all, both mAPs are -1;
* ``precision50`` and ``recall50`` are TP / (TP + FP) and TP / n_gt at IoU 0.5 over all
  detections (no 100 limit), classes pooled; 0.0 where the denominator is 0.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import TYPE_CHECKING, NamedTuple, TypeVar

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

    from replaybench.types import Detection

K = TypeVar('K', bound=Hashable)

__all__ = [
    'IOU_THRESHOLDS',
    'MAX_DETECTIONS',
    'RECALL_POINTS',
    'AccuracyResult',
    'FrameScores',
    'evaluate',
    'frame_scores',
    'resampled_map50',
]

#: 0.50, 0.55, ..., 0.95, computed exactly as pycocotools does.
IOU_THRESHOLDS = np.linspace(0.5, 0.95, int(np.round((0.95 - 0.5) / 0.05)) + 1, endpoint=True)
#: 0.00, 0.01, ..., 1.00, computed exactly as pycocotools does.
RECALL_POINTS = np.linspace(0.0, 1.00, int(np.round((1.00 - 0.0) / 0.01)) + 1, endpoint=True)
MAX_DETECTIONS = 100
_CHUNK_ELEMENTS = 1 << 22  # array elements one matching batch may use


class AccuracyResult(NamedTuple):
    """Accuracy of one backend's detections against ground truth."""

    precision50: float
    recall50: float
    map50: float
    map50_95: float
    ap50: dict[str, float]
    ap50_95: dict[str, float]
    n_gt: int
    n_det: int


class _Boxes(NamedTuple):
    """Flattened boxes sorted by (class, frame, -score, input order)."""

    key: npt.NDArray[np.int64]  # class * n_frames + frame
    cls: npt.NDArray[np.int64]
    score: npt.NDArray[np.float64]
    box: npt.NDArray[np.float64]  # x, y, w, h as COCO holds them


def _flatten(
    frames: Mapping[K, Sequence[Detection]],
    frame_index: Mapping[K, int],
    label_index: Mapping[str, int],
    *,
    by_score: bool,
) -> _Boxes:
    fidx: list[int] = []
    cidx: list[int] = []
    scores: list[float] = []
    coords: list[tuple[float, float, float, float]] = []
    for key, items in frames.items():
        index = frame_index.get(key)
        if index is None:
            continue
        for det in items:
            fidx.append(index)
            cidx.append(label_index[det.label])
            scores.append(det.score)
            coords.append((det.x0, det.y0, det.x1, det.y1))
    frame = np.asarray(fidx, dtype=np.int64)
    cls = np.asarray(cidx, dtype=np.int64)
    score = np.asarray(scores, dtype=np.float64)
    xyxy = np.asarray(coords, dtype=np.float64).reshape(-1, 4)
    box = xyxy.copy()
    box[:, 2:] -= xyxy[:, :2]
    order_keys: tuple[npt.NDArray[np.generic], ...] = (np.arange(len(frame)),)
    if by_score:
        order_keys += (-score,)
    order = np.lexsort((*order_keys, frame, cls))
    n_frames = max(len(frame_index), 1)
    return _Boxes(cls[order] * n_frames + frame[order], cls[order], score[order], box[order])


def _runs(key: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Start index and length of each run of equal values in a sorted array."""
    if len(key) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    starts = np.flatnonzero(np.diff(key)) + 1
    starts = np.concatenate(([0], starts)).astype(np.int64)
    lengths = np.diff(np.concatenate((starts, [len(key)]))).astype(np.int64)
    return starts, lengths


def _iou(det: npt.NDArray[np.float64], gt: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """IoU of (..., D, 4) against (..., G, 4) xywh boxes, computed as pycocotools' bbIou."""
    d = det[..., :, None, :]
    g = gt[..., None, :, :]
    iw = np.minimum(d[..., 2] + d[..., 0], g[..., 2] + g[..., 0]) - np.maximum(d[..., 0], g[..., 0])
    ih = np.minimum(d[..., 3] + d[..., 1], g[..., 3] + g[..., 1]) - np.maximum(d[..., 1], g[..., 1])
    inter = np.where((iw > 0) & (ih > 0), iw * ih, 0.0)
    union = d[..., 2] * d[..., 3] + g[..., 2] * g[..., 3] - inter
    out = np.zeros(inter.shape, dtype=np.float64)
    np.divide(inter, union, out=out, where=inter > 0)
    return out


def _match(
    dets: _Boxes, keep: npt.NDArray[np.bool_], gts: _Boxes, thresholds: npt.NDArray[np.float64]
) -> npt.NDArray[np.bool_]:
    """Greedy COCO matching; (n_det, n_thresholds) True where a kept detection is a TP.

    Groups (frame, class) are batched by size so that the greedy loop runs over the
    detection rank only, vectorised over groups and thresholds.
    """
    n_t = len(thresholds)
    matched = np.zeros((len(dets.key), n_t), dtype=bool)
    index = np.flatnonzero(keep)
    d_key = dets.key[index]
    d_start, d_len = _runs(d_key)
    g_start, g_len = _runs(gts.key)
    if len(d_start) == 0 or len(g_start) == 0:
        return matched
    common, d_pos, g_pos = np.intersect1d(
        d_key[d_start], gts.key[g_start], assume_unique=True, return_indices=True
    )
    if len(common) == 0:
        return matched
    ds, dn = d_start[d_pos], d_len[d_pos]
    gs, gn = g_start[g_pos], g_len[g_pos]
    limits = np.minimum(thresholds, 1 - 1e-10)[None, :, None]
    bucket = np.ceil(np.log2(dn)).astype(np.int64) * 64 + np.ceil(np.log2(gn)).astype(np.int64)
    for value in np.unique(bucket):
        sel = np.flatnonzero(bucket == value)
        sel = sel[np.argsort(-dn[sel], kind='stable')]  # active groups form a prefix
        per_group = int(dn[sel].max()) * int(gn[sel].max()) * (1 + 4 * n_t)
        step = max(1, _CHUNK_ELEMENTS // per_group)  # bounds the memory of one batch
        for first in range(0, len(sel), step):
            part = sel[first : first + step]
            _match_batch(
                dets.box, index, ds[part], dn[part], gts.box, gs[part], gn[part], limits, matched
            )
    return matched


def _match_batch(
    d_box: npt.NDArray[np.float64],
    index: npt.NDArray[np.int64],
    bds: npt.NDArray[np.int64],
    bdn: npt.NDArray[np.int64],
    g_box: npt.NDArray[np.float64],
    bgs: npt.NDArray[np.int64],
    bgn: npt.NDArray[np.int64],
    limits: npt.NDArray[np.float64],
    matched: npt.NDArray[np.bool_],
) -> None:
    """Greedy matching of a batch of groups sorted by detection count, descending."""
    n_t = limits.shape[1]
    n_d, n_g = int(bdn.max()), int(bgn.max())
    d_valid = np.arange(n_d)[None, :] < bdn[:, None]
    g_valid = np.arange(n_g)[None, :] < bgn[:, None]
    d_rows = index[np.where(d_valid, bds[:, None] + np.arange(n_d)[None, :], bds[:, None])]
    g_rows = np.where(g_valid, bgs[:, None] + np.arange(n_g)[None, :], bgs[:, None])
    ious = _iou(d_box[d_rows], g_box[g_rows])
    ious[~np.broadcast_to(g_valid[:, None, :], ious.shape)] = -1.0
    taken = np.zeros((len(bds), n_t, n_g), dtype=bool)
    hits = np.zeros((len(bds), n_d, n_t), dtype=bool)
    for rank in range(n_d):
        active = int(np.count_nonzero(bdn > rank))
        cand = np.where(taken[:active], -1.0, ious[:active, rank, None, :])
        cand = np.where(cand >= limits, cand, -1.0)
        best = n_g - 1 - np.argmax(cand[:, :, ::-1], axis=2)  # last of equal maxima
        hit = np.take_along_axis(cand, best[:, :, None], axis=2)[:, :, 0] >= 0.0
        hits[:active, rank] = hit
        groups, thr = np.nonzero(hit)
        taken[groups, thr, best[groups, thr]] = True
    matched[d_rows[d_valid]] = hits[d_valid]


def _average_precision(tp: npt.NDArray[np.bool_], n_gt: int) -> npt.NDArray[np.float64]:
    """101-point interpolated AP per threshold from (n_thresholds, n_det) TP flags in rank order."""
    n_t, n_d = tp.shape
    if n_d == 0:
        return np.zeros(n_t, dtype=np.float64)
    tp_sum = np.cumsum(tp, axis=1).astype(np.float64)
    fp_sum = np.cumsum(~tp, axis=1).astype(np.float64)
    recall = tp_sum / n_gt
    precision = tp_sum / (fp_sum + tp_sum + np.spacing(1))
    envelope = np.maximum.accumulate(precision[:, ::-1], axis=1)[:, ::-1]
    ap = np.zeros(n_t, dtype=np.float64)
    for t in range(n_t):
        at = np.searchsorted(recall[t], RECALL_POINTS, side='left')
        sampled = np.where(at < n_d, envelope[t, np.minimum(at, n_d - 1)], 0.0)
        ap[t] = sampled.mean()
    return ap


def evaluate(
    gt: Mapping[K, Sequence[Detection]], dets: Mapping[K, Sequence[Detection]]
) -> AccuracyResult:
    """Score ``dets`` against ``gt``, both keyed by frame; see the module docstring."""
    frame_index = {key: i for i, key in enumerate(gt)}
    labels = {det.label for items in gt.values() for det in items}
    labels |= {det.label for key, items in dets.items() if key in frame_index for det in items}
    names = sorted(labels)
    label_index = {name: i for i, name in enumerate(names)}

    gts = _flatten(gt, frame_index, label_index, by_score=False)
    found = _flatten(dets, frame_index, label_index, by_score=True)
    n_gt, n_det = len(gts.key), len(found.key)

    starts, lengths = _runs(found.key)
    rank = np.arange(n_det) - np.repeat(starts, lengths)
    top = rank < MAX_DETECTIONS
    matched = _match(found, top, gts, IOU_THRESHOLDS)

    gt_per_class = np.bincount(gts.cls, minlength=len(names))
    ap50: dict[str, float] = {}
    ap50_95: dict[str, float] = {}
    for c, name in enumerate(names):
        if gt_per_class[c] == 0:
            ap50[name] = ap50_95[name] = -1.0
            continue
        rows = np.flatnonzero(top & (found.cls == c))  # frame order, score order within a frame
        rows = rows[np.argsort(-found.score[rows], kind='mergesort')]
        ap = _average_precision(matched[rows].T, int(gt_per_class[c]))
        ap50[name] = float(ap[0])
        ap50_95[name] = float(ap.mean())

    scored = [name for name in names if gt_per_class[label_index[name]] > 0]
    map50 = float(np.mean([ap50[name] for name in scored])) if scored else -1.0
    map50_95 = float(np.mean([ap50_95[name] for name in scored])) if scored else -1.0

    if top.all():
        tp50 = int(np.count_nonzero(matched[:, 0]))
    else:
        every = np.ones(n_det, dtype=bool)
        tp50 = int(np.count_nonzero(_match(found, every, gts, IOU_THRESHOLDS[:1])))
    return AccuracyResult(
        precision50=tp50 / n_det if n_det else 0.0,
        recall50=tp50 / n_gt if n_gt else 0.0,
        map50=map50,
        map50_95=map50_95,
        ap50=ap50,
        ap50_95=ap50_95,
        n_gt=n_gt,
        n_det=n_det,
    )


class FrameScores(NamedTuple):
    """Each detection's part of mAP@0.5, made once so that resampled sets of frames score fast
    (``resampled_map50``): matching is per frame and class, so a frame's true positives do not
    depend on which other frames are scored."""

    #: per detection, in frame order then the order ``evaluate`` ranks a frame's boxes in
    frame: npt.NDArray[np.int64]
    cls: npt.NDArray[np.int64]
    score: npt.NDArray[np.float64]
    #: a true positive at IoU 0.5 (among the first ``MAX_DETECTIONS`` of its frame and class)
    tp: npt.NDArray[np.bool_]
    #: among the first ``MAX_DETECTIONS`` of its frame and class (the rest are not ranked)
    top: npt.NDArray[np.bool_]
    #: (frames, classes) ground-truth boxes
    gt_count: npt.NDArray[np.int64]
    #: detections of each frame: ``starts[f]`` .. ``starts[f] + counts[f]``
    starts: npt.NDArray[np.int64]
    counts: npt.NDArray[np.int64]


def frame_scores(
    gt: Mapping[K, Sequence[Detection]], dets: Mapping[K, Sequence[Detection]]
) -> FrameScores:
    """``dets`` matched against ``gt`` frame by frame as ``evaluate`` matches them; frames are
    the keys of ``gt`` in its order (frame ``f`` is the ``f``-th key)."""
    frame_index = {key: i for i, key in enumerate(gt)}
    labels = {det.label for items in gt.values() for det in items}
    labels |= {det.label for key, items in dets.items() if key in frame_index for det in items}
    label_index = {name: i for i, name in enumerate(sorted(labels))}
    n_frames, n_classes = len(frame_index), len(label_index)
    gts = _flatten(gt, frame_index, label_index, by_score=False)
    found = _flatten(dets, frame_index, label_index, by_score=True)
    starts, lengths = _runs(found.key)
    rank = np.arange(len(found.key)) - np.repeat(starts, lengths)
    top = rank < MAX_DETECTIONS
    tp = _match(found, top, gts, IOU_THRESHOLDS[:1])[:, 0]
    frame = found.key - found.cls * max(n_frames, 1)
    # frame order, then the (class, score) order _flatten gave inside the frame
    order = np.argsort(frame, kind='stable')
    gt_frame = gts.key - gts.cls * max(n_frames, 1)
    gt_count = np.zeros((n_frames, max(n_classes, 1)), dtype=np.int64)
    np.add.at(gt_count, (gt_frame, gts.cls), 1)
    counts = np.bincount(frame, minlength=n_frames).astype(np.int64)
    return FrameScores(
        frame[order],
        found.cls[order],
        found.score[order],
        tp[order] & top[order],
        top[order],
        gt_count,
        (np.cumsum(counts) - counts).astype(np.int64),
        counts,
    )


def resampled_map50(scores: FrameScores, picks: npt.NDArray[np.int64]) -> float:
    """mAP@0.5 that ``evaluate`` gives for the frames ``picks`` (indices into ``scores``' frames,
    repeats allowed: each pick a frame of its own, in pick order); -1 without ground truth."""
    counts = scores.counts[picks]
    total = int(counts.sum())
    offsets = np.repeat(scores.starts[picks] - (np.cumsum(counts) - counts), counts)
    rows = np.arange(total, dtype=np.int64) + offsets
    position = np.repeat(np.arange(len(picks), dtype=np.int64), counts)
    keep = scores.top[rows]
    rows, position = rows[keep], position[keep]
    cls = scores.cls[rows]
    # evaluate's rank: by class, score descending, then frame (pick) order, then its own order
    order = np.lexsort((np.arange(len(rows)), position, -scores.score[rows], cls))
    rows, cls = rows[order], cls[order]
    n_gt = scores.gt_count[picks].sum(axis=0)
    aps = []
    for c in np.flatnonzero(n_gt > 0).tolist():
        tp = scores.tp[rows[cls == c]]
        aps.append(float(_average_precision(tp[None, :], int(n_gt[c]))[0]))
    return float(np.mean(aps)) if aps else -1.0
