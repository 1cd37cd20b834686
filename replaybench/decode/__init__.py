"""RawMessage -> Frame (image array and header), CameraInfo and ground-truth detections.

Heavy libraries (OpenCV, rosbags, protobuf) are imported when a message first needs them.
"""

from __future__ import annotations

from replaybench.decode.camera_info import (
    CameraInfoIndex,
    camera_info_topic_for,
    decode_camera_info,
)
from replaybench.decode.detections import GroundTruth, decode_detections
from replaybench.decode.image import decode_image, to_bgr8
from replaybench.decode.kinds import MessageKind, message_kind
from replaybench.decode.probe import CameraTopic, probe_topics

__all__ = [
    'CameraInfoIndex',
    'CameraTopic',
    'GroundTruth',
    'MessageKind',
    'camera_info_topic_for',
    'decode_camera_info',
    'decode_detections',
    'decode_image',
    'message_kind',
    'probe_topics',
    'to_bgr8',
]
