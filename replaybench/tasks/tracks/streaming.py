"""Streaming scores of tracks: each frame's box truth (with its objects' ids) against the
tracks of the output in use at its release (``replaybench.replay.streaming`` picks them), the
frames in replay order one sequence scored as offline tracks are
(``replaybench.tasks.tracks.recording.score_sequence``: HOTA, identity and CLEAR). An output
in use at several frames shows the same tracks, with the same ids, at each, as a planner
holding the latest tracks sees them; before the first output a frame has no tracks. A row the
offline figures refuse (truth without ids) has none either."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.tasks.detections.truth import BoxTruth
    from replaybench.tasks.tracks.recording import TracksRecording
    from replaybench.types import Detection

__all__ = ['score']


def score(
    recorder: Any, backend: str, topic: str, picks: Sequence[Any]
) -> Mapping[str, float | None]:
    """``streaming_hota``, ``streaming_idf1`` and ``streaming_mota`` of the picks of a
    (backend label, topic); empty where no frame has truth or the row's truth has no ids. The
    tracks of each output are the recorder's kept detections (``Recorder.detections``)."""
    from replaybench.tasks.detections.streaming import truth_boxes
    from replaybench.tasks.tracks.recording import figures_of, score_sequence, without_distractors

    recording = cast('TracksRecording | None', recorder.task_recording('tracks'))
    if recording is not None and (backend, topic) in recording.refused:
        return {}
    outputs: Mapping[tuple[int, int], tuple[Detection, ...]] = recorder.detections.get(
        (backend, topic), {}
    )
    frames: list[tuple[tuple[Detection, ...], tuple[Detection, ...]]] = []
    for pick in picks:
        truth = cast('BoxTruth | None', recorder.inputs[pick.input].truth.get('detections'))
        if truth is None:
            continue
        external = truth.external
        if external is not None and external.format != 'mot':
            return {}
        boxes = truth_boxes(recorder.inputs[pick.input], pick.frame)
        if boxes is None:
            continue
        if any(not d.id for d in boxes):
            return {}
        tracks = () if pick.output is None else outputs.get((pick.input, pick.output[1]), ())
        if external is not None:
            tracks = without_distractors(boxes, external.others_of(topic, pick.frame[1]), tracks)
        frames.append((tuple(boxes), tuple(tracks)))
    if not frames:
        return {}
    try:
        figures = figures_of(score_sequence(frames))
    except ValueError:  # an id twice in a frame: refused offline too, with the reason
        return {}
    return {
        'streaming_hota': figures['hota'],
        'streaming_idf1': figures['idf1'],
        'streaming_mota': figures['mota'],
    }
