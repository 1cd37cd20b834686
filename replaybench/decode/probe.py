"""Find the camera topics of a source and what their first frame looks like."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple, Protocol

from replaybench.decode._wire import as_bytes_view, parse_compressed
from replaybench.decode.camera_info import camera_info_topic_for
from replaybench.decode.compressed import parse_format
from replaybench.decode.image import decode_image
from replaybench.decode.kinds import MessageKind, message_kind
from replaybench.errors import ReplaybenchError

if TYPE_CHECKING:
    from replaybench.decode.kinds import MessageSource
    from replaybench.types import RawMessage, SkippedTopic, TopicInfo

__all__ = ['CameraTopic', 'probe_topics', 'unreadable_image_topics']

_IMAGE_KINDS = frozenset({'image', 'compressed_image'})


class SkippingSource(Protocol):
    """A source that lists the topics it holds but cannot read."""

    def skipped_topics(self) -> list[SkippedTopic]: ...


class CameraTopic(NamedTuple):
    """An image or compressed-image topic and its first frame.

    ``encoding`` is the first frame's source encoding ('rgb8', '16UC1', 'jpeg', ...), '?' when it
    could not be decoded (``error`` says why); width / height are 0 then. The rate is
    ``(count - 1) / (last_ns - first_ns)``, left to callers.
    """

    name: str
    msgtype: str
    kind: MessageKind
    count: int  # type: ignore[assignment]
    first_ns: int
    last_ns: int
    encoding: str
    width: int
    height: int
    is_depth: bool
    camera_info_topic: str | None
    error: str


def _first_message(source: MessageSource, topic: str) -> RawMessage | None:
    messages = source.messages(topics=[topic])
    try:
        return next(messages, None)
    finally:
        close = getattr(messages, 'close', None)
        if close is not None:
            close()


def _depth_hint(topic: str, raw: RawMessage | None) -> bool:
    """Whether an undecodable compressed topic still says it is compressedDepth."""
    if topic.rstrip('/').endswith('/compressedDepth'):
        return True
    if raw is None or raw.serialization not in {'cdr', 'ros1'}:
        return False
    try:
        fields = parse_compressed(as_bytes_view(raw.data), raw.serialization)
    except ReplaybenchError:
        return False
    return parse_format(fields.format).depth


def unreadable_image_topics(source: SkippingSource) -> list[SkippedTopic]:
    """The image / compressed-image topics ``source`` holds in an encoding it cannot read.

    They are not in :func:`probe_topics`: none of their messages can be replayed.
    """
    return [t for t in source.skipped_topics() if message_kind(t.msgtype) in _IMAGE_KINDS]


def probe_topics(source: MessageSource) -> list[CameraTopic]:
    """Every image / compressed-image topic of ``source``, its first message decoded."""
    topics = source.topics()
    info_topics = [t.name for t in topics if message_kind(t.msgtype) == 'camera_info']
    cameras: list[tuple[TopicInfo, MessageKind]] = []
    for t in topics:
        kind = message_kind(t.msgtype)
        if kind in {'image', 'compressed_image'} and kind is not None:
            cameras.append((t, kind))
    image_topics = [t.name for t, _ in cameras]
    out: list[CameraTopic] = []
    for topic, kind in cameras:
        encoding, width, height, is_depth, error = '?', 0, 0, False, ''
        raw: RawMessage | None = None
        try:
            raw = _first_message(source, topic.name)
            if raw is None:
                error = 'no messages'
            else:
                decoded = decode_image(raw)
                encoding = decoded.source_encoding
                height, width = (int(n) for n in decoded.image.shape[:2])
                is_depth = decoded.is_depth
        except ReplaybenchError as err:
            error = str(err) or type(err).__name__
        if error and kind == 'compressed_image':
            is_depth = _depth_hint(topic.name, raw)
        out.append(
            CameraTopic(
                name=topic.name,
                msgtype=topic.msgtype,
                kind=kind,
                count=topic.count,
                first_ns=topic.first_ns,
                last_ns=topic.last_ns,
                encoding=encoding,
                width=width,
                height=height,
                is_depth=is_depth,
                camera_info_topic=camera_info_topic_for(topic.name, info_topics, image_topics),
                error=error,
            )
        )
    return out
