"""Streaming scores of tags: each frame's tag truth against the tags of the output in use at its
release (``replaybench.replay.streaming`` picks them), matched and scored as offline tags are
(``replaybench.tasks.tags.scoring``): the recall, and the pose error of the matched tags."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.tasks.tags.recording import TagScores
    from replaybench.tasks.tags.scoring import FrameTagScore
    from replaybench.tasks.tags.truth import TagTable

__all__ = ['score']


def score(
    recorder: Any, backend: str, topic: str, picks: Sequence[Any]
) -> Mapping[str, float | None]:
    """``streaming_tag_recall``, ``streaming_tag_trans_err_m`` and
    ``streaming_tag_rot_err_deg`` of the picks of a (backend label, topic); empty where no
    frame has tag truth. The tags of each output are the tag recording's
    (``TagScores.found``); before the first output a frame is scored against no tags."""
    from replaybench.tasks.tags.scoring import score_frame, tag_accuracy

    recording = cast('TagScores', recorder.task_recording('tags'))
    outputs = recording.found.get((backend, topic), {})
    scores: list[FrameTagScore] = []
    for pick in picks:
        table = cast('TagTable | None', recorder.inputs[pick.input].truth.get('tags'))
        _, _, _, stamp_ns, frame_id = pick.frame
        truth = None if table is None else table.get((frame_id, stamp_ns))
        if truth is None:
            continue
        shown = () if pick.output is None else outputs.get((pick.input, pick.output[1]), ())
        scores.append(score_frame(shown, truth))
    if not scores:
        return {}
    found = tag_accuracy(scores)
    return {
        'streaming_tag_recall': found.recall,
        'streaming_tag_trans_err_m': found.trans_err_m,
        'streaming_tag_rot_err_deg': found.rot_err_deg,
    }
