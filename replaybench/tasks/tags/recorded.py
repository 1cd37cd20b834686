"""Recorded AprilTag outputs: an AprilTagDetectionArray a robot's tag node published, read as the
``TagResult`` a tag backend returns for the frame (the tags task's ``recorded_readers``; the
message is parsed by ``replaybench.fiducials.msgs``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.decode.recorded import OutputReader, RecordedMessage
from replaybench.fiducials.msgs import APRILTAG_DETECTION_ARRAY, decode_tag_array
from replaybench.fiducials.types import TagResult, tag_box

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.types import RawMessage

__all__ = ['READERS', 'read_tag_array_output']


def read_tag_array_output(raw: RawMessage) -> RecordedMessage:
    """The tags as a tag backend returns them (``replaybench.fiducials.detect.TagAssembler``):
    sorted by id, each with its box (the corners' bounding box, pixel centres at +0.5);
    tags with a non-finite corner are left out."""
    import math

    found = decode_tag_array(raw)
    usable = [t for t in found.tags if all(math.isfinite(v) for c in t.corners for v in c)]
    usable.sort(key=lambda t: (t.tag_id, t.corners))
    boxes = [tag_box(tag) for tag in usable]
    posed = any(t.pose is not None for t in usable)
    note = ''
    if usable and not all(t.pose is not None for t in usable):
        note = f'{raw.topic}: tags recorded without a pose: corners and ids only'
    result = TagResult(
        tuple(boxes), tags=tuple(usable), camera_frame=found.frame_id if posed else '', note=note
    )
    return RecordedMessage(found.frame_id, found.stamp_ns, result, len(found.tags) - len(usable))


#: message type (ROS 2 spelling) -> its reader; a frame without a recorded message gets no
#: tags, so it counts against tag recall
READERS: Mapping[str, OutputReader] = {
    APRILTAG_DETECTION_ARRAY: OutputReader(
        'tags',
        read_tag_array_output,
        missing=TagResult(()),
        unusable='tag(s) with a NaN or infinite corner',
        producer='the tag detector',
    ),
}
