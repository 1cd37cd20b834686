from __future__ import annotations

import subprocess
import sys
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic

from replaybench import msgs
from replaybench.types import CameraInfo, Detection

STAMP = 1_700_000_123_456_789_012
DETS = [
    Detection(0, 'red', 0.875, 10.0, 20.0, 50.0, 80.0),
    Detection(3, 'yellow', 0.5, 1.5, 2.25, 7.5, 9.0),
]


def _info() -> CameraInfo:
    return CameraInfo(
        stamp_ns=STAMP,
        frame_id='camera_optical_frame',
        width=640,
        height=480,
        distortion_model='plumb_bob',
        d=(0.1, -0.2, 0.001, 0.002, 0.0),
        k=(500.0, 0.0, 320.0, 0.0, 501.0, 240.0, 0.0, 0.0, 1.0),
        r=(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        p=(500.0, 0.0, 320.0, -60.0, 0.0, 501.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0),
        binning_x=2,
        binning_y=1,
        roi=(4, 8, 100, 200, True),
    )


def test_ros2_vision_msgs_hash_like_the_real_vision_msgs_4_package() -> None:
    # Type hash that rosidl generates for vision_msgs 4.x Detection2DArray (Jazzy).
    expected = 'RIHS01_214274120007f4a683866481336b70310268cfa107aebe9d594a6acf75bda968'
    assert msgs.typestore().hash_rihs01(msgs.DETECTION2DARRAY) == expected


def test_ros1_vision_msgs_differ_from_the_noetic_release_only_in_a_string_id() -> None:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    noetic = get_typestore(Stores.ROS1_NOETIC)
    types: dict[str, object] = {}
    for name, text in msgs.VISION_MSGS_ROS1.items():
        types.update(get_types_from_msg(text.replace('string id\n', 'int64 id\n'), name))
    noetic.register(types)  # type: ignore[arg-type]
    _, md5sum = noetic.generate_msgdef(msgs.DETECTION2DARRAY, ros_version=1)
    assert md5sum == '402071f61477de256df9f1aa45e6e4c8'  # vision_msgs 0.0.2 as built for Noetic
    ours = msgs.typestore(ros1=True).fielddefs['vision_msgs/msg/ObjectHypothesisWithPose'][1]
    assert ours[0] == ('id', (1, ('string', 0)))


def test_importing_the_modules_loads_no_heavy_library() -> None:
    code = (
        'import sys, replaybench.msgs, replaybench.sinks, replaybench.fixtures; '
        "print(sorted({'cv2', 'mcap', 'mcap_ros2', 'rosbags'} & set(sys.modules)))"
    )
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == '[]'


def test_typestore_is_one_cached_store_per_ros_version() -> None:
    assert msgs.typestore() is msgs.typestore(False) is msgs.typestore(ros1=False)
    assert msgs.typestore(ros1=True) is msgs.typestore(True)
    assert msgs.typestore() is not msgs.typestore(ros1=True)
    assert 'vision_msgs/msg/Point2D' in msgs.typestore().types
    assert 'vision_msgs/msg/Point2D' not in msgs.typestore(ros1=True).types


def test_ros2msg_schema_puts_each_dependency_once_after_80_equals() -> None:
    text = msgs.ros2msg_schema(msgs.DETECTION2DARRAY)
    blocks = text.split('\n' + '=' * 80 + '\n')
    assert blocks[0] == 'std_msgs/Header header\nvision_msgs/Detection2D[] detections'
    names = [block.split('\n', 1)[0] for block in blocks[1:]]
    assert all(name.startswith('MSG: ') for name in names)
    assert len(names) == len(set(names))
    assert set(names) == {
        'MSG: std_msgs/Header',
        'MSG: builtin_interfaces/Time',
        'MSG: vision_msgs/Detection2D',
        'MSG: vision_msgs/ObjectHypothesisWithPose',
        'MSG: vision_msgs/ObjectHypothesis',
        'MSG: geometry_msgs/PoseWithCovariance',
        'MSG: geometry_msgs/Pose',
        'MSG: geometry_msgs/Point',
        'MSG: geometry_msgs/Quaternion',
        'MSG: vision_msgs/BoundingBox2D',
        'MSG: vision_msgs/Pose2D',
        'MSG: vision_msgs/Point2D',
    }
    assert '\nMSG: vision_msgs/BoundingBox2D\nvision_msgs/Pose2D center\n' in text
    # No line of '=' of any other length.
    assert {len(line) for line in text.splitlines() if set(line) == {'='}} == {80}
    assert msgs.ros2msg_schema(msgs.DETECTION2DARRAY) == text


def test_mcap_ros2_decodes_serialized_detections_with_the_schema() -> None:
    decode = generate_dynamic(msgs.DETECTION2DARRAY, msgs.ros2msg_schema(msgs.DETECTION2DARRAY))
    message = decode[msgs.DETECTION2DARRAY](msgs.serialize_detections(STAMP, 'cam', DETS))
    assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == STAMP
    assert message.header.frame_id == 'cam'
    assert len(message.detections) == 2
    for det, got in zip(DETS, message.detections, strict=True):
        assert got.header.frame_id == 'cam'
        assert got.bbox.center.position.x == (det.x0 + det.x1) / 2
        assert got.bbox.center.position.y == (det.y0 + det.y1) / 2
        assert got.bbox.center.theta == 0.0
        assert got.bbox.size_x == det.x1 - det.x0
        assert got.bbox.size_y == det.y1 - det.y0
        assert [r.hypothesis.class_id for r in got.results] == [det.label]
        assert [r.hypothesis.score for r in got.results] == [det.score]
        assert got.id == ''


def _dict_message(detections: list[Detection]) -> dict[str, object]:
    sec, nanosec = divmod(STAMP, 10**9)
    header = {'stamp': {'sec': sec, 'nanosec': nanosec}, 'frame_id': 'cam'}
    pose = {
        'pose': {
            'position': {'x': 0.0, 'y': 0.0, 'z': 0.0},
            'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
        },
        'covariance': [0.0] * 36,
    }
    return {
        'header': header,
        'detections': [
            {
                'header': header,
                'results': [{'hypothesis': {'class_id': d.label, 'score': d.score}, 'pose': pose}],
                'bbox': {
                    'center': {
                        'position': {'x': (d.x0 + d.x1) / 2, 'y': (d.y0 + d.y1) / 2},
                        'theta': 0.0,
                    },
                    'size_x': d.x1 - d.x0,
                    'size_y': d.y1 - d.y0,
                },
                'id': '',
            }
            for d in detections
        ],
    }


@pytest.mark.parametrize('count', [0, 1, 2])
def test_serialized_detections_are_byte_identical_to_the_mcap_ros2_encoder(count: int) -> None:
    encode = serialize_dynamic(msgs.DETECTION2DARRAY, msgs.ros2msg_schema(msgs.DETECTION2DARRAY))
    expected = encode[msgs.DETECTION2DARRAY](_dict_message(DETS[:count]))
    assert msgs.serialize_detections(STAMP, 'cam', DETS[:count]) == expected


def _rosbags_detections(stamp_ns: int, frame_id: str, detections: list[Detection]) -> bytes:
    """The same message built from rosbags' message classes and its CDR serialiser."""
    types = msgs.typestore().types
    sec, nanosec = divmod(stamp_ns, 10**9)
    header = types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec), frame_id=frame_id
    )
    pose = types['geometry_msgs/msg/PoseWithCovariance'](
        pose=types['geometry_msgs/msg/Pose'](
            position=types['geometry_msgs/msg/Point'](x=0.0, y=0.0, z=0.0),
            orientation=types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        covariance=np.zeros(36),
    )
    items = [
        types['vision_msgs/msg/Detection2D'](
            header=header,
            results=[
                types['vision_msgs/msg/ObjectHypothesisWithPose'](
                    hypothesis=types['vision_msgs/msg/ObjectHypothesis'](
                        class_id=d.label, score=d.score
                    ),
                    pose=pose,
                )
            ],
            bbox=types['vision_msgs/msg/BoundingBox2D'](
                center=types['vision_msgs/msg/Pose2D'](
                    position=types['vision_msgs/msg/Point2D'](
                        x=(d.x0 + d.x1) / 2, y=(d.y0 + d.y1) / 2
                    ),
                    theta=0.0,
                ),
                size_x=d.x1 - d.x0,
                size_y=d.y1 - d.y0,
            ),
            id=d.id,
        )
        for d in detections
    ]
    message = types[msgs.DETECTION2DARRAY](header=header, detections=items)
    return bytes(msgs.typestore().serialize_cdr(message, msgs.DETECTION2DARRAY))


_floats = st.floats(-1e6, 1e6, allow_nan=False)
_detection = st.builds(
    Detection,
    st.integers(0, 100),
    st.text(max_size=9),
    st.floats(0, 1),
    _floats,
    _floats,
    _floats,
    _floats,
    st.text(max_size=5),
)


@settings(max_examples=150, deadline=None)
@given(
    stamp=st.integers(0, (2**31 - 1) * 10**9),
    frame_id=st.text(max_size=11),
    detections=st.lists(_detection, max_size=4),
)
def test_detections_cdr_matches_the_rosbags_serialiser_for_any_labels_and_alignment(
    stamp: int, frame_id: str, detections: list[Detection]
) -> None:
    expected = _rosbags_detections(stamp, frame_id, detections)
    assert msgs.serialize_detections(stamp, frame_id, detections) == expected


def test_ros1_detections_carry_the_class_name_score_and_box() -> None:
    data = msgs.serialize_detections(STAMP, 'cam', DETS, ros1=True, seq=7)
    message: Any = msgs.typestore(ros1=True).deserialize_ros1(data, msgs.DETECTION2DARRAY)
    assert message.header.seq == 7
    assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == STAMP
    assert [d.results[0].id for d in message.detections] == ['red', 'yellow']
    assert [d.results[0].score for d in message.detections] == [0.875, 0.5]
    first = message.detections[0]
    assert (first.bbox.center.x, first.bbox.center.y) == (30.0, 50.0)
    assert (first.bbox.size_x, first.bbox.size_y) == (40.0, 60.0)
    assert first.source_img.data.size == 0


@pytest.mark.parametrize(
    ('ros1', 'stamp_ns', 'expected'),
    [
        (False, (2**31 + 5) * 10**9, (2**31 - 1, 999_999_999)),
        (False, -(2**31 + 5) * 10**9, (-(2**31), 0)),
        (True, 2**32 * 10**9, (2**31 - 1, 999_999_999)),
        (True, -1, (0, 0)),
        (False, (2**31 - 1) * 10**9 + 7, (2**31 - 1, 7)),
    ],
)
def test_stamps_the_header_cannot_hold_are_clamped_to_the_nearest_time(
    ros1: bool, stamp_ns: int, expected: tuple[int, int]
) -> None:
    data = msgs.serialize_detections(stamp_ns, 'cam', DETS, ros1=ros1)
    store = msgs.typestore(ros1=ros1)
    message: Any
    if ros1:
        message = store.deserialize_ros1(data, msgs.DETECTION2DARRAY)
    else:
        message = store.deserialize_cdr(data, msgs.DETECTION2DARRAY)
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == expected


def test_camera_info_round_trips_through_cdr_and_ros1() -> None:
    info = _info()
    cdr: Any = msgs.typestore().deserialize_cdr(msgs.serialize_camera_info(info), msgs.CAMERA_INFO)
    ros1: Any = msgs.typestore(ros1=True).deserialize_ros1(
        msgs.serialize_camera_info(info, ros1=True), msgs.CAMERA_INFO
    )
    for got, (d, k, r, p) in (
        (cdr, (cdr.d, cdr.k, cdr.r, cdr.p)),
        (ros1, (ros1.D, ros1.K, ros1.R, ros1.P)),
    ):
        assert got.header.stamp.sec * 10**9 + got.header.stamp.nanosec == STAMP
        assert got.header.frame_id == info.frame_id
        assert (got.width, got.height, got.distortion_model) == (640, 480, 'plumb_bob')
        assert (tuple(d), tuple(k), tuple(r), tuple(p)) == (info.d, info.k, info.r, info.p)
        assert (got.binning_x, got.binning_y) == (2, 1)
        roi = got.roi
        assert (roi.x_offset, roi.y_offset, roi.height, roi.width, roi.do_rectify) == info.roi


def test_camera_info_cdr_decodes_with_mcap_ros2() -> None:
    decode = generate_dynamic(msgs.CAMERA_INFO, msgs.ros2msg_schema(msgs.CAMERA_INFO))
    got = decode[msgs.CAMERA_INFO](msgs.serialize_camera_info(_info()))
    assert got.k == list(_info().k)
    assert got.roi.do_rectify is True


@pytest.mark.parametrize('ros1', [False, True])
def test_images_round_trip_with_packed_rows(ros1: bool) -> None:
    store = msgs.typestore(ros1=ros1)
    deserialize = store.deserialize_ros1 if ros1 else store.deserialize_cdr
    rgb = np.arange(5 * 7 * 3, dtype=np.uint8).reshape(5, 7, 3)
    depth = (np.arange(4 * 6, dtype=np.uint16) * 1000).reshape(4, 6)
    for pixels, encoding in ((rgb, 'rgb8'), (depth[:, ::-1], '16UC1')):
        data = msgs.serialize_image(STAMP, 'cam', pixels, encoding, ros1=ros1)
        message: Any = deserialize(data, msgs.IMAGE)
        assert (message.height, message.width, message.encoding) == (*pixels.shape[:2], encoding)
        assert message.step == pixels.shape[1] * pixels.itemsize * (
            pixels.shape[2] if pixels.ndim == 3 else 1
        )
        assert message.is_bigendian == 0
        got = message.data.view(pixels.dtype).reshape(pixels.shape)
        assert np.array_equal(got, pixels)


def test_compressed_images_keep_format_and_bytes() -> None:
    payload = bytes(range(256)) * 3
    data = msgs.serialize_compressed_image(STAMP, 'cam', payload, 'rgb8; jpeg compressed bgr8')
    message: Any = msgs.typestore().deserialize_cdr(data, msgs.COMPRESSED_IMAGE)
    assert message.format == 'rgb8; jpeg compressed bgr8'
    assert message.data.tobytes() == payload
    assert message.header.frame_id == 'cam'
