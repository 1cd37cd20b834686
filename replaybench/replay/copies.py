"""A bag's camera set copied k times, for ``replaybench peak --cameras``.

``camera_set`` names the cameras a bag replays (its image topics other than depth, or those
given) and their recorded rate. ``write_copies`` writes a bag holding ``k`` copies of that set:
copy ``j`` (0 to k - 1) holds the same message bytes as the bag, each message's log time moved
by ``j / k`` of a frame period, its topics renamed ``/copyJ<topic>`` (copy 0 keeps the bag's
names); the CameraInfo topics are copied beside their images, so a camera's
``<namespace>/camera_info`` stays its own in every copy. Replayed at the recorded rate with
``--pipelines per-topic``, it is k rigs whose frames arrive spread over each frame period, each
camera of each copy in a pipeline of its own.

The copies bag is an MCAP in uncompressed chunks (each frame a view of the mapped file: the
replay's reading thread does no decompression for k x the bag's cameras); its schemas carry
their names and, for protobuf, the bag's descriptors: it is written for replaybench to read,
and deleted after its trial.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench.errors import UsageError

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

__all__ = ['CameraSet', 'camera_set', 'copy_topic', 'write_copies']

_NS = 1_000_000_000
_SCHEMA_ENCODINGS = {'cdr': 'ros2msg', 'ros1': 'ros1msg', 'protobuf': 'protobuf'}


class CameraSet(NamedTuple):
    """The cameras of a bag: image topics (sorted), the CameraInfo topics copied with them,
    the most frames of one camera, and the lowest recorded rate among them (Hz)."""

    cameras: tuple[str, ...]
    infos: tuple[str, ...]
    frames: int
    recorded_hz: float


def copy_topic(topic: str, copy: int) -> str:
    """The name of ``topic`` in copy ``copy`` of the camera set."""
    return topic if copy == 0 else f'/copy{copy}{topic}'


def camera_set(bag: Path, topics: Sequence[str] | None) -> CameraSet:
    """The camera set of ``bag``: the image topics that are not depth (or ``topics``), with
    their CameraInfo topics. ``UsageError`` when it has none, or no camera with two frames to
    give a recorded rate."""
    from replaybench.decode.kinds import message_kind
    from replaybench.decode.probe import probe_topics
    from replaybench.sources import open_source

    with open_source(bag) as source:
        found = probe_topics(source)
        infos = tuple(t.name for t in source.topics() if message_kind(t.msgtype) == 'camera_info')
    if topics:
        missing = sorted(set(topics) - {t.name for t in found})
        if missing:
            msg = f'{bag}: no image topic {", ".join(missing)} (--topic) to copy for --cameras'
            raise UsageError(msg)
        chosen = [t for t in found if t.name in set(topics)]
    else:
        chosen = [t for t in found if not t.is_depth]
    if not chosen:
        msg = f'{bag}: no camera topic (an image topic that is not depth) for --cameras'
        raise UsageError(msg)
    rates = [
        (t.count - 1) / ((t.last_ns - t.first_ns) / _NS)
        for t in chosen
        if t.count > 1 and t.last_ns > t.first_ns
    ]
    if not rates:
        msg = (
            f'{bag}: --cameras replays the cameras at their recorded rate, and no camera of '
            'the bag holds two frames to give one'
        )
        raise UsageError(msg)
    return CameraSet(
        tuple(sorted(t.name for t in chosen)), infos, max(t.count for t in chosen), min(rates)
    )


class _Message(NamedTuple):
    log_time_ns: int
    topic: str
    msgtype: str
    serialization: str
    schema: bytes
    data: bytes


def _one_copy(bag: Path, rig: CameraSet, frames: int) -> list[_Message]:
    """The bag's messages of the camera set, in replay order: each camera's first ``frames``
    images, and the CameraInfo messages up to the last of them."""
    from replaybench.sources import open_source

    cameras = set(rig.cameras)
    kept: list[_Message] = []
    with open_source(bag) as source:
        for raw in source.messages([*rig.cameras, *rig.infos]):
            if raw.topic in cameras and raw.seq >= frames:
                continue
            kept.append(
                _Message(
                    raw.log_time_ns,
                    raw.topic,
                    raw.msgtype,
                    raw.serialization,
                    bytes(raw.schema),
                    bytes(raw.data),
                )
            )
    last = max((m.log_time_ns for m in kept if m.topic in cameras), default=0)
    return [m for m in kept if m.topic in cameras or m.log_time_ns <= last]


def write_copies(bag: Path, path: Path, copies: int, rig: CameraSet, frames: int) -> Path:
    """Write ``path``: ``copies`` copies of ``bag``'s camera set, each camera's first
    ``frames`` images, copy ``j``'s log times moved by ``j / copies`` of a frame period of the
    set's recorded rate (messages in log-time order, copy by copy at equal times)."""
    from mcap.writer import CompressionType, Writer

    if copies < 1:
        msg = f'copies must be at least 1, not {copies}'
        raise ValueError(msg)
    one = _one_copy(bag, rig, frames)
    period_ns = _NS / rig.recorded_hz
    shifts = [round(j * period_ns / copies) for j in range(copies)]
    order = sorted(
        ((m.log_time_ns + shifts[j], j, i) for j in range(copies) for i, m in enumerate(one)),
    )
    schemas: dict[tuple[str, str], int] = {}
    channels: dict[str, int] = {}
    sequences: dict[int, int] = {}
    with path.open('wb') as stream:
        writer: Any = Writer(stream, chunk_size=1 << 20, compression=CompressionType.NONE)
        writer.start(profile='', library='replaybench peak --cameras')
        for log_time, j, i in order:
            message = one[i]
            topic = copy_topic(message.topic, j)
            if (channel := channels.get(topic)) is None:
                key = (message.msgtype, message.serialization)
                if (schema := schemas.get(key)) is None:
                    schema = writer.register_schema(
                        name=message.msgtype,
                        encoding=_SCHEMA_ENCODINGS[message.serialization],
                        data=message.schema if message.serialization == 'protobuf' else b'',
                    )
                    schemas[key] = schema
                channel = writer.register_channel(
                    topic=topic, message_encoding=message.serialization, schema_id=schema
                )
                channels[topic] = channel
            sequence = sequences.get(channel, 0)
            sequences[channel] = sequence + 1
            writer.add_message(
                channel_id=channel,
                log_time=log_time,
                data=message.data,
                publish_time=log_time,
                sequence=sequence,
            )
        writer.finish()
    return path
