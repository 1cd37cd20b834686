"""vision_msgs/Detection2DArray ground truth: vision_msgs 4.x (CDR) and noetic (ROS 1)."""

from __future__ import annotations

import numpy as np
import pytest

from replaybench.decode import decode_detections
from replaybench.errors import DecodeError
from replaybench.types import Detection, RawMessage

msgs = pytest.importorskip('replaybench.msgs', reason='replaybench.msgs (vision_msgs) not present')

DETECTION2DARRAY = 'vision_msgs/msg/Detection2DArray'
BOXES = [  # label, score, cx, cy, w, h
    ('7', 0.9, 100.0, 50.0, 40.0, 20.0),
    ('3', 0.25, 10.5, 20.5, 5.0, 9.0),
]


def header(store, ros1: bool, stamp_ns: int, frame_id: str):
    time = store.types['builtin_interfaces/msg/Time'](
        sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
    )
    if ros1:
        return store.types['std_msgs/msg/Header'](seq=0, stamp=time, frame_id=frame_id)
    return store.types['std_msgs/msg/Header'](stamp=time, frame_id=frame_id)


def pose_with_covariance(store):
    t = store.types
    pose = t['geometry_msgs/msg/Pose'](
        position=t['geometry_msgs/msg/Point'](x=0.0, y=0.0, z=0.0),
        orientation=t['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    return t['geometry_msgs/msg/PoseWithCovariance'](pose=pose, covariance=np.zeros(36))


def ros1_id_is_string() -> bool:
    fields = dict(
        msgs.typestore(ros1=True).fielddefs['vision_msgs/msg/ObjectHypothesisWithPose'][1]
    )
    return bool(fields['id'][1][0] == 'string')


def detection_array(ros1: bool, stamp_ns: int, boxes, *, with_results: bool = True) -> bytes:
    store = msgs.typestore(ros1=ros1)
    t = store.types
    head = header(store, ros1, stamp_ns, 'cam')
    detections = []
    for label, score, cx, cy, w, h in boxes:
        if ros1:
            center = t['geometry_msgs/msg/Pose2D'](x=cx, y=cy, theta=0.0)
            # noetic's id is an int64 class index; replaybench.msgs may register it as a string
            result = t['vision_msgs/msg/ObjectHypothesisWithPose'](
                id=label if ros1_id_is_string() else int(label),
                score=score,
                pose=pose_with_covariance(store),
            )
        else:
            center = t['vision_msgs/msg/Pose2D'](
                position=t['vision_msgs/msg/Point2D'](x=cx, y=cy), theta=0.0
            )
            result = t['vision_msgs/msg/ObjectHypothesisWithPose'](
                hypothesis=t['vision_msgs/msg/ObjectHypothesis'](class_id=label, score=score),
                pose=pose_with_covariance(store),
            )
        bbox = t['vision_msgs/msg/BoundingBox2D'](center=center, size_x=w, size_y=h)
        fields = {'header': head, 'results': [result] if with_results else [], 'bbox': bbox}
        if ros1:
            image = t['sensor_msgs/msg/Image'](
                header=head, height=0, width=0, encoding='', is_bigendian=0, step=0,
                data=np.zeros(0, np.uint8),
            )  # fmt: skip
            fields['source_img'] = image
        else:
            fields['id'] = 'track-1'
        names = [f[0] for f in store.fielddefs['vision_msgs/msg/Detection2D'][1]]
        detections.append(t['vision_msgs/msg/Detection2D'](**{k: fields[k] for k in names}))
    message = t[DETECTION2DARRAY](header=head, detections=detections)
    if ros1:
        return bytes(store.serialize_ros1(message, DETECTION2DARRAY))
    return bytes(store.serialize_cdr(message, DETECTION2DARRAY))


@pytest.mark.parametrize('serialization', ['cdr', 'ros1'])
def test_detection_arrays_decode_into_boxes_labels_and_scores(serialization):
    data = detection_array(serialization == 'ros1', 1_234_000_000_567, BOXES)
    gt = decode_detections(RawMessage('/gt', DETECTION2DARRAY, serialization, 0, 0, data))
    assert gt.stamp_ns == 1_234_000_000_567
    assert gt.frame_id == 'cam'
    assert gt.detections == (
        Detection(-1, '7', 0.9, 80.0, 40.0, 120.0, 60.0),
        Detection(-1, '3', 0.25, 8.0, 16.0, 13.0, 25.0),
    )


@pytest.mark.parametrize('serialization', ['cdr', 'ros1'])
def test_detections_without_hypotheses_get_score_one_and_no_label(serialization):
    data = detection_array(serialization == 'ros1', 5, BOXES[:1], with_results=False)
    gt = decode_detections(RawMessage('/gt', DETECTION2DARRAY, serialization, 0, 0, data))
    assert gt.detections == (Detection(-1, '', 1.0, 80.0, 40.0, 120.0, 60.0),)


def test_empty_detection_arrays_decode():
    data = detection_array(False, 5, [])
    assert (
        decode_detections(RawMessage('/gt', DETECTION2DARRAY, 'cdr', 0, 0, data)).detections == ()
    )


def test_broken_detection_arrays_raise_decode_error():
    data = detection_array(False, 5, BOXES)
    with pytest.raises(DecodeError, match='Detection2DArray'):
        decode_detections(RawMessage('/gt', DETECTION2DARRAY, 'cdr', 0, 0, data[:40]))
    with pytest.raises(DecodeError, match='not a Detection2DArray'):
        decode_detections(RawMessage('/gt', 'sensor_msgs/msg/Image', 'cdr', 0, 0, data))


def test_detections_written_by_msgs_read_back_unchanged():
    serialize = getattr(msgs, 'serialize_detections', None)
    if serialize is None:
        pytest.skip('replaybench.msgs.serialize_detections not present')
    dets = [Detection(0, 'person', 0.75, 10.0, 20.0, 50.0, 100.0)]
    for ros1 in (False, True):
        data = serialize(42, 'cam', dets, ros1=ros1)
        gt = decode_detections(
            RawMessage('/gt', DETECTION2DARRAY, 'ros1' if ros1 else 'cdr', 0, 0, data)
        )
        assert (gt.stamp_ns, gt.frame_id) == (42, 'cam')
        (got,) = gt.detections
        assert got[2:] == (0.75, 10.0, 20.0, 50.0, 100.0)
        if not ros1 or ros1_id_is_string():  # an int64 id carries the class index instead
            assert got.label == 'person'


NOETIC_TEXTS = {
    'vision_msgs/msg/Detection2DArray': 'Header header\nDetection2D[] detections\n',
    'vision_msgs/msg/ObjectHypothesisWithPose': (
        'int64 id\nfloat64 score\ngeometry_msgs/PoseWithCovariance pose\n'
    ),
    'vision_msgs/msg/BoundingBox2D': (
        'geometry_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n'
    ),
}


@pytest.mark.parametrize('tracking', [False, True])
def test_genuine_noetic_detections_with_an_integer_id_decode(tracking):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    texts = dict(NOETIC_TEXTS)
    texts['vision_msgs/msg/Detection2D'] = (
        'Header header\nObjectHypothesisWithPose[] results\nBoundingBox2D bbox\n'
        'sensor_msgs/Image source_img\n'
        + ('bool is_tracking\nstring tracking_id\n' if tracking else '')
    )
    types = {}
    for name, text in texts.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    t = store.types
    head = header(store, True, 3_000_000_004, 'cam')
    fields = {
        'header': head,
        'results': [
            t['vision_msgs/msg/ObjectHypothesisWithPose'](
                id=41, score=0.5, pose=pose_with_covariance(store)
            )
        ],
        'bbox': t['vision_msgs/msg/BoundingBox2D'](
            center=t['geometry_msgs/msg/Pose2D'](x=10.0, y=20.0, theta=0.0), size_x=4.0, size_y=6.0
        ),
        'source_img': t['sensor_msgs/msg/Image'](
            header=head, height=0, width=0, encoding='', is_bigendian=0, step=0,
            data=np.zeros(0, np.uint8),
        ),
    }  # fmt: skip
    if tracking:
        fields.update(is_tracking=True, tracking_id='track-9')
    message = t[DETECTION2DARRAY](
        header=head, detections=[t['vision_msgs/msg/Detection2D'](**fields)]
    )
    data = bytes(store.serialize_ros1(message, DETECTION2DARRAY))
    gt = decode_detections(RawMessage('/gt', DETECTION2DARRAY, 'ros1', 0, 0, data))
    assert gt.stamp_ns == 3_000_000_004
    assert gt.detections == (Detection(-1, '41', 0.5, 8.0, 17.0, 12.0, 23.0),)
