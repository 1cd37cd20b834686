"""Message builders for the decode tests: real rosbags serialisers, hand-made pixel buffers."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from replaybench.types import RawMessage, TopicInfo

if TYPE_CHECKING:
    from collections.abc import Collection, Iterator

    from replaybench.types import Serialization

REAL = (Path(__file__).resolve().parents[2] / '..' / 'shared' / 'real').resolve()

STORES = {
    'cdr': get_typestore(Stores.ROS2_HUMBLE),
    'ros1': get_typestore(Stores.ROS1_NOETIC),
}


@pytest.fixture(scope='session')
def real_dir() -> Path:
    if not REAL.is_dir():
        pytest.skip(f'{REAL} (…/shared/real) not present')
    return REAL


def header(serialization: Serialization, stamp_ns: int, frame_id: str) -> Any:
    store = STORES[serialization]
    time = store.types['builtin_interfaces/msg/Time'](
        sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
    )
    cls = store.types['std_msgs/msg/Header']
    if serialization == 'ros1':
        return cls(seq=7, stamp=time, frame_id=frame_id)
    return cls(stamp=time, frame_id=frame_id)


def serialize(
    serialization: Serialization, message: Any, msgtype: str, little_endian: bool = True
) -> bytes:
    store = STORES[serialization]
    if serialization == 'ros1':
        return bytes(store.serialize_ros1(message, msgtype))
    return bytes(store.serialize_cdr(message, msgtype, little_endian=little_endian))


def pack_rows(pixels: np.ndarray, step: int, *, big_endian: bool = False) -> np.ndarray:
    """The bytes of ``pixels`` (HxW or HxWxC), each row padded with 0xAB to ``step`` bytes."""
    order: Literal['>', '<'] = '>' if big_endian else '<'
    rows = np.ascontiguousarray(pixels, dtype=pixels.dtype.newbyteorder(order))
    rows = rows.reshape(rows.shape[0], -1).view(np.uint8)
    out = np.full((rows.shape[0], step), 0xAB, dtype=np.uint8)
    out[:, : rows.shape[1]] = rows
    return out.reshape(-1)


def image_message(
    serialization: Serialization,
    data: np.ndarray,
    *,
    width: int,
    height: int,
    step: int,
    encoding: str,
    is_bigendian: int = 0,
    stamp_ns: int = 1_700_000_000_123_456_789,
    frame_id: str = 'camera_optical',
    little_endian: bool = True,
    topic: str = '/cam/image_raw',
) -> RawMessage:
    store = STORES[serialization]
    msg = store.types['sensor_msgs/msg/Image'](
        header=header(serialization, stamp_ns, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=is_bigendian,
        step=step,
        data=np.asarray(data, dtype=np.uint8),
    )
    raw = serialize(serialization, msg, 'sensor_msgs/msg/Image', little_endian)
    return RawMessage(topic, 'sensor_msgs/msg/Image', serialization, 5, 0, raw)


def compressed_message(
    serialization: Serialization,
    payload: bytes,
    fmt: str,
    *,
    stamp_ns: int = 1_700_000_000_000_000_042,
    frame_id: str = 'camera_optical',
    topic: str = '/cam/image_raw/compressed',
) -> RawMessage:
    store = STORES[serialization]
    msg = store.types['sensor_msgs/msg/CompressedImage'](
        header=header(serialization, stamp_ns, frame_id),
        format=fmt,
        data=np.frombuffer(payload, dtype=np.uint8),
    )
    raw = serialize(serialization, msg, 'sensor_msgs/msg/CompressedImage')
    return RawMessage(topic, 'sensor_msgs/msg/CompressedImage', serialization, 5, 0, raw)


def simple_image(
    pixels: np.ndarray, serialization: Serialization, encoding: str, **kw: Any
) -> RawMessage:
    """An Image message of ``pixels`` with packed rows."""
    height, width = pixels.shape[:2]
    step = pixels[0].nbytes
    data = pack_rows(pixels, step, big_endian=bool(kw.get('is_bigendian')))
    return image_message(
        serialization, data, width=width, height=height, step=step, encoding=encoding, **kw
    )


class ListSource:
    """A tiny in-memory source: the two methods decode needs, over a list of messages."""

    def __init__(self, messages: list[RawMessage]) -> None:
        self._messages = sorted(messages, key=lambda m: (m.log_time_ns, m.topic))
        self.opened = 0

    def topics(self) -> list[TopicInfo]:
        by_topic: dict[str, list[RawMessage]] = {}
        for m in self._messages:
            by_topic.setdefault(m.topic, []).append(m)
        return [
            TopicInfo(
                t,
                ms[0].msgtype,
                ms[0].serialization,
                len(ms),
                ms[0].log_time_ns,
                ms[-1].log_time_ns,
            )
            for t, ms in sorted(by_topic.items())
        ]

    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[RawMessage]:
        self.opened += 1
        for m in self._messages:
            if topics is None or m.topic in topics:
                yield m


@pytest.fixture(scope='session')
def mk() -> SimpleNamespace:
    """The builders above, for test modules."""
    return SimpleNamespace(
        stores=STORES,
        header=header,
        serialize=serialize,
        pack_rows=pack_rows,
        image=image_message,
        compressed=compressed_message,
        simple=simple_image,
        source=ListSource,
    )
