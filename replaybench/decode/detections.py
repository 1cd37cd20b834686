"""Ground-truth detections from vision_msgs/Detection2DArray messages."""

from __future__ import annotations

import contextlib
import functools
import math
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench.decode._wire import as_bytes_view, parse_detection_array
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


def _detection(d: Any) -> Detection:
    bbox = d.bbox
    center = bbox.center
    position = getattr(center, 'position', center)  # 4.x: Pose2D.position; ROS 1: Pose2D.x/y
    cx, cy = float(position.x), float(position.y)
    half_w, half_h = float(bbox.size_x) / 2, float(bbox.size_y) / 2
    label, score = '', 1.0
    if len(d.results):
        result = d.results[0]
        hypothesis = getattr(result, 'hypothesis', None)
        if hypothesis is not None:  # 4.x: ObjectHypothesis class_id (string) + score
            label, score = str(hypothesis.class_id), float(hypothesis.score)
        else:  # ROS 1: ObjectHypothesisWithPose id (int64) + score
            label, score = str(result.id), float(result.score)
    return Detection(-1, label, score, cx - half_w, cy - half_h, cx + half_w, cy + half_h)


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


def _decode_cdr(msg: RawMessage) -> GroundTruth:
    """vision_msgs 4.x in CDR, read by hand (``parse_detection_array``): the ROS 2 type store's
    import would cost a bag with ground truth more than the rest of a run's start."""
    try:
        fields = parse_detection_array(as_bytes_view(msg.data))
    except DecodeError as err:
        text = f'invalid {DETECTION2DARRAY} (cdr) on {msg.topic}: {err}'
        raise DecodeError(text) from err
    decoded = [
        Detection(
            -1,
            '' if b.class_id is None else b.class_id,
            b.score,
            b.cx - b.size_x / 2,
            b.cy - b.size_y / 2,
            b.cx + b.size_x / 2,
            b.cy + b.size_y / 2,
        )
        for b in fields.boxes
    ]
    detections = tuple(d for d in decoded if _finite(d))
    return GroundTruth(fields.stamp_ns, fields.frame_id, detections, len(decoded) - len(detections))


def decode_detections(msg: RawMessage) -> GroundTruth:
    """Decode a vision_msgs/Detection2DArray.

    cdr: vision_msgs 4.x, read by hand. ros1: the layout ``replaybench.msgs`` registers, else
    noetic's own (int64 class id, with or without the tracking fields).
    """
    if message_kind(msg.msgtype) != 'detections' or msg.serialization not in {'cdr', 'ros1'}:
        text = f'{msg.msgtype} ({msg.serialization}) is not a Detection2DArray message'
        raise DecodeError(text)
    if msg.serialization == 'cdr':
        return _decode_cdr(msg)
    try:
        m = _deserialize(msg)
        decoded = [_detection(d) for d in m.detections]
    except Exception as err:
        text = f'invalid {DETECTION2DARRAY} ({msg.serialization}) on {msg.topic}: {err}'
        raise DecodeError(text) from err
    detections = tuple(d for d in decoded if _finite(d))
    stamp = m.header.stamp
    stamp_ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return GroundTruth(stamp_ns, m.header.frame_id, detections, len(decoded) - len(detections))


def _finite(d: Detection) -> bool:
    return all(math.isfinite(v) for v in (d.score, d.x0, d.y0, d.x1, d.y1))
