"""Foxglove image annotations beside the detections, and source images copied into the file."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from replaybench import msgs
from replaybench.decode import decode_camera_info, decode_image
from replaybench.errors import DecodeError
from replaybench.report.svg import colour
from replaybench.sinks import DetectionsWriter, annotations_channel, ros1_to_ros2_cdr
from replaybench.sinks.annotations import LINE_LOOP, rgba
from replaybench.sources import open_source
from replaybench.types import Detection, RawMessage

if TYPE_CHECKING:
    from collections.abc import Iterator

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / 'fixtures' / 'bags'
SHARED_REAL = (REPO / '..' / 'shared' / 'real').resolve()

T0 = 1_700_000_000_000_000_000
RED = Detection(0, 'red', 0.875, 10.0, 20.0, 30.0, 60.0)
BLUE = Detection(2, 'blue', 0.25, 100.5, 0.0, 120.0, 8.0)
CAM = '/camera/image_raw'


def _decoded(path: Path, topics: list[str] | None = None) -> Iterator[tuple[str, Any, Any, Any]]:
    """(topic, schema, message, decoded) of every cdr message, in log time order."""
    with path.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(topics=topics):
            yield channel.topic, schema, message, decoded


def _raw(path: Path) -> list[tuple[str, Any, Any, Any]]:
    """(topic, schema, channel, message) of every message, undecoded."""
    with path.open('rb') as stream:
        reader = make_reader(stream)
        return [(c.topic, s, c, m) for s, c, m in reader.iter_messages(log_time_order=True)]


def _as_raw(schema: Any, channel: Any, message: Any, seq: int = 0) -> RawMessage:
    """A message of the written file as a source would yield it."""
    protobuf = channel.message_encoding == 'protobuf'
    return RawMessage(
        channel.topic,
        schema.name,
        'protobuf' if protobuf else 'cdr',
        message.log_time,
        seq,
        message.data,
        schema.data if protobuf else b'',
    )


def _stamp(time: Any) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


# ------------------------------------------------------------------------------- annotations


def test_annotations_are_written_beside_the_detections_and_outline_each_box(
    tmp_path: Path,
) -> None:
    path = tmp_path / 'detections.mcap'
    with DetectionsWriter(path, annotations=True) as writer:
        writer.add('hsv', CAM, T0 + 7, T0 + 5, 'cam', [RED, BLUE])
        writer.add('hsv', CAM, T0 + 40, T0 + 33, 'cam', [])
    got = list(_decoded(path))
    assert [(topic, schema.name, schema.encoding) for topic, schema, _, _ in got] == [
        ('/replaybench/hsv/camera/image_raw/detections', msgs.DETECTION2DARRAY, 'ros2msg'),
        ('/replaybench/hsv/camera/image_raw/annotations', msgs.IMAGE_ANNOTATIONS, 'ros2msg'),
        ('/replaybench/hsv/camera/image_raw/detections', msgs.DETECTION2DARRAY, 'ros2msg'),
        ('/replaybench/hsv/camera/image_raw/annotations', msgs.IMAGE_ANNOTATIONS, 'ros2msg'),
    ]
    _, _, message, first = got[1]
    assert (message.log_time, message.publish_time) == (T0 + 7, T0 + 7)
    assert first.circles == []
    assert len(first.points) == len(first.texts) == 2
    for det, box, text in zip([RED, BLUE], first.points, first.texts, strict=True):
        assert box.type == LINE_LOOP == 2
        corners = [(p.x, p.y) for p in box.points]
        assert corners == [(det.x0, det.y0), (det.x1, det.y0), (det.x1, det.y1), (det.x0, det.y1)]
        assert _stamp(box.timestamp) == _stamp(text.timestamp) == T0 + 5
        assert box.thickness > 0
        assert box.fill_color.a == 0.0
        assert box.outline_colors == []
        assert text.text == f'{det.label} {det.score:.2f}'
        assert text.position.x == det.x0
        assert text.font_size > 0
    # the label sits above the box when there is room, inside it at the top edge otherwise
    assert first.texts[0].position.y == RED.y0
    assert first.texts[1].position.y > BLUE.y0
    empty = got[3][3]
    assert (empty.circles, empty.points, empty.texts) == ([], [], [])


def test_each_backend_draws_in_its_report_colour(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    with DetectionsWriter(path, annotations=True, backends=['hsv', 'yolo-nano']) as writer:
        writer.add('yolo-nano', CAM, T0, T0, 'cam', [RED])
        writer.add('hsv', CAM, T0, T0, 'cam', [RED])
        writer.add('extra', CAM, T0, T0, 'cam', [RED])
    outlines = {}
    for topic, _, _, decoded in _decoded(path):
        if topic.endswith('/annotations'):
            c = decoded.points[0].outline_color
            outlines[topic.split('/')[2]] = (c.r, c.g, c.b, c.a)
            assert decoded.texts[0].background_color.r == c.r
    assert outlines == {
        'hsv': rgba(colour(0)),
        'yolo_nano': rgba(colour(1)),
        'extra': rgba(colour(2)),
    }
    assert len(set(outlines.values())) == 3


def test_annotations_are_off_unless_asked_for(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    with DetectionsWriter(path) as writer:
        writer.add('hsv', CAM, T0, T0, 'cam', [RED])
    assert [topic for topic, *_ in _decoded(path)] == [
        '/replaybench/hsv/camera/image_raw/detections'
    ]


def test_annotations_channel_is_named_like_the_detections_channel() -> None:
    assert annotations_channel('yolo-nano', '/cam/image_raw/compressed') == (
        '/replaybench/yolo_nano/cam/image_raw/compressed/annotations'
    )
    assert annotations_channel('hsv', 'cam/image') == '/replaybench/hsv/cam/image/annotations'


def test_annotation_schema_has_the_current_foxglove_msgs_fields_in_order() -> None:
    text = msgs.ros2msg_schema(msgs.IMAGE_ANNOTATIONS)
    blocks = {
        b.split('\n', 1)[0].removeprefix('MSG: '): b.split('\n', 1)[1]
        for b in text.split('\n' + '=' * 80 + '\n')[1:]
    }
    assert text.startswith(
        'builtin_interfaces/Time timestamp\n'
        'foxglove_msgs/CircleAnnotation[] circles\nfoxglove_msgs/PointsAnnotation[] points\n'
        'foxglove_msgs/TextAnnotation[] texts\nfoxglove_msgs/KeyValuePair[] metadata\n'
    )
    fields = {
        name: [ln for ln in body.splitlines() if '=' not in ln] for name, body in blocks.items()
    }
    assert fields['foxglove_msgs/PointsAnnotation'] == [
        'builtin_interfaces/Time timestamp',
        'uint8 type',
        'foxglove_msgs/Point2[] points',
        'foxglove_msgs/Color outline_color',
        'foxglove_msgs/Color[] outline_colors',
        'foxglove_msgs/Color fill_color',
        'float64 thickness',
        'foxglove_msgs/KeyValuePair[] metadata',
    ]
    assert 'uint8 LINE_LOOP=2' in blocks['foxglove_msgs/PointsAnnotation']
    assert fields['foxglove_msgs/TextAnnotation'] == [
        'builtin_interfaces/Time timestamp',
        'foxglove_msgs/Point2 position',
        'string text',
        'float64 font_size',
        'foxglove_msgs/Color text_color',
        'foxglove_msgs/Color background_color',
        'foxglove_msgs/KeyValuePair[] metadata',
    ]
    assert fields['foxglove_msgs/CircleAnnotation'] == [
        'builtin_interfaces/Time timestamp',
        'foxglove_msgs/Point2 position',
        'float64 diameter',
        'float64 thickness',
        'foxglove_msgs/Color fill_color',
        'foxglove_msgs/Color outline_color',
        'foxglove_msgs/KeyValuePair[] metadata',
    ]
    assert fields['foxglove_msgs/KeyValuePair'] == ['string key', 'string value']
    assert fields['foxglove_msgs/Point2'] == ['float64 x', 'float64 y']
    assert fields['foxglove_msgs/Color'] == ['float64 r', 'float64 g', 'float64 b', 'float64 a']


# ------------------------------------------------------------------------------- copied images


def _copy(path: Path, bag: Path, *, prefix: str = '') -> dict[str, list[RawMessage]]:
    """Copy every image and CameraInfo of ``bag`` into ``path``; the source messages by topic."""
    sources: dict[str, list[RawMessage]] = {}
    with open_source(bag) as source, DetectionsWriter(path, annotations=True) as writer:
        for raw in source.messages():
            if raw.topic == '/ground_truth/detections':
                continue
            raw = raw._replace(data=bytes(raw.data))
            writer.add_image(
                prefix + raw.topic,
                raw.log_time_ns,
                raw.msgtype,
                raw.serialization,
                raw.data,
                raw.schema,
            )
            sources.setdefault(prefix + raw.topic, []).append(raw)
            if 'camera_info' not in raw.topic:
                image = decode_image(raw)
                writer.add('hsv', raw.topic, raw.log_time_ns, image.stamp_ns, image.frame_id, [RED])
    return sources


def test_cdr_images_are_copied_byte_for_byte_and_decode_to_the_same_pixels(
    tmp_path: Path,
) -> None:
    path = tmp_path / 'detections.mcap'
    for bag in ('rgb8_raw.mcap', 'jpeg.mcap'):
        sources = _copy(path, BAGS / bag)
        copied: dict[str, list[Any]] = {}
        for topic, schema, channel, message in _raw(path):
            copied.setdefault(topic, []).append((schema, channel, message))
        for topic, originals in sources.items():
            assert len(copied[topic]) == len(originals) == 10
            for original, (schema, channel, message) in zip(originals, copied[topic], strict=True):
                assert (schema.name, schema.encoding) == (original.msgtype, 'ros2msg')
                assert channel.message_encoding == 'cdr'
                assert message.data == original.data
                assert message.log_time == original.log_time_ns
                if 'camera_info' in topic:
                    continue
                want, got = decode_image(original), decode_image(_as_raw(schema, channel, message))
                assert got.stamp_ns == want.stamp_ns
                assert got.frame_id == want.frame_id
                np.testing.assert_array_equal(got.image, want.image)


def test_ros1_images_and_camera_info_are_converted_to_ros2_cdr(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    sources = _copy(path, BAGS / 'rgb8.bag')
    copied = _raw(path)
    topics = {topic for topic, *_ in copied}
    assert {'/camera/image_raw', '/camera/camera_info'} <= topics
    n = {'/camera/image_raw': 0, '/camera/camera_info': 0}
    for topic, schema, channel, message in copied:
        if topic not in n:
            continue
        original = sources[topic][n[topic]]
        n[topic] += 1
        assert (schema.encoding, channel.message_encoding) == ('ros2msg', 'cdr')
        assert schema.data.decode() == msgs.ros2msg_schema(original.msgtype)
        raw = _as_raw(schema, channel, message)
        if topic == '/camera/camera_info':
            assert decode_camera_info(raw) == decode_camera_info(original)
        else:
            want, got = decode_image(original), decode_image(raw)
            assert (got.stamp_ns, got.frame_id, got.encoding) == (
                want.stamp_ns,
                want.frame_id,
                want.encoding,
            )
            np.testing.assert_array_equal(got.image, want.image)
    assert n == {'/camera/image_raw': 10, '/camera/camera_info': 10}


def test_ros1_conversion_equals_deserialising_and_serialising_as_ros2() -> None:
    with open_source(BAGS / 'rgb8.bag') as source:
        raws = [r for r in source.messages() if r.topic != '/ground_truth/detections'][:4]
    ros1, ros2 = msgs.typestore(ros1=True), msgs.typestore()
    for raw in raws:
        old: Any = ros1.deserialize_ros1(bytes(raw.data), raw.msgtype)
        header = ros2.types['std_msgs/msg/Header'](
            stamp=old.header.stamp, frame_id=old.header.frame_id
        )
        values = {
            name.lower(): getattr(old, name)
            for name in old.__dataclass_fields__
            if name not in {'header', '__msgtype__'}
        }
        new = ros2.types[raw.msgtype](header=header, **values)
        assert ros1_to_ros2_cdr(raw.data, raw.msgtype) == bytes(
            ros2.serialize_cdr(new, raw.msgtype)
        )


def test_one_file_holds_images_and_boxes_that_rosbags_reads_in_step(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    _copy(path, BAGS / 'rgb8.bag')
    image_stamps: list[int] = []
    annotation_stamps: list[int] = []
    with AnyReader([path]) as reader:
        assert {c.topic for c in reader.connections} == {
            '/camera/image_raw',
            '/camera/camera_info',
            '/replaybench/hsv/camera/image_raw/detections',
            '/replaybench/hsv/camera/image_raw/annotations',
        }
        for connection, _, data in reader.messages():
            message: Any = reader.deserialize(data, connection.msgtype)
            if connection.topic == '/camera/image_raw':
                assert (message.width, message.height, message.encoding) == (320, 240, 'rgb8')
                image_stamps.append(_stamp(message.header.stamp))
            elif connection.topic.endswith('/annotations'):
                corner = message.points[0].points[0]
                assert (corner.x, corner.y) == (RED.x0, RED.y0)
                annotation_stamps.append(_stamp(message.points[0].timestamp))
    assert len(image_stamps) == 10
    assert annotation_stamps == image_stamps


def _raw_image_schema() -> bytes:
    """A FileDescriptorSet for foxglove.RawImage (fields as in foxglove/schemas)."""
    field = descriptor_pb2.FieldDescriptorProto
    proto = descriptor_pb2.FileDescriptorProto(
        name='foxglove/RawImage.proto',
        package='foxglove',
        syntax='proto3',
        dependency=['google/protobuf/timestamp.proto'],
    )
    message = proto.message_type.add(name='RawImage')
    for name, number, kind in [
        ('timestamp', 1, field.TYPE_MESSAGE),
        ('frame_id', 7, field.TYPE_STRING),
        ('width', 2, field.TYPE_FIXED32),
        ('height', 3, field.TYPE_FIXED32),
        ('encoding', 4, field.TYPE_STRING),
        ('step', 5, field.TYPE_FIXED32),
        ('data', 6, field.TYPE_BYTES),
    ]:
        added = message.field.add(name=name, number=number, type=kind, label=field.LABEL_OPTIONAL)
        if kind == field.TYPE_MESSAGE:
            added.type_name = '.google.protobuf.Timestamp'
    timestamp = descriptor_pb2.FileDescriptorProto()
    timestamp_pb2.DESCRIPTOR.CopyToProto(timestamp)
    data: bytes = descriptor_pb2.FileDescriptorSet(file=[proto, timestamp]).SerializeToString()
    return data


def test_protobuf_images_are_copied_as_sensor_msgs_cdr_with_the_same_pixels(
    tmp_path: Path,
) -> None:
    schema = _raw_image_schema()
    pool = descriptor_pool.DescriptorPool()
    for proto in reversed(descriptor_pb2.FileDescriptorSet.FromString(schema).file):
        pool.Add(proto)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName('foxglove.RawImage'))
    pixels = np.random.default_rng(5).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    image = cls(frame_id='cam', width=8, height=6, encoding='rgb8', step=24, data=pixels.tobytes())
    image.timestamp.seconds, image.timestamp.nanos = 1_700_000_000, 5
    original = RawMessage(
        '/cam', 'foxglove.RawImage', 'protobuf', T0, 0, image.SerializeToString(), schema
    )
    path = tmp_path / 'detections.mcap'
    with DetectionsWriter(path) as writer:
        writer.add_raw(original)
        writer.add_raw(original._replace(log_time_ns=T0 + 1))
    copied = _raw(path)
    assert [message.log_time for *_, message in copied] == [T0, T0 + 1]
    for _, stored_schema, channel, message in copied:
        assert (stored_schema.name, stored_schema.encoding) == (msgs.IMAGE, 'ros2msg')
        assert stored_schema.data == msgs.ros2msg_schema(msgs.IMAGE).encode()
        assert channel.message_encoding == 'cdr'
        got = decode_image(_as_raw(stored_schema, channel, message))
        assert (got.stamp_ns, got.frame_id, got.encoding) == (T0 + 5, 'cam', 'rgb8')
        np.testing.assert_array_equal(got.image, pixels)
    with AnyReader([path]) as reader:
        decoded: list[Any] = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert [(m.width, m.height, m.step, m.is_bigendian) for m in decoded] == [(8, 6, 24, 0)] * 2


def test_real_foxglove_protobuf_recording_copies_to_the_same_pixels(tmp_path: Path) -> None:
    bag = SHARED_REAL / 'derived' / 'ctu_spot_raw_foxglove_protobuf.mcap'
    if not bag.is_file():
        pytest.skip(f'{SHARED_REAL} not present (real recordings are optional)')
    path = tmp_path / 'detections.mcap'
    sources = _copy(path, bag)
    assert len(sources) == 4
    copied = [row for row in _raw(path) if row[0] in sources]
    assert len(copied) == 4
    for topic, stored_schema, channel, message in copied:
        assert (stored_schema.name, channel.message_encoding) == (msgs.IMAGE, 'cdr')
        original = sources[topic][0]
        got = decode_image(_as_raw(stored_schema, channel, message))
        want = decode_image(original)
        assert (got.stamp_ns, got.frame_id, got.encoding) == (
            want.stamp_ns,
            want.frame_id,
            want.encoding,
        )
        np.testing.assert_array_equal(got.image, want.image)


def test_real_ros1_camera_info_converts_to_ros2() -> None:
    bag = SHARED_REAL / 'bags' / 'ros1' / 'ubiquity_aruco_images.bag'
    if not bag.is_file():
        pytest.skip(f'{SHARED_REAL} not present (real recordings are optional)')
    with open_source(bag) as source:
        infos = [r for r in source.messages() if r.msgtype == msgs.CAMERA_INFO]
    assert len(infos) == 15
    for raw in infos:
        converted = RawMessage(
            raw.topic,
            raw.msgtype,
            'cdr',
            raw.log_time_ns,
            raw.seq,
            ros1_to_ros2_cdr(raw.data, raw.msgtype),
        )
        assert decode_camera_info(converted) == decode_camera_info(raw)


def test_messages_that_cannot_be_copied_raise_decode_error_and_write_nothing(
    tmp_path: Path,
) -> None:
    path = tmp_path / 'detections.mcap'
    ros1_detections = msgs.serialize_detections(T0, 'cam', [RED], ros1=True)
    with DetectionsWriter(path) as writer:
        with pytest.raises(DecodeError, match='the types differ'):
            writer.add_image('/gt', T0, msgs.DETECTION2DARRAY, 'ros1', ros1_detections)
        with pytest.raises(DecodeError, match='invalid ROS 1 sensor_msgs/msg/Image'):
            writer.add_image('/cam', T0, msgs.IMAGE, 'ros1', b'\x01\x02')
        with pytest.raises(DecodeError, match='without its schema'):
            writer.add_image('/cam', T0, 'foxglove.RawImage', 'protobuf', b'')
        with pytest.raises(DecodeError, match='no ROS 2 definition of acme_msgs/msg/Frame'):
            writer.add_image('/cam', T0, 'acme_msgs/msg/Frame', 'cdr', b'\x00\x01\x00\x00')
        assert writer.message_count == 0
    assert _raw(path) == []
