"""Sequence metrics of multi-object tracking, as TrackEval defines them.

``score_tracks`` takes one ``TrackFrame`` per frame (the truth's ids, the tracker's ids and
their similarity, box IoU for boxes) and gives the figures of three families:

* **HOTA** (Luiten et al., IJCV 2021; TrackEval ``metrics/hota.py``): for each localisation
  threshold alpha in 0.05, 0.10, ..., 0.95 (``HOTA_ALPHAS``, 19 of them), a frame's truth and
  tracker boxes are matched one to one by the Hungarian algorithm on the product of their
  similarity and their ids' global alignment (the IoU of the two ids' trajectories, weighted by
  similarity), a match counting where the similarity reaches alpha; DetA = TP / (TP + FN + FP),
  AssA the mean over the TPs of the matched ids' association IoU, HOTA = sqrt(DetA x AssA),
  LocA the mean similarity of the TPs. The reported HOTA, DetA, AssA, LocA are the means over
  the 19 thresholds, as TrackEval reports them.
* **CLEAR** (Bernardin and Stiefelhagen 2008; TrackEval ``metrics/clear.py``): matches at
  similarity >= 0.5, preferring the pair matched in the previous frame; MOTA = (TP - FP -
  IDSW) / (TP + FN), MOTP the mean similarity of the matches, ID switches against the id a
  truth object last had, fragmentations (tracked again after a gap), mostly tracked (> 80 % of
  its frames matched) and mostly lost (< 20 %).
* **Identity** (Ristani et al. 2016; TrackEval ``metrics/identity.py``): one global one-to-one
  assignment of truth ids to tracker ids maximising the frames they are matched at similarity
  >= 0.5; IDF1 = IDTP / (IDTP + (IDFP + IDFN) / 2).

The same edge cases as TrackEval (no tracker boxes at all, no truth at all, frames with one
side empty), and the same floating-point tolerance (``eps``) in its comparisons:
tests/tracking/ checks every figure equal to TrackEval's to 1e-6 on the TUD-Campus and
TUD-Stadtmitte files the motmetrics wheel ships.

These are sequence metrics: a frame has no value of its own. ``clear_matching`` gives the
CLEAR matching itself (each frame's matched pairs and every ID switch: the report's id-switch
timeline), from the same code that counts ``id_switches``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from replaybench.errors import MissingDependencyError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    import numpy.typing as npt

__all__ = [
    'HOTA_ALPHAS',
    'ClearMatching',
    'IdSwitch',
    'TrackFrame',
    'TrackScores',
    'box_iou_xywh',
    'clear_matching',
    'score_and_match',
    'score_tracks',
]

#: HOTA's localisation thresholds, as TrackEval's ``np.arange(0.05, 0.99, 0.05)``
HOTA_ALPHAS: npt.NDArray[np.float64] = np.arange(0.05, 0.99, 0.05)
_EPS = float(np.finfo('float').eps)
#: the similarity CLEAR and identity matches need
MATCH_THRESHOLD = 0.5


@dataclass(frozen=True, slots=True)
class TrackFrame:
    """One frame: the truth's object ids, the tracker's track ids (any integers, stable across
    the sequence) and ``similarity[i, j]`` between truth box i and tracker box j (0..1)."""

    gt_ids: npt.NDArray[np.int64]
    tracker_ids: npt.NDArray[np.int64]
    similarity: npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class TrackScores:
    """A sequence's tracking figures; shares are fractions 0..1."""

    hota: float
    deta: float
    assa: float
    loca: float
    detre: float
    detpr: float
    assre: float
    asspr: float
    mota: float
    motp: float
    id_switches: int
    fragmentations: int
    mostly_tracked: int
    partly_tracked: int
    mostly_lost: int
    clr_tp: int
    clr_fn: int
    clr_fp: int
    idf1: float
    idr: float
    idp: float
    idtp: int
    idfn: int
    idfp: int
    gt_ids: int
    tracker_ids: int
    gt_dets: int
    tracker_dets: int
    frames: int
    #: HOTA at each threshold of ``HOTA_ALPHAS``
    hota_per_alpha: tuple[float, ...] = ()


@dataclass(frozen=True, slots=True)
class IdSwitch:
    """One CLEAR ID switch: at ``frame`` (the frame's index in the sequence, from 0) the truth
    object ``gt_id`` is matched to track ``to_id`` after it was last matched (in this frame's
    predecessor or before a gap) to ``from_id``; ids as the ``TrackFrame`` s give them."""

    frame: int
    gt_id: int
    from_id: int
    to_id: int


@dataclass(frozen=True, slots=True)
class ClearMatching:
    """CLEAR's matching of a sequence, the one ``score_tracks`` counts its CLEAR figures from:
    each frame's matched (truth id, tracker id) pairs, in the frame's truth order, and the ID
    switches in frame order (as many as ``TrackScores.id_switches``)."""

    pairs: tuple[tuple[tuple[int, int], ...], ...]
    switches: tuple[IdSwitch, ...]


def box_iou_xywh(
    a: npt.NDArray[np.floating], b: npt.NDArray[np.floating]
) -> npt.NDArray[np.float64]:
    """IoU of each box of ``a`` (N x 4, x y w h) with each of ``b`` (M x 4): N x M, as
    TrackEval's ``_calculate_box_ious`` with ``box_format='xywh'`` computes it."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    a = np.concatenate([a[:, :2], a[:, :2] + a[:, 2:]], axis=1)
    b = np.concatenate([b[:, :2], b[:, :2] + b[:, 2:]], axis=1)
    min_ = np.minimum(a[:, np.newaxis, :], b[np.newaxis, :, :])
    max_ = np.maximum(a[:, np.newaxis, :], b[np.newaxis, :, :])
    intersection = np.maximum(min_[..., 2] - max_[..., 0], 0) * np.maximum(
        min_[..., 3] - max_[..., 1], 0
    )
    area1 = (a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1])
    area2 = (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])
    union = area1[:, np.newaxis] + area2[np.newaxis, :] - intersection
    intersection[area1 <= 0 + _EPS, :] = 0
    intersection[:, area2 <= 0 + _EPS] = 0
    intersection[union <= 0 + _EPS] = 0
    union[union <= 0 + _EPS] = 1
    ious: npt.NDArray[np.float64] = intersection / union
    return ious


class _Sequence:
    """The frames with their ids renumbered 0..n-1 in order of first appearance."""

    def __init__(self, frames: Sequence[TrackFrame]) -> None:
        gt_index: dict[int, int] = {}
        tr_index: dict[int, int] = {}
        self.gt_index = gt_index
        self.tr_index = tr_index
        self.gt: list[npt.NDArray[np.int64]] = []
        self.tr: list[npt.NDArray[np.int64]] = []
        self.sim: list[npt.NDArray[np.float64]] = []
        for frame in frames:
            gt = np.asarray(frame.gt_ids, dtype=np.int64).reshape(-1)
            tr = np.asarray(frame.tracker_ids, dtype=np.int64).reshape(-1)
            sim = np.asarray(frame.similarity, dtype=np.float64).reshape(len(gt), len(tr))
            if len(set(gt.tolist())) != len(gt) or len(set(tr.tolist())) != len(tr):
                msg = 'an id appears twice in one frame'
                raise ValueError(msg)
            self.gt.append(
                np.array([gt_index.setdefault(int(i), len(gt_index)) for i in gt], dtype=np.int64)
            )
            self.tr.append(
                np.array([tr_index.setdefault(int(i), len(tr_index)) for i in tr], dtype=np.int64)
            )
            self.sim.append(sim)
        self.n_gt = len(gt_index)
        self.n_tr = len(tr_index)
        self.gt_dets = sum(len(g) for g in self.gt)
        self.tr_dets = sum(len(t) for t in self.tr)


@functools.cache
def _solver() -> Callable[..., tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]]:
    """SciPy's ``linear_sum_assignment``, imported once (``MissingDependencyError`` without
    SciPy, on every call until it is there)."""
    try:
        from scipy.optimize import linear_sum_assignment
    except ImportError as err:
        msg = (
            'the tracking metrics need SciPy: pip install "replaybench[tracking]" '
            f'({type(err).__name__}: {err})'
        )
        raise MissingDependencyError(msg) from err
    solver: Callable[..., tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]] = linear_sum_assignment
    return solver


def _assign(cost: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """The minimum-cost one-to-one assignment: SciPy's ``linear_sum_assignment``, TrackEval's
    solver (the same solver breaks ties the same way)."""
    return _solver()(cost)


def _hota(s: _Sequence) -> dict[str, npt.NDArray[np.float64]]:
    k = len(HOTA_ALPHAS)
    tp, fn, fp, loca = np.zeros(k), np.zeros(k), np.zeros(k), np.zeros(k)
    assa, assre, asspr = np.zeros(k), np.zeros(k), np.zeros(k)
    if s.tr_dets == 0 or s.gt_dets == 0:
        (fn if s.tr_dets == 0 else fp)[:] = s.gt_dets if s.tr_dets == 0 else s.tr_dets
        return _hota_final(tp, fn, fp, np.ones(k), assa, assre, asspr)
    potential = np.zeros((s.n_gt, s.n_tr))
    gt_count = np.zeros((s.n_gt, 1))
    tr_count = np.zeros((1, s.n_tr))
    for gt, tr, sim in zip(s.gt, s.tr, s.sim, strict=True):
        denom = sim.sum(0)[np.newaxis, :] + sim.sum(1)[:, np.newaxis] - sim
        sim_iou = np.zeros_like(sim)
        mask = denom > 0 + _EPS
        sim_iou[mask] = sim[mask] / denom[mask]
        potential[gt[:, np.newaxis], tr[np.newaxis, :]] += sim_iou
        gt_count[gt] += 1
        tr_count[0, tr] += 1
    alignment = potential / (gt_count + tr_count - potential)
    matches = [np.zeros_like(potential) for _ in range(k)]
    for gt, tr, sim in zip(s.gt, s.tr, s.sim, strict=True):
        if len(gt) == 0:
            fp += len(tr)
            continue
        if len(tr) == 0:
            fn += len(gt)
            continue
        rows, cols = _assign(-(alignment[gt[:, np.newaxis], tr[np.newaxis, :]] * sim))
        matched_sim = sim[rows, cols]
        for a, alpha in enumerate(HOTA_ALPHAS):
            keep = matched_sim >= alpha - _EPS
            n = int(keep.sum())
            tp[a] += n
            fn[a] += len(gt) - n
            fp[a] += len(tr) - n
            if n:
                loca[a] += matched_sim[keep].sum()
                matches[a][gt[rows[keep]], tr[cols[keep]]] += 1
    for a in range(k):
        m = matches[a]
        assa[a] = np.sum(m * (m / np.maximum(1, gt_count + tr_count - m))) / max(1.0, tp[a])
        assre[a] = np.sum(m * (m / np.maximum(1, gt_count))) / max(1.0, tp[a])
        asspr[a] = np.sum(m * (m / np.maximum(1, tr_count))) / max(1.0, tp[a])
    loca = np.maximum(1e-10, loca) / np.maximum(1e-10, tp)
    return _hota_final(tp, fn, fp, loca, assa, assre, asspr)


def _hota_final(
    tp: npt.NDArray[np.float64],
    fn: npt.NDArray[np.float64],
    fp: npt.NDArray[np.float64],
    loca: npt.NDArray[np.float64],
    assa: npt.NDArray[np.float64],
    assre: npt.NDArray[np.float64],
    asspr: npt.NDArray[np.float64],
) -> dict[str, npt.NDArray[np.float64]]:
    deta = tp / np.maximum(1, tp + fn + fp)
    return {
        'HOTA': np.sqrt(deta * assa),
        'DetA': deta,
        'AssA': assa,
        'LocA': loca,
        'DetRe': tp / np.maximum(1, tp + fn),
        'DetPr': tp / np.maximum(1, tp + fp),
        'AssRe': assre,
        'AssPr': asspr,
    }


class _Matched:
    """What ``_clear`` matched, kept where asked for (``clear_matching``), in the given ids."""

    def __init__(self, s: _Sequence) -> None:
        self.gt_names = np.array(list(s.gt_index), dtype=np.int64)
        self.tr_names = np.array(list(s.tr_index), dtype=np.int64)
        self.pairs: list[tuple[tuple[int, int], ...]] = []
        self.switches: list[IdSwitch] = []

    def frame(
        self,
        matched_gt: npt.NDArray[np.int64],
        matched_tr: npt.NDArray[np.int64],
        before: npt.NDArray[np.float64],
    ) -> None:
        frame = len(self.pairs)
        gt = self.gt_names[matched_gt].tolist()
        tr = self.tr_names[matched_tr].tolist()
        order = np.argsort(matched_gt, kind='stable')
        self.pairs.append(tuple((int(gt[i]), int(tr[i])) for i in order))
        for i in order:
            if not np.isnan(before[i]) and matched_tr[i] != before[i]:
                was = int(self.tr_names[int(before[i])])
                self.switches.append(IdSwitch(frame, int(gt[i]), was, int(tr[i])))


def _clear(s: _Sequence, kept: _Matched | None = None) -> dict[str, float]:
    out = dict.fromkeys(('TP', 'FN', 'FP', 'IDSW', 'MT', 'PT', 'ML', 'Frag', 'MOTP_sum'), 0.0)
    nothing = np.zeros(0, dtype=np.int64)
    if s.tr_dets == 0 or s.gt_dets == 0:
        for _ in s.gt:
            if kept is not None:
                kept.frame(nothing, nothing, np.zeros(0))
        if s.tr_dets == 0:
            out.update(FN=s.gt_dets, ML=s.n_gt)
        else:
            out['FP'] = s.tr_dets
        return out
    gt_count = np.zeros(s.n_gt)
    gt_matched = np.zeros(s.n_gt)
    gt_frag = np.zeros(s.n_gt)
    prev_id = np.full(s.n_gt, np.nan)  # the id each truth object last had
    prev_step = np.full(s.n_gt, np.nan)  # its id in the previous frame
    for gt, tr, sim in zip(s.gt, s.tr, s.sim, strict=True):
        if len(gt) == 0 or len(tr) == 0:
            if kept is not None:
                kept.frame(nothing, nothing, np.zeros(0))
            if len(gt) == 0:
                out['FP'] += len(tr)
            else:
                out['FN'] += len(gt)
                gt_count[gt] += 1
            continue
        score = 1000.0 * (tr[np.newaxis, :] == prev_step[gt[:, np.newaxis]]) + sim
        score[sim < MATCH_THRESHOLD - _EPS] = 0
        rows, cols = _assign(-score)
        keep = score[rows, cols] > 0 + _EPS
        rows, cols = rows[keep], cols[keep]
        matched_gt, matched_tr = gt[rows], tr[cols]
        before = prev_id[matched_gt]
        out['IDSW'] += float(np.sum(~np.isnan(before) & (matched_tr != before)))
        if kept is not None:
            kept.frame(matched_gt, matched_tr, before)
        gt_count[gt] += 1
        gt_matched[matched_gt] += 1
        not_tracked = np.isnan(prev_step)
        prev_id[matched_gt] = matched_tr
        prev_step[:] = np.nan
        prev_step[matched_gt] = matched_tr
        gt_frag += not_tracked & ~np.isnan(prev_step)
        out['TP'] += len(matched_gt)
        out['FN'] += len(gt) - len(matched_gt)
        out['FP'] += len(tr) - len(matched_gt)
        if len(matched_gt):
            out['MOTP_sum'] += float(sim[rows, cols].sum())
    ratio = gt_matched[gt_count > 0] / gt_count[gt_count > 0]
    out['MT'] = float(np.sum(ratio > 0.8))
    out['PT'] = float(np.sum(ratio >= 0.2)) - out['MT']
    out['ML'] = s.n_gt - out['MT'] - out['PT']
    out['Frag'] = float(np.sum(gt_frag[gt_frag > 0] - 1))
    return out


def _identity(s: _Sequence) -> dict[str, float]:
    if s.tr_dets == 0:
        return {'IDTP': 0.0, 'IDFN': float(s.gt_dets), 'IDFP': 0.0}
    if s.gt_dets == 0:
        return {'IDTP': 0.0, 'IDFN': 0.0, 'IDFP': float(s.tr_dets)}
    potential = np.zeros((s.n_gt, s.n_tr))
    gt_count = np.zeros(s.n_gt)
    tr_count = np.zeros(s.n_tr)
    for gt, tr, sim in zip(s.gt, s.tr, s.sim, strict=True):
        i, j = np.nonzero(sim >= MATCH_THRESHOLD - _EPS)
        potential[gt[i], tr[j]] += 1
        gt_count[gt] += 1
        tr_count[tr] += 1
    n_gt, n_tr = s.n_gt, s.n_tr
    fp_mat = np.zeros((n_gt + n_tr, n_gt + n_tr))
    fn_mat = np.zeros((n_gt + n_tr, n_gt + n_tr))
    fp_mat[n_gt:, :n_tr] = 1e10
    fn_mat[:n_gt, n_tr:] = 1e10
    for g in range(n_gt):
        fn_mat[g, :n_tr] = gt_count[g]
        fn_mat[g, n_tr + g] = gt_count[g]
    for t in range(n_tr):
        fp_mat[:n_gt, t] = tr_count[t]
        fp_mat[t + n_gt, t] = tr_count[t]
    fn_mat[:n_gt, :n_tr] -= potential
    fp_mat[:n_gt, :n_tr] -= potential
    rows, cols = _assign(fn_mat + fp_mat)
    idfn = float(fn_mat[rows, cols].sum().astype(int))
    idfp = float(fp_mat[rows, cols].sum().astype(int))
    return {'IDTP': float(gt_count.sum() - idfn), 'IDFN': idfn, 'IDFP': idfp}


def clear_matching(frames: Sequence[TrackFrame]) -> ClearMatching:
    """The CLEAR matching of one sequence (``TrackFrame`` per frame, in order) that
    ``score_tracks`` counts TP, FN, FP, ID switches and fragmentations from: the same code, so
    ``len(clear_matching(f).switches) == score_tracks(f).id_switches``. ``ValueError`` as
    ``score_tracks``."""
    s = _Sequence(frames)
    kept = _Matched(s)
    _clear(s, kept)
    return ClearMatching(tuple(kept.pairs), tuple(kept.switches))


def score_and_match(frames: Sequence[TrackFrame]) -> tuple[TrackScores, ClearMatching]:
    """``score_tracks`` and ``clear_matching`` of one sequence in one pass: the figures and
    the matching their CLEAR figures were counted from."""
    s = _Sequence(frames)
    kept = _Matched(s)
    scores = _scores(s, _clear(s, kept), len(frames))
    return scores, ClearMatching(tuple(kept.pairs), tuple(kept.switches))


def score_tracks(frames: Sequence[TrackFrame]) -> TrackScores:
    """The HOTA, CLEAR and identity figures of one sequence (``TrackFrame`` per frame, in
    order). ``ValueError`` for an id twice in one frame or a similarity of the wrong shape."""
    s = _Sequence(frames)
    return _scores(s, _clear(s), len(frames))


def _scores(s: _Sequence, clear: dict[str, float], frames: int) -> TrackScores:
    hota = _hota(s)
    ident = _identity(s)
    tp, fn, fp = clear['TP'], clear['FN'], clear['FP']
    idtp, idfn, idfp = ident['IDTP'], ident['IDFN'], ident['IDFP']
    return TrackScores(
        hota=float(hota['HOTA'].mean()),
        deta=float(hota['DetA'].mean()),
        assa=float(hota['AssA'].mean()),
        loca=float(hota['LocA'].mean()),
        detre=float(hota['DetRe'].mean()),
        detpr=float(hota['DetPr'].mean()),
        assre=float(hota['AssRe'].mean()),
        asspr=float(hota['AssPr'].mean()),
        # a sequence without truth: 0, as TrackEval leaves it (its per-sequence CLEAR returns
        # before computing MOTA), not -FP
        mota=(tp - fp - clear['IDSW']) / max(1.0, tp + fn) if s.gt_dets else 0.0,
        motp=clear['MOTP_sum'] / max(1.0, tp),
        id_switches=int(clear['IDSW']),
        fragmentations=int(clear['Frag']),
        mostly_tracked=int(clear['MT']),
        partly_tracked=int(clear['PT']),
        mostly_lost=int(clear['ML']),
        clr_tp=int(tp),
        clr_fn=int(fn),
        clr_fp=int(fp),
        idf1=idtp / max(1.0, idtp + 0.5 * idfp + 0.5 * idfn),
        idr=idtp / max(1.0, idtp + idfn),
        idp=idtp / max(1.0, idtp + idfp),
        idtp=int(idtp),
        idfn=int(idfn),
        idfp=int(idfp),
        gt_ids=s.n_gt,
        tracker_ids=s.n_tr,
        gt_dets=s.gt_dets,
        tracker_dets=s.tr_dets,
        frames=frames,
        hota_per_alpha=tuple(float(v) for v in hota['HOTA']),
    )
