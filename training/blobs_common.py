"""Shared pieces of the blobs detector's training and evaluation (numpy and OpenCV only).

Model input: ``INPUT_SIZE`` square, RGB, scaled by 1/255, letterboxed with pad value 114 and
the resized image centred (``pad = (size - resized) // 2`` on the left/top). The model's one
output ``output0`` is ``[1, 4 + C, N]``: decoded ``cx, cy, w, h`` in model-input pixels, then
the sigmoid scores of the classes ``red, green, blue, yellow``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from replaybench.fixtures.scene import CLASS_NAMES
from replaybench.types import Detection

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    'INPUT_SIZE',
    'PAD_VALUE',
    'STRIDE',
    'Letterbox',
    'decode_output',
    'letterbox',
    'nms',
]

INPUT_SIZE = 320
STRIDE = 8
PAD_VALUE = 114


class Letterbox(NamedTuple):
    """Maps model-input pixels back to source pixels: ``x_src = (x - pad_x) / scale``."""

    scale: float
    pad_x: int
    pad_y: int
    src_w: int
    src_h: int


def letterbox(
    bgr: npt.NDArray[np.uint8], size: int = INPUT_SIZE
) -> tuple[npt.NDArray[np.uint8], Letterbox]:
    """Resize keeping the aspect ratio, centre on a ``size`` x ``size`` canvas; returns RGB HWC."""
    import cv2

    src_h, src_w = bgr.shape[:2]
    scale = min(size / src_w, size / src_h)
    new_w, new_h = round(src_w * scale), round(src_h * scale)
    rgb: npt.NDArray[np.uint8] = bgr[:, :, ::-1]
    if (new_w, new_h) != (src_w, src_h):
        rgb = np.asarray(
            cv2.resize(rgb, (new_w, new_h), interpolation=cv2.INTER_LINEAR), dtype=np.uint8
        )
    pad_x, pad_y = (size - new_w) // 2, (size - new_h) // 2
    canvas = np.full((size, size, 3), PAD_VALUE, dtype=np.uint8)
    canvas[pad_y : pad_y + new_h, pad_x : pad_x + new_w] = rgb
    return canvas, Letterbox(scale, pad_x, pad_y, src_w, src_h)


def nms(
    boxes: npt.NDArray[np.float32],
    scores: npt.NDArray[np.float32],
    class_ids: npt.NDArray[np.int64],
    iou: float,
) -> npt.NDArray[np.int64]:
    """Class-aware greedy NMS; indices kept, by descending score (ties: lower index first)."""
    order = np.lexsort((np.arange(len(scores)), -scores))
    # Offsetting boxes per class keeps classes apart in one pass.
    offset = class_ids[:, None].astype(np.float32) * 4096.0
    b = boxes + offset
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    keep: list[int] = []
    suppressed = np.zeros(len(scores), dtype=bool)
    for i in order:
        if suppressed[i]:
            continue
        keep.append(int(i))
        x0 = np.maximum(b[i, 0], b[:, 0])
        y0 = np.maximum(b[i, 1], b[:, 1])
        x1 = np.minimum(b[i, 2], b[:, 2])
        y1 = np.minimum(b[i, 3], b[:, 3])
        inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
        overlap = inter / np.maximum(area[i] + area - inter, 1e-9)
        suppressed |= overlap > iou
    return np.asarray(keep, dtype=np.int64)


def decode_output(
    output: npt.NDArray[np.float32],
    box: Letterbox,
    conf: float = 0.25,
    iou: float = 0.45,
    names: tuple[str, ...] = CLASS_NAMES,
) -> list[Detection]:
    """``[1, 4 + C, N]`` output -> detections in source pixels (conf, class-aware NMS)."""
    pred = output[0].T  # N, 4 + C
    scores_all = pred[:, 4:]
    class_ids = scores_all.argmax(axis=1)
    scores = scores_all[np.arange(len(pred)), class_ids]
    mask = scores >= conf
    pred, scores, class_ids = pred[mask], scores[mask], class_ids[mask]
    xyxy = np.stack(
        [
            pred[:, 0] - pred[:, 2] / 2,
            pred[:, 1] - pred[:, 3] / 2,
            pred[:, 0] + pred[:, 2] / 2,
            pred[:, 1] + pred[:, 3] / 2,
        ],
        axis=1,
    )
    kept = nms(xyxy, scores, class_ids, iou)
    detections = []
    for i in kept:
        x0 = float(np.clip((xyxy[i, 0] - box.pad_x) / box.scale, 0, box.src_w))
        y0 = float(np.clip((xyxy[i, 1] - box.pad_y) / box.scale, 0, box.src_h))
        x1 = float(np.clip((xyxy[i, 2] - box.pad_x) / box.scale, 0, box.src_w))
        y1 = float(np.clip((xyxy[i, 3] - box.pad_y) / box.scale, 0, box.src_h))
        if x1 <= x0 or y1 <= y0:
            continue
        c = int(class_ids[i])
        detections.append(Detection(c, names[c], float(scores[i]), x0, y0, x1, y1))
    return detections
