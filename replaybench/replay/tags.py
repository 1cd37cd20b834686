"""The tag task beside the replay: ground truth read from the inputs, each tag backend's tags
written into detections.mcap and scored per frame, and the tag accuracy of each summary.

The engine calls it from three places (``_execute``, ``_Pass.record_processed``,
``_summaries``) after a frame's timing is taken: nothing here runs inside a timed region.
Backends that return no ``TagResult`` pass through untouched (their tag columns stay empty).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

from replaybench.errors import DecodeError
from replaybench.fiducials.msgs import APRILTAG_DETECTION_ARRAY, decode_tag_array
from replaybench.fiducials.types import TagResult
from replaybench.results.tags import score_frame, tag_accuracy
from replaybench.sinks.tags import write_tags

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.fiducials.types import TagDetection
    from replaybench.results.stats import Summary
    from replaybench.results.tags import FrameTagScore
    from replaybench.sources import Source
    from replaybench.types import BackendResult

__all__ = ['TAG_GROUND_TRUTH_TOPIC', 'TagRun']

#: Where tag ground truth is read from (AprilTagDetectionArray, keyed by frame_id and stamp).
TAG_GROUND_TRUTH_TOPIC = '/ground_truth/tags'


class TagRun:
    """The tag task's state over one run."""

    def __init__(self, truth_topic: str = TAG_GROUND_TRUTH_TOPIC) -> None:
        self.truth_topic = truth_topic
        # (input, frame_id, stamp) -> truth tags
        self.truth: dict[tuple[int, str, int], tuple[TagDetection, ...]] = {}
        self.truth_frames: dict[int, int] = {}
        # (backend label, topic) -> scores of its frames with truth, in replay order
        self.scores: dict[tuple[str, str], list[FrameTagScore]] = {}
        self.notes: dict[tuple[str, str], str] = {}
        self.bad_truth = 0

    def read_truth(self, number: int, source: Source) -> None:
        """The input's tag ground truth, if it has the topic."""
        if not any(t.name == self.truth_topic for t in source.topics()):
            return
        count = 0
        for raw in source.messages(topics=[self.truth_topic]):
            if raw.msgtype != APRILTAG_DETECTION_ARRAY:
                self.bad_truth += 1
                continue
            try:
                found = decode_tag_array(raw)
            except DecodeError:
                self.bad_truth += 1
                continue
            self.truth[(number, found.frame_id, found.stamp_ns)] = found.tags
            count += 1
        self.truth_frames[number] = count

    def frame(
        self,
        label: str,
        number: int,
        topic: str,
        log_time_ns: int,
        stamp_ns: int,
        frame_id: str,
        result: BackendResult,
        writer: Any,
    ) -> dict[str, Any]:
        """One processed frame: its tags written and scored; its frames.csv tag columns."""
        if not isinstance(result, TagResult):
            return {}
        if result.note and (label, topic) not in self.notes:
            self.notes[(label, topic)] = f'{label}: {result.note}'
        write_tags(writer, label, topic, log_time_ns, stamp_ns, frame_id, result)
        truth = self.truth.get((number, frame_id, stamp_ns))
        if truth is None:
            return {'tags': len(result.tags)}
        score = score_frame(result.tags, truth)
        self.scores.setdefault((label, topic), []).append(score)
        return score.columns()

    def summaries(self, summaries: Sequence[Summary]) -> list[Summary]:
        """Each summary with its tag accuracy (``tag_accuracy``), where it was scored."""
        out = []
        for s in summaries:
            scores = self.scores.get((s.backend, s.topic))
            if scores:
                out.append(replace(s, tag_accuracy=tag_accuracy(scores).document()))
            else:
                out.append(s)
        return out

    def warnings(self) -> list[str]:
        """One line per (backend, topic) whose tags got no pose, and for bad truth."""
        lines = list(self.notes.values())
        if self.bad_truth:
            lines.append(
                f'{self.truth_topic}: {self.bad_truth} message(s) are not a readable '
                'AprilTagDetectionArray; left out'
            )
        return lines
