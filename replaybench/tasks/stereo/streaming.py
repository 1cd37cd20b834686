"""Streaming scores of disparities: each pair's truth against the disparity of the output in
use at its release (``replaybench.replay.streaming`` picks them), scored as offline pairs are
(``replaybench.stereo.metrics``: pixel sums pooled over the pairs). Before the first output a
pair has no estimate: its truth pixels count as bad. Truth given as depth is made disparity
with the geometry of the output it is scored against."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np

from replaybench.stereo.metrics import DisparityCounts, score_disparity
from replaybench.tasks.stereo.recording import figures_of

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.tasks.stereo.recording import DisparityTruth, StereoRecording

__all__ = ['score']


def score(
    recorder: Any, backend: str, topic: str, picks: Sequence[Any]
) -> Mapping[str, float | None]:
    """``streaming_epe``, ``streaming_bad2`` and ``streaming_density`` of the picks of a
    (backend label, topic); empty where no pair has truth. The outputs' disparities are those
    the recording kept (``StereoRecording.kept``)."""
    from replaybench.tasks.stereo.truth import depth_to_disparity

    recording = cast('StereoRecording', recorder.task_recording('stereo'))
    kept = recording.kept.get((backend, topic), {})
    total: DisparityCounts | None = None
    for pick in picks:
        table = cast('DisparityTruth | None', recorder.inputs[pick.input].truth.get('stereo'))
        _, _, _, stamp_ns, frame_id = pick.frame
        truth = None if table is None else table.lookup(frame_id, stamp_ns)
        if truth is None:
            continue
        shown = None if pick.output is None else kept.get((pick.input, pick.output[1]))
        if getattr(table, 'depth', False) and shown is not None:
            if not (shown.f > 0 and shown.t > 0):
                continue  # as offline: a depth truth needs the output's geometry
            truth = depth_to_disparity(truth, shown.f, shown.t, shown.cx_offset)
        values = shown.values() if shown is not None else None
        if values is None or values.shape != truth.shape:
            values = np.full(truth.shape, np.nan, np.float32)
        counts = score_disparity(values, truth, min_disparity=float('-inf'))
        total = counts if total is None else total + counts
    if total is None:
        return {}
    figures = figures_of(total.figures())
    return {
        'streaming_epe': figures['epe'],
        'streaming_bad2': figures['bad2'],
        'streaming_density': figures['density'],
    }
