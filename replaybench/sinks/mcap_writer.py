"""Detections MCAP writer: one vision_msgs/Detection2DArray per processed frame.

The file is a ROS 2 MCAP (profile ``ros2``, schemas ``ros2msg``, messages ``cdr``, zstd chunks).
It is written as ``<path>.part`` and renamed into place when finished, also when the run stops
on an exception, so an interrupted run leaves a valid MCAP with everything written so far.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench import __version__
from replaybench.msgs import (
    CAMERA_INFO,
    DETECTION2DARRAY,
    ros2msg_schema,
    serialize_camera_info,
    serialize_detections,
)

if TYPE_CHECKING:
    from collections.abc import Sequence
    from types import TracebackType
    from typing import BinaryIO, Self

    from replaybench.types import CameraInfo, Detection

__all__ = ['CHUNK_SIZE', 'DetectionsWriter', 'detections_channel']

#: Target uncompressed chunk size in bytes.
CHUNK_SIZE = 1 << 20


def detections_channel(backend: str, image_topic: str) -> str:
    """Return the detections topic of a backend on an image topic.

    >>> detections_channel('yolo-nano', '/camera/image_raw')
    '/replaybench/yolo_nano/camera/image_raw/detections'
    """
    topic = image_topic if image_topic.startswith('/') else f'/{image_topic}'
    return f'/replaybench/{backend.replace("-", "_")}{topic}/detections'


class DetectionsWriter:
    """Write detections (and the CameraInfo they refer to) into a ROS 2 MCAP, atomically."""

    def __init__(self, path: Path) -> None:
        """Open ``<path>.part`` for writing; ``finish`` renames it to ``path``."""
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.part_path = self.path.with_name(f'{self.path.name}.part')
        self.message_count = 0
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequences: dict[int, int] = {}
        self._finished = False
        self._stream: BinaryIO = self.part_path.open('wb')
        try:
            self._writer: Any = Writer(
                self._stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD
            )
            self._writer.start(profile='ros2', library=f'replaybench {__version__}')
        except BaseException:
            self._stream.close()
            self.part_path.unlink(missing_ok=True)
            raise

    def _channel(self, topic: str, msgtype: str) -> int:
        if (channel_id := self._channels.get(topic)) is None:
            if (schema_id := self._schemas.get(msgtype)) is None:
                schema_id = self._writer.register_schema(
                    name=msgtype, encoding='ros2msg', data=ros2msg_schema(msgtype).encode()
                )
                self._schemas[msgtype] = schema_id
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding='cdr', schema_id=schema_id
            )
            self._channels[topic] = channel_id
            self._sequences[channel_id] = 0
        return channel_id

    def _write(self, topic: str, msgtype: str, log_time_ns: int, data: bytes) -> None:
        if self._finished:
            msg = f'{self.path} is already finished'
            raise ValueError(msg)
        channel_id = self._channel(topic, msgtype)
        self._writer.add_message(
            channel_id=channel_id,
            log_time=log_time_ns,
            data=data,
            publish_time=log_time_ns,
            sequence=self._sequences[channel_id],
        )
        self._sequences[channel_id] += 1
        self.message_count += 1

    def add_camera_info(self, topic: str, log_time_ns: int, ci: CameraInfo) -> None:
        """Copy a CameraInfo message through on its original topic."""
        self._write(topic, CAMERA_INFO, log_time_ns, serialize_camera_info(ci))

    def add(
        self,
        backend: str,
        image_topic: str,
        log_time_ns: int,
        stamp_ns: int,
        frame_id: str,
        detections: Sequence[Detection],
    ) -> None:
        """Write the detections of one frame; ``stamp_ns`` and ``frame_id`` come from the image."""
        self._write(
            detections_channel(backend, image_topic),
            DETECTION2DARRAY,
            log_time_ns,
            serialize_detections(stamp_ns, frame_id, detections),
        )

    def finish(self) -> None:
        """Write the summary, close the file and rename it into place; later calls do nothing."""
        if self._finished:
            return
        self._finished = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()
        self.part_path.replace(self.path)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.finish()
