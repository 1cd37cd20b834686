"""Isaac ROS AprilTag messages and TF: definitions, serialisation, decoding.

``isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray`` as Isaac ROS defines it
(``std_msgs/Header header``, ``AprilTagDetection[] detections``; each ``string family``,
``int32 id``, ``geometry_msgs/Point center``, ``geometry_msgs/Point[4] corners``,
``geometry_msgs/PoseWithCovarianceStamped pose``) is registered in replaybench's ROS 2 typestore
(``replaybench.msgs.typestore``) on first use; ``tf2_msgs/msg/TFMessage`` is in the store
already. A tag without a pose is written with a zero pose (position 0, orientation 0, 0, 0, 0:
not a rotation) and an empty pose frame, so a reader can tell it apart.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench.errors import DecodeError
from replaybench.fiducials.types import TagDetection, TagPose

if TYPE_CHECKING:
    from collections.abc import Sequence

    from rosbags.typesys.store import Typestore

    from replaybench.types import RawMessage

__all__ = [
    'APRILTAG_DETECTION_ARRAY',
    'APRILTAG_MSGS_ROS2',
    'TF_MESSAGE',
    'DecodedTags',
    'decode_tag_array',
    'serialize_tag_array',
    'serialize_tf',
    'tag_typestore',
]

APRILTAG_DETECTION_ARRAY = 'isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray'
TF_MESSAGE = 'tf2_msgs/msg/TFMessage'

#: isaac_ros_apriltag_interfaces (Isaac ROS), the two messages replaybench reads and writes.
APRILTAG_MSGS_ROS2: dict[str, str] = {
    'isaac_ros_apriltag_interfaces/msg/AprilTagDetection': (
        'string family\n'
        'int32 id\n'
        'geometry_msgs/Point center\n'
        'geometry_msgs/Point[4] corners\n'
        'geometry_msgs/PoseWithCovarianceStamped pose\n'
    ),
    APRILTAG_DETECTION_ARRAY: (
        'std_msgs/Header header\nisaac_ros_apriltag_interfaces/AprilTagDetection[] detections\n'
    ),
}


def tag_typestore() -> Typestore:
    """replaybench's ROS 2 typestore with the AprilTag messages registered."""
    from rosbags.typesys import get_types_from_msg

    from replaybench.msgs import typestore

    store = typestore()
    if APRILTAG_DETECTION_ARRAY not in store.fielddefs:
        types: dict[str, Any] = {}
        for name, text in APRILTAG_MSGS_ROS2.items():
            types.update(get_types_from_msg(text, name))
        store.register(types)
    return store


def _header(store: Typestore, stamp_ns: int, frame_id: str) -> Any:
    from replaybench.msgs import _stamp

    sec, nanosec = _stamp(stamp_ns, False)
    t = store.types
    stamp = t['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)
    return t['std_msgs/msg/Header'](stamp=stamp, frame_id=frame_id)


def serialize_tag_array(
    stamp_ns: int, frame_id: str, tags: Sequence[TagDetection], camera_frame: str = ''
) -> bytes:
    """An AprilTagDetectionArray (ROS 2 CDR) of one frame's tags; the header is the image's,
    each pose's header the camera frame the pose is in (``camera_frame``, else ``frame_id``)."""
    import numpy as np

    store = tag_typestore()
    t = store.types
    header = _header(store, stamp_ns, frame_id)
    point, quat = t['geometry_msgs/msg/Point'], t['geometry_msgs/msg/Quaternion']
    items = []
    for tag in tags:
        pose = tag.pose
        if pose is None:
            position, orientation = point(x=0.0, y=0.0, z=0.0), quat(x=0.0, y=0.0, z=0.0, w=0.0)
            pose_header = _header(store, stamp_ns, '')
        else:
            position = point(x=pose.position[0], y=pose.position[1], z=pose.position[2])
            qx, qy, qz, qw = pose.orientation
            orientation = quat(x=qx, y=qy, z=qz, w=qw)
            pose_header = _header(store, stamp_ns, camera_frame or frame_id)
        stamped = t['geometry_msgs/msg/PoseWithCovarianceStamped'](
            header=pose_header,
            pose=t['geometry_msgs/msg/PoseWithCovariance'](
                pose=t['geometry_msgs/msg/Pose'](position=position, orientation=orientation),
                covariance=np.zeros(36, dtype=np.float64),
            ),
        )
        items.append(
            t['isaac_ros_apriltag_interfaces/msg/AprilTagDetection'](
                family=tag.family,
                id=int(tag.tag_id),
                center=point(x=float(tag.center[0]), y=float(tag.center[1]), z=0.0),
                corners=[point(x=float(x), y=float(y), z=0.0) for x, y in tag.corners],
                pose=stamped,
            )
        )
    message = t[APRILTAG_DETECTION_ARRAY](header=header, detections=items)
    return bytes(store.serialize_cdr(message, APRILTAG_DETECTION_ARRAY))


def serialize_tf(stamp_ns: int, camera_frame: str, tags: Sequence[TagDetection]) -> bytes:
    """A tf2_msgs/TFMessage: camera frame -> ``family:id`` for every tag with a pose."""
    store = tag_typestore()
    t = store.types
    transforms = []
    for tag in tags:
        if tag.pose is None:
            continue
        x, y, z = tag.pose.position
        qx, qy, qz, qw = tag.pose.orientation
        transforms.append(
            t['geometry_msgs/msg/TransformStamped'](
                header=_header(store, stamp_ns, camera_frame),
                child_frame_id=tag.label,
                transform=t['geometry_msgs/msg/Transform'](
                    translation=t['geometry_msgs/msg/Vector3'](x=x, y=y, z=z),
                    rotation=t['geometry_msgs/msg/Quaternion'](x=qx, y=qy, z=qz, w=qw),
                ),
            )
        )
    message = t[TF_MESSAGE](transforms=transforms)
    return bytes(store.serialize_cdr(message, TF_MESSAGE))


class DecodedTags(NamedTuple):
    """One AprilTagDetectionArray: the header's frame and stamp, and the tags."""

    frame_id: str
    stamp_ns: int
    tags: tuple[TagDetection, ...]


def decode_tag_array(raw: RawMessage) -> DecodedTags:
    """An AprilTagDetectionArray message (ROS 2 CDR) -> its frame, stamp and tags (corners as
    written; a zero orientation is no pose). ``DecodeError`` for anything else."""
    import math

    if raw.serialization != 'cdr' or raw.msgtype != APRILTAG_DETECTION_ARRAY:
        msg = f'{raw.topic}: {raw.msgtype} ({raw.serialization}) is not an AprilTagDetectionArray'
        raise DecodeError(msg)
    try:
        message: Any = tag_typestore().deserialize_cdr(bytes(raw.data), APRILTAG_DETECTION_ARRAY)
    except Exception as err:
        msg = f'{raw.topic}: invalid AprilTagDetectionArray: {err}'
        raise DecodeError(msg) from err
    tags = []
    for det in message.detections:
        p = det.pose.pose.pose
        q = (p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)
        pose = None
        if any(q) and all(math.isfinite(v) for v in (*q, p.position.x, p.position.y, p.position.z)):
            pose = TagPose((p.position.x, p.position.y, p.position.z), q)
        corners = tuple((float(c.x), float(c.y)) for c in det.corners)
        tags.append(
            TagDetection(
                str(det.family),
                int(det.id),
                (float(det.center.x), float(det.center.y)),
                corners,  # type: ignore[arg-type]
                pose,
            )
        )
    stamp = message.header.stamp
    return DecodedTags(
        str(message.header.frame_id), stamp.sec * 1_000_000_000 + stamp.nanosec, tuple(tags)
    )
