"""Protobuf messages decoded with the FileDescriptorSet their channel carries."""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

from replaybench.errors import DecodeError

if TYPE_CHECKING:
    from replaybench.types import RawMessage

__all__ = ['message_class', 'parse_protobuf', 'stamp_ns']


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
