"""Detections MCAP writer: one vision_msgs/Detection2DArray per processed frame.

The file is a ROS 2 MCAP (profile ``ros2``, schemas ``ros2msg``, messages ``cdr``, zstd chunks).
It is written as ``<path>.part`` and renamed into place when finished, also when the run stops
on an exception, so an interrupted run leaves a valid MCAP with everything written so far.

Optionally it also holds, for viewing in Foxglove, ``foxglove_msgs/msg/ImageAnnotations`` beside
each Detection2DArray (``annotations=True``) and copies of the source images (``add_image``):
ROS 2 CDR messages byte for byte, ROS 1 messages converted to ROS 2 CDR, protobuf messages with
their protobuf schema.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

from replaybench import __version__
from replaybench.errors import DecodeError
from replaybench.msgs import (
    CAMERA_INFO,
    DETECTION2DARRAY,
    IMAGE_ANNOTATIONS,
    ros2msg_schema,
    serialize_camera_info,
    serialize_detections,
    typestore,
)
from replaybench.sinks.annotations import (
    annotations_channel,
    backend_colour,
    serialize_image_annotations,
)

if TYPE_CHECKING:
    from collections.abc import Sequence
    from types import TracebackType
    from typing import BinaryIO, Self

    from replaybench.sinks._mcapio import McapWriter
    from replaybench.types import CameraInfo, Detection, RawMessage, Serialization

__all__ = ['CHUNK_SIZE', 'DetectionsWriter', 'detections_channel', 'ros1_to_ros2_cdr']

#: Target uncompressed chunk size in bytes.
CHUNK_SIZE = 1 << 20


def detections_channel(backend: str, image_topic: str) -> str:
    """Return the detections topic of a backend on an image topic.

    >>> detections_channel('yolo-nano', '/camera/image_raw')
    '/replaybench/yolo_nano/camera/image_raw/detections'
    """
    topic = image_topic if image_topic.startswith('/') else f'/{image_topic}'
    return f'/replaybench/{backend.replace("-", "_")}{topic}/detections'


@cache
def _ros2msg_bytes(msgtype: str) -> bytes:
    """The ros2msg schema text of ``msgtype``, encoded once (its hash is kept with it)."""
    return ros2msg_schema(msgtype).encode()


@cache
def _same_wire_format(msgtype: str) -> bool:
    """Whether ROS 1 ``msgtype`` lays out its fields like the ROS 2 type, except Header.seq."""
    from rosbags.interfaces import Nodetype

    ros1, ros2 = typestore(ros1=True), typestore()

    def same(name: str) -> bool:
        if name == 'std_msgs/msg/Header':  # ROS 1 adds seq, which the conversion drops
            return True
        if name not in ros1.fielddefs or name not in ros2.fielddefs:
            return False
        fields1, fields2 = ros1.fielddefs[name][1], ros2.fielddefs[name][1]
        if len(fields1) != len(fields2):
            return False
        for (_, desc1), (_, desc2) in zip(fields1, fields2, strict=True):
            if desc1 != desc2:
                return False
            sub = desc1[1][0] if desc1[0] in {Nodetype.ARRAY, Nodetype.SEQUENCE} else desc1
            if sub[0] == Nodetype.NAME and not same(sub[1]):
                return False
        return True

    return same(msgtype)


def ros1_to_ros2_cdr(data: bytes | memoryview, msgtype: str) -> bytes:
    """Convert a ROS 1 message to the ROS 2 CDR of the same type (``Header.seq`` is dropped).

    ``msgtype`` uses ROS 2 spelling. Works for types whose fields match the ROS 2 type but for
    the header's seq (sensor_msgs Image, CompressedImage, CameraInfo, ...); the result is the
    bytes ``serialize_cdr`` gives for the ROS 2 message with the same values. Raises
    ``DecodeError`` for any other type and for a message that does not parse.
    """
    if not _same_wire_format(msgtype):
        msg = f'cannot convert ROS 1 {msgtype} to ROS 2: the types differ'
        raise DecodeError(msg)
    try:
        return bytes(typestore().ros1_to_cdr(data, msgtype))
    except Exception as err:
        msg = f'invalid ROS 1 {msgtype}: {err}'
        raise DecodeError(msg) from None


class DetectionsWriter:
    """Write detections (and the CameraInfo they refer to) into a ROS 2 MCAP, atomically.

    With ``annotations`` each ``add`` also writes a ``foxglove_msgs/msg/ImageAnnotations`` on
    ``annotations_channel(backend, image_topic)``, in the backend's colour: the ``backends``
    labels get the report's palette colours in order, other labels the next colours in order
    of first use.
    """

    def __init__(
        self, path: Path, *, annotations: bool = False, backends: Sequence[str] = ()
    ) -> None:
        """Open ``<path>.part`` for writing; ``finish`` renames it to ``path``."""
        from replaybench.sinks._mcapio import McapWriter

        self.path = Path(path)
        self.part_path = self.path.with_name(f'{self.path.name}.part')
        self.annotations = bool(annotations)
        self.message_count = 0
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[tuple[str, str, str], int] = {}
        self._sequences: dict[int, int] = {}
        self._colours: dict[str, str] = {}
        # (backend, image topic) -> detections channel id: the per-frame path looks up one key
        self._detections: dict[tuple[str, str], int] = {}
        for backend in backends:
            self._colour(backend)
        self._finished = False
        self._stream: BinaryIO = self.part_path.open('wb')
        try:
            self._writer: McapWriter = McapWriter(
                self._stream, chunk_size=CHUNK_SIZE, compression='zstd'
            )
            self._writer.start(profile='ros2', library=f'replaybench {__version__}')
        except BaseException:
            self._stream.close()
            self.part_path.unlink(missing_ok=True)
            raise

    def _colour(self, backend: str) -> str:
        label = backend.replace('-', '_')
        if (colour := self._colours.get(label)) is None:
            colour = self._colours[label] = backend_colour(len(self._colours))
        return colour

    def _channel(
        self,
        topic: str,
        schema_name: str,
        schema_encoding: str,
        schema_data: bytes,
        message_encoding: str,
    ) -> int:
        key = (topic, schema_name, message_encoding)
        if (channel_id := self._channels.get(key)) is None:
            schema_key = (schema_name, schema_encoding, schema_data)
            if (schema_id := self._schemas.get(schema_key)) is None:
                schema_id = self._writer.register_schema(
                    name=schema_name, encoding=schema_encoding, data=schema_data
                )
                self._schemas[schema_key] = schema_id
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding=message_encoding, schema_id=schema_id
            )
            self._channels[key] = channel_id
            self._sequences[channel_id] = 0
        return channel_id

    def _write(
        self,
        topic: str,
        msgtype: str,
        log_time_ns: int,
        data: bytes | memoryview,
        *,
        schema: bytes | None = None,
        encoding: str = 'cdr',
    ) -> None:
        if self._finished:
            msg = f'{self.path} is already finished'
            raise ValueError(msg)
        if encoding == 'protobuf':
            channel_id = self._channel(topic, msgtype, 'protobuf', schema or b'', 'protobuf')
        else:
            schema_data = schema or _ros2msg_bytes(msgtype)
            channel_id = self._channel(topic, msgtype, 'ros2msg', schema_data, 'cdr')
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
        """Write the detections of one frame; ``stamp_ns`` and ``frame_id`` come from the image.

        With ``annotations`` the frame's ImageAnnotations follow on the annotations channel.
        """
        channel_id = self._detections.get((backend, image_topic))
        if channel_id is None or self._finished:
            self._write(
                detections_channel(backend, image_topic),
                DETECTION2DARRAY,
                log_time_ns,
                serialize_detections(stamp_ns, frame_id, detections),
            )
            self._detections[(backend, image_topic)] = self._channels[
                (detections_channel(backend, image_topic), DETECTION2DARRAY, 'cdr')
            ]
        else:
            sequence = self._sequences[channel_id]
            self._writer.add_message(
                channel_id,
                log_time_ns,
                serialize_detections(stamp_ns, frame_id, detections),
                log_time_ns,
                sequence,
            )
            self._sequences[channel_id] = sequence + 1
            self.message_count += 1
        if self.annotations:
            self._write(
                annotations_channel(backend, image_topic),
                IMAGE_ANNOTATIONS,
                log_time_ns,
                serialize_image_annotations(stamp_ns, detections, self._colour(backend)),
            )

    def add_image(
        self,
        topic: str,
        log_time_ns: int,
        msgtype: str,
        serialization: Serialization,
        data: bytes | memoryview,
        schema: bytes = b'',
    ) -> None:
        """Copy a source message (an image or its CameraInfo) onto ``topic``.

        ``cdr``: the bytes unchanged, under ``schema`` (ros2msg text) or, when empty, the
        definition of ``msgtype`` in the ROS 2 typestore. ``ros1``: converted to ROS 2 CDR
        (``ros1_to_ros2_cdr``). ``protobuf``: the bytes unchanged on a protobuf channel whose
        schema is ``schema`` (the FileDescriptorSet the source gives). Raises ``DecodeError``
        for a message that cannot be copied, before anything is written.
        """
        if serialization == 'cdr':
            if not schema and msgtype not in typestore().fielddefs:
                msg = f'cannot copy {topic}: no ROS 2 definition of {msgtype} (and no schema)'
                raise DecodeError(msg)
            self._write(topic, msgtype, log_time_ns, data, schema=schema or None)
        elif serialization == 'ros1':
            self._write(topic, msgtype, log_time_ns, ros1_to_ros2_cdr(data, msgtype))
        elif serialization == 'protobuf':
            if not schema:
                msg = f'cannot copy {topic}: protobuf {msgtype} without its schema'
                raise DecodeError(msg)
            self._write(topic, msgtype, log_time_ns, data, schema=schema, encoding='protobuf')
        else:
            msg = f'cannot copy {topic}: unknown serialization {serialization!r}'
            raise DecodeError(msg)

    def add_raw(self, message: RawMessage) -> None:
        """``add_image`` for a source message, on its own topic at its own log time."""
        self.add_image(
            message.topic,
            message.log_time_ns,
            message.msgtype,
            message.serialization,
            message.data,
            message.schema,
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
