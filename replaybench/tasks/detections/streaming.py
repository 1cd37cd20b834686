"""Streaming scores of boxes: each frame's box truth against the boxes of the output in use at
its release (``replaybench.replay.streaming`` picks them), scored as offline boxes are
(``replaybench.results.accuracy``, pycocotools-equal)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.tasks.detections.truth import BoxTruth
    from replaybench.types import Detection

__all__ = ['score', 'truth_boxes']


def truth_boxes(inp: Any, frame: tuple[str, int, int, int, str]) -> tuple[Detection, ...] | None:
    """The frame's boxes of truth: the ground-truth file's (matched by topic, seq, stamp), else
    the input's topic's (by frame_id, stamp); None where the frame has none."""
    found = cast('BoxTruth | None', inp.truth.get('detections'))
    if found is None:
        return None
    topic, seq, _, stamp_ns, frame_id = frame
    if found.external is not None:
        return found.external.lookup(topic, seq, stamp_ns)
    return found.frames.get((frame_id, stamp_ns))


def score(recorder: Any, backend: str, topic: str, picks: Sequence[Any]) -> Mapping[str, float]:
    """``streaming_map50``, ``streaming_map50_95``, ``streaming_recall`` and
    ``streaming_precision`` of the picks (``replaybench.replay.streaming.Pick``, each frame's
    header known) of a (backend label, topic); empty where no frame has truth. The boxes of
    each output come from the recorder's kept detections (``Recorder.detections``); before the
    first output a frame is scored against no boxes."""
    from replaybench.results.accuracy import evaluate

    outputs: Mapping[tuple[int, int], tuple[Detection, ...]] = recorder.detections.get(
        (backend, topic), {}
    )
    truth: dict[tuple[int, str, int], tuple[Detection, ...]] = {}
    shown: dict[tuple[int, str, int], tuple[Detection, ...]] = {}
    for pick in picks:
        boxes = truth_boxes(recorder.inputs[pick.input], pick.frame)
        if boxes is None:
            continue
        key = (pick.input, pick.frame[0], pick.frame[1])
        truth[key] = boxes
        shown[key] = () if pick.output is None else outputs.get((pick.input, pick.output[1]), ())
    if not truth:
        return {}
    result = evaluate(truth, shown)
    found = {
        'streaming_recall': float(result.recall50),
        'streaming_precision': float(result.precision50),
    }
    if result.map50 >= 0:
        found['streaming_map50'] = float(result.map50)
    if result.map50_95 >= 0:
        found['streaming_map50_95'] = float(result.map50_95)
    return found
