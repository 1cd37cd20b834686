"""Small writers for tests that need hand-made bags (bad messages, depth-only, odd layouts)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from mcap.writer import Writer
from rosbags.typesys import Stores, get_typestore

if TYPE_CHECKING:
    from collections.abc import Iterable
    from pathlib import Path

TS = get_typestore(Stores.ROS2_HUMBLE)
Header = TS.types['std_msgs/msg/Header']
Time = TS.types['builtin_interfaces/msg/Time']
Image = TS.types['sensor_msgs/msg/Image']


def image_msg(
    stamp_ns: int,
    pixels: np.ndarray,
    encoding: str = 'rgb8',
    frame_id: str = 'cam',
    step: int | None = None,
    data: bytes | None = None,
) -> object:
    height, width = pixels.shape[:2]
    raw = np.ascontiguousarray(pixels).tobytes() if data is None else data
    return Image(
        header=Header(
            stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=frame_id
        ),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=step if step is not None else (pixels.strides[0] if data is None else width * 3),
        data=np.frombuffer(raw, dtype=np.uint8),
    )


def write_mcap(
    path: Path, messages: Iterable[tuple[str, int, object, str]], chunk_size: int = 1 << 20
) -> None:
    """Write (topic, log_time_ns, msg, msgtype) as a ros2 MCAP with uncompressed chunks."""
    with path.open('wb') as f:
        writer = Writer(f, chunk_size=chunk_size, compression=None)  # type: ignore[arg-type]
        writer.start(profile='ros2', library='tests')
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, log_ns, msg, msgtype in messages:
            if msgtype not in schemas:
                text = TS.generate_msgdef(msgtype, ros_version=2)[0]
                schemas[msgtype] = writer.register_schema(msgtype, 'ros2msg', text.encode())
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, 'cdr', schemas[msgtype])
            payload = bytes(TS.serialize_cdr(msg, msgtype))
            writer.add_message(channels[topic], log_time=log_ns, publish_time=log_ns, data=payload)
        writer.finish()


def noise_frames(n: int, width: int = 64, height: int = 48, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(90, 140, size=(height, width, 3), dtype=np.uint8) for _ in range(n)]
