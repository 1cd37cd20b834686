"""Detections MCAP writer: one vision_msgs/Detection2DArray per processed frame.

The file is a ROS 2 MCAP as ``ros2 bag record`` writes it: profile ``ros2``, every schema
``ros2msg`` and every message ``cdr``, zstd chunks, messages in non-decreasing log time across
channels, each channel with the ``offered_qos_profiles`` and ``topic_type_hash`` metadata of
rosbag2's MCAP storage and a ``rosbag2`` metadata record (``serialized_metadata``, version 8).

Messages are staged as they come (``<path>.stage``: the bytes, plus four numbers each in memory)
and written at ``finish``, merged by log time with a fixed tie order: copied source messages
(CameraInfo, images) first, then detections, then annotations, each by channel then arrival. The
MCAP is written as ``<path>.part`` and renamed into place, also when the run stops on an
exception, so an interrupted run leaves a valid MCAP with everything added so far.

Optionally it also holds, for viewing in Foxglove, ``foxglove_msgs/msg/ImageAnnotations`` beside
each Detection2DArray (``annotations=True``) and copies of the source images (``add_image``):
ROS 2 CDR messages byte for byte, ROS 1 messages converted to ROS 2 CDR, Foxglove protobuf
images and calibrations converted to their sensor_msgs counterparts in ROS 2 CDR.
"""

from __future__ import annotations

from array import array
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from replaybench._version import __version__
from replaybench.errors import DecodeError
from replaybench.msgs import (
    CAMERA_INFO,
    COMPRESSED_IMAGE,
    DETECTION2DARRAY,
    IMAGE,
    IMAGE_ANNOTATIONS,
    ros2msg_schema,
    serialize_camera_info,
    serialize_compressed_image,
    serialize_detections,
    serialize_image_fields,
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

    from replaybench.types import CameraInfo, Detection, RawMessage, Serialization

__all__ = [
    'CHUNK_SIZE',
    'OFFERED_QOS_PROFILES',
    'DetectionsWriter',
    'detections_channel',
    'protobuf_to_ros2_cdr',
    'ros1_to_ros2_cdr',
]

#: Target uncompressed chunk size in bytes.
CHUNK_SIZE = 1 << 20

#: The QoS every channel offers, as rosbag2 (metadata version <= 8, integer policies) writes a
#: recorded publisher's: reliable, volatile, history and depth unknown, no deadline, lifespan or
#: lease limit.
OFFERED_QOS_PROFILES = """- history: 3
  depth: 0
  reliability: 1
  durability: 2
  deadline:
    sec: 9223372036
    nsec: 854775807
  lifespan:
    sec: 9223372036
    nsec: 854775807
  liveliness: 1
  liveliness_lease_duration:
    sec: 9223372036
    nsec: 854775807
  avoid_ros_namespace_conventions: false"""

# tie order of messages with one log time: copied source messages, detections, annotations
_SOURCE, _DETECTIONS, _ANNOTATIONS = 0, 1, 2


def detections_channel(backend: str, image_topic: str) -> str:
    """Return the detections topic of a backend on an image topic.

    >>> detections_channel('yolo-nano', '/camera/image_raw')
    '/replaybench/yolo_nano/camera/image_raw/detections'
    """
    topic = image_topic if image_topic.startswith('/') else f'/{image_topic}'
    # a tracked backend's + (hsv+sort) as _: ROS names hold letters, digits, _ and /
    name = backend.replace('-', '_').replace('+', '_')
    return f'/replaybench/{name}{topic}/detections'


@cache
def _ros2msg_bytes(msgtype: str) -> bytes:
    """The ros2msg schema text of ``msgtype``, encoded once (its hash is kept with it)."""
    return ros2msg_schema(msgtype).encode()


@cache
def _type_hash(msgtype: str) -> str:
    """The RIHS01 type hash of ``msgtype`` (rosbag2's ``topic_type_hash``); '' when unknown."""
    try:
        return str(typestore().hash_rihs01(msgtype))
    except Exception:  # noqa: BLE001  rosbags refuses an unknown type in several ways
        return ''


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
        raise DecodeError(msg) from err


def protobuf_to_ros2_cdr(
    data: bytes | memoryview, msgtype: str, schema: bytes, topic: str = ''
) -> tuple[str, bytes]:
    """Convert a Foxglove protobuf image or calibration to ROS 2 CDR: (ROS 2 type, bytes).

    ``foxglove.RawImage`` becomes ``sensor_msgs/msg/Image`` (little endian, the data as it is),
    ``foxglove.CompressedImage`` a ``sensor_msgs/msg/CompressedImage`` (same format string and
    bytes), ``foxglove.CameraCalibration`` a ``sensor_msgs/msg/CameraInfo``; the header is the
    message's timestamp and frame_id. Raises ``DecodeError`` for other types and for a message
    that does not parse.
    """
    from replaybench.decode._protobuf import parse_protobuf, stamp_ns
    from replaybench.types import RawMessage

    raw = RawMessage(topic, msgtype, 'protobuf', 0, 0, data, schema)
    if msgtype == 'foxglove.CameraCalibration':
        from replaybench.decode import decode_camera_info

        return CAMERA_INFO, serialize_camera_info(decode_camera_info(raw))
    if msgtype not in {'foxglove.RawImage', 'foxglove.CompressedImage'}:
        msg = f'cannot copy protobuf {msgtype}: only images and calibrations convert to ROS 2'
        raise DecodeError(msg)
    pb = parse_protobuf(raw)
    stamp = stamp_ns(pb.timestamp)
    if msgtype == 'foxglove.CompressedImage':
        return COMPRESSED_IMAGE, serialize_compressed_image(stamp, pb.frame_id, pb.data, pb.format)
    return IMAGE, serialize_image_fields(
        stamp,
        pb.frame_id,
        height=int(pb.height),
        width=int(pb.width),
        encoding=pb.encoding,
        step=int(pb.step),
        data=pb.data,
    )


class _Channel(NamedTuple):
    topic: str
    msgtype: str
    #: the ros2msg text; None: the type's own, generated when the file is written
    schema: bytes | None
    rank: int


class DetectionsWriter:
    """Write detections (and the CameraInfo they refer to) into a ROS 2 MCAP, atomically.

    With ``annotations`` each ``add`` also writes a ``foxglove_msgs/msg/ImageAnnotations`` on
    ``annotations_channel(backend, image_topic)``, in the backend's colour: the ``backends``
    labels get the report's palette colours in order, other labels the next colours in order
    of first use. Nothing reaches the MCAP before ``finish``, which writes every message in
    log time order (see the module's description). It is an ``OutputWriter``
    (``replaybench.sinks.writer``): the tasks' sinks write their messages through it.
    """

    #: It keeps what it is given (``OutputWriter.keeps``).
    keeps: bool = True

    def __init__(
        self,
        path: Path,
        *,
        annotations: bool = False,
        depth: bool = False,
        backends: Sequence[str] = (),
    ) -> None:
        """Open ``<path>.stage`` for the messages; ``finish`` writes ``path``."""
        self.path = Path(path)
        self.part_path = self.path.with_name(f'{self.path.name}.part')
        self.stage_path = self.path.with_name(f'{self.path.name}.stage')
        self.annotations = bool(annotations)
        self.depth = bool(depth)
        self.message_count = 0
        # (topic, msgtype) -> channel id (from 1); _specs[id - 1] describes it
        self._channels: dict[tuple[str, str], int] = {}
        self._specs: list[_Channel] = []
        self._colours: dict[str, str] = {}
        # (backend, image topic) -> detections channel id: the per-frame path looks up one key
        self._detections: dict[tuple[str, str], int] = {}
        # per staged message, in arrival order: log time, channel id, offset and size in the
        # stage file; a message counts once its size is recorded (the last of the four)
        self._times = array('Q')
        self._ids = array('H')
        self._offsets = array('Q')
        self._sizes = array('Q')
        self._staged_bytes = 0
        for backend in backends:
            self._colour(backend)
        # MCAP metadata records written after the rosbag2 one, by name
        self._metadata: dict[str, dict[str, str]] = {}
        # CameraInfo copied before the passes, serialised when the file is written (the ROS 2
        # type store it needs is not loaded before the first frame): channel id, time, info
        self._infos: list[tuple[int, int, CameraInfo]] = []
        self._info_channels: set[int] = set()
        self._finished = False
        self._stage: BinaryIO = self.stage_path.open('w+b')

    def colour(self, backend: str) -> str:
        """The backend's colour in annotations (``OutputWriter.colour``)."""
        return self._colour(backend)

    def _colour(self, backend: str) -> str:
        label = backend.replace('-', '_')
        if (colour := self._colours.get(label)) is None:
            colour = self._colours[label] = backend_colour(len(self._colours))
        return colour

    def _channel(self, topic: str, msgtype: str, schema: bytes | None, rank: int) -> int:
        key = (topic, msgtype)
        if (channel_id := self._channels.get(key)) is None:
            if len(self._specs) >= 0xFFFF:
                msg = f'{self.path}: too many channels'
                raise ValueError(msg)
            self._specs.append(_Channel(topic, msgtype, schema or None, rank))
            channel_id = self._channels[key] = len(self._specs)
        return channel_id

    def _write(
        self,
        topic: str,
        msgtype: str,
        log_time_ns: int,
        data: bytes | memoryview,
        *,
        schema: bytes | None = None,
        rank: int = _SOURCE,
    ) -> None:
        if self._finished:
            msg = f'{self.path} is already finished'
            raise ValueError(msg)
        channel_id = self._channel(topic, msgtype, schema, rank)
        if channel_id in self._info_channels:
            self._stage_infos()  # a channel's messages keep their order of arrival
        self._stage_message(channel_id, log_time_ns, data)

    def _stage_infos(self) -> None:
        infos, self._infos = self._infos, []
        self._info_channels.clear()
        for channel_id, log_time_ns, ci in infos:
            self._stage_message(channel_id, log_time_ns, serialize_camera_info(ci))

    def _stage_message(self, channel_id: int, log_time_ns: int, data: bytes | memoryview) -> None:
        offset, size = self._staged_bytes, len(data)
        try:
            self._staged_bytes = offset + size
            self._stage.write(data)
        except BaseException:  # a Ctrl-C inside the write: drop what part of it got through
            self._stage.seek(offset)
            self._stage.truncate()
            self._staged_bytes = offset
            raise
        n = len(self._sizes)
        if len(self._times) != n:  # an earlier message was interrupted while being indexed
            del self._times[n:], self._ids[n:], self._offsets[n:]
        self._times.append(log_time_ns)
        self._ids.append(channel_id)
        self._offsets.append(offset)
        self._sizes.append(size)
        self.message_count += 1

    def add_message(
        self,
        topic: str,
        msgtype: str,
        log_time_ns: int,
        data: bytes | memoryview,
        *,
        annotation: bool = False,
    ) -> None:
        """Stage one ROS 2 CDR message of a result channel (``msgtype`` in the ROS 2 typestore);
        ``annotation``: it sorts after the results of the same log time, as ImageAnnotations."""
        self._write(
            topic, msgtype, log_time_ns, data, rank=_ANNOTATIONS if annotation else _DETECTIONS
        )

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """An MCAP metadata record ``name`` (string keys and values), written by ``finish``."""
        self._metadata[name] = dict(data)

    def add_camera_info_channel(self, topic: str) -> None:
        """Make the channel of CameraInfo messages on ``topic`` now (``add_camera_info`` makes
        it when not made yet), so that its id does not depend on when they are copied."""
        if self._finished:
            msg = f'{self.path} is already finished'
            raise ValueError(msg)
        self._info_channels.add(self._channel(topic, CAMERA_INFO, None, _SOURCE))

    def add_camera_info(self, topic: str, log_time_ns: int, ci: CameraInfo) -> None:
        """Copy a CameraInfo message through on its original topic. Its channel is made now;
        the message is serialised when the file is written (in log time order like the rest,
        so the bytes are the same), since serialising needs the ROS 2 type store."""
        if self._finished:
            msg = f'{self.path} is already finished'
            raise ValueError(msg)
        channel_id = self._channel(topic, CAMERA_INFO, None, _SOURCE)
        self._info_channels.add(channel_id)
        self._infos.append((channel_id, log_time_ns, ci))

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
                rank=_DETECTIONS,
            )
            self._detections[(backend, image_topic)] = self._channels[
                (detections_channel(backend, image_topic), DETECTION2DARRAY)
            ]
        else:
            self._stage_message(
                channel_id, log_time_ns, serialize_detections(stamp_ns, frame_id, detections)
            )
        if self.annotations:
            self._write(
                annotations_channel(backend, image_topic),
                IMAGE_ANNOTATIONS,
                log_time_ns,
                serialize_image_annotations(stamp_ns, detections, self._colour(backend)),
                rank=_ANNOTATIONS,
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
        """Copy a source message (an image or its CameraInfo) onto ``topic``, as ROS 2 CDR.

        ``cdr``: the bytes unchanged, under ``schema`` (ros2msg text) or, when empty, the
        definition of ``msgtype`` in the ROS 2 typestore. ``ros1``: converted to ROS 2 CDR
        (``ros1_to_ros2_cdr``). ``protobuf``: a Foxglove image or calibration converted to its
        sensor_msgs type (``protobuf_to_ros2_cdr``; ``schema`` is the FileDescriptorSet the
        source gives). Raises ``DecodeError`` for a message that cannot be copied, before
        anything is written.
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
            ros2_type, cdr = protobuf_to_ros2_cdr(data, msgtype, schema, topic)
            self._write(topic, ros2_type, log_time_ns, cdr)
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

    def _order(self) -> list[int]:
        """Staged message numbers by (log time, channel rank, channel id, arrival)."""
        import numpy as np

        n = len(self._sizes)
        times = np.frombuffer(self._times, dtype=np.uint64, count=n)
        ranks = np.array([0] + [spec.rank for spec in self._specs], dtype=np.uint8)
        ids = np.frombuffer(self._ids, dtype=np.uint16, count=n)
        order = np.lexsort((np.arange(n), ids, ranks[ids], times))
        result: list[int] = order.tolist()
        return result

    def _summary(self) -> tuple[list[int], int, int]:
        """Messages per channel (index 0 unused), first and last log time of the staged ones."""
        counts = [0] * (len(self._specs) + 1)
        for channel_id in self._ids[: len(self._sizes)]:
            counts[channel_id] += 1
        times = self._times[: len(self._sizes)]
        return counts, (min(times) if times else 0), (max(times) if times else 0)

    def _write_mcap(self, stream: BinaryIO) -> None:
        from mcap.writer import CompressionType, Writer

        from replaybench.sinks.rosbag2 import bag_information, serialized_metadata

        self._stage_infos()
        n = len(self._sizes)
        counts, start, end = self._summary()
        topics = [
            (spec.topic, spec.msgtype, counts[i], OFFERED_QOS_PROFILES, _type_hash(spec.msgtype))
            for i, spec in enumerate(self._specs, start=1)
        ]
        info = bag_information(self.path.name, topics, start, end)
        # every option fixed and no clock read: a rerun writes the same bytes
        writer = Writer(stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        writer.start(profile='ros2', library=f'replaybench {__version__}')
        writer.add_metadata('rosbag2', {'serialized_metadata': serialized_metadata(info)})
        for name, data in sorted(self._metadata.items()):
            writer.add_metadata(name, data)
        schemas: dict[tuple[str, bytes], int] = {}
        for spec in self._specs:
            text = spec.schema or _ros2msg_bytes(spec.msgtype)
            key = (spec.msgtype, text)
            if (schema_id := schemas.get(key)) is None:
                schema_id = schemas[key] = writer.register_schema(
                    name=spec.msgtype, encoding='ros2msg', data=text
                )
            writer.register_channel(
                topic=spec.topic,
                message_encoding='cdr',
                schema_id=schema_id,
                metadata={
                    'offered_qos_profiles': OFFERED_QOS_PROFILES,
                    'topic_type_hash': _type_hash(spec.msgtype),
                },
            )
        if n:
            import mmap

            self._stage.flush()
            sequences = [0] * (len(self._specs) + 1)
            times, ids, offsets, sizes = self._times, self._ids, self._offsets, self._sizes
            size = self._staged_bytes
            # slices of an mmap are bytes: no view on the map outlives it, even on an exception
            with mmap.mmap(self._stage.fileno(), size, access=mmap.ACCESS_READ) as staged:
                for i in self._order():
                    channel_id, t, at = ids[i], times[i], offsets[i]
                    seq = sequences[channel_id]
                    sequences[channel_id] = seq + 1
                    writer.add_message(channel_id, t, staged[at : at + sizes[i]], t, seq)
        writer.finish()  # type: ignore[no-untyped-call]  # mcap leaves finish() unannotated

    def finish(self) -> None:
        """Write the MCAP, close it and rename it into place; later calls do nothing."""
        if self._finished:
            return
        self._finished = True
        try:
            with self.part_path.open('wb') as stream:
                self._write_mcap(stream)
        finally:
            self._stage.close()
            self.stage_path.unlink(missing_ok=True)
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
