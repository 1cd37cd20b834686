"""The trackers as they were before their Kalman filters became elementwise 2x2 blocks
(replaybench/tracking/trackers.py at commit 76421b2), frozen here as the reference the
current ones are tested against (test_trackers_reference.py): the same ids frame by frame and
the same boxes to 1e-6 px. Only the solver import differs: SciPy's ``linear_sum_assignment``
directly, which ``replaybench.tracking.metrics._assign`` calls.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import linear_sum_assignment as _assign

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ['ByteTrackTracker', 'IouTracker', 'SortTracker', 'Track', 'box_iou_xyxy', 'make_tracker']


@dataclass(frozen=True, slots=True)
class Track:
    """A track reported for a frame: its id, its box (x1 y1 x2 y2) and the index of the input
    box it was matched to in this frame (None where the box is the filter's prediction)."""

    id: int
    box: tuple[float, float, float, float]
    detection: int | None


def box_iou_xyxy(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """IoU of each box of ``a`` (N x 4, x1 y1 x2 y2) with each of ``b`` (M x 4)."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    x1 = np.maximum(a[:, None, 0], b[None, :, 0])
    y1 = np.maximum(a[:, None, 1], b[None, :, 1])
    x2 = np.minimum(a[:, None, 2], b[None, :, 2])
    y2 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.maximum(x2 - x1, 0.0) * np.maximum(y2 - y1, 0.0)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    out: npt.NDArray[np.float64] = np.zeros_like(inter)
    np.divide(inter, union, out=out, where=union > 0)
    return out


def _match(
    iou: npt.NDArray[np.float64], threshold: float
) -> tuple[list[tuple[int, int]], list[int], list[int]]:
    """One-to-one matches of rows to columns with IoU ≥ ``threshold`` (Hungarian on -IoU), the
    unmatched rows and the unmatched columns, each in increasing order."""
    rows_n, cols_n = iou.shape
    if not (rows_n and cols_n):
        return [], list(range(rows_n)), list(range(cols_n))
    rows, cols = _assign(-iou)  # rows ascending
    good = iou[rows, cols] >= threshold
    rows, cols = rows[good], cols[good]
    free_r = np.ones(rows_n, bool)
    free_r[rows] = False
    free_c = np.ones(cols_n, bool)
    free_c[cols] = False
    return (
        list(zip(rows.tolist(), cols.tolist(), strict=True)),
        np.flatnonzero(free_r).tolist(),
        np.flatnonzero(free_c).tolist(),
    )


def _box(values: npt.NDArray[np.float64]) -> tuple[float, float, float, float]:
    return (float(values[0]), float(values[1]), float(values[2]), float(values[3]))


class IouTracker:
    """Ids carried by IoU to the previous frame's boxes only."""

    name = 'iou'

    def __init__(self, iou_threshold: float = 0.3) -> None:
        self.iou_threshold = iou_threshold
        self._prev: npt.NDArray[np.float64] = np.zeros((0, 4))
        self._prev_ids: list[int] = []
        self._next = 1

    def update(
        self, boxes: npt.NDArray[np.float64], scores: npt.NDArray[np.float64]
    ) -> list[Track]:
        del scores
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        pairs, _, new = _match(box_iou_xyxy(self._prev, boxes), self.iou_threshold)
        ids = [0] * len(boxes)
        for r, c in pairs:
            ids[c] = self._prev_ids[r]
        for c in new:
            ids[c] = self._next
            self._next += 1
        self._prev, self._prev_ids = boxes, ids
        return [Track(ids[i], _box(boxes[i]), i) for i in range(len(boxes))]


# ---------------------------------------------------------------- SORT


_SORT_F = np.eye(7)
_SORT_F[0, 4] = _SORT_F[1, 5] = _SORT_F[2, 6] = 1.0
_SORT_H = np.eye(4, 7)
_SORT_R = np.diag([1.0, 1.0, 10.0, 10.0])
_SORT_Q = np.diag([1.0, 1.0, 1.0, 1.0, 0.01, 0.01, 0.0001])
_SORT_P0 = np.diag([10.0, 10.0, 10.0, 10.0, 1e4, 1e4, 1e4])


class _Bank:
    """The Kalman filters of a tracker's tracks, as one array each: means ``x`` (N x n),
    covariances ``p`` (N x n x n), predicted and updated for every track in one operation."""

    def __init__(self, f: npt.NDArray[np.float64], h: npt.NDArray[np.float64]) -> None:
        self.f = f
        self.h = h
        n = f.shape[0]
        m = h.shape[0]
        #: H measures the first m states (the trackers' H): H P, H P H^T and H x are slices,
        #: the same numbers as the products (every other term is an exact zero), fewer steps
        self.select = m if np.array_equal(h, np.eye(m, n)) else None
        #: F is the identity plus ones off the diagonal, at most one a row (constant velocity):
        #: F x and F P F^T are sums of two terms, added here without the products (the same
        #: numbers: the products add exact zeros)
        off = f - np.eye(n)
        rows, cols = np.nonzero(off)
        simple = bool(np.all(off[rows, cols] == 1.0)) and len(set(rows.tolist())) == len(rows)
        ranges = (
            simple
            and len(rows) > 0
            and np.count_nonzero(off) == len(rows)
            and np.array_equal(rows, np.arange(rows[0], rows[0] + len(rows)))
            and np.array_equal(cols, np.arange(cols[0], cols[0] + len(cols)))
        )
        self.velocity = (
            (slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1))
            if ranges
            else None
        )
        self.x = np.zeros((0, n))
        self.p = np.zeros((0, n, n))

    def add(self, x: npt.NDArray[np.float64], p: npt.NDArray[np.float64]) -> None:
        self.x = np.concatenate([self.x, x.reshape(1, -1)])
        self.p = np.concatenate([self.p, p.reshape(1, *p.shape)])

    def keep(self, mask: npt.NDArray[np.bool_]) -> None:
        self.x, self.p = self.x[mask], self.p[mask]

    def predict(self, q: npt.NDArray[np.float64]) -> None:
        """``q``: the process noise, n x n or N x n x n."""
        if not len(self.x):
            return
        if self.velocity is None:
            self.x = self.x @ self.f.T
            self.p = self.f @ self.p @ self.f.T + q
            return
        rows, cols = self.velocity
        x = self.x.copy()
        x[:, rows] += self.x[:, cols]
        fp = self.p.copy()
        fp[:, rows, :] += self.p[:, cols, :]
        fp[:, :, rows] += fp[:, :, cols]
        fp += q
        self.x, self.p = x, fp

    def update(
        self, rows: npt.NDArray[np.intp], z: npt.NDArray[np.float64], r: npt.NDArray[np.float64]
    ) -> None:
        """Tracks ``rows`` measured ``z`` (len(rows) x m), with noise ``r`` (m x m or per row)."""
        if not len(rows):
            return
        x, p, h, m = self.x[rows], self.p[rows], self.h, self.select
        hp = p[:, :m, :] if m is not None else h @ p
        s = (hp[:, :, :m] if m is not None else hp @ h.T) + r
        k = np.linalg.solve(s, hp).transpose(0, 2, 1)  # P H^T S^-1, S symmetric
        y = z - (x[:, :m] if m is not None else x @ h.T)
        self.x[rows] = x + np.einsum('nij,nj->ni', k, y)
        self.p[rows] = p - k @ s @ k.transpose(0, 2, 1)


def _to_z_all(boxes: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    w, h = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
    return np.stack(
        [boxes[:, 0] + w / 2, boxes[:, 1] + h / 2, w * h, w / np.maximum(h, 1e-9)], axis=1
    )


def _from_x_all(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    area, ratio = np.maximum(x[:, 2], 1e-9), np.maximum(x[:, 3], 1e-9)
    w = np.sqrt(area * ratio)
    h = area / w
    return np.stack([x[:, 0] - w / 2, x[:, 1] - h / 2, x[:, 0] + w / 2, x[:, 1] + h / 2], axis=1)


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
        self.bank = _Bank(_SORT_F, _SORT_H)
        self.ids = np.zeros(0, np.int64)
        self.streak = np.zeros(0, np.int64)
        self.since = np.zeros(0, np.int64)  # frames since the last match
        self.frame_count = 0
        self._next = 1

    def _keep(self, mask: npt.NDArray[np.bool_]) -> None:
        """Only the tracks of ``mask``: their filters and their counters."""
        self.bank.keep(mask)
        self.ids, self.streak, self.since = self.ids[mask], self.streak[mask], self.since[mask]

    def update(
        self, boxes: npt.NDArray[np.float64], scores: npt.NDArray[np.float64]
    ) -> list[Track]:
        self.frame_count += 1
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        scores = np.asarray(scores, dtype=np.float64).reshape(-1)
        keep = np.flatnonzero(scores >= self.det_thresh)
        dets = boxes[keep]
        bank = self.bank
        if len(bank.x):  # an area that would go negative stops shrinking
            bank.x[bank.x[:, 6] + bank.x[:, 2] <= 0, 6] = 0.0
        bank.predict(_SORT_Q)
        self.streak[self.since > 0] = 0
        self.since += 1
        pred = _from_x_all(bank.x)
        alive = np.all(np.isfinite(pred), axis=1)
        if not alive.all():
            self._keep(alive)
            pred = pred[alive]
        pairs, new, _ = _match(box_iou_xyxy(dets, pred), self.iou_threshold)
        matched: dict[int, int] = {}
        if pairs:
            d_rows = np.array([d for d, _ in pairs])
            t_rows = np.array([t for _, t in pairs])
            bank.update(t_rows, _to_z_all(dets[d_rows]), _SORT_R)
            self.since[t_rows] = 0
            self.streak[t_rows] += 1
            matched = dict(zip(t_rows.tolist(), keep[d_rows].tolist(), strict=True))
        for d in new:
            x = np.zeros(7)
            x[:4] = _to_z_all(dets[d : d + 1])[0]
            bank.add(x, _SORT_P0)
            matched[len(self.ids)] = int(keep[d])
            self.ids = np.append(self.ids, self._next)
            self.streak = np.append(self.streak, 1)
            self.since = np.append(self.since, 0)
            self._next += 1
        shown = (self.since < 1) & (
            (self.streak >= self.min_hits) | (self.frame_count <= self.min_hits)
        )
        rows = np.flatnonzero(shown)
        now = _from_x_all(bank.x[rows]).tolist()
        # in id order: a track's row never moves before an older one's (new tracks are
        # appended with the next id, gone ones removed in place)
        out = [
            Track(track_id, (b[0], b[1], b[2], b[3]), matched.get(row))
            for track_id, b, row in zip(self.ids[rows].tolist(), now, rows.tolist(), strict=True)
        ]
        alive = self.since <= self.max_age
        if not alive.all():
            self._keep(alive)
        return out


# ---------------------------------------------------------------- ByteTrack

_STD_POS = 1.0 / 20
_STD_VEL = 1.0 / 160


def _xyah_all(boxes: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    w, h = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
    return np.stack([boxes[:, 0] + w / 2, boxes[:, 1] + h / 2, w / np.maximum(h, 1e-9), h], axis=1)


def _xyxy_all(m: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    w = m[:, 2] * m[:, 3]
    return np.stack(
        [m[:, 0] - w / 2, m[:, 1] - m[:, 3] / 2, m[:, 0] + w / 2, m[:, 1] + m[:, 3] / 2], axis=1
    )


_BT_F = np.eye(8)
for _i in range(4):
    _BT_F[_i, 4 + _i] = 1.0
_BT_H = np.eye(4, 8)


def _diag(std: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """N x k standard deviations as N x k x k diagonal covariances."""
    n, k = std.shape
    out = np.zeros((n, k, k))
    out[:, np.arange(k), np.arange(k)] = std * std
    return out


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
        self.bank = _Bank(_BT_F, _BT_H)
        self.ids = np.zeros(0, np.int64)
        self.confirmed = np.zeros(0, bool)
        self.lost = np.zeros(0, bool)
        self.last = np.zeros(0, np.int64)  # the frame of the last match
        self.frame = 0
        self._next = 1

    def _update(self, rows: list[int], boxes: npt.NDArray[np.float64]) -> None:
        if not rows:
            return
        index = np.array(rows)
        h = self.bank.x[index, 3]
        pos = _STD_POS * h
        r = _diag(np.stack([pos, pos, np.full_like(h, 1e-1), pos], axis=1))
        self.bank.update(index, _xyah_all(boxes), r)
        self.confirmed[index] = True
        self.lost[index] = False
        self.last[index] = self.frame

    def update(
        self, boxes: npt.NDArray[np.float64], scores: npt.NDArray[np.float64]
    ) -> list[Track]:
        self.frame += 1
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        scores = np.asarray(scores, dtype=np.float64).reshape(-1)
        high = np.flatnonzero(scores >= self.track_thresh)
        low = np.flatnonzero((scores >= self.low_thresh) & (scores < self.track_thresh))
        bank = self.bank
        if len(bank.x):
            bank.x[self.lost, 7] = 0.0
            h = bank.x[:, 3]
            pos, vel = _STD_POS * h, _STD_VEL * h
            small = np.full_like(h, 1e-2)
            tiny = np.full_like(h, 1e-5)
            bank.predict(_diag(np.stack([pos, pos, small, pos, vel, vel, tiny, vel], axis=1)))
        current = _xyxy_all(bank.x)
        used: dict[int, int] = {}  # track row -> input box
        confirmed = np.flatnonzero(self.confirmed)
        unconfirmed = np.flatnonzero(~self.confirmed)
        # 1: the high boxes against every confirmed track, active or lost
        pairs, left_tracks, left_high = _match(
            box_iou_xyxy(current[confirmed], boxes[high]), 1.0 - self.match_thresh
        )
        self._update([int(confirmed[t]) for t, _ in pairs], boxes[[high[d] for _, d in pairs]])
        used.update({int(confirmed[t]): int(high[d]) for t, d in pairs})
        # 2: the low boxes against the active tracks still unmatched
        remaining = [int(confirmed[t]) for t in left_tracks if not self.lost[confirmed[t]]]
        pairs, left2, _ = _match(box_iou_xyxy(current[remaining], boxes[low]), 0.5)
        self._update([remaining[t] for t, _ in pairs], boxes[[low[d] for _, d in pairs]])
        used.update({remaining[t]: int(low[d]) for t, d in pairs})
        for t in left2:
            self.lost[remaining[t]] = True
        # 3: unconfirmed tracks against the high boxes left (IoU >= 0.3)
        rest = high[left_high]
        pairs, dead, left_new = _match(box_iou_xyxy(current[unconfirmed], boxes[rest]), 0.3)
        self._update([int(unconfirmed[t]) for t, _ in pairs], boxes[[rest[d] for _, d in pairs]])
        used.update({int(unconfirmed[t]): int(rest[d]) for t, d in pairs})
        removed = np.zeros(len(self.ids), bool)
        removed[[int(unconfirmed[t]) for t in dead]] = True
        # 4: new tracks from the high boxes no track took
        for d in left_new:
            index = int(rest[d])
            if scores[index] < self.track_thresh + 0.1:
                continue
            z = _xyah_all(boxes[index : index + 1])[0]
            hz = z[3]
            std = [2 * _STD_POS * hz, 2 * _STD_POS * hz, 1e-2, 2 * _STD_POS * hz]
            std += [10 * _STD_VEL * hz, 10 * _STD_VEL * hz, 1e-5, 10 * _STD_VEL * hz]
            bank.add(np.r_[z, np.zeros(4)], np.diag(np.square(std)))
            used[len(self.ids)] = index
            self.ids = np.append(self.ids, self._next)
            self.confirmed = np.append(self.confirmed, self.frame == 1)
            self.lost = np.append(self.lost, False)
            self.last = np.append(self.last, self.frame)
            removed = np.append(removed, False)
            self._next += 1
        now = _xyxy_all(bank.x)
        shown = self.confirmed & ~self.lost & (self.last == self.frame) & ~removed
        out = [
            Track(int(self.ids[i]), _box(now[i]), used.get(int(i))) for i in np.flatnonzero(shown)
        ]
        alive = ~removed & (self.frame - self.last <= self.track_buffer)
        if not alive.all():
            bank.keep(alive)
            self.ids, self.confirmed = self.ids[alive], self.confirmed[alive]
            self.lost, self.last = self.lost[alive], self.last[alive]
        return sorted(out, key=lambda t: t.id)


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
