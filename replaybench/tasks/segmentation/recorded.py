"""Recorded label masks: a ``mono8`` (or ``mono16`` with ids up to 255) Image of class ids a
robot's segmentation node published, read as the ``BackendResult.mask`` of a segmentation
backend (the segmentation task's ``recorded_readers``). An Image that is not a label mask
(``rgb8``, a ``16UC1`` depth image) is refused with a ``UsageError``."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.decode.recorded import OutputReader, RecordedMessage
from replaybench.errors import DecodeError, UsageError
from replaybench.types import BackendResult, LabelMask

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.types import RawMessage

__all__ = ['MASK_ENCODINGS', 'READERS', 'read_label_mask']

#: Image encodings read as label masks (as ``decode_image`` names them).
MASK_ENCODINGS = ('mono8', 'mono16')


def read_label_mask(raw: RawMessage) -> RecordedMessage:
    """A mono8 / mono16 Image of class ids as a segmentation backend's mask (class names are
    not recorded: ids stand for them). ``UsageError`` for an image that is not a label mask,
    ``DecodeError`` for a mono16 mask with an id above 255. The masks of the topic are held for
    the run, one ``H x W`` byte array each, as a pass holds its backends' masks."""
    import numpy as np

    from replaybench.decode.image import decode_image

    frame = decode_image(raw)
    if frame.encoding not in MASK_ENCODINGS or frame.is_depth:
        msg = (
            f'{raw.topic} holds {frame.source_encoding} images, not label masks (mono8 or mono16 '
            'class ids): the recorded backend reads an Image topic as label masks'
        )
        raise UsageError(msg)
    image = frame.image.reshape(frame.height, frame.width)
    if frame.encoding == 'mono16' and image.size and int(image.max()) > 255:
        msg = f'a mask with class id {int(image.max())}: ids above 255 are not read'
        raise DecodeError(msg)
    labels = np.array(image, dtype=np.uint8, order='C')
    mask = LabelMask(labels, ())
    return RecordedMessage(frame.frame_id, frame.stamp_ns, BackendResult((), mask=mask))


#: message type (ROS 2 spelling) -> its reader. Camera topics are Images too: a mask topic is
#: never picked alone (``--recorded-topic`` names it); its boxes (none) are not scored, as no
#: segmentation frame's are (``replaybench.tasks.segmentation.recording``).
READERS: Mapping[str, OutputReader] = {
    'sensor_msgs/msg/Image': OutputReader(
        'segmentation',
        read_label_mask,
        candidate=False,
        outputs='masks',
        producer='the segmentation node',
    ),
}
