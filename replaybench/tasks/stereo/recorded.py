"""Recorded disparity: a ``stereo_msgs/msg/DisparityImage`` a robot's stereo node (ESS,
stereo_image_proc's disparity node) published, read as the ``Disparity`` a stereo backend
returns for the pair (the stereo task's ``recorded_readers``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.decode.recorded import OutputReader, RecordedMessage
from replaybench.stereo.msgs import DISPARITY_IMAGE, parse_disparity_image
from replaybench.stereo.output import Disparity
from replaybench.types import BackendResult

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.types import RawMessage

__all__ = ['READERS', 'read_disparity_output']


def read_disparity_output(raw: RawMessage) -> RecordedMessage:
    """The message's disparity, keyed by its header (the left image's)."""
    found = parse_disparity_image(raw.data, ros1=raw.serialization == 'ros1')
    result = BackendResult((), output=Disparity.of_message(found))
    return RecordedMessage(found.frame_id, found.stamp_ns, result, 0)


#: message type (ROS 2 spelling) -> its reader; a frame without a recorded disparity has no
#: estimate (its truth pixels count as bad)
READERS: Mapping[str, OutputReader] = {
    DISPARITY_IMAGE: OutputReader(
        'stereo',
        read_disparity_output,
        outputs='disparity images',
        producer='the stereo node',
    ),
}
