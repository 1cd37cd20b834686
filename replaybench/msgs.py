"""rosbags typestores with vision_msgs registered, and the serialisers replaybench writes with.

ROS 2 uses the ``ROS2_HUMBLE`` store plus vision_msgs 4.x (Humble, Jazzy); these hash like
the real package (RIHS01 of Detection2DArray: ``214274120007f4a6...``). The ROS 2 store also
holds the foxglove_msgs image-annotation types (``foxglove_msgs`` 3.4.x, the layout released since
March 2026) that ``--annotations`` writes for the Foxglove Image panel. ROS 1 uses the
``ROS1_NOETIC`` store plus the vision_msgs definitions released for Noetic (0.0.2) with one
change: ``ObjectHypothesisWithPose.id`` is a ``string`` holding the class name where Noetic has
an ``int64`` class index, because accuracy is scored by class name and a bag has no table from
index to name. Noetic recordings whose ground truth uses the ``int64`` id therefore fail to
deserialize with this store (rosbags reports a size mismatch or a short buffer); only an id of
exactly 4 reads, as a label of four NUL characters.
"""

from __future__ import annotations

import struct
from functools import cache, lru_cache
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy as np
    import numpy.typing as npt
    from rosbags.typesys.store import Typestore

    from replaybench.types import CameraInfo, Detection

__all__ = [
    'CAMERA_INFO',
    'COMPRESSED_IMAGE',
    'DETECTION2DARRAY',
    'FOXGLOVE_MSGS_ROS2',
    'FOXGLOVE_MSGS_VERSION',
    'IMAGE',
    'IMAGE_ANNOTATIONS',
    'VISION_MSGS_ROS1',
    'VISION_MSGS_ROS2',
    'ros2msg_schema',
    'serialize_camera_info',
    'serialize_compressed_image',
    'serialize_detections',
    'serialize_image',
    'serialize_image_fields',
    'typestore',
]

DETECTION2DARRAY = 'vision_msgs/msg/Detection2DArray'
CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
IMAGE = 'sensor_msgs/msg/Image'
COMPRESSED_IMAGE = 'sensor_msgs/msg/CompressedImage'
IMAGE_ANNOTATIONS = 'foxglove_msgs/msg/ImageAnnotations'


def _msg(*lines: str) -> str:
    return ''.join(f'{line}\n' for line in lines)


#: vision_msgs 4.x (ROS 2 Humble and Jazzy), the types replaybench reads and writes.
VISION_MSGS_ROS2: dict[str, str] = {
    'vision_msgs/msg/Detection2DArray': _msg(
        'std_msgs/Header header',
        'Detection2D[] detections',
    ),
    'vision_msgs/msg/Detection2D': _msg(
        'std_msgs/Header header',
        'ObjectHypothesisWithPose[] results',
        'BoundingBox2D bbox',
        'string id',
    ),
    'vision_msgs/msg/BoundingBox2D': _msg(
        'vision_msgs/Pose2D center',
        'float64 size_x',
        'float64 size_y',
    ),
    'vision_msgs/msg/Pose2D': _msg(
        'vision_msgs/Point2D position',
        'float64 theta',
    ),
    'vision_msgs/msg/Point2D': _msg(
        'float64 x',
        'float64 y',
    ),
    'vision_msgs/msg/ObjectHypothesisWithPose': _msg(
        'vision_msgs/ObjectHypothesis hypothesis',
        'geometry_msgs/PoseWithCovariance pose',
    ),
    'vision_msgs/msg/ObjectHypothesis': _msg(
        'string class_id',
        'float64 score',
    ),
}

#: vision_msgs for ROS 1: the Noetic (0.0.2) definitions, except ``string id`` (Noetic: ``int64``).
#: With ``int64 id`` the Detection2DArray md5sum is Noetic's 402071f61477de256df9f1aa45e6e4c8.
VISION_MSGS_ROS1: dict[str, str] = {
    'vision_msgs/msg/Detection2DArray': _msg(
        'Header header',
        'Detection2D[] detections',
    ),
    'vision_msgs/msg/Detection2D': _msg(
        'Header header',
        'ObjectHypothesisWithPose[] results',
        'BoundingBox2D bbox',
        'sensor_msgs/Image source_img',
    ),
    'vision_msgs/msg/ObjectHypothesisWithPose': _msg(
        'string id',
        'float64 score',
        'geometry_msgs/PoseWithCovariance pose',
    ),
    'vision_msgs/msg/BoundingBox2D': _msg(
        'geometry_msgs/Pose2D center',
        'float64 size_x',
        'float64 size_y',
    ),
}


#: The foxglove_msgs release whose ImageAnnotations layout ``--annotations`` writes.
FOXGLOVE_MSGS_VERSION = '3.4.3'

#: foxglove_msgs (ROS 2) image annotations as released since March 2026 (3.4.x): the
#: ``ros/src/foxglove_msgs/ros2`` definitions of foxglove/foxglove-sdk, field for field, comments
#: left out. Against 3.2.4 and earlier, ImageAnnotations gained a leading ``timestamp`` and a
#: trailing ``metadata``, and every annotation a trailing ``metadata``.
FOXGLOVE_MSGS_ROS2: dict[str, str] = {
    'foxglove_msgs/msg/ImageAnnotations': _msg(
        'builtin_interfaces/Time timestamp',
        'foxglove_msgs/CircleAnnotation[] circles',
        'foxglove_msgs/PointsAnnotation[] points',
        'foxglove_msgs/TextAnnotation[] texts',
        'foxglove_msgs/KeyValuePair[] metadata',
    ),
    'foxglove_msgs/msg/CircleAnnotation': _msg(
        'builtin_interfaces/Time timestamp',
        'foxglove_msgs/Point2 position',
        'float64 diameter',
        'float64 thickness',
        'foxglove_msgs/Color fill_color',
        'foxglove_msgs/Color outline_color',
        'foxglove_msgs/KeyValuePair[] metadata',
    ),
    'foxglove_msgs/msg/PointsAnnotation': _msg(
        'builtin_interfaces/Time timestamp',
        'uint8 UNKNOWN=0',
        'uint8 POINTS=1',
        'uint8 LINE_LOOP=2',
        'uint8 LINE_STRIP=3',
        'uint8 LINE_LIST=4',
        'uint8 type',
        'foxglove_msgs/Point2[] points',
        'foxglove_msgs/Color outline_color',
        'foxglove_msgs/Color[] outline_colors',
        'foxglove_msgs/Color fill_color',
        'float64 thickness',
        'foxglove_msgs/KeyValuePair[] metadata',
    ),
    'foxglove_msgs/msg/TextAnnotation': _msg(
        'builtin_interfaces/Time timestamp',
        'foxglove_msgs/Point2 position',
        'string text',
        'float64 font_size',
        'foxglove_msgs/Color text_color',
        'foxglove_msgs/Color background_color',
        'foxglove_msgs/KeyValuePair[] metadata',
    ),
    'foxglove_msgs/msg/KeyValuePair': _msg(
        'string key',
        'string value',
    ),
    'foxglove_msgs/msg/Point2': _msg(
        'float64 x',
        'float64 y',
    ),
    'foxglove_msgs/msg/Color': _msg(
        'float64 r',
        'float64 g',
        'float64 b',
        'float64 a',
    ),
}


_STORES: dict[bool, Typestore] = {}


def typestore(ros1: bool = False) -> Typestore:
    """Return the shared typestore: ROS 2 Humble or ROS 1 Noetic, with vision_msgs registered.

    The ROS 2 store also has the foxglove_msgs annotation types (``FOXGLOVE_MSGS_ROS2``).
    """
    ros1 = bool(ros1)
    if (store := _STORES.get(ros1)) is None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        types: dict[str, Any] = {}
        texts = VISION_MSGS_ROS1 if ros1 else {**VISION_MSGS_ROS2, **FOXGLOVE_MSGS_ROS2}
        for name, text in texts.items():
            types.update(get_types_from_msg(text, name))
        store.register(types)
        store = _STORES.setdefault(ros1, store)
    return store


@cache
def ros2msg_schema(msgtype: str) -> str:
    """Return the ``ros2msg`` schema text of a type as ``ros2 bag record`` writes it into MCAP.

    The type's own definition comes first, then each dependency once (depth-first, in field
    order) after a line of 80 ``=`` and a ``MSG: pkg/Name`` line.
    """
    text: str = typestore().generate_msgdef(msgtype, ros_version=2)[0]
    return text


def _zero_covariance() -> npt.NDArray[np.float64]:
    import numpy as np

    covariance = np.zeros(36, dtype=np.float64)
    covariance.flags.writeable = False
    return covariance


def _serialize(message: object, msgtype: str, ros1: bool) -> bytes:
    store = typestore(ros1)
    if ros1:
        return bytes(store.serialize_ros1(message, msgtype))
    return bytes(store.serialize_cdr(message, msgtype))


#: Header seconds that can be written: ROS 2 ``builtin_interfaces/Time.sec`` is int32; ROS 1
#: ``time`` is unsigned, and the rosbags serialiser packs its seconds as int32 as well.
_SEC_RANGE = {True: (0, 2**31 - 1), False: (-(2**31), 2**31 - 1)}


def _stamp(stamp_ns: int, ros1: bool) -> tuple[int, int]:
    """Split ``stamp_ns`` into (sec, nanosec), saturated to what the header type can hold.

    A stamp beyond 2038 (or before 1970 in ROS 1) cannot be written in a header; it is
    clamped to the nearest representable time rather than failing the whole message. The MCAP
    record around the message keeps the exact time as its log time.
    """
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    low, high = _SEC_RANGE[ros1]
    if sec < low:
        return low, 0
    if sec > high:
        return high, 999_999_999
    return sec, nanosec


def _header(stamp_ns: int, frame_id: str, ros1: bool, seq: int = 0) -> Any:
    types = typestore(ros1).types
    sec, nanosec = _stamp(stamp_ns, ros1)
    stamp = types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)
    if ros1:
        return types['std_msgs/msg/Header'](seq=seq, stamp=stamp, frame_id=frame_id)
    return types['std_msgs/msg/Header'](stamp=stamp, frame_id=frame_id)


def serialize_detections(
    stamp_ns: int,
    frame_id: str,
    detections: Sequence[Detection],
    *,
    ros1: bool = False,
    seq: int = 0,
) -> bytes:
    """Serialise a ``vision_msgs/msg/Detection2DArray`` (ROS 2 CDR, or ROS 1 with ``ros1``).

    Each detection becomes one Detection2D with an axis-aligned box (centre and size) and one
    hypothesis: the label as ``class_id`` (ROS 2) or ``id`` (ROS 1), and the score.
    Every Detection2D carries the array's header. ``seq`` is the ROS 1 header sequence number.
    """
    if not ros1:
        return _detections_cdr(stamp_ns, frame_id, detections)
    import numpy as np

    types = typestore(ros1=True).types
    header = _header(stamp_ns, frame_id, True, seq)
    point = types['geometry_msgs/msg/Point'](x=0.0, y=0.0, z=0.0)
    orientation = types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)
    pose = types['geometry_msgs/msg/PoseWithCovariance'](
        pose=types['geometry_msgs/msg/Pose'](position=point, orientation=orientation),
        covariance=_zero_covariance(),
    )
    detection2d = types['vision_msgs/msg/Detection2D']
    bbox = types['vision_msgs/msg/BoundingBox2D']
    with_pose = types['vision_msgs/msg/ObjectHypothesisWithPose']
    pose2d = types['geometry_msgs/msg/Pose2D']
    empty = types['sensor_msgs/msg/Image'](
        header=_header(0, '', True),
        height=0,
        width=0,
        encoding='',
        is_bigendian=0,
        step=0,
        data=np.zeros(0, dtype=np.uint8),
    )
    items: list[Any] = []
    for det in detections:
        box = bbox(
            center=pose2d(x=(det.x0 + det.x1) / 2, y=(det.y0 + det.y1) / 2, theta=0.0),
            size_x=float(det.x1 - det.x0),
            size_y=float(det.y1 - det.y0),
        )
        hyp = with_pose(id=det.label, score=float(det.score), pose=pose)
        items.append(detection2d(header=header, results=[hyp], bbox=box, source_img=empty))
    message = types[DETECTION2DARRAY](header=header, detections=items)
    return _serialize(message, DETECTION2DARRAY, True)


#: PoseWithCovariance of every hypothesis: position 0, identity orientation, zero covariance.
_IDENTITY_POSE = struct.pack('<7d', 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0) + bytes(36 * 8)


def _cdr_string(out: bytearray, text: str) -> None:
    """Append a CDR string (aligned u32 length with the NUL, the bytes, the NUL)."""
    data = text.encode()
    out += bytes(-(len(out) - 4) % 4)
    out += struct.pack('<I', len(data) + 1)
    out += data
    out += b'\0'


@lru_cache(maxsize=256)
def _frame_id_cdr(frame_id: str) -> bytes:
    """A header's frame_id as CDR after its stamp, padded to 4: what follows is 4-aligned.

    The same bytes wherever a header starts 4-aligned (the array's and every Detection2D's).
    """
    out = bytearray(12)  # encapsulation header + stamp
    _cdr_string(out, frame_id)
    out += bytes(-(len(out) - 4) % 4)
    return bytes(out[12:])


_EMPTY_SEQUENCE = bytes(4)


def _detections_cdr(stamp_ns: int, frame_id: str, detections: Sequence[Detection]) -> bytes:
    """``serialize_detections`` for ROS 2, written directly as little-endian CDR.

    The same bytes as the rosbags and mcap_ros2 serialisers (tests compare them), without
    building a message object per detection: this runs once per replayed frame.
    Alignment counts from the end of the 4-byte encapsulation header.
    """
    sec, nanosec = _stamp(stamp_ns, ros1=False)
    header = struct.pack('<iI', sec, nanosec) + _frame_id_cdr(frame_id)
    if not detections:
        return b'\x00\x01\x00\x00' + header + _EMPTY_SEQUENCE
    out = bytearray(b'\x00\x01\x00\x00')
    out += header
    out += struct.pack('<I', len(detections))
    for det in detections:
        out += bytes(-(len(out) - 4) % 4)
        out += header
        out += b'\x01\x00\x00\x00'  # one hypothesis
        _cdr_string(out, det.label)
        out += bytes(-(len(out) - 4) % 8)
        out += struct.pack('<d', float(det.score))
        out += _IDENTITY_POSE
        out += struct.pack(
            '<5d',
            (det.x0 + det.x1) / 2,
            (det.y0 + det.y1) / 2,
            0.0,
            float(det.x1 - det.x0),
            float(det.y1 - det.y0),
        )
        _cdr_string(out, det.id)  # Detection2D.id
    return bytes(out)


def serialize_camera_info(ci: CameraInfo, *, ros1: bool = False, seq: int = 0) -> bytes:
    """Serialise ``sensor_msgs/msg/CameraInfo`` (ROS 2 CDR, or ROS 1 with ``ros1``)."""
    import numpy as np

    types = typestore(ros1).types
    x_offset, y_offset, roi_height, roi_width, do_rectify = ci.roi
    roi = types['sensor_msgs/msg/RegionOfInterest'](
        x_offset=x_offset,
        y_offset=y_offset,
        height=roi_height,
        width=roi_width,
        do_rectify=bool(do_rectify),
    )
    matrices = {
        'd': np.array(ci.d, dtype=np.float64),
        'k': np.array(ci.k, dtype=np.float64),
        'r': np.array(ci.r, dtype=np.float64),
        'p': np.array(ci.p, dtype=np.float64),
    }
    if ros1:
        matrices = {name.upper(): value for name, value in matrices.items()}
    message = types[CAMERA_INFO](
        header=_header(ci.stamp_ns, ci.frame_id, ros1, seq),
        height=ci.height,
        width=ci.width,
        distortion_model=ci.distortion_model,
        binning_x=ci.binning_x,
        binning_y=ci.binning_y,
        roi=roi,
        **matrices,
    )
    return _serialize(message, CAMERA_INFO, ros1)


def serialize_image(
    stamp_ns: int,
    frame_id: str,
    image: npt.NDArray[Any],
    encoding: str,
    *,
    ros1: bool = False,
    seq: int = 0,
) -> bytes:
    """Serialise ``sensor_msgs/msg/Image`` from an HxW or HxWxC array (packed rows, LE)."""
    import numpy as np

    pixels = np.ascontiguousarray(image, dtype=image.dtype.newbyteorder('<'))
    height, width = int(pixels.shape[0]), int(pixels.shape[1])
    step = pixels.nbytes // height if height else 0
    message = typestore(ros1).types[IMAGE](
        header=_header(stamp_ns, frame_id, ros1, seq),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=pixels.reshape(-1).view(np.uint8),
    )
    return _serialize(message, IMAGE, ros1)


def serialize_image_fields(
    stamp_ns: int,
    frame_id: str,
    *,
    height: int,
    width: int,
    encoding: str,
    step: int,
    data: bytes | memoryview,
    is_bigendian: bool = False,
) -> bytes:
    """Serialise ``sensor_msgs/msg/Image`` (ROS 2 CDR) from its fields, ``data`` as it is."""
    import numpy as np

    message = typestore().types[IMAGE](
        header=_header(stamp_ns, frame_id, False),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=int(bool(is_bigendian)),
        step=step,
        data=np.frombuffer(data, dtype=np.uint8),
    )
    return _serialize(message, IMAGE, False)


def serialize_compressed_image(
    stamp_ns: int,
    frame_id: str,
    data: bytes,
    fmt: str,
    *,
    ros1: bool = False,
    seq: int = 0,
) -> bytes:
    """Serialise ``sensor_msgs/msg/CompressedImage`` (``fmt`` as image_transport writes it)."""
    import numpy as np

    message = typestore(ros1).types[COMPRESSED_IMAGE](
        header=_header(stamp_ns, frame_id, ros1, seq),
        format=fmt,
        data=np.frombuffer(data, dtype=np.uint8),
    )
    return _serialize(message, COMPRESSED_IMAGE, ros1)
