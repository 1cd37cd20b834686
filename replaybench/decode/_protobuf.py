"""Protobuf messages decoded with the FileDescriptorSet their channel carries."""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

from replaybench.errors import DecodeError

if TYPE_CHECKING:
    from collections.abc import Iterator

    from replaybench.types import RawMessage

__all__ = ['message_class', 'parse_protobuf', 'stamp_ns', 'wire_timestamp']


@functools.lru_cache(maxsize=64)
def message_class(name: str, schema: bytes) -> Any:
    """The generated message class for ``name`` in the FileDescriptorSet ``schema`` (cached)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    try:
        fds = descriptor_pb2.FileDescriptorSet.FromString(schema)
        files = {f.name: f for f in fds.file}
        pool = descriptor_pool.DescriptorPool()
        added: set[str] = set()

        def add(file_name: str) -> None:
            if file_name in added:
                return
            added.add(file_name)
            proto = files.get(file_name)
            if proto is None:
                msg = f'schema of {name} lacks {file_name}'
                raise DecodeError(msg)
            for dep in proto.dependency:
                add(dep)
            pool.Add(proto)

        for file_name in files:
            add(file_name)
        return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    except DecodeError:
        raise
    except Exception as err:
        msg = f'unusable protobuf schema for {name}: {err}'
        raise DecodeError(msg) from err


def parse_protobuf(msg: RawMessage) -> Any:
    """``msg`` parsed with the class its schema defines; DecodeError when it cannot be."""
    if not msg.schema:
        msg_ = f'protobuf message on {msg.topic} without a schema'
        raise DecodeError(msg_)
    schema = msg.schema if isinstance(msg.schema, bytes) else bytes(msg.schema)
    cls = message_class(msg.msgtype, schema)
    try:
        return cls.FromString(msg.data)
    except Exception as err:
        msg_ = f'invalid {msg.msgtype} message: {err}'
        raise DecodeError(msg_) from err


def stamp_ns(timestamp: Any) -> int:
    """Nanoseconds of a google.protobuf.Timestamp."""
    return int(timestamp.seconds) * 1_000_000_000 + int(timestamp.nanos)


def _varint(data: memoryview, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if pos >= len(data) or shift > 63:
            msg = 'truncated or overlong protobuf varint'
            raise DecodeError(msg)
        byte = data[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, pos


def _fields(data: memoryview) -> Iterator[tuple[int, int, int, int]]:
    """(field number, wire type, value or start, end) of each field, read off the wire."""
    pos = 0
    while pos < len(data):
        key, pos = _varint(data, pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _varint(data, pos)
            yield number, wire, value, pos
            continue
        if wire == 2:
            size, pos = _varint(data, pos)
            end = pos + size
        elif wire in (1, 5):
            end = pos + (8 if wire == 1 else 4)
        else:
            msg = f'protobuf wire type {wire} is not read here'
            raise DecodeError(msg)
        if end > len(data):
            msg = 'protobuf field runs past the end of the message'
            raise DecodeError(msg)
        yield number, wire, pos, end
        pos = end


def _signed(value: int, bits: int) -> int:
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >> (bits - 1) else value


def wire_timestamp(data: memoryview | bytes, field: int = 1) -> int:
    """Nanoseconds of the google.protobuf.Timestamp in field ``field`` of a serialized message
    (foxglove.RawImage and CompressedImage: field 1), read off the wire without a schema and
    without copying the rest (the image bytes are skipped). A message without it: 0, as proto3
    reads it."""
    view = data if isinstance(data, memoryview) else memoryview(data)
    seconds = nanos = 0
    for number, wire, start, end in _fields(view):
        if number != field or wire != 2:
            continue
        for sub, sub_wire, value, _ in _fields(view[start:end]):  # a repeated field merges
            if sub_wire != 0:
                continue
            if sub == 1:
                seconds = _signed(value, 64)
            elif sub == 2:
                nanos = _signed(value, 32)
    return seconds * 1_000_000_000 + nanos
