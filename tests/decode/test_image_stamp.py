"""``image_stamp``: the header stamp of an image message read without its pixels, the stamp
``decode_image`` gives, for ROS 1, CDR (both byte orders) and Foxglove protobuf messages."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2

from replaybench.decode import decode_image
from replaybench.decode.image import image_stamp
from replaybench.errors import DecodeError
from replaybench.types import RawMessage

F = descriptor_pb2.FieldDescriptorProto
STAMP = 1_700_000_000_123_456_789


@pytest.mark.parametrize('serialization', ['cdr', 'ros1'])
def test_a_raw_image_stamp_is_the_one_decode_image_reads(mk: Any, serialization: str) -> None:
    pixels = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    msg = mk.simple(pixels, serialization, 'rgb8', stamp_ns=STAMP)
    assert image_stamp(msg) == decode_image(msg).stamp_ns == STAMP


def test_a_big_endian_cdr_image_stamp_is_read_in_its_byte_order(mk: Any) -> None:
    pixels = np.zeros((2, 2, 3), dtype=np.uint8)
    msg = mk.image(
        'cdr', pixels.reshape(-1), width=2, height=2, step=6, encoding='rgb8', little_endian=False
    )
    assert image_stamp(msg) == decode_image(msg).stamp_ns == 1_700_000_000_123_456_789


@pytest.mark.parametrize('serialization', ['cdr', 'ros1'])
def test_a_compressed_image_stamp_needs_no_jpeg_decoder(mk: Any, serialization: str) -> None:
    msg = mk.compressed(serialization, b'not a jpeg at all', 'jpeg', stamp_ns=STAMP + 1)
    assert image_stamp(msg) == STAMP + 1
    with pytest.raises(DecodeError):
        decode_image(msg)  # the payload is no image: only the header was read


def test_a_message_too_short_for_a_header_stamp_is_a_decode_error() -> None:
    msg = RawMessage('/cam', 'sensor_msgs/msg/Image', 'cdr', 0, 0, b'\x00\x01\x00\x00\x01')
    with pytest.raises(DecodeError, match='no header stamp'):
        image_stamp(msg)


def _foxglove(name: str) -> tuple[Any, bytes]:
    fields = {
        'RawImage': [('timestamp', 1), ('width', 2), ('height', 3), ('encoding', 4),
                     ('step', 5), ('data', 6), ('frame_id', 7)],
        'CompressedImage': [('timestamp', 1), ('data', 2), ('format', 3), ('frame_id', 4)],
    }[name]  # fmt: skip
    kinds = {'timestamp': F.TYPE_MESSAGE, 'width': F.TYPE_FIXED32, 'height': F.TYPE_FIXED32,
             'step': F.TYPE_FIXED32, 'data': F.TYPE_BYTES}  # fmt: skip
    proto = descriptor_pb2.FileDescriptorProto(
        name=f'foxglove/{name}.proto',
        package='foxglove',
        syntax='proto3',
        dependency=['google/protobuf/timestamp.proto'],
    )
    message = proto.message_type.add(name=name)
    for field_name, number in fields:
        field = message.field.add(
            name=field_name,
            number=number,
            type=kinds.get(field_name, F.TYPE_STRING),
            label=F.LABEL_OPTIONAL,
        )
        if field_name == 'timestamp':
            field.type_name = '.google.protobuf.Timestamp'
    timestamp = descriptor_pb2.FileDescriptorProto()
    timestamp_pb2.DESCRIPTOR.CopyToProto(timestamp)
    schema = descriptor_pb2.FileDescriptorSet(file=[proto, timestamp]).SerializeToString()
    pool = descriptor_pool.DescriptorPool()
    pool.Add(timestamp)
    pool.Add(proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(f'foxglove.{name}')), schema


def test_a_foxglove_raw_image_stamp_is_the_one_decode_image_reads() -> None:
    cls, schema = _foxglove('RawImage')
    pixels = np.arange(2 * 3 * 3, dtype=np.uint8)
    message = cls(width=3, height=2, step=9, encoding='rgb8', data=pixels.tobytes())
    message.timestamp.seconds, message.timestamp.nanos = 1_700_000_000, 999_999_999
    raw = RawMessage(
        '/c', 'foxglove.RawImage', 'protobuf', 0, 0, message.SerializeToString(), schema
    )
    assert image_stamp(raw) == decode_image(raw).stamp_ns == 1_700_000_000_999_999_999


def test_a_foxglove_stamp_after_the_image_bytes_is_found_past_them() -> None:
    cls, schema = _foxglove('CompressedImage')
    head = cls(format='jpeg', data=bytes(range(256)) * 40).SerializeToString()
    tail = cls()
    tail.timestamp.seconds, tail.timestamp.nanos = 12, 34
    data = head + tail.SerializeToString()  # protobuf merges concatenated messages
    raw = RawMessage('/c', 'foxglove.CompressedImage', 'protobuf', 0, 0, data, schema)
    assert image_stamp(raw) == 12_000_000_034
    assert image_stamp(raw._replace(data=head)) == 0  # no timestamp: proto3's zero


def test_a_truncated_foxglove_message_is_a_decode_error() -> None:
    cls, schema = _foxglove('CompressedImage')
    message = cls(format='jpeg', data=b'x' * 100)
    message.timestamp.seconds = 5
    data = message.SerializeToString()[:-10]
    raw = RawMessage('/c', 'foxglove.CompressedImage', 'protobuf', 0, 0, data, schema)
    with pytest.raises(DecodeError, match='protobuf'):
        image_stamp(raw)
