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

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from replaybench.tracking.metrics import _assign

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
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
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
    pairs: list[tuple[int, int]] = []
    if rows_n and cols_n:
        rows, cols = _assign(-iou)
        pairs = sorted(
            (int(r), int(c)) for r, c in zip(rows, cols, strict=True) if iou[r, c] >= threshold
        )
    used_r = {r for r, _ in pairs}
    used_c = {c for _, c in pairs}
    return (
        pairs,
        [r for r in range(rows_n) if r not in used_r],
        [c for c in range(cols_n) if c not in used_c],
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


def _to_z(box: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    w, h = box[2] - box[0], box[3] - box[1]
    return np.array([box[0] + w / 2, box[1] + h / 2, w * h, w / max(h, 1e-9)])


def _from_x(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    area, ratio = max(float(x[2]), 1e-9), max(float(x[3]), 1e-9)
    w = np.sqrt(area * ratio)
    h = area / w
    return np.array([x[0] - w / 2, x[1] - h / 2, x[0] + w / 2, x[1] + h / 2])


_SORT_F = np.eye(7)
_SORT_F[0, 4] = _SORT_F[1, 5] = _SORT_F[2, 6] = 1.0
_SORT_H = np.eye(4, 7)
_SORT_R = np.diag([1.0, 1.0, 10.0, 10.0])
_SORT_Q = np.diag([1.0, 1.0, 1.0, 1.0, 0.01, 0.01, 0.0001])
_SORT_P0 = np.diag([10.0, 10.0, 10.0, 10.0, 1e4, 1e4, 1e4])


class _SortTrack:
    def __init__(self, box: npt.NDArray[np.float64], ident: int) -> None:
        self.x = np.zeros(7)
        self.x[:4] = _to_z(box)
        self.p = _SORT_P0.copy()
        self.id = ident
        self.hits = 1
        self.hit_streak = 1
        self.age = 0
        self.time_since_update = 0

    def predict(self) -> npt.NDArray[np.float64]:
        if self.x[6] + self.x[2] <= 0:
            self.x[6] = 0.0
        self.x = _SORT_F @ self.x
        self.p = _SORT_F @ self.p @ _SORT_F.T + _SORT_Q
        self.age += 1
        if self.time_since_update > 0:
            self.hit_streak = 0
        self.time_since_update += 1
        return _from_x(self.x)

    def update(self, box: npt.NDArray[np.float64]) -> None:
        self.time_since_update = 0
        self.hits += 1
        self.hit_streak += 1
        y = _to_z(box) - _SORT_H @ self.x
        s = _SORT_H @ self.p @ _SORT_H.T + _SORT_R
        k = self.p @ _SORT_H.T @ np.linalg.inv(s)
        self.x = self.x + k @ y
        self.p = (np.eye(7) - k @ _SORT_H) @ self.p


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
        self.tracks: list[_SortTrack] = []
        self.frame_count = 0
        self._next = 1

    def update(
        self, boxes: npt.NDArray[np.float64], scores: npt.NDArray[np.float64]
    ) -> list[Track]:
        self.frame_count += 1
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        scores = np.asarray(scores, dtype=np.float64).reshape(-1)
        keep = np.flatnonzero(scores >= self.det_thresh)
        dets = boxes[keep]
        predicted = [t.predict() for t in self.tracks]
        alive = [i for i, p in enumerate(predicted) if np.all(np.isfinite(p))]
        self.tracks = [self.tracks[i] for i in alive]
        pred = np.array([predicted[i] for i in alive]).reshape(-1, 4)
        pairs, new, _ = _match(box_iou_xyxy(dets, pred), self.iou_threshold)
        matched: dict[int, int] = {}
        for d, t in pairs:
            self.tracks[t].update(dets[d])
            matched[t] = int(keep[d])
        for d in new:
            track = _SortTrack(dets[d], self._next)
            self._next += 1
            matched[len(self.tracks)] = int(keep[d])
            self.tracks.append(track)
        out: list[Track] = []
        for i, track in enumerate(self.tracks):
            if track.time_since_update < 1 and (
                track.hit_streak >= self.min_hits or self.frame_count <= self.min_hits
            ):
                out.append(Track(track.id, _box(_from_x(track.x)), matched.get(i)))
        self.tracks = [t for t in self.tracks if t.time_since_update <= self.max_age]
        return sorted(out, key=lambda t: t.id)


# ---------------------------------------------------------------- ByteTrack

_STD_POS = 1.0 / 20
_STD_VEL = 1.0 / 160


def _xyah(box: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    w, h = box[2] - box[0], box[3] - box[1]
    return np.array([box[0] + w / 2, box[1] + h / 2, w / max(h, 1e-9), h])


def _xyxy(m: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    w = m[2] * m[3]
    return np.array([m[0] - w / 2, m[1] - m[3] / 2, m[0] + w / 2, m[1] + m[3] / 2])


_BT_F = np.eye(8)
for _i in range(4):
    _BT_F[_i, 4 + _i] = 1.0
_BT_H = np.eye(4, 8)


class _ByteTrack:
    def __init__(self, box: npt.NDArray[np.float64], score: float, ident: int, frame: int) -> None:
        z = _xyah(box)
        self.mean = np.r_[z, np.zeros(4)]
        h = z[3]
        std = [2 * _STD_POS * h, 2 * _STD_POS * h, 1e-2, 2 * _STD_POS * h]
        std += [10 * _STD_VEL * h, 10 * _STD_VEL * h, 1e-5, 10 * _STD_VEL * h]
        self.cov = np.diag(np.square(std))
        self.score = score
        self.id = ident
        self.confirmed = frame == 1
        self.lost = False
        self.last_frame = frame

    def predict(self) -> None:
        h = self.mean[3]
        std = [_STD_POS * h, _STD_POS * h, 1e-2, _STD_POS * h]
        std += [_STD_VEL * h, _STD_VEL * h, 1e-5, _STD_VEL * h]
        if self.lost:
            self.mean[7] = 0.0
        self.mean = _BT_F @ self.mean
        self.cov = _BT_F @ self.cov @ _BT_F.T + np.diag(np.square(std))

    def update(self, box: npt.NDArray[np.float64], score: float, frame: int) -> None:
        h = self.mean[3]
        r = np.diag(np.square([_STD_POS * h, _STD_POS * h, 1e-1, _STD_POS * h]))
        s = _BT_H @ self.cov @ _BT_H.T + r
        k = self.cov @ _BT_H.T @ np.linalg.inv(s)
        self.mean = self.mean + k @ (_xyah(box) - _BT_H @ self.mean)
        self.cov = self.cov - k @ s @ k.T
        self.score = score
        self.confirmed = True
        self.lost = False
        self.last_frame = frame

    @property
    def box(self) -> npt.NDArray[np.float64]:
        return _xyxy(self.mean)


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
        self.tracks: list[_ByteTrack] = []
        self.frame = 0
        self._next = 1

    def update(
        self, boxes: npt.NDArray[np.float64], scores: npt.NDArray[np.float64]
    ) -> list[Track]:
        self.frame += 1
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        scores = np.asarray(scores, dtype=np.float64).reshape(-1)
        high = np.flatnonzero(scores >= self.track_thresh)
        low = np.flatnonzero((scores >= self.low_thresh) & (scores < self.track_thresh))
        for track in self.tracks:
            track.predict()
        confirmed = [t for t in self.tracks if t.confirmed]
        unconfirmed = [t for t in self.tracks if not t.confirmed]
        used: dict[int, int] = {}  # track id -> input box

        def boxes_of(tracks: list[_ByteTrack]) -> npt.NDArray[np.float64]:
            return np.array([t.box for t in tracks]).reshape(-1, 4)

        # 1: the high boxes against every confirmed track, active or lost
        pairs, left_tracks, left_high = _match(
            box_iou_xyxy(boxes_of(confirmed), boxes[high]), 1.0 - self.match_thresh
        )
        for t, d in pairs:
            confirmed[t].update(boxes[high[d]], float(scores[high[d]]), self.frame)
            used[confirmed[t].id] = int(high[d])
        # 2: the low boxes against the active tracks still unmatched
        remaining = [confirmed[t] for t in left_tracks if not confirmed[t].lost]
        pairs, left2, _ = _match(box_iou_xyxy(boxes_of(remaining), boxes[low]), 0.5)
        for t, d in pairs:
            remaining[t].update(boxes[low[d]], float(scores[low[d]]), self.frame)
            used[remaining[t].id] = int(low[d])
        for t in left2:
            remaining[t].lost = True
        # 3: unconfirmed tracks against the high boxes left (IoU >= 0.3)
        rest = high[left_high]
        pairs, dead, left_new = _match(box_iou_xyxy(boxes_of(unconfirmed), boxes[rest]), 0.3)
        for t, d in pairs:
            unconfirmed[t].update(boxes[rest[d]], float(scores[rest[d]]), self.frame)
            used[unconfirmed[t].id] = int(rest[d])
        removed = {unconfirmed[t].id for t in dead}
        # 4: new tracks from the high boxes no track took
        for d in left_new:
            index = int(rest[d])
            if scores[index] >= self.track_thresh + 0.1:
                track = _ByteTrack(boxes[index], float(scores[index]), self._next, self.frame)
                self._next += 1
                self.tracks.append(track)
                used[track.id] = index
        self.tracks = [
            t
            for t in self.tracks
            if t.id not in removed and self.frame - t.last_frame <= self.track_buffer
        ]
        return sorted(
            (
                Track(t.id, _box(t.box), used.get(t.id))
                for t in self.tracks
                if t.confirmed and not t.lost and t.last_frame == self.frame
            ),
            key=lambda t: t.id,
        )


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
