"""The detector's pre- and post-processing in torch ops, on whatever device the tensors are on.

They mirror ``replaybench.detector`` (``preprocess.Letterboxer``, ``decoders``) step by step so
that the GPU backends give the same detections as ``onnx-cpu``; being device-agnostic, they are
tested on the CPU against the numpy versions. torch is imported by the caller and passed in
as ``torch``, so importing this module imports nothing heavy. torchvision is not used.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.detector.decoders import MAX_CANDIDATES
from replaybench.detector.spec import STRIDES
from replaybench.errors import BackendError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.detector.preprocess import Transform
    from replaybench.detector.spec import Preprocess

__all__ = [
    'NMS_CHUNK',
    'batched_nms',
    'boxes_to_source',
    'decode',
    'decode_yolov5',
    'decode_yolov8',
    'decode_yolox',
    'letterbox_into',
    'normaliser',
    'yolox_grid',
]

Tensor = Any  # torch.Tensor; torch is optional, so it is not named in annotations
#: Candidates compared at once in ``batched_nms`` (a chunk x chunk bool matrix).
NMS_CHUNK = 2048


def normaliser(torch: Any, pre: Preprocess, device: Any) -> tuple[Tensor, Tensor]:
    """Per-channel gain and offset ``[1, 3, 1, 1]``: ``value = pixel * gain + offset``."""
    gains = [pre.scale / s for s in pre.std]
    offsets = [-m / s for m, s in zip(pre.mean, pre.std, strict=True)]
    shape = (1, 3, 1, 1)
    return (
        torch.tensor(gains, dtype=torch.float32, device=device).reshape(shape),
        torch.tensor(offsets, dtype=torch.float32, device=device).reshape(shape),
    )


def letterbox_into(
    torch: Any,
    out: Tensor,
    image: Tensor,
    layout: str,
    pre: Preprocess,
    placement: tuple[int, int, int, int],
    norm: tuple[Tensor, Tensor],
) -> None:
    """Fill ``out`` ``[1, 3, H, W]`` (float32) with the model input made from ``image``.

    ``image`` is HxW or HxWxC uint8 on the device, channels as ``layout`` says (``bgr``,
    ``rgb``, ``bgra``, ``rgba``, ``y``). ``placement`` is ``(new_w, new_h, left, top)`` from
    ``detector.preprocess.geometry``. Bilinear resize with half-pixel centres, rounded to
    integers like OpenCV's uint8 ``INTER_LINEAR`` (which differs by at most one level),
    padding with ``pad_value``, channel order, then ``pixel * gain + offset``.
    """
    new_w, new_h, left, top = placement
    pixels = image if image.ndim == 3 else image[:, :, None]
    planes = pixels.permute(2, 0, 1)[None].to(torch.float32)
    if planes.shape[1] == 1:
        planes = planes.expand(1, 3, -1, -1)
    else:
        planes = planes[:, 0:3]
        if layout[:3] != pre.channel_order:
            planes = planes.flip(1)
    if (int(planes.shape[2]), int(planes.shape[3])) != (new_h, new_w):
        planes = torch.nn.functional.interpolate(
            planes, size=(new_h, new_w), mode='bilinear', align_corners=False, antialias=False
        )
        planes = planes.round_().clamp_(0.0, 255.0)
    out.fill_(float(pre.pad_value))
    out[:, :, top : top + new_h, left : left + new_w] = planes
    gain, offset = norm
    out.mul_(gain).add_(offset)


def yolox_grid(
    torch: Any, size: tuple[int, int], device: Any, strides: Sequence[int] = STRIDES
) -> tuple[Tensor, Tensor]:
    """YOLOX grid cells ``[N, 2]`` and strides ``[N, 1]`` (float32) on ``device``."""
    from replaybench.detector.decoders import yolox_grid as numpy_grid

    grid, stride = numpy_grid((int(size[0]), int(size[1])), tuple(strides))
    return (
        torch.from_numpy(np.array(grid)).to(device),
        torch.from_numpy(np.array(stride)).to(device),
    )


def _rank3(out: Tensor, what: str) -> Tensor:
    if out.ndim == 2:
        out = out[None]
    if out.ndim != 3 or out.shape[0] != 1:
        msg = f'{what}: expected an output of shape [1, ., .], got {list(out.shape)}'
        raise BackendError(msg)
    return out[0]


def _pairs(torch: Any, cls: Tensor, obj: Tensor | None, conf: float) -> tuple[Tensor, ...]:
    """Rows, classes and scores of every (row, class) with ``obj * cls > conf``, row-major.

    As ``decoders._pairs``: rows whose best score (objectness x best class score) is NaN or
    above ``conf`` (objectness NaN or above ``conf`` too) are read; those with a NaN or inf
    best score are left out, and the last item is their count (a 0-d tensor).
    """
    best = cls.amax(dim=1)  # NaN if any class score is NaN
    if obj is None:
        scores = cls
    else:
        scores = cls * obj[:, None]
        best = torch.where(obj <= conf, torch.zeros_like(best), best * obj)
    read = ~(best <= conf)
    finite = torch.isfinite(best)
    mask = (scores > conf) & (read & finite)[:, None]
    rows, classes = torch.nonzero(mask, as_tuple=True)
    return rows, classes, scores[rows, classes], (read & ~finite).sum()


def _finite(
    torch: Any, boxes: Tensor, scores: Tensor, classes: Tensor, rows: Tensor, bad: Tensor, n: int
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Drop the pairs whose box is not finite; ``bad`` plus the rows they came from."""
    ok = torch.isfinite(boxes).all(dim=1)
    row_bad = torch.zeros(n, dtype=torch.bool, device=boxes.device)
    row_bad[rows[~ok]] = True
    return boxes[ok], scores[ok], classes[ok], bad + row_bad.sum()


def _xywh_to_xyxy(torch: Any, xy: Tensor, wh: Tensor) -> Tensor:
    half = wh * 0.5
    return torch.cat((xy - half, xy + half), dim=1)


def decode(
    torch: Any, family: str, out: Tensor, conf: float, grid: tuple[Tensor, Tensor] | None = None
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The dense head ``family`` (yolox needs ``grid``: cells and strides) decoded.

    Boxes, scores, classes as the ``decode_*`` functions give them, and the number of
    candidate rows left out for NaN or inf values (a 0-d int64 tensor, still on the device).
    """
    if family == 'yolox':
        if grid is None:
            msg = 'yolox: the grid is needed'
            raise BackendError(msg)
        return _yolox(torch, out, grid[0], grid[1], conf)
    if family == 'yolov5':
        return _yolov5(torch, out, conf)
    if family == 'yolov8':
        return _yolov8(torch, out, conf)
    msg = f'unknown model family {family!r}'
    raise BackendError(msg)


def decode_yolox(
    torch: Any, out: Tensor, grid: Tensor, stride: Tensor, conf: float
) -> tuple[Tensor, Tensor, Tensor]:
    """YOLOX raw grid ``[1, N, 5+C]`` -> boxes ``[K, 4]``, scores ``[K]``, classes ``[K]``."""
    return _yolox(torch, out, grid, stride, conf)[:3]


def _yolox(
    torch: Any, out: Tensor, grid: Tensor, stride: Tensor, conf: float
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    rows_all = _rank3(out, 'yolox').to(torch.float32)
    if rows_all.shape[0] != grid.shape[0] or rows_all.shape[1] < 6:
        msg = (
            f'yolox: output {list(out.shape)} does not match the {grid.shape[0]} grid points '
            'of the input size with 5 + classes values'
        )
        raise BackendError(msg)
    rows, classes, scores, bad = _pairs(torch, rows_all[:, 5:], rows_all[:, 4], conf)
    picked = rows_all[rows, 0:4]
    step = stride[rows]
    xy = (picked[:, 0:2] + grid[rows]) * step
    wh = torch.exp(picked[:, 2:4]) * step
    boxes = _xywh_to_xyxy(torch, xy, wh)
    return _finite(torch, boxes, scores, classes, rows, bad, int(rows_all.shape[0]))


def decode_yolov5(torch: Any, out: Tensor, conf: float) -> tuple[Tensor, Tensor, Tensor]:
    """YOLOv5 / v7 ``[1, N, 5+C]`` (cx, cy, w, h, obj, classes)."""
    return _yolov5(torch, out, conf)[:3]


def _yolov5(torch: Any, out: Tensor, conf: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    rows_all = _rank3(out, 'yolov5').to(torch.float32)
    if rows_all.shape[1] < 6:
        msg = f'yolov5: output rows have {rows_all.shape[1]} values; expected 5 + classes'
        raise BackendError(msg)
    rows, classes, scores, bad = _pairs(torch, rows_all[:, 5:], rows_all[:, 4], conf)
    picked = rows_all[rows, 0:4]
    boxes = _xywh_to_xyxy(torch, picked[:, 0:2], picked[:, 2:4])
    return _finite(torch, boxes, scores, classes, rows, bad, int(rows_all.shape[0]))


def decode_yolov8(torch: Any, out: Tensor, conf: float) -> tuple[Tensor, Tensor, Tensor]:
    """YOLOv8 / YOLO11 ``[1, 4+C, N]`` (cx, cy, w, h, classes)."""
    return _yolov8(torch, out, conf)[:3]


def _yolov8(torch: Any, out: Tensor, conf: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    chans = _rank3(out, 'yolov8').to(torch.float32)
    if chans.shape[0] < 5:
        msg = f'yolov8: output has {chans.shape[0]} channels; expected 4 + classes'
        raise BackendError(msg)
    rows, classes, scores, bad = _pairs(torch, chans[4:].T, None, conf)
    picked = chans[0:4, rows].T
    boxes = _xywh_to_xyxy(torch, picked[:, 0:2], picked[:, 2:4])
    return _finite(torch, boxes, scores, classes, rows, bad, int(chans.shape[1]))


def _suppression(
    torch: Any, boxes: Tensor, areas: Tensor, classes: Tensor, a: Tensor, b: Tensor, iou: float
) -> Tensor:
    """``[len(a), len(b)]`` bool: same class and IoU above ``iou`` (float64, numpy's formula)."""
    ba, bb = boxes[a][:, None], boxes[b][None]
    w = torch.minimum(ba[..., 2], bb[..., 2]) - torch.maximum(ba[..., 0], bb[..., 0])
    h = torch.minimum(ba[..., 3], bb[..., 3]) - torch.maximum(ba[..., 1], bb[..., 1])
    inter = w.clamp(min=0) * h.clamp(min=0)
    union = areas[a][:, None] + areas[b][None] - inter
    overlap = torch.where(union > 0, inter / union.where(union > 0, 1.0), 0.0)
    return (classes[a][:, None] == classes[b][None]) & (overlap > iou)


def batched_nms(
    torch: Any,
    boxes: Tensor,
    scores: Tensor,
    classes: Tensor,
    iou: float,
    max_det: int | None = None,
    chunk: int = NMS_CHUNK,
) -> Tensor:
    """Indices kept by greedy class-aware NMS, best first; the same as ``decoders.nms``.

    Order: score descending, ties by class, x0, y0, x1, y1, then input index (stable sorts,
    least significant key first). IoU in float64, a box dropped when above ``iou`` with a kept
    box of its class. Exact greedy without a loop per box: candidates are taken in chunks; a
    chunk first loses what earlier kept boxes suppress, then its own keep mask is iterated to
    the fixed point ``keep[i] = alive[i] and no kept j < i suppresses i``, which is unique and
    equals the sequential greedy result.
    """
    n = int(scores.shape[0])
    device = scores.device
    if n == 0:
        return torch.zeros(0, dtype=torch.int64, device=device)
    b = boxes.to(torch.float64)
    order = torch.arange(n, device=device)
    for key in (b[:, 3], b[:, 2], b[:, 1], b[:, 0], classes, -scores):
        order = order[torch.sort(key[order], stable=True).indices]
    order = order[:MAX_CANDIDATES]
    b, cls = b[order], classes[order]
    areas = (b[:, 2] - b[:, 0]).clamp(min=0) * (b[:, 3] - b[:, 1]).clamp(min=0)
    m = int(order.shape[0])
    limit = max_det if max_det is not None else m
    kept = torch.zeros(0, dtype=torch.int64, device=device)
    for start in range(0, m, chunk):
        idx = torch.arange(start, min(start + chunk, m), device=device)
        alive = torch.ones(idx.shape[0], dtype=torch.bool, device=device)
        if kept.numel():
            alive &= ~_suppression(torch, b, areas, cls, kept, idx, iou).any(0)
        inside = _suppression(torch, b, areas, cls, idx, idx, iou).triu(diagonal=1)
        keep = alive
        while True:
            new = alive & ~(inside & keep[:, None]).any(0)
            if bool(torch.equal(new, keep)):
                break
            keep = new
        kept = torch.cat((kept, idx[keep]))
        if kept.shape[0] >= limit:
            kept = kept[:limit]
            break
    return order[kept]


def boxes_to_source(torch: Any, boxes: Tensor, transform: Transform) -> Tensor:
    """Model-input pixels -> source pixels (float32), clipped; as ``preprocess.boxes_to_source``."""
    sy = transform.scale if transform.scale_y is None else transform.scale_y
    out = boxes.to(torch.float32).clone()
    out[:, 0::2] = ((out[:, 0::2] - transform.pad_x) / transform.scale).clamp(0, transform.src_w)
    out[:, 1::2] = ((out[:, 1::2] - transform.pad_y) / sy).clamp(0, transform.src_h)
    return out
