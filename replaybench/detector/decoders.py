"""Model outputs -> boxes, scores and classes (numpy), class-aware NMS, and Detections.

Every decoder returns ``(boxes, scores, class_ids)``: float32 ``[K, 4]`` x0, y0, x1, y1 in
model-input pixels, float32 ``[K]``, int64 ``[K]``. Dense heads are decoded multi-label: every
(candidate, class) pair whose score is above ``conf`` is kept (as YOLOX's demo and
``check_model.py`` do), in row-major order (candidate, then class). Only the candidates that
pass the threshold are decoded.

Layouts:

* ``decode_yolox``: ``[1, N, 5+C]`` raw grid (x, y, log w, log h, obj, classes; obj and classes
  already sigmoid); ``xy = (xy + grid) * stride``, ``wh = exp(wh) * stride``; score = obj * cls.
* ``decode_yolov5``: ``[1, N, 5+C]`` decoded cx, cy, w, h, obj, classes; score = obj * cls.
* ``decode_yolov8``: ``[1, 4+C, N]`` decoded cx, cy, w, h, classes (no objectness).
* ``decode_nms``: detections after NMS in the graph (see its docstring).

Non-finite outputs: a candidate (a row of a dense head, a detection of an NMS head) is left
out when a value the decoder reads for it is NaN or +-inf: its objectness, its best score
(objectness x best class score), its box, or (NMS heads) its score or class; decoding that
overflows to inf (YOLOX's ``exp(log w)``) counts too. A NaN score is never below ``conf`` and
is read; values a threshold has already rejected are not: the class scores of a row whose
objectness is at most ``conf`` (-inf included), the box of a candidate scored at most
``conf``. ``postprocess`` counts the candidates left out in a ``NonfiniteTally``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np

from replaybench.detector.preprocess import boxes_to_source
from replaybench.detector.spec import STRIDES, grid_points
from replaybench.errors import BackendError
from replaybench.types import Detection

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

    from replaybench.detector.preprocess import Transform
    from replaybench.detector.spec import ModelSpec

__all__ = [
    'MAX_CANDIDATES',
    'MAX_DETECTIONS',
    'Decoded',
    'NonfiniteTally',
    'decode',
    'decode_nms',
    'decode_yolov5',
    'decode_yolov8',
    'decode_yolox',
    'nms',
    'postprocess',
    'yolox_grid',
]

F32 = np.float32
#: (boxes [K, 4] x0 y0 x1 y1, scores [K], class ids [K]).
Decoded: TypeAlias = (
    'tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.int64]]'
)
#: Most detections kept per frame after NMS.
MAX_DETECTIONS = 300
#: Most (box, class) candidates NMS considers, the highest scores first.
MAX_CANDIDATES = 30000


@dataclass(slots=True)
class NonfiniteTally:
    """Candidates left out because the model gave NaN or inf for them, over a run.

    ``dropped``: candidates (rows of a dense head, detections of an NMS head); ``frames``:
    frames that had at least one. A backend keeps one and reports ``info()`` in run.json.
    """

    dropped: int = 0
    frames: int = 0

    def add(self, dropped: int) -> None:
        """Count one frame's non-finite candidates (nothing when there were none)."""
        if dropped:
            self.dropped += dropped
            self.frames += 1

    def reset(self) -> None:
        """Start counting again (after detects that are not part of the run)."""
        self.dropped = 0
        self.frames = 0

    def info(self) -> dict[str, int]:
        """``nonfinite_dropped`` and ``nonfinite_frames`` for a backend's ``info()``."""
        return {'nonfinite_dropped': self.dropped, 'nonfinite_frames': self.frames}


def _quiet() -> np.errstate:
    """NaN / inf arithmetic on model outputs is expected (and left out): no RuntimeWarnings."""
    return np.errstate(over='ignore', invalid='ignore')


def _empty() -> Decoded:
    return np.zeros((0, 4), F32), np.zeros(0, F32), np.zeros(0, np.int64)


def _finite(
    boxes: npt.NDArray[np.float32],
    scores: npt.NDArray[np.float32],
    classes: npt.NDArray[np.int64],
    rows: npt.NDArray[np.intp],
) -> tuple[Decoded, int]:
    """The (row, class) pairs whose decoded boxes are finite, and the rows left out.

    Scores are finite already (``_pairs``); a row's pairs share its box, so a row counts once.
    """
    if math.isfinite(boxes.sum()):
        return (boxes, scores, classes), 0
    ok = np.isfinite(boxes).all(axis=1)
    lost = np.unique(rows[~ok])
    return (boxes[ok], scores[ok], classes[ok]), int(lost.size)


def _xywh_to_xyxy(xywh: npt.NDArray[Any]) -> npt.NDArray[np.float32]:
    boxes = np.empty((xywh.shape[0], 4), F32)
    half = xywh[:, 2:4] * F32(0.5)
    np.subtract(xywh[:, 0:2], half, out=boxes[:, 0:2], casting='unsafe')
    np.add(xywh[:, 0:2], half, out=boxes[:, 2:4], casting='unsafe')
    return boxes


def _rank3(out: npt.NDArray[Any], what: str) -> npt.NDArray[Any]:
    if out.ndim == 2:
        out = out[None]
    if out.ndim != 3 or out.shape[0] != 1:
        msg = f'{what}: expected an output of shape [1, ., .], got {list(out.shape)}'
        raise BackendError(msg)
    return out


def _above(best: npt.NDArray[Any], conf: float) -> tuple[npt.NDArray[np.bool_], int]:
    """Which best scores are above ``conf`` and finite; how many NaN / inf ones were read."""
    if math.isfinite(best.sum()):  # the usual case: nothing NaN or inf (or a sum overflow)
        return best > conf, 0
    read = ~(best <= conf)  # above conf, or NaN
    finite = np.isfinite(best)
    return read & finite, int(np.count_nonzero(read & ~finite))


def _pairs(
    cls: npt.NDArray[Any], obj: npt.NDArray[Any] | None, conf: float
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.int64], npt.NDArray[np.float32], int]:
    """Rows, classes and scores of every (row, class) with ``obj * cls > conf`` (row-major).

    ``cls`` is ``[N, C]`` (may be a strided view); ``obj`` ``[N]`` or None. Both hold
    probabilities (0..1, sigmoid applied in the graph). Rows whose best score (``obj`` x the
    best class score) is NaN or above ``conf`` are read; those of them with a NaN or inf
    objectness or best score are left out and counted (the last item). ``max`` propagates
    NaN, so one NaN class score makes the best score NaN. Call under ``np.errstate``.
    """
    if obj is not None:
        # scores are probabilities: obj * cls > conf needs obj > conf (a cheap first cut)
        rows = np.flatnonzero(~(obj <= conf))  # above conf, or NaN
        keep, bad = _above(cls[rows].max(axis=1) * obj[rows], conf)
        rows = rows[keep]
    else:
        keep, bad = _above(cls.max(axis=1), conf)
        rows = np.flatnonzero(keep)
    sub = cls[rows].astype(F32, copy=False)
    if obj is not None:
        sub = sub * obj[rows, None]
    r, c = np.nonzero(sub > conf)
    return rows[r], c.astype(np.int64), sub[r, c].astype(F32, copy=False), bad


@lru_cache(maxsize=8)
def yolox_grid(
    size: tuple[int, int], strides: tuple[int, ...] = STRIDES
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Grid cell (x, y) ``[N, 2]`` and stride ``[N, 1]`` of each YOLOX output row (read-only)."""
    grids = []
    steps = []
    for s in strides:
        gw, gh = size[0] // s, size[1] // s
        xv, yv = np.meshgrid(np.arange(gw, dtype=F32), np.arange(gh, dtype=F32))
        grids.append(np.stack((xv, yv), axis=2).reshape(-1, 2))
        steps.append(np.full((gw * gh, 1), s, dtype=F32))
    grid, stride = np.concatenate(grids), np.concatenate(steps)
    grid.flags.writeable = False
    stride.flags.writeable = False
    return grid, stride


def decode_yolox(
    out: npt.NDArray[Any],
    size: tuple[int, int],
    strides: Sequence[int] = STRIDES,
    conf: float = 0.0,
) -> Decoded:
    """YOLOX raw grid output ``[1, N, 5+C]``, input ``size`` (w, h)."""
    with _quiet():
        return _yolox(out, size, strides, conf)[0]


def _yolox(
    out: npt.NDArray[Any], size: tuple[int, int], strides: Sequence[int], conf: float
) -> tuple[Decoded, int]:
    out = _rank3(out, 'yolox')[0]
    grid, stride = yolox_grid((int(size[0]), int(size[1])), tuple(strides))
    if out.shape[0] != grid.shape[0]:
        msg = (
            f'yolox: output has {out.shape[0]} rows; a {size[0]}x{size[1]} input with strides '
            f'{", ".join(map(str, strides))} gives {grid_points(size, strides)}'
        )
        raise BackendError(msg)
    if out.shape[1] < 6:
        msg = f'yolox: output rows have {out.shape[1]} values; expected 5 + classes'
        raise BackendError(msg)
    rows, classes, scores, bad = _pairs(out[:, 5:], out[:, 4], conf)
    if rows.size == 0:
        return _empty(), bad
    picked = out[rows, :4].astype(F32)
    s = stride[rows]
    xywh = np.empty_like(picked)
    xywh[:, 0:2] = (picked[:, 0:2] + grid[rows]) * s
    xywh[:, 2:4] = np.exp(picked[:, 2:4]) * s
    decoded, lost = _finite(_xywh_to_xyxy(xywh), scores, classes, rows)
    return decoded, bad + lost


def decode_yolov5(out: npt.NDArray[Any], conf: float = 0.0) -> Decoded:
    """YOLOv5 / YOLOv7 decoded output ``[1, N, 5+C]`` (cx, cy, w, h, obj, classes)."""
    with _quiet():
        return _yolov5(out, conf)[0]


def _yolov5(out: npt.NDArray[Any], conf: float) -> tuple[Decoded, int]:
    out = _rank3(out, 'yolov5')[0]
    if out.shape[1] < 6:
        msg = f'yolov5: output rows have {out.shape[1]} values; expected 5 + classes'
        raise BackendError(msg)
    rows, classes, scores, bad = _pairs(out[:, 5:], out[:, 4], conf)
    if rows.size == 0:
        return _empty(), bad
    decoded, lost = _finite(_xywh_to_xyxy(out[rows, :4]), scores, classes, rows)
    return decoded, bad + lost


def decode_yolov8(out: npt.NDArray[Any], conf: float = 0.0) -> Decoded:
    """YOLOv8 / YOLO11 output ``[1, 4+C, N]`` (cx, cy, w, h, classes; no objectness)."""
    with _quiet():
        return _yolov8(out, conf)[0]


def _yolov8(out: npt.NDArray[Any], conf: float) -> tuple[Decoded, int]:
    out = _rank3(out, 'yolov8')[0]
    if out.shape[0] < 5:
        msg = f'yolov8: output has {out.shape[0]} channels; expected 4 + classes'
        raise BackendError(msg)
    rows, classes, scores, bad = _pairs(out[4:].T, None, conf)
    if rows.size == 0:
        return _empty(), bad
    decoded, lost = _finite(_xywh_to_xyxy(out[:4, rows].T), scores, classes, rows)
    return decoded, bad + lost


def _find(outputs: Mapping[str, npt.NDArray[Any]], words: Sequence[str]) -> str | None:
    for name in outputs:
        low = name.lower()
        if any(word in low for word in words):
            return name
    return None


def decode_nms(outputs: Mapping[str, npt.NDArray[Any]], conf: float = 0.0) -> Decoded:
    """Detections of a model with NMS in the graph; boxes are x0, y0, x1, y1 input pixels.

    Layouts (batch 1):

    * one output ``[K, 6]`` or ``[1, K, 6]``: x0, y0, x1, y1, score, class (Ultralytics
      ``nms=True`` / end-to-end heads, YOLOv10);
    * one output ``[K, 7]`` or ``[1, K, 7]``: batch, x0, y0, x1, y1, class, score (YOLOv7
      ``--end2end`` with onnxruntime NMS);
    * several outputs: boxes ``[1, K, 4]`` / ``[K, 4]``; scores ``[1, K]`` / ``[K]`` (name
      containing ``score``); classes (name containing ``class`` or ``label``); optionally a
      count (name containing ``num``, e.g. ``num_dets`` ``[1, 1]``) that limits K (TensorRT
      EfficientNMS-style ``num_dets, det_boxes, det_scores, det_classes``).
    """
    with _quiet():
        return _nms_head(outputs, conf)[0]


def _nms_head(outputs: Mapping[str, npt.NDArray[Any]], conf: float) -> tuple[Decoded, int]:
    if len(outputs) == 1:
        (arr,) = outputs.values()
        det = np.asarray(arr)
        if det.ndim == 3 and det.shape[0] == 1:
            det = det[0]
        if det.ndim != 2 or det.shape[1] not in (6, 7):
            msg = f'nms: one output must be [K, 6] or [K, 7], got {list(np.shape(arr))}'
            raise BackendError(msg)
        det = det.astype(F32, copy=False)
        if det.shape[1] == 6:
            boxes, scores, classes = det[:, 0:4], det[:, 4], det[:, 5]
        else:
            det = det[det[:, 0] == 0]
            boxes, scores, classes = det[:, 1:5], det[:, 6], det[:, 5]
    else:
        boxes_name = None
        for name, arr in outputs.items():
            if np.ndim(arr) in (2, 3) and np.shape(arr)[-1] == 4:
                boxes_name = name
                break
        scores_name = _find(outputs, ('score', 'conf'))
        classes_name = _find(outputs, ('class', 'label'))
        if boxes_name is None or scores_name is None or classes_name is None:
            msg = (
                f'nms: outputs {", ".join(outputs)}: need boxes [K, 4], scores (name with '
                '"score") and classes (name with "class" or "label")'
            )
            raise BackendError(msg)
        boxes = np.asarray(outputs[boxes_name], dtype=F32).reshape(-1, 4)
        scores = np.asarray(outputs[scores_name], dtype=F32).reshape(-1)
        classes = np.asarray(outputs[classes_name]).reshape(-1)
        count = min(boxes.shape[0], scores.shape[0], classes.shape[0])
        num_name = _find(outputs, ('num',))
        if num_name is not None and num_name not in (boxes_name, scores_name, classes_name):
            num = np.asarray(outputs[num_name]).reshape(-1)
            if num.size and np.isfinite(num[0]):  # a NaN count limits nothing
                count = min(count, max(int(num[0]), 0))
        boxes, scores, classes = boxes[:count], scores[:count], classes[:count]
    keep = ~(scores <= conf)  # above conf, or NaN: read further
    ok = np.isfinite(boxes).all(axis=1) & np.isfinite(scores)
    if classes.dtype.kind == 'f':
        ok &= np.isfinite(classes)
    bad = int(np.count_nonzero(keep & ~ok))
    keep &= ok
    return (
        np.ascontiguousarray(boxes[keep], dtype=F32),
        np.ascontiguousarray(scores[keep], dtype=F32),
        classes[keep].astype(np.int64),
    ), bad


def nms(
    boxes: npt.NDArray[np.floating[Any]],
    scores: npt.NDArray[np.floating[Any]],
    class_ids: npt.NDArray[np.integer[Any]],
    iou: float,
    max_det: int | None = None,
) -> npt.NDArray[np.int64]:
    """Indices kept by greedy class-aware NMS, best first.

    Order: score descending, ties by class, x0, y0, x1, y1, then input index, so equal inputs
    give equal results. A box is dropped when its IoU (continuous, no +1) with a kept box of
    the same class is above ``iou``. At most ``MAX_CANDIDATES`` are considered and
    ``max_det`` kept.
    """
    n = int(scores.shape[0])
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    b = np.asarray(boxes, dtype=np.float64)
    order = np.lexsort(
        (np.arange(n), b[:, 3], b[:, 2], b[:, 1], b[:, 0], class_ids, -np.asarray(scores))
    )[:MAX_CANDIDATES]
    b = b[order]
    cls = np.asarray(class_ids)[order]
    areas = np.maximum(b[:, 2] - b[:, 0], 0) * np.maximum(b[:, 3] - b[:, 1], 0)
    keep: list[int] = []
    remaining = np.arange(order.shape[0])
    limit = max_det if max_det is not None else order.shape[0]
    while remaining.size and len(keep) < limit:
        i = int(remaining[0])
        keep.append(i)
        rest = remaining[1:]
        if rest.size == 0:
            break
        same = cls[rest] == cls[i]
        cand = rest[same]
        w = np.minimum(b[i, 2], b[cand, 2]) - np.maximum(b[i, 0], b[cand, 0])
        h = np.minimum(b[i, 3], b[cand, 3]) - np.maximum(b[i, 1], b[cand, 1])
        inter = np.maximum(w, 0) * np.maximum(h, 0)
        union = areas[i] + areas[cand] - inter
        overlap = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
        suppressed = np.zeros(rest.shape[0], dtype=bool)
        suppressed[np.flatnonzero(same)[overlap > iou]] = True
        remaining = rest[~suppressed]
    return order[np.asarray(keep, dtype=np.int64)]


def decode(outputs: Mapping[str, npt.NDArray[Any]], spec: ModelSpec, conf: float) -> Decoded:
    """The family decoder of ``spec`` applied to ``outputs`` (name -> array)."""
    return _decode(outputs, spec, conf)[0]


def _decode(
    outputs: Mapping[str, npt.NDArray[Any]], spec: ModelSpec, conf: float
) -> tuple[Decoded, int]:
    """``decode`` and the number of candidates left out for NaN / inf values."""
    family = spec.family
    with _quiet():
        if family == 'nms':
            return _nms_head(outputs, conf)
        out = outputs[spec.output_names[0]]
        if family == 'yolox':
            return _yolox(out, spec.preprocess.size, STRIDES, conf)
        if family == 'yolov5':
            return _yolov5(out, conf)
        if family == 'yolov8':
            return _yolov8(out, conf)
    msg = f'unknown model family {family!r}'
    raise BackendError(msg)


def _sort_key(det: Detection) -> tuple[float, int, float, float]:
    return (-det.score, det.class_index, det.x0, det.y0)


def postprocess(
    outputs: Mapping[str, npt.NDArray[Any]],
    spec: ModelSpec,
    transform: Transform,
    conf: float,
    iou: float,
    max_det: int = MAX_DETECTIONS,
    tally: NonfiniteTally | None = None,
) -> tuple[Detection, ...]:
    """Decode, NMS (not for ``nms`` models: done in the graph), map to source pixels, label.

    Boxes left empty by clipping to the image are dropped. Sorted by (-score, class, x0, y0).
    Candidates with NaN or inf values are left out and counted in ``tally`` when given.
    """
    (boxes, scores, classes), nonfinite = _decode(outputs, spec, conf)
    if tally is not None:
        tally.add(nonfinite)
    if scores.shape[0] == 0:
        return ()
    if spec.family == 'nms':
        keep = np.lexsort((np.arange(scores.shape[0]), -scores))[:max_det]
    else:
        keep = nms(boxes, scores, classes, iou, max_det)
    src = boxes_to_source(boxes[keep], transform).tolist()
    names = spec.class_names
    n_names = len(names)
    detections = []
    for (x0, y0, x1, y1), score, cid in zip(
        src, scores[keep].tolist(), classes[keep].tolist(), strict=True
    ):
        if x1 <= x0 or y1 <= y0:
            continue
        label = names[cid] if 0 <= cid < n_names else str(cid)
        detections.append(Detection(cid, label, score, x0, y0, x1, y1))
    detections.sort(key=_sort_key)
    return tuple(detections)
