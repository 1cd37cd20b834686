"""Segmentation accuracy: per-class IoU, mIoU and pixel accuracy from confusion matrices.

A prediction and its ground truth are frame-sized uint8 label masks whose ids mean the same
classes. Everything follows from the 256 x 256 confusion matrix ``C[truth, predicted]``
(pixel counts), summed over the frames scored:

* ``IoU(c) = C[c, c] / (sum_k C[c, k] + sum_k C[k, c] - C[c, c])``, for every class ``c`` whose
  union is not empty (in the truth or the prediction of some scored frame); a class in
  neither has no IoU;
* ``mIoU`` = the mean of those IoUs (background, id 0, included);
* ``pixel accuracy = trace(C) / sum(C)``.

A frame's own values (frames.csv ``miou`` and ``pixel_accuracy``) come from its own matrix;
the summary's from the sum over the frames, not from the mean of the frames' values.
Pixels whose truth is ``ignore`` (255 by default, as in Cityscapes / VOC) are left out of
every count.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

__all__ = [
    'GROUND_TRUTH_MASK_TOPIC',
    'IGNORE_ID',
    'SEGMENTATION_COLUMNS',
    'SegScores',
    'class_name',
    'confusion',
    'scores',
]

#: Default topic of ground-truth label masks (mono8 Images, as ``replaybench fixtures --masks``
#: writes them).
GROUND_TRUTH_MASK_TOPIC = '/ground_truth/labels'
#: Ground-truth id that marks pixels left out of the scores.
IGNORE_ID = 255
#: Segmentation columns of frames.csv and summary.csv.
SEGMENTATION_COLUMNS: tuple[str, ...] = ('miou', 'pixel_accuracy')


class SegScores(NamedTuple):
    """Accuracy of a set of frames; ``iou`` by class id, for classes with a non-empty union."""

    miou: float | None
    pixel_accuracy: float | None
    iou: Mapping[int, float]
    pixels: int


def confusion(
    predicted: npt.NDArray[np.uint8],
    truth: npt.NDArray[np.uint8],
    *,
    ignore: int | None = IGNORE_ID,
) -> npt.NDArray[np.int64]:
    """The 256 x 256 matrix ``C[truth, predicted]`` of pixel counts of two equal-sized masks."""
    if predicted.shape != truth.shape:
        msg = f'mask shapes differ: predicted {predicted.shape}, truth {truth.shape}'
        raise ValueError(msg)
    pairs = truth.astype(np.int32).ravel() * 256 + predicted.ravel()
    if ignore is not None:
        pairs = pairs[truth.ravel() != ignore]
    counts = np.bincount(pairs, minlength=256 * 256)
    return counts.reshape(256, 256).astype(np.int64)


def scores(matrix: npt.NDArray[np.int64]) -> SegScores:
    """Per-class IoU, mIoU and pixel accuracy of a confusion matrix (see the module)."""
    total = int(matrix.sum())
    if total == 0:
        return SegScores(None, None, {}, 0)
    hits = np.diag(matrix).astype(np.float64)
    union = matrix.sum(axis=0) + matrix.sum(axis=1) - np.diag(matrix)
    present = np.flatnonzero(union > 0)
    iou = {int(c): float(hits[c] / union[c]) for c in present}
    miou = float(np.mean(list(iou.values()))) if iou else None
    return SegScores(miou, float(hits.sum() / total), iou, total)


def class_name(class_id: int, names: Sequence[str]) -> str:
    """The name of a class id: its entry in ``names``, else the id as text."""
    return names[class_id] if 0 <= class_id < len(names) else str(class_id)
