"""Streaming scores of label masks: each frame's ground-truth mask against the mask of the
output in use at its release (``replaybench.replay.streaming`` picks them), scored as offline
masks are (``replaybench.tasks.segmentation.scoring``: one confusion matrix summed over the
frames). Before the first output a frame has no answer: every pixel is counted as labelled
``IGNORE_ID`` (wrong for every class, and left out of the mean over classes)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np

from replaybench.tasks.segmentation.scoring import IGNORE_ID, confusion, scores

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

    from replaybench.tasks.segmentation.recording import MaskTruth, Segmentation

__all__ = ['score']


def score(
    recorder: Any, backend: str, topic: str, picks: Sequence[Any]
) -> Mapping[str, float | None]:
    """``streaming_miou`` and ``streaming_pixel_accuracy`` of the picks of a (backend label,
    topic); empty where no frame has a ground-truth mask. The masks of the outputs are those
    the recording kept, PNG-compressed (``Segmentation.kept``)."""
    from replaybench.tasks.segmentation.recording import _unpng

    recording = cast('Segmentation', recorder.task_recording('segmentation'))
    kept = recording.kept.get((backend, topic), {})
    total: npt.NDArray[np.int64] | None = None
    for pick in picks:
        truth = cast('MaskTruth | None', recorder.inputs[pick.input].truth.get('segmentation'))
        _, _, _, stamp_ns, frame_id = pick.frame
        expected = None if truth is None else truth.lookup(frame_id, stamp_ns)
        if expected is None:
            continue
        png = None if pick.output is None else kept.get((pick.input, pick.output[1]))
        shown = _unpng(png) if png is not None else None
        if shown is None or shown.shape != expected.shape:
            shown = np.full(expected.shape, IGNORE_ID, np.uint8)
        matrix = confusion(shown, expected)
        total = matrix if total is None else total + matrix
    if total is None:
        return {}
    found = scores(total)
    classes = [v for c, v in found.iou.items() if c != IGNORE_ID]
    return {
        'streaming_miou': float(np.mean(classes)) if classes else None,
        'streaming_pixel_accuracy': found.pixel_accuracy,
    }
