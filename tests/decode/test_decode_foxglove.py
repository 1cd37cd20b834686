"""Foxglove protobuf images and calibrations, decoded with the schema their channel carries."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2

from replaybench.decode import decode_camera_info, decode_image
from replaybench.errors import DecodeError
from replaybench.types import RawMessage

F = descriptor_pb2.FieldDescriptorProto

# (name, number, type, repeated) as in foxglove/schemas
FIELDS = {
    'RawImage': [
        ('timestamp', 1, F.TYPE_MESSAGE, False), ('frame_id', 7, F.TYPE_STRING, False),
        ('width', 2, F.TYPE_FIXED32, False), ('height', 3, F.TYPE_FIXED32, False),
        ('encoding', 4, F.TYPE_STRING, False), ('step', 5, F.TYPE_FIXED32, False),
        ('data', 6, F.TYPE_BYTES, False),
    ],
    'CompressedImage': [
        ('timestamp', 1, F.TYPE_MESSAGE, False), ('frame_id', 4, F.TYPE_STRING, False),
        ('data', 2, F.TYPE_BYTES, False), ('format', 3, F.TYPE_STRING, False),
    ],
    'CameraCalibration': [
        ('timestamp', 1, F.TYPE_MESSAGE, False), ('frame_id', 9, F.TYPE_STRING, False),
        ('width', 2, F.TYPE_FIXED32, False), ('height', 3, F.TYPE_FIXED32, False),
        ('distortion_model', 4, F.TYPE_STRING, False), ('D', 5, F.TYPE_DOUBLE, True),
        ('K', 6, F.TYPE_DOUBLE, True), ('R', 7, F.TYPE_DOUBLE, True), ('P', 8, F.TYPE_DOUBLE, True),
    ],
}  # fmt: skip


def schema(name: str) -> bytes:
    """A FileDescriptorSet for foxglove.<name>, the dependency listed after its user."""
    proto = descriptor_pb2.FileDescriptorProto(
        name=f'foxglove/{name}.proto',
        package='foxglove',
        syntax='proto3',
        dependency=['google/protobuf/timestamp.proto'],
    )
    message = proto.message_type.add(name=name)
    for field_name, number, kind, repeated in FIELDS[name]:
        field = message.field.add(
            name=field_name,
            number=number,
            type=kind,
            label=F.LABEL_REPEATED if repeated else F.LABEL_OPTIONAL,
        )
        if kind == F.TYPE_MESSAGE:
            field.type_name = '.google.protobuf.Timestamp'
    timestamp = descriptor_pb2.FileDescriptorProto()
    timestamp_pb2.DESCRIPTOR.CopyToProto(timestamp)
    return bytes(descriptor_pb2.FileDescriptorSet(file=[proto, timestamp]).SerializeToString())


def make(name: str, **fields) -> RawMessage:
    data = schema(name)
    pool = descriptor_pool.DescriptorPool()
    fds = descriptor_pb2.FileDescriptorSet.FromString(data)
    for proto in reversed(fds.file):
        pool.Add(proto)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(f'foxglove.{name}'))
    message = cls(**fields)
    message.timestamp.seconds = 1_700_000_000
    message.timestamp.nanos = 250
    return RawMessage(
        '/cam/image', f'foxglove.{name}', 'protobuf', 9, 0, message.SerializeToString(), data
    )


def test_foxglove_raw_image_rgb8_with_padding_decodes():
    pixels = np.random.default_rng(3).integers(0, 256, (171, 224, 3), dtype=np.uint8)
    step = 224 * 3 + 4
    padded = np.zeros((171, step), np.uint8)
    padded[:, : 224 * 3] = pixels.reshape(171, -1)
    msg = make(
        'RawImage', frame_id='hand', width=224, height=171, encoding='rgb8', step=step,
        data=padded.tobytes(),
    )  # fmt: skip
    decoded = decode_image(msg)
    assert (decoded.encoding, decoded.source_encoding) == ('rgb8', 'rgb8')
    assert (decoded.stamp_ns, decoded.frame_id) == (1_700_000_000_000_000_250, 'hand')
    np.testing.assert_array_equal(decoded.image, pixels)


def test_foxglove_raw_image_16uc1_is_little_endian_depth():
    depth = np.arange(12, dtype='<u2').reshape(3, 4) * 1000
    msg = make('RawImage', width=4, height=3, encoding='16UC1', step=8, data=depth.tobytes())
    decoded = decode_image(msg)
    assert decoded.encoding == 'mono16'
    assert decoded.is_depth is True
    np.testing.assert_array_equal(decoded.image, depth)


def test_foxglove_compressed_image_decodes():
    bgr = np.zeros((20, 30, 3), np.uint8)
    bgr[..., 2] = 250
    ok, png = cv2.imencode('.png', bgr)
    assert ok
    msg = make('CompressedImage', frame_id='c', format='png', data=png.tobytes())
    decoded = decode_image(msg)
    assert (decoded.encoding, decoded.source_encoding, decoded.frame_id) == ('bgr8', 'png', 'c')
    np.testing.assert_array_equal(decoded.image, bgr)


def test_foxglove_camera_calibration_decodes():
    k = [500.0, 0, 320, 0, 510.0, 240, 0, 0, 1]
    p = [500.0, 0, 320, 0, 0, 510.0, 240, 0, 0, 0, 1, 0]
    msg = make(
        'CameraCalibration', frame_id='cam', width=640, height=480, distortion_model='plumb_bob',
        D=[0.1, -0.2, 0, 0, 0], K=k, R=[1, 0, 0, 0, 1, 0, 0, 0, 1], P=p,
    )  # fmt: skip
    info = decode_camera_info(msg)
    assert (info.width, info.height, info.frame_id) == (640, 480, 'cam')
    assert info.distortion_model == 'plumb_bob'
    assert info.d == (0.1, -0.2, 0, 0, 0)
    assert info.k == tuple(k)
    assert info.p == tuple(p)
    assert info.stamp_ns == 1_700_000_000_000_000_250
    assert (info.topic, info.log_time_ns) == ('/cam/image', 9)


def test_protobuf_without_or_with_a_wrong_schema_is_rejected():
    msg = make('RawImage', width=1, height=1, encoding='mono8', step=1, data=b'\x00')
    with pytest.raises(DecodeError, match='without a schema'):
        decode_image(msg._replace(schema=b''))
    with pytest.raises(DecodeError, match='schema'):
        decode_image(msg._replace(schema=schema('CompressedImage')))
    with pytest.raises(DecodeError):
        decode_image(msg._replace(data=b'\xff\xff\xff'))
    with pytest.raises(DecodeError, match='cdr'):
        decode_image(msg._replace(serialization='cdr'))


def read_mcap(path):
    from mcap.reader import make_reader

    with path.open('rb') as f:
        for schema_, channel, message in make_reader(f).iter_messages():
            assert schema_ is not None
            yield RawMessage(
                channel.topic, schema_.name, 'protobuf', message.log_time, 0,
                message.data, schema_.data,
            )  # fmt: skip


def test_real_foxglove_raw_images_decode_like_the_ros1_bag(real_dir):
    path = real_dir / 'derived' / 'ctu_spot_raw_foxglove_protobuf.mcap'
    shapes = {}
    for msg in read_mcap(path):
        decoded = decode_image(msg)
        shapes[msg.topic] = (decoded.encoding, decoded.image.shape, int(decoded.image.max()))
    assert shapes['/spot/camera/hand_color/image'][:2] == ('rgb8', (480, 640, 3))
    assert shapes['/spot/camera/frontleft/image'][:2] == ('mono8', (480, 640))
    assert shapes['/spot/camera/hand_mono/image'][:2] == ('mono8', (171, 224))
    assert shapes['/spot/depth/frontleft/image'] == ('mono16', (240, 424), 4820)


def test_real_foxglove_compressed_images_and_calibrations_decode(real_dir):
    derived = real_dir / 'derived'
    got = {}
    for msg in read_mcap(derived / 'ctu_spot_compressed_foxglove_protobuf.mcap'):
        decoded = decode_image(msg)
        got[msg.topic] = (decoded.source_encoding, decoded.encoding, decoded.image.shape)
    assert got['/spot/camera/hand_color/image/compressed'] == ('jpeg', 'bgr8', (480, 640, 3))
    assert got['/spot/depth/frontleft/image/compressed'] == ('png', 'mono16', (240, 424))
    infos = []
    for msg in read_mcap(derived / 'ubiquity_aruco_images_foxglove_protobuf.mcap'):
        if msg.msgtype == 'foxglove.CameraCalibration':
            infos.append(decode_camera_info(msg))
        else:
            assert decode_image(msg).image.shape == (960, 1280, 3)
    assert len(infos) == 15
    assert {(i.width, i.height, i.frame_id) for i in infos} == {(1280, 960, 'raspicam')}
    assert round(infos[0].k[0], 1) == 1014.3
    assert round(infos[0].k[4], 1) == 1011.7
