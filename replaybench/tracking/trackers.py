"""Multi-object trackers over any detector's boxes: an IoU baseline, SORT and ByteTrack.

Written here with SciPy's linear-sum assignment rather than taken from a library. I looked at
three:

- roboflow's `trackers` 2.6.1 (Apache-2.0) needs `opencv-python`, the GUI build, which cannot
  share an environment with replaybench's `opencv-python-headless` (both install `cv2`). It
  also pulls in `supervision`, `rich` and `requests`.
- `boxmot` is AGPL.
- `lap` is a solver only.

Each tracker takes a frame's boxes (x1 y1 x2 y2 in pixels) and scores and returns the tracks
it reports for that frame. A dropped frame is not given to it: the gap is a frame the tracks
were not seen in. Track ids start at 1 and are deterministic: the same boxes in the same order
give the same ids.

- `IouTracker`: each box takes the id of the previous frame's box it overlaps most (IoU ≥
  `iou_threshold`, a one-to-one Hungarian match), else a new id. There is no motion model and
  no memory beyond one frame. It is the baseline a tracker must beat.
- `SortTracker` (Bewley et al., ICIP 2016):
  - a constant-velocity Kalman filter per track on (centre x, centre y, area, aspect ratio);
  - Hungarian matching on IoU with the predictions (≥ `iou_threshold`);
  - a track is deleted after `max_age` frames unmatched, and reported once it has `min_hits`
    matches (or in the first `min_hits` frames).
  - Boxes below `det_thresh` are ignored.
- `ByteTrackTracker` (Zhang et al., ECCV 2022):
  - a Kalman filter on (centre x, centre y, aspect ratio, height), its noise scaled by the
    height;
  - the high-score boxes (≥ `track_thresh`) are matched first to every active or lost track
    (IoU distance ≤ `match_thresh`);
  - the low-score boxes (≥ `low_thresh`) are then matched to the tracks still unmatched
    (IoU ≥ 0.5), which keeps occluded objects' ids;
  - new tracks start from unmatched high boxes scoring ≥ `track_thresh + 0.1`, are confirmed
    on their second match, and are kept lost for `track_buffer` frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from replaybench.tracking import kernels
from replaybench.tracking.kalman import Filters
from replaybench.tracking.metrics import _assign

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ['ByteTrackTracker', 'IouTracker', 'SortTracker', 'Track', 'box_iou_xyxy', 'make_tracker']

#: what ``step`` returns, in the order of the tracks (id order): their ids, their boxes as four
#: lists (x1s, y1s, x2s, y2s) and the input boxes they were matched to (-1 for none)
Reported = tuple[list[int], list[list[float]], list[int]]

_F64 = np.float64


def _c(values: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``values`` C-contiguous, as the kernels take them (the array itself where it is; a
    copy of a column selection such as ``s[0:4, rows]``, which numpy lays out by columns)."""
    return np.ascontiguousarray(values, dtype=_F64)


def _nonzero(mask: npt.NDArray[np.bool_]) -> npt.NDArray[np.intp]:
    """The indices of a 1-D mask's True entries."""
    return mask.nonzero()[0]


_NO_ROWS = np.zeros(0, np.intp)
_NO_ROWS.flags.writeable = False


@dataclass(frozen=True, slots=True)
class Track:
    """A track reported for a frame: its id, its box (x1 y1 x2 y2) and the index of the input
    box it was matched to in this frame (None where the box is the filter's prediction)."""

    id: int
    box: tuple[float, float, float, float]
    detection: int | None


def _tracks(reported: Reported) -> list[Track]:
    ids, columns, dets = reported
    return [
        Track(i, box, None if d < 0 else d)
        for i, box, d in zip(ids, zip(*columns, strict=True), dets, strict=True)
    ]


def _columns(boxes: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Boxes (N x 4) as four rows x1 y1 x2 y2 (4 x N), each contiguous."""
    return np.ascontiguousarray(np.asarray(boxes, dtype=_F64).reshape(-1, 4).T)


def _cost(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """-IoU of each box of ``a`` (4 x N, rows x1 y1 x2 y2) with each of ``b`` (4 x M), each row
    contiguous: the intersection's width and height clipped at 0, their product over the
    negated union (the intersection less the sum of the areas), which is -IoU exactly; -0.0
    where that union is not negative (``kernels.cost``)."""
    n, m = a.shape[1], b.shape[1]
    if not (n and m):
        return np.zeros((n, m))
    out: npt.NDArray[np.float64] = kernels.cost(_c(a), _c(b))
    return out


def _iou(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """IoU of each box of ``a`` (4 x N) with each of ``b`` (4 x M); 0 where the union is not
    positive."""
    return np.negative(_cost(a, b))


def box_iou_xyxy(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """IoU of each box of ``a`` (N x 4, x1 y1 x2 y2) with each of ``b`` (M x 4)."""
    return _iou(_columns(a), _columns(b))


def _match(
    cost: npt.NDArray[np.float64], threshold: float
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """One-to-one matches of rows to columns with IoU ≥ ``threshold`` (Hungarian on ``cost``,
    -IoU): the matched rows (ascending) and their columns."""
    if not cost.size:
        return _NO_ROWS, _NO_ROWS
    rows, cols = _assign(cost)  # rows ascending
    picked = cost[rows, cols]
    if not picked.max() <= -threshold:  # IoU >= threshold, the negation being exact
        good = picked <= -threshold
        rows, cols = rows[good], cols[good]
    return rows, cols


def _match_free(
    cost: npt.NDArray[np.float64], threshold: float
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """``_match``'s rows and columns, then the unmatched rows and the unmatched columns
    (ascending)."""
    rows, cols = _match(cost, threshold)
    rows_n, cols_n = cost.shape
    return rows, cols, _free(rows, rows_n), _free(cols, cols_n)


#: ``_at``'s index of every row
_ALL = None


def _at(
    index: npt.NDArray[np.intp] | None, positions: npt.NDArray[np.intp]
) -> npt.NDArray[np.intp]:
    """``index[positions]``; ``positions`` where ``index`` is ``_ALL`` (every row, in order)."""
    return positions if index is None else index[positions]


def _cols(
    values: npt.NDArray[np.float64], index: npt.NDArray[np.intp] | None
) -> npt.NDArray[np.float64]:
    """The columns ``index`` of ``values``; all of them for ``_ALL``."""
    return values if index is None else values[:, index]


def _free(taken: npt.NDArray[np.intp], n: int) -> npt.NDArray[np.intp]:
    """The indices below ``n`` not in ``taken`` (distinct), ascending."""
    if len(taken) == n:
        return _NO_ROWS
    free = np.ones(n, bool)
    free[taken] = False
    return free.nonzero()[0]


class IouTracker:
    """Ids carried by IoU to the previous frame's boxes only."""

    name = 'iou'

    def __init__(self, iou_threshold: float = 0.3) -> None:
        self.iou_threshold = iou_threshold
        self._prev: npt.NDArray[np.float64] = np.zeros((4, 0))
        self._prev_ids: npt.NDArray[np.int64] = np.zeros(0, np.int64)
        self._next = 1

    def update(
        self, boxes: npt.NDArray[np.float64], scores: npt.NDArray[np.float64]
    ) -> list[Track]:
        return _tracks(self.step(boxes, scores))

    def step(self, boxes: npt.ArrayLike, scores: npt.ArrayLike) -> Reported:
        """``update``'s tracks as lists: ids, boxes and input boxes (the tracks' order)."""
        del scores
        now = _columns(boxes)
        n = now.shape[1]
        rows, cols = _match(_cost(self._prev, now), self.iou_threshold)
        new = _free(cols, n)
        ids = np.zeros(n, np.int64)
        ids[cols] = self._prev_ids[rows]
        ids[new] = np.arange(self._next, self._next + len(new))
        self._next += len(new)
        self._prev, self._prev_ids = now, ids
        return ids.tolist(), now.tolist(), list(range(n))


# ---------------------------------------------------------------- SORT

#: Q on rows 8-23 (Paa, Pab, Pba, Pbb): zeros off the diagonal, added as the matrix form adds them
_SORT_Q = np.array([1.0] * 4 + [0.0] * 8 + [0.01, 0.01, 0.0001, 0.0]).reshape(16, 1)
_SORT_R = np.array([[1.0], [1.0], [10.0], [10.0]])
_SORT_PAA = np.array([[10.0], [10.0], [10.0], [10.0]])
_SORT_PBB = np.array([[1e4], [1e4], [1e4], [0.0]])


def _to_z(d: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Boxes (4 x k) as (centre x, centre y, area, aspect ratio)."""
    z: npt.NDArray[np.float64] = kernels.sort_z(_c(d))
    return z


def _from_x(s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """SORT's means (rows 0-3 of ``s``) as boxes (4 x k)."""
    out: npt.NDArray[np.float64] = kernels.sort_boxes(_c(s))
    return out


class SortTracker:
    """SORT: a Kalman filter per track and Hungarian IoU matching to its prediction."""

    name = 'sort'

    def __init__(
        self,
        iou_threshold: float = 0.3,
        max_age: int = 1,
        min_hits: int = 3,
        det_thresh: float = 0.0,
    ) -> None:
        self.iou_threshold = iou_threshold
        self.max_age = max_age
        self.min_hits = min_hits
        self.det_thresh = det_thresh
        self.filters = Filters()
        #: per track: its id, its streak of matches, the frames since its last match and the
        #: input box it was last matched to (-1 for none yet)
        self.counts = np.zeros((4, 0), np.int64)
        self.frame_count = 0
        self._next = 1

    def _keep(self, mask: npt.NDArray[np.bool_]) -> None:
        """Only the tracks of ``mask``: their filters and their counters."""
        self.filters.keep(mask)
        self.counts = self.counts[:, mask]

    def update(
        self, boxes: npt.NDArray[np.float64], scores: npt.NDArray[np.float64]
    ) -> list[Track]:
        return _tracks(self.step(boxes, scores))

    def step(self, boxes: npt.ArrayLike, scores: npt.ArrayLike) -> Reported:
        """``update``'s tracks as lists: ids, boxes and input boxes (in id order)."""
        self.frame_count += 1
        scores = np.asarray(scores, dtype=_F64).reshape(-1)
        dets = _columns(boxes)
        keep = None  # None: every box
        if scores.size and not scores.min() >= self.det_thresh:  # a NaN among them too
            keep = _nonzero(scores >= self.det_thresh)
            dets = dets[:, keep]
        f = self.filters
        s = f.s
        if s.shape[1]:
            ahead = s[6] + s[2]
            if ahead.min() <= 0:  # an area that would go negative stops shrinking
                s[6, ahead <= 0] = 0.0
            f.predict(_SORT_Q)
        pred = _from_x(s)
        if not math.isfinite(pred.sum()):  # a NaN or an infinity (or a finite sum's overflow)
            alive = np.all(np.isfinite(pred), axis=0)
            self._keep(alive)
            pred = pred[:, alive]
        n = dets.shape[1]
        d_rows, t_rows = _match(_cost(dets, pred), self.iou_threshold)
        new = _free(d_rows, n)
        # the counters: a streak ends with a frame unmatched; the frames since the last match
        # count on; a matched track's streak grows and its count restarts at 0
        counts = self.counts
        k, m = counts.shape[1], len(d_rows)
        since = counts[2]
        stale = k and since.any()
        if stale:
            counts[1, since > 0] = 0
        if m == k:  # every track matched: t_rows is a permutation
            counts[1] += 1
            if stale:
                since[:] = 0
        else:
            since += 1
            since[t_rows] = 0
            counts[1, t_rows] += 1
        z = _to_z(dets) if n else dets  # every box is matched or new
        if m:  # d_rows ascending: all of them where as many as the boxes
            f.update(t_rows, z if m == n else z[:, d_rows], _SORT_R)
            counts[3, t_rows] = d_rows if keep is None else keep[d_rows]
        if len(new):
            b = len(new)
            f.add(z[:, new], _SORT_PAA, _SORT_PBB)
            born = np.zeros((4, b), np.int64)
            born[0] = np.arange(self._next, self._next + b)
            born[1] = 1
            born[3] = new if keep is None else keep[new]
            self.counts = counts = np.concatenate([counts, born], axis=1)
            self._next += b
        # shown: matched or new this frame (since 0; where every track matched, all of them),
        # past the first min_hits frames with a streak of min_hits
        shown = None  # None: every track
        if m != k:
            shown = counts[2] < 1
        if self.frame_count > self.min_hits and counts.shape[1]:
            streak = counts[1]
            if shown is not None:
                shown &= streak >= self.min_hits
            elif streak.min() < self.min_hits:
                shown = streak >= self.min_hits
        # in id order: a track's row never moves before an older one's (new tracks are
        # appended with the next id, gone ones removed in place); a shown track's row 3 is its
        # input box of this frame
        if shown is None or shown.all():
            ids, matched = counts[0:4:3].tolist()
            out = (ids, _from_x(f.s).tolist(), matched)
        else:
            rows = _nonzero(shown)
            ids, matched = counts[0:4:3, rows].tolist()
            out = (ids, _from_x(f.s[0:4, rows]).tolist(), matched)
        if m != k or self.max_age < 0:  # else every count is 0
            alive = counts[2] <= self.max_age
            if not alive.all():
                self._keep(alive)
        return out


# ---------------------------------------------------------------- ByteTrack

_STD_POS = 1.0 / 20
_STD_VEL = 1.0 / 160
_VAR_A = 1e-2 * 1e-2  # the aspect ratio's process noise
_VAR_VA = 1e-5 * 1e-5  # its velocity's
_VAR_RA = 1e-1 * 1e-1  # its measurement noise
#: Q's standard deviations on rows 8-23 per unit of height (the aspect ratio's set apart)
_BT_STD = np.array([_STD_POS] * 2 + [0.0, _STD_POS] + [0.0] * 8 + [_STD_VEL] * 2 + [0.0, _STD_VEL])
#: the aspect ratio's variances, rows 2 and 14 of Q (``2:15:12``)
_BT_VAR_A = np.array([[_VAR_A], [_VAR_VA]])
#: R's standard deviations per unit of height (the aspect ratio's set apart)
_BT_R_STD = np.array([_STD_POS, _STD_POS, 0.0, _STD_POS])


def _bt_noise(heights: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """ByteTrack's measurement noise variances (4 x k) for filters of these heights (row 3 of
    their means): (h / 20)^2 but the aspect ratio's 0.01."""
    r: npt.NDArray[np.float64] = np.multiply.outer(_BT_R_STD, heights)
    r *= r
    r[2] = _VAR_RA
    return r


def _xyah(d: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Boxes (4 x k) as (centre x, centre y, aspect ratio, height)."""
    z: npt.NDArray[np.float64] = kernels.bt_xyah(_c(d))
    return z


def _xyxy(m: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """ByteTrack's means (rows 0-3 of ``m``) as boxes (4 x k)."""
    out: npt.NDArray[np.float64] = kernels.bt_boxes(_c(m))
    return out


_ID, _LAST, _CONFIRMED, _LOST, _USED = range(5)


class ByteTrackTracker:
    """ByteTrack: high-score boxes first, then the low-score ones for the tracks left."""

    name = 'bytetrack'

    def __init__(
        self,
        track_thresh: float = 0.5,
        low_thresh: float = 0.1,
        match_thresh: float = 0.8,
        track_buffer: int = 30,
    ) -> None:
        self.track_thresh = track_thresh
        self.low_thresh = low_thresh
        self.match_thresh = match_thresh
        self.track_buffer = track_buffer
        self.filters = Filters()
        #: per track: its id, the frame of its last match, confirmed (0/1), lost (0/1), the
        #: input box of its last match
        self.state = np.zeros((5, 0), np.int64)
        self.frame = 0
        self._next = 1

    def update(
        self, boxes: npt.NDArray[np.float64], scores: npt.NDArray[np.float64]
    ) -> list[Track]:
        return _tracks(self.step(boxes, scores))

    def step(self, boxes: npt.ArrayLike, scores: npt.ArrayLike) -> Reported:
        """``update``'s tracks as lists: ids, boxes and input boxes (in id order)."""
        self.frame += 1
        d = _columns(boxes)
        scores = np.asarray(scores, dtype=_F64).reshape(-1)
        is_high = scores >= self.track_thresh
        high = _nonzero(is_high)
        low = _NO_ROWS
        if len(high) < len(scores):
            low = _nonzero((scores >= self.low_thresh) & ~is_high)
        f, state = self.filters, self.state
        s = f.s
        n = s.shape[1]
        lost = state[_LOST] != 0
        if n:
            s[7, lost] = 0.0
            q = np.multiply.outer(_BT_STD, s[3])  # the standard deviations, scaled by the height
            q *= q
            q[2:15:12] = _BT_VAR_A
            f.predict(q)
        current = _xyxy(s)
        every = n == 0 or state[_CONFIRMED].min() != 0  # then confirmed is every row
        if every:
            confirmed, unconfirmed = _ALL, _NO_ROWS
        else:
            confirmed_now = state[_CONFIRMED] != 0
            confirmed, unconfirmed = _nonzero(confirmed_now), _nonzero(~confirmed_now)
        # 1: the high boxes against every confirmed track, active or lost
        high_all = len(high) == d.shape[1]
        t1, d1, left_tracks, left_high = _match_free(
            _cost(_cols(current, confirmed), d if high_all else d[:, high]), 1.0 - self.match_thresh
        )
        rows = [_at(confirmed, t1)]
        took = [d1 if high_all else high[d1]]
        # 2: the low boxes against the active tracks still unmatched
        if len(left_tracks):
            remaining = _at(confirmed, left_tracks)
            remaining = remaining[~lost[remaining]]
            if len(low):
                t2, d2 = _match(_cost(current[:, remaining], d[:, low]), 0.5)
                state[_LOST, remaining[_free(t2, len(remaining))]] = 1
                rows.append(remaining[t2])
                took.append(low[d2])
            else:
                state[_LOST, remaining] = 1
        # 3: unconfirmed tracks against the high boxes left (IoU >= 0.3)
        rest = high[left_high]
        dead = left_new = _NO_ROWS
        if len(unconfirmed):
            t3, d3, dead, left_new = _match_free(_cost(current[:, unconfirmed], d[:, rest]), 0.3)
            rows.append(unconfirmed[t3])
            took.append(rest[d3])
        else:
            left_new = np.arange(len(rest))
        rows_a = rows[0] if len(rows) == 1 else np.concatenate(rows)
        took_a = took[0] if len(took) == 1 else np.concatenate(took)
        if len(rows_a):  # the three stages' rows are distinct: one update for all
            f.update(rows_a, _xyah(d[:, took_a]), _bt_noise(f.s[3, rows_a]))
            state[_LAST : _LOST + 1, rows_a] = ((self.frame,), (1,), (0,))  # confirmed, not lost
            state[_USED, rows_a] = took_a
        # 4: new tracks from the high boxes no track took
        born = rest[left_new]
        if len(born):
            born = born[scores[born] >= self.track_thresh + 0.1]
        if len(born):
            k = len(born)
            z = _xyah(d[:, born])
            a, b = (2 * _STD_POS) * z[3], (10 * _STD_VEL) * z[3]
            a *= a
            b *= b
            f.add(
                z, np.stack([a, a, np.full(k, _VAR_A), a]), np.stack([b, b, np.full(k, _VAR_VA), b])
            )
            new = np.zeros((5, k), np.int64)
            new[_ID] = np.arange(self._next, self._next + k)
            new[_LAST] = self.frame
            new[_CONFIRMED] = self.frame == 1
            new[_USED] = born
            self.state = state = np.concatenate([state, new], axis=1)
            self._next += k
        # shown: confirmed and matched in this frame (so not lost, and not removed, whose
        # unconfirmed tracks were not matched); their row _USED is their input box of this frame
        last = state[_LAST]
        shown = last * state[_CONFIRMED] == self.frame  # confirmed is 0 or 1, the frame >= 1
        # in id order: rows are kept in the order the tracks were made
        if shown.all():
            ids, used = state[0:5:4].tolist()
            out = (ids, _xyxy(f.s).tolist(), used)
        else:
            shown_rows = _nonzero(shown)
            ids, used = state[0:5:4, shown_rows].tolist()
            out = (ids, _xyxy(f.s[0:4, shown_rows]).tolist(), used)
        if len(dead) or (len(last) and last.min() < self.frame - self.track_buffer):
            alive = self.frame - last <= self.track_buffer
            alive[unconfirmed[dead]] = False
            f.keep(alive)
            self.state = state[:, alive]
        return out


_TRACKERS = {'iou': IouTracker, 'sort': SortTracker, 'bytetrack': ByteTrackTracker}


def make_tracker(name: str, **params: float) -> IouTracker | SortTracker | ByteTrackTracker:
    """A new tracker by name (``iou``, ``sort``, ``bytetrack``) with its parameters.
    ``ValueError`` naming the known trackers for another name or an unknown parameter."""
    cls = _TRACKERS.get(name)
    if cls is None:
        msg = f'unknown tracker {name!r}; known: {", ".join(_TRACKERS)}'
        raise ValueError(msg)
    try:
        made: IouTracker | SortTracker | ByteTrackTracker = cls(**params)
    except TypeError as err:
        msg = f'tracker {name!r}: {err}'
        raise ValueError(msg) from None
    return made
