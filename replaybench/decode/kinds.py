"""Which message types replaybench decodes, as what, and the source interface decode reads."""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal, Protocol

if TYPE_CHECKING:
    from collections.abc import Collection, Iterator

    from replaybench.types import RawMessage, TopicInfo

__all__ = [
    'CAMERA_INFO_TYPES',
    'COMPRESSED_IMAGE_TYPES',
    'DETECTION_TYPES',
    'IMAGE_TYPES',
    'MessageKind',
    'MessageSource',
    'message_kind',
]

MessageKind = Literal['image', 'compressed_image', 'camera_info', 'detections']

IMAGE_TYPES = frozenset({'sensor_msgs/msg/Image', 'sensor_msgs/Image', 'foxglove.RawImage'})
COMPRESSED_IMAGE_TYPES = frozenset(
    {'sensor_msgs/msg/CompressedImage', 'sensor_msgs/CompressedImage', 'foxglove.CompressedImage'}
)
CAMERA_INFO_TYPES = frozenset(
    {'sensor_msgs/msg/CameraInfo', 'sensor_msgs/CameraInfo', 'foxglove.CameraCalibration'}
)
DETECTION_TYPES = frozenset({'vision_msgs/msg/Detection2DArray', 'vision_msgs/Detection2DArray'})

_KINDS: dict[str, MessageKind] = {
    **dict.fromkeys(IMAGE_TYPES, 'image'),
    **dict.fromkeys(COMPRESSED_IMAGE_TYPES, 'compressed_image'),
    **dict.fromkeys(CAMERA_INFO_TYPES, 'camera_info'),
    **dict.fromkeys(DETECTION_TYPES, 'detections'),
}


def message_kind(msgtype: str) -> MessageKind | None:
    """What a message of ``msgtype`` decodes to; None for types replaybench ignores."""
    return _KINDS.get(msgtype)


class MessageSource(Protocol):
    """The part of ``replaybench.sources.Source`` the decode package uses."""

    def topics(self) -> list[TopicInfo]: ...

    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[RawMessage]: ...
