"""vision_msgs/Detection2DArray ground truth: vision_msgs 4.x (CDR) and noetic (ROS 1)."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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
    ident = '' if serialization == 'ros1' else 'track-1'  # Detection2D.id: ROS 2 only
    assert gt.detections == (
        Detection(-1, '7', 0.9, 80.0, 40.0, 120.0, 60.0, ident),
        Detection(-1, '3', 0.25, 8.0, 16.0, 13.0, 25.0, ident),
    )


@pytest.mark.parametrize('serialization', ['cdr', 'ros1'])
def test_detections_without_hypotheses_get_score_one_and_no_label(serialization):
    data = detection_array(serialization == 'ros1', 5, BOXES[:1], with_results=False)
    gt = decode_detections(RawMessage('/gt', DETECTION2DARRAY, serialization, 0, 0, data))
    ident = '' if serialization == 'ros1' else 'track-1'
    assert gt.detections == (Detection(-1, '', 1.0, 80.0, 40.0, 120.0, 60.0, ident),)


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
        assert got[2:7] == (0.75, 10.0, 20.0, 50.0, 100.0)
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
    ident = 'track-9' if tracking else ''  # noetic's tracking_id is the track's id
    assert gt.detections == (Detection(-1, '41', 0.5, 8.0, 17.0, 12.0, 23.0, ident),)


# -- CDR read by hand, against rosbags' deserialiser ------------------------------------------

_ANY_FLOAT = st.floats(width=64)  # NaN and inf included: such boxes are left out
_HYPOTHESES = st.lists(st.tuples(st.text(max_size=6), _ANY_FLOAT), max_size=3)
_DETECTION = st.fixed_dictionaries(
    {
        'frame_id': st.text(max_size=5),
        'stamp': st.integers(0, 2**31 * 1_000_000_000 - 1),
        'results': _HYPOTHESES,
        'box': st.lists(_ANY_FLOAT, min_size=5, max_size=5),  # cx, cy, theta, size_x, size_y
        'covariance': st.lists(_ANY_FLOAT, min_size=36, max_size=36),
        'id': st.text(max_size=5),
    }
)


def _cdr_array(stamp_ns: int, frame_id: str, detections, little_endian: bool) -> bytes:
    store = msgs.typestore()
    t = store.types
    items = []
    for d in detections:
        pose = pose_with_covariance(store)
        pose = t['geometry_msgs/msg/PoseWithCovariance'](
            pose=pose.pose, covariance=np.array(d['covariance'], dtype=np.float64)
        )
        cx, cy, theta, w, h = d['box']
        center = t['vision_msgs/msg/Pose2D'](
            position=t['vision_msgs/msg/Point2D'](x=cx, y=cy), theta=theta
        )
        results = [
            t['vision_msgs/msg/ObjectHypothesisWithPose'](
                hypothesis=t['vision_msgs/msg/ObjectHypothesis'](class_id=label, score=score),
                pose=pose,
            )
            for label, score in d['results']
        ]
        items.append(
            t['vision_msgs/msg/Detection2D'](
                header=header(store, False, d['stamp'], d['frame_id']),
                results=results,
                bbox=t['vision_msgs/msg/BoundingBox2D'](center=center, size_x=w, size_y=h),
                id=d['id'],
            )
        )
    message = t[DETECTION2DARRAY](header=header(store, False, stamp_ns, frame_id), detections=items)
    return bytes(store.serialize_cdr(message, DETECTION2DARRAY, little_endian=little_endian))


def _as_rosbags_reads_it(data: bytes):
    """(stamp_ns, frame_id, boxes) from rosbags' deserialiser, boxes with a NaN or inf left out;
    None where it refuses the message."""
    try:
        m = msgs.typestore().deserialize_cdr(data, DETECTION2DARRAY)
    except Exception:  # noqa: BLE001 - any refusal
        return None
    boxes = []
    for d in m.detections:
        cx, cy = d.bbox.center.position.x, d.bbox.center.position.y
        w, h = d.bbox.size_x, d.bbox.size_y
        label, score = '', 1.0
        if d.results:
            label, score = d.results[0].hypothesis.class_id, d.results[0].hypothesis.score
        box = Detection(-1, label, score, cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2, d.id)
        if all(math.isfinite(v) for v in box[2:7]):
            boxes.append(box)
    stamp = m.header.stamp
    return stamp.sec * 1_000_000_000 + stamp.nanosec, m.header.frame_id, tuple(boxes)


def _as_decoded(data: bytes):
    try:
        gt = decode_detections(RawMessage('/gt', DETECTION2DARRAY, 'cdr', 0, 0, data))
    except DecodeError:
        return None
    return gt.stamp_ns, gt.frame_id, gt.detections


@settings(max_examples=80, deadline=None)
@given(
    frame_id=st.text(max_size=9),
    stamp=st.integers(0, 2**31 * 1_000_000_000 - 1),
    detections=st.lists(_DETECTION, max_size=4),
    little_endian=st.booleans(),
)
def test_cdr_detection_arrays_read_as_the_rosbags_deserialiser_reads_them(
    frame_id, stamp, detections, little_endian
):
    data = _cdr_array(stamp, frame_id, detections, little_endian)
    expected = _as_rosbags_reads_it(data)
    assert expected is not None
    assert _as_decoded(data) == expected
    assert len(expected[2]) <= len(detections)


@settings(max_examples=150, deadline=None)
@given(
    detections=st.lists(_DETECTION, min_size=1, max_size=3),
    little_endian=st.booleans(),
    edits=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=3),
    cut=st.one_of(st.none(), st.integers(0, 10_000)),
    tail=st.binary(max_size=6),
)
def test_a_corrupted_cdr_detection_array_is_refused_or_read_exactly_as_rosbags_reads_it(
    detections, little_endian, edits, cut, tail
):
    data = bytearray(_cdr_array(7, 'cam', detections, little_endian))
    for at, value in edits:
        data[at % len(data)] = value
    if cut is not None:
        data = data[: cut % (len(data) + 1)]
    data += tail
    assert _as_decoded(bytes(data)) == _as_rosbags_reads_it(bytes(data))


@pytest.mark.parametrize(
    ('found', 'replaced'),
    [
        (b'person\x00', b'person!'),  # a string without its terminating NUL
        (b'person', b'\xfferson'),  # a class id that is not UTF-8
        (b'cam\x00', b'cam!'),
        (b'track\x00', b'track!'),
    ],
)
def test_a_cdr_detection_array_with_a_broken_string_is_refused_as_rosbags_refuses_it(
    found, replaced
):
    box = {
        'frame_id': 'cam', 'stamp': 1, 'results': [('person', 0.5)],
        'box': [10.0, 20.0, 0.0, 4.0, 6.0], 'covariance': [0.0] * 36, 'id': 'track',
    }  # fmt: skip
    data = _cdr_array(7, 'cam', [box], True)
    expected = _as_rosbags_reads_it(data)
    assert expected is not None
    assert _as_decoded(data) == expected
    broken = data.replace(found, replaced, 1)
    assert broken != data
    assert _as_rosbags_reads_it(broken) is None
    assert _as_decoded(broken) is None


def test_a_cdr_detection_array_is_read_without_the_ros2_type_store():
    data = _cdr_array(9, 'cam', [], True)
    code = (
        'import sys\n'
        'from replaybench.decode import decode_detections\n'
        'from replaybench.types import RawMessage\n'
        f'gt = decode_detections(RawMessage("/gt", {DETECTION2DARRAY!r}, "cdr", 0, 0, {data!r}))\n'
        'assert gt.stamp_ns == 9, gt\n'
        'print(sorted(m for m in sys.modules if m.startswith("rosbags.typesys")))\n'
    )
    done = subprocess.run(
        [sys.executable, '-c', code], capture_output=True, text=True, check=True, timeout=60
    )
    assert done.stdout.strip() == '[]'
