"""The tag task in the engine: tag ground truth read from an input, and each tag backend's tags
written into outputs.mcap and scored per frame.

``read_tag_truth`` runs when an input opens (``replaybench.replay.inputs.open_input``);
``TagScores`` is kept by the ``Recorder`` (``Recorder.task_outputs`` calls ``frame`` after the
pass, outside any timed region) and gives each (backend, topic) its ``TagAccuracy``
(``replaybench.replay.record.summaries``). Backends that return no ``TagResult`` pass through
untouched (their tag columns stay empty): the scorer and the sink are imported at the first
tag result, so that a run without tags does not load them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.errors import DecodeError
from replaybench.fiducials.msgs import APRILTAG_DETECTION_ARRAY, decode_tag_array
from replaybench.fiducials.types import TagResult

if TYPE_CHECKING:
    from replaybench.fiducials.types import TagDetection
    from replaybench.results.model import TagAccuracy
    from replaybench.results.tags import FrameTagScore
    from replaybench.sources import Source
    from replaybench.types import BackendResult

__all__ = ['TAG_GROUND_TRUTH_TOPIC', 'TagScores', 'TagTable', 'read_tag_truth']

#: Where tag ground truth is read from (AprilTagDetectionArray, keyed by frame_id and stamp).
TAG_GROUND_TRUTH_TOPIC = '/ground_truth/tags'

#: Truth tags by (frame_id, stamp_ns), as the ground-truth topic holds them
TagTable = dict[tuple[str, int], tuple['TagDetection', ...]]


def read_tag_truth(source: Source, notes: list[str]) -> TagTable:
    """The input's tag ground truth (empty without the topic); ``notes`` gets one line when
    some of its messages are not a readable AprilTagDetectionArray (they are left out)."""
    topic = TAG_GROUND_TRUTH_TOPIC
    if not any(t.name == topic for t in source.topics()):
        return {}
    truth: TagTable = {}
    bad = 0
    for raw in source.messages(topics=[topic]):
        if raw.msgtype != APRILTAG_DETECTION_ARRAY:
            bad += 1
            continue
        try:
            found = decode_tag_array(raw)
        except DecodeError:
            bad += 1
            continue
        truth[(found.frame_id, found.stamp_ns)] = found.tags
    if bad:
        notes.append(
            f'{topic}: {bad} message(s) are not a readable AprilTagDetectionArray; left out'
        )
    return truth


class TagScores:
    """The tag task's state over one run: each (backend label, topic)'s frame scores."""

    def __init__(self) -> None:
        # (backend label, topic) -> scores of its frames with truth, in replay order
        self.scores: dict[tuple[str, str], list[FrameTagScore]] = {}
        self.notes: dict[tuple[str, str], str] = {}

    def frame(
        self,
        label: str,
        topic: str,
        log_time_ns: int,
        stamp_ns: int,
        frame_id: str,
        result: BackendResult,
        truth: tuple[TagDetection, ...] | None,
        writer: object,
    ) -> dict[str, Any]:
        """One processed frame: its tags written and, against ``truth`` (None: the frame has
        none), scored; its frames.csv tag columns (none for a backend that finds no tags)."""
        if not isinstance(result, TagResult):
            return {}
        from replaybench.results.tags import score_frame
        from replaybench.sinks.tags import write_tags

        if result.note and (label, topic) not in self.notes:
            self.notes[(label, topic)] = f'{label}: {result.note}'
        write_tags(writer, label, topic, log_time_ns, stamp_ns, frame_id, result)
        if truth is None:
            return {'tags': len(result.tags)}
        score = score_frame(result.tags, truth)
        self.scores.setdefault((label, topic), []).append(score)
        return score.columns()

    def accuracy(self, backend: str, topic: str) -> TagAccuracy | None:
        """The tag accuracy of a (backend label, topic), None where no frame was scored."""
        from replaybench.results.tags import tag_accuracy

        scores = self.scores.get((backend, topic))
        return tag_accuracy(scores) if scores else None

    def warnings(self) -> list[str]:
        """One line per (backend label, topic) whose tags got no pose."""
        return list(self.notes.values())
