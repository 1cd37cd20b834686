"""Tag ground truth: the AprilTagDetectionArray messages of the input's ``/ground_truth/tags``
(parsed by ``replaybench.fiducials.msgs``), read whole when the input opens and keyed by
frame_id and stamp."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.errors import DecodeError
from replaybench.fiducials.msgs import APRILTAG_DETECTION_ARRAY, decode_tag_array
from replaybench.tasks.tags import TAG_GROUND_TRUTH_TOPIC

if TYPE_CHECKING:
    from replaybench.fiducials.types import TagDetection
    from replaybench.sources import Source

__all__ = ['TAG_GROUND_TRUTH_TOPIC', 'TagTable', 'read_tag_truth']

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
