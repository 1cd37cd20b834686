"""Ground-truth detections from vision_msgs/Detection2DArray messages."""

from __future__ import annotations

import contextlib
import functools
import math
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench.decode._wire import (
    BoxFields,
    DetectionArrayFields,
    as_bytes_view,
    parse_detection_array,
)
from replaybench.decode.kinds import message_kind
from replaybench.errors import DecodeError
from replaybench.types import Detection

if TYPE_CHECKING:
    from replaybench.types import RawMessage

__all__ = ['DETECTION2DARRAY', 'GroundTruth', 'decode_detections']

DETECTION2DARRAY = 'vision_msgs/msg/Detection2DArray'


class GroundTruth(NamedTuple):
    """The detections of one Detection2DArray, keyed by the image it describes."""

    stamp_ns: int
    frame_id: str
    detections: tuple[Detection, ...]
    nonfinite: int = 0  #: detections left out because a coordinate or the score is NaN or inf


def _box_fields(d: Any) -> BoxFields:
    """A deserialised ROS 1 Detection2D's box and first hypothesis (its ``id``: a string as
    ``replaybench.msgs`` registers it, an int64 in noetic's own layout)."""
    bbox = d.bbox
    label, score = '', 1.0
    if len(d.results):
        result = d.results[0]
        label, score = str(result.id), float(result.score)
    size_x, size_y = float(bbox.size_x), float(bbox.size_y)
    ident = str(getattr(d, 'tracking_id', '') or '')  # noetic's tracking layout only
    return BoxFields(
        float(bbox.center.x), float(bbox.center.y), size_x, size_y, label, score, ident
    )


def _detection(b: BoxFields) -> Detection:
    half_w, half_h = b.size_x / 2, b.size_y / 2
    return Detection(
        -1,
        b.class_id,
        b.score,
        b.cx - half_w,
        b.cy - half_h,
        b.cx + half_w,
        b.cy + half_h,
        b.id,
    )


# Genuine ROS 1 noetic vision_msgs: int64 class id; later releases add tracking fields.
_NOETIC = {
    'vision_msgs/msg/Detection2DArray': 'std_msgs/Header header\nDetection2D[] detections\n',
    'vision_msgs/msg/ObjectHypothesisWithPose': (
        'int64 id\nfloat64 score\ngeometry_msgs/PoseWithCovariance pose\n'
    ),
    'vision_msgs/msg/BoundingBox2D': (
        'geometry_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n'
    ),
}
_NOETIC_DETECTION2D = (
    'std_msgs/Header header\nObjectHypothesisWithPose[] results\nBoundingBox2D bbox\n'
    'sensor_msgs/Image source_img\n'
)
_NOETIC_TRACKING = 'bool is_tracking\nstring tracking_id\n'


@functools.cache
def _noetic_store(tracking: bool) -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    texts = dict(_NOETIC)
    texts['vision_msgs/msg/Detection2D'] = _NOETIC_DETECTION2D + (
        _NOETIC_TRACKING if tracking else ''
    )
    types: dict[str, Any] = {}
    for name, text in texts.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def _deserialize(msg: RawMessage) -> Any:
    from replaybench.msgs import typestore

    try:
        return typestore(ros1=True).deserialize_ros1(msg.data, DETECTION2DARRAY)
    except Exception as first:  # the layout replaybench writes failed: try noetic's own
        for tracking in (False, True):
            with contextlib.suppress(Exception):
                return _noetic_store(tracking).deserialize_ros1(msg.data, DETECTION2DARRAY)
        raise first from None


def _read_ros1(msg: RawMessage) -> DetectionArrayFields:
    m = _deserialize(msg)
    stamp = m.header.stamp
    stamp_ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return DetectionArrayFields(
        stamp_ns, m.header.frame_id, tuple(_box_fields(d) for d in m.detections)
    )


def decode_detections(msg: RawMessage) -> GroundTruth:
    """Decode a vision_msgs/Detection2DArray.

    cdr: vision_msgs 4.x, read by hand (``parse_detection_array``: the ROS 2 type store's import
    would cost a bag with ground truth more than the rest of a run's start). ros1: the layout
    ``replaybench.msgs`` registers, else noetic's own (int64 class id, with or without the
    tracking fields).
    """
    if message_kind(msg.msgtype) != 'detections' or msg.serialization not in {'cdr', 'ros1'}:
        text = f'{msg.msgtype} ({msg.serialization}) is not a Detection2DArray message'
        raise DecodeError(text)
    try:
        if msg.serialization == 'cdr':
            fields = parse_detection_array(as_bytes_view(msg.data))
        else:
            fields = _read_ros1(msg)
    except Exception as err:
        text = f'invalid {DETECTION2DARRAY} ({msg.serialization}) on {msg.topic}: {err}'
        raise DecodeError(text) from err
    decoded = [_detection(b) for b in fields.boxes]
    detections = tuple(d for d in decoded if _finite(d))
    return GroundTruth(fields.stamp_ns, fields.frame_id, detections, len(decoded) - len(detections))


def _finite(d: Detection) -> bool:
    return all(math.isfinite(v) for v in (d.score, d.x0, d.y0, d.x1, d.y1))
