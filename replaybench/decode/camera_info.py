"""CameraInfo decoding, and matching camera_info topics and messages to image frames."""

from __future__ import annotations

import bisect
from typing import TYPE_CHECKING, Any

from replaybench.decode._wire import as_bytes_view, parse_camera_info
from replaybench.decode.kinds import message_kind
from replaybench.errors import DecodeError
from replaybench.types import CameraInfo

if TYPE_CHECKING:
    from collections.abc import Collection, Iterable

    from replaybench.decode.kinds import MessageSource
    from replaybench.types import RawMessage

__all__ = [
    'TRANSPORT_SUFFIXES',
    'CameraInfoIndex',
    'camera_info_topic_for',
    'camera_namespace',
    'decode_camera_info',
]

CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'

#: Last topic components image_transport plugins append to the base image topic.
TRANSPORT_SUFFIXES = frozenset(
    {'compressed', 'compressedDepth', 'theora', 'zstd', 'ffmpeg', 'h264', 'qoi'}
)


def _floats(values: Any) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def _from_ros(msg: RawMessage) -> CameraInfo:
    try:
        m = parse_camera_info(as_bytes_view(msg.data), msg.serialization)
    except DecodeError as err:
        text = f'invalid sensor_msgs/CameraInfo ({msg.serialization}) on {msg.topic}: {err}'
        raise DecodeError(text) from err
    return CameraInfo(
        stamp_ns=m.stamp_ns,
        frame_id=m.frame_id,
        width=m.width,
        height=m.height,
        distortion_model=m.distortion_model,
        d=m.d,
        k=m.k,
        r=m.r,
        p=m.p,
        binning_x=m.binning_x,
        binning_y=m.binning_y,
        roi=m.roi,
        log_time_ns=msg.log_time_ns,
        topic=msg.topic,
    )


def _from_foxglove(msg: RawMessage) -> CameraInfo:
    from replaybench.decode._protobuf import parse_protobuf, stamp_ns

    pb = parse_protobuf(msg)
    return CameraInfo(
        stamp_ns=stamp_ns(pb.timestamp),
        frame_id=pb.frame_id,
        width=int(pb.width),
        height=int(pb.height),
        distortion_model=pb.distortion_model,
        d=_floats(pb.D),
        k=_floats(pb.K),
        r=_floats(pb.R),
        p=_floats(pb.P),
        log_time_ns=msg.log_time_ns,
        topic=msg.topic,
    )


def decode_camera_info(msg: RawMessage) -> CameraInfo:
    """Decode sensor_msgs/CameraInfo (cdr, ros1) or foxglove.CameraCalibration (protobuf)."""
    if message_kind(msg.msgtype) != 'camera_info':
        text = f'{msg.msgtype} is not a camera info message'
        raise DecodeError(text)
    foxglove = msg.msgtype.startswith('foxglove.')
    if foxglove != (msg.serialization == 'protobuf'):
        text = f'{msg.msgtype} in {msg.serialization} serialization is not supported'
        raise DecodeError(text)
    return _from_foxglove(msg) if foxglove else _from_ros(msg)


def camera_namespace(image_topic: str) -> str:
    """The camera namespace of an image topic, without leading or trailing slashes.

    A trailing transport suffix is dropped, then the image name: '/cam/image_raw/compressed'
    -> 'cam'.
    """
    parts = image_topic.strip('/').split('/')
    if len(parts) > 1 and parts[-1] in TRANSPORT_SUFFIXES:
        parts.pop()
    return '/'.join(parts[:-1])


def camera_info_topic_for(
    image_topic: str, candidates: Iterable[str], image_topics: Iterable[str] | None = None
) -> str | None:
    """The camera_info topic belonging to ``image_topic`` among ``candidates``.

    '<namespace>/camera_info' when present. Otherwise, when there is exactly one candidate and
    every image topic (``image_topics``, or just ``image_topic`` when not given) lies in one
    camera namespace, that candidate. Else None.
    """
    names = list(candidates)
    ns = camera_namespace(image_topic)
    wanted = f'{ns}/camera_info' if ns else 'camera_info'
    for name in names:
        if name.strip('/') == wanted:
            return name
    if len(names) != 1:
        return None
    others = [image_topic] if image_topics is None else [*image_topics, image_topic]
    if {camera_namespace(t) for t in others} == {ns}:
        return names[0]
    return None


class CameraInfoIndex:
    """CameraInfo messages by topic, looked up for an image frame by nearest header stamp.

    ``deferred`` makes one that reads its messages on first use: a run whose backends never
    read a frame's camera info does not read them before its first frame.
    """

    def __init__(
        self,
        infos: Iterable[CameraInfo] = (),
        image_topics: Iterable[str] | None = None,
        *,
        skipped: int = 0,
    ) -> None:
        self._image_topics = None if image_topics is None else list(image_topics)
        self._topic_for: dict[str, str | None] = {}
        #: (source, camera_info topics) still to be read; None once read
        self._pending: tuple[MessageSource, list[str]] | None = None
        self._build(list(infos), skipped)

    def _build(self, infos: list[CameraInfo], skipped: int) -> None:
        self._all = infos
        by_topic: dict[str, list[CameraInfo]] = {}
        for info in self._all:
            by_topic.setdefault(info.topic, []).append(info)
        self._infos = {t: sorted(v, key=lambda i: i.stamp_ns) for t, v in by_topic.items()}
        self._stamps = {t: [i.stamp_ns for i in v] for t, v in self._infos.items()}
        self._skipped = skipped

    def _ready(self) -> None:
        """Read the messages of a deferred index (once)."""
        if self._pending is None:
            return
        source, topics = self._pending
        self._pending = None
        infos: list[CameraInfo] = []
        skipped = 0
        for raw in source.messages(topics=topics) if topics else ():
            try:
                infos.append(decode_camera_info(raw))
            except DecodeError:
                skipped += 1
        self._build(infos, skipped)

    @property
    def skipped(self) -> int:
        """Messages of the camera_info topics that could not be decoded."""
        self._ready()
        return self._skipped

    @classmethod
    def from_source(
        cls, source: MessageSource, camera_info_topics: Collection[str]
    ) -> CameraInfoIndex:
        """Read every message of ``camera_info_topics`` (skipping undecodable ones)."""
        index = cls.deferred(source, camera_info_topics)
        index._ready()
        return index

    @classmethod
    def deferred(
        cls, source: MessageSource, camera_info_topics: Collection[str]
    ) -> CameraInfoIndex:
        """``from_source``, read when first used (``source`` must stay open until then)."""
        image_topics = [
            t.name
            for t in source.topics()
            if message_kind(t.msgtype) in {'image', 'compressed_image'}
        ]
        index = cls((), image_topics)
        index._pending = (source, list(camera_info_topics))
        return index

    def first_topics(self) -> list[str]:
        """The topics holding a decodable CameraInfo, in the order of their first one (as
        ``all`` lists them); a deferred index reads only up to the first of each."""
        if self._pending is None:
            return list(dict.fromkeys(info.topic for info in self._all))
        source, topics = self._pending
        found: dict[str, None] = {}
        for raw in source.messages(topics=topics) if topics else ():
            if raw.topic in found:
                continue
            try:
                decode_camera_info(raw)
            except DecodeError:
                continue
            found[raw.topic] = None
            if len(found) == len(set(topics)):
                break
        return list(found)

    def __len__(self) -> int:
        self._ready()
        return len(self._all)

    def topics(self) -> list[str]:
        """The camera_info topics holding at least one message, sorted."""
        self._ready()
        return sorted(self._infos)

    def all(self) -> list[CameraInfo]:
        """Every CameraInfo in the order it was read."""
        self._ready()
        return list(self._all)

    def topic_for(self, image_topic: str) -> str | None:
        """The camera_info topic used for ``image_topic`` (cached)."""
        self._ready()
        try:
            return self._topic_for[image_topic]
        except KeyError:
            topic = camera_info_topic_for(image_topic, self._infos, self._image_topics)
            self._topic_for[image_topic] = topic
            return topic

    def lookup(self, image_topic: str, stamp_ns: int) -> CameraInfo | None:
        """The CameraInfo of ``image_topic``'s camera nearest to ``stamp_ns``; ties -> earlier."""
        topic = self.topic_for(image_topic)  # reads a deferred index
        if topic is None:
            return None
        stamps = self._stamps[topic]
        i = bisect.bisect_left(stamps, stamp_ns)
        if i == len(stamps) or (i > 0 and stamp_ns - stamps[i - 1] <= stamps[i] - stamp_ns):
            i -= 1
        return self._infos[topic][i]
