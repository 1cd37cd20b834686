"""Recorded boxes: a Detection2DArray a robot's detector published, read as the detections a
detector returns for the frame (the detections task's ``recorded_readers``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.decode.detections import decode_detections
from replaybench.decode.recorded import OutputReader, RecordedMessage
from replaybench.types import BackendResult

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.types import RawMessage

__all__ = ['READERS', 'read_detection2d_array']


def read_detection2d_array(raw: RawMessage) -> RecordedMessage:
    """The message's boxes; those with a non-finite box or score are left out."""
    found = decode_detections(raw)
    return RecordedMessage(
        found.frame_id, found.stamp_ns, BackendResult(found.detections), found.nonfinite
    )


#: message type (ROS 2 spelling) -> its reader
READERS: Mapping[str, OutputReader] = {
    'vision_msgs/msg/Detection2DArray': OutputReader(
        'detections',
        read_detection2d_array,
        unusable='detection(s) with a NaN or infinite box or score',
        producer='the detector',
        # a tracker's output: boxes that carry ids are tracks (replaybench.tasks.tracks)
        identified_task='tracks',
    ),
}
