"""Value types shared by every stage: source -> decode -> backend -> sink/metrics -> report.

They are immutable (NamedTuples / frozen dataclasses) and know nothing of any library.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

__all__ = [
    'CANONICAL_ENCODINGS',
    'BackendResult',
    'CameraInfo',
    'Detection',
    'Frame',
    'FrameSet',
    'LabelMask',
    'RawMessage',
    'Serialization',
    'SkippedTopic',
    'StageTimes',
    'TopicInfo',
]

Serialization = Literal['cdr', 'ros1', 'protobuf']

#: Encodings a decoded ``Frame.image`` can have. Everything else (bayer, yuv, nv12, 8UC3, ...)
#: is converted to one of these by the decoder.
CANONICAL_ENCODINGS = frozenset({'rgb8', 'bgr8', 'rgba8', 'bgra8', 'mono8', 'mono16', '32FC1'})


class RawMessage(NamedTuple):
    """One undecoded message as a source yields it, in replay order.

    ``data`` is a zero-copy view into the container where the container allows it.
    ``seq`` is the 0-based index of the message within its topic in this source, in replay order.
    ``msgtype`` uses ROS 2 spelling (``sensor_msgs/msg/Image``) for ROS 1 and ROS 2 sources
    alike; protobuf channels use their schema name (``foxglove.RawImage``).
    ``schema`` is the schema data protobuf decoding needs (a FileDescriptorSet); ``b''`` otherwise.
    """

    topic: str
    msgtype: str
    serialization: Serialization
    log_time_ns: int
    seq: int
    data: memoryview | bytes
    schema: bytes = b''


class TopicInfo(NamedTuple):
    """One topic of a container, as its index or a scan tells it."""

    name: str
    msgtype: str
    serialization: Serialization
    count: int  # type: ignore[assignment]
    first_ns: int
    last_ns: int


class SkippedTopic(NamedTuple):
    """A topic whose messages a container holds but replaybench cannot read at all.

    ``encoding`` is the message encoding (or serialization format) the file names; ``count`` the
    messages it holds; ``reason`` one line saying why they are skipped.
    """

    name: str
    msgtype: str
    encoding: str
    count: int  # type: ignore[assignment]
    reason: str


@dataclass(frozen=True, slots=True)
class CameraInfo:
    """sensor_msgs/CameraInfo, ROS 2 field names."""

    stamp_ns: int
    frame_id: str
    width: int
    height: int
    distortion_model: str
    d: tuple[float, ...]
    k: tuple[float, ...]
    r: tuple[float, ...]
    p: tuple[float, ...]
    binning_x: int = 0
    binning_y: int = 0
    roi: tuple[int, int, int, int, bool] = (
        0,
        0,
        0,
        0,
        False,
    )  # x_offset, y_offset, height, width, do_rectify
    log_time_ns: int = 0
    topic: str = ''


class Frame(NamedTuple):
    """A decoded camera frame as a backend receives it (one is built per replayed frame).

    ``image`` is HxW (mono) or HxWxC, dtype uint8 / uint16 / float32, laid out as ``encoding``
    says (one of ``CANONICAL_ENCODINGS``); it may be a read-only view into the container.
    ``source_encoding`` is what the message said (``rgb8``, ``bayer_rggb8``, ``jpeg``, ...).
    """

    topic: str
    seq: int
    log_time_ns: int
    stamp_ns: int
    frame_id: str
    image: npt.NDArray[np.generic]
    encoding: str
    source_encoding: str
    is_depth: bool = False
    camera_info: CameraInfo | None = None
    input_index: int = 0

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
        return int(self.image.shape[0])


@dataclass(frozen=True, slots=True)
class FrameSet:
    """A synchronised set of frames (``--sync``) as a backend that takes sets receives it
    (``Backend.takes_frame_sets``): one decoded ``Frame`` per synchronised topic, in the order
    of the topics paired (the run's replayed topics, or its ``--topic`` options' order).

    The first frame is the set's reference (a stereo pair's left image): the set's ``topic``,
    ``seq``, ``log_time_ns``, ``stamp_ns`` and ``frame_id`` are its, and its result is recorded
    under its key (frames.csv, outputs.mcap). Each member carries its own ``camera_info``, as a
    single frame does. ``latest_log_time_ns``: the log time of the member logged last, when a
    live synchronizer would have completed the set.
    """

    frames: tuple[Frame, ...]

    def __post_init__(self) -> None:
        if not self.frames:
            msg = 'a frame set holds at least one frame'
            raise ValueError(msg)

    @property
    def reference(self) -> Frame:
        return self.frames[0]

    @property
    def topics(self) -> tuple[str, ...]:
        return tuple(f.topic for f in self.frames)

    @property
    def topic(self) -> str:
        return self.frames[0].topic

    @property
    def seq(self) -> int:
        return self.frames[0].seq

    @property
    def log_time_ns(self) -> int:
        return self.frames[0].log_time_ns

    @property
    def stamp_ns(self) -> int:
        return self.frames[0].stamp_ns

    @property
    def frame_id(self) -> str:
        return self.frames[0].frame_id

    @property
    def input_index(self) -> int:
        return self.frames[0].input_index

    @property
    def latest_log_time_ns(self) -> int:
        return max(f.log_time_ns for f in self.frames)


class Detection(NamedTuple):
    """One detected object; the box is in source-image pixels, x0 < x1, y0 < y1.

    ``id``: the object's identity, ``vision_msgs/Detection2D.id`` (a track's id from a tracker,
    an object's id in ground truth); '' for none.
    """

    class_index: int
    label: str
    score: float
    x0: float
    y0: float
    x1: float
    y1: float
    id: str = ''


class StageTimes(NamedTuple):
    """A backend's own stage timings in nanoseconds; None where a stage does not apply.

    The first five are host wall-clock times (a GPU backend synchronises its stream before
    reading the clock); the ``*_device_ns`` ones are the GPU's own time for the same stages,
    from CUDA events on the backend's stream (None for CPU backends).
    """

    preprocess_ns: int | None = None
    infer_ns: int | None = None
    postprocess_ns: int | None = None
    h2d_ns: int | None = None
    d2h_ns: int | None = None
    preprocess_device_ns: int | None = None
    infer_device_ns: int | None = None
    postprocess_device_ns: int | None = None
    h2d_device_ns: int | None = None
    d2h_device_ns: int | None = None


class LabelMask(NamedTuple):
    """A segmentation backend's answer for one frame: one class id per source pixel.

    ``labels`` is HxW uint8, the frame's size, C-contiguous and owned by the result (never a
    buffer the backend reuses); ``labels[y, x]`` indexes ``class_names``.
    """

    labels: npt.NDArray[np.uint8]
    class_names: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class BackendResult:
    """What ``Backend.detect`` returns for one frame.

    ``mask``: the label mask of a segmentation backend (its ``detections`` are then empty);
    None for detectors. ``output``: the output of a task that has no type of its own here (a
    task from an entry point), as that task's recording reads it; None for the built-in tasks.
    """

    detections: tuple[Detection, ...]
    stages: StageTimes = field(default_factory=StageTimes)
    mask: LabelMask | None = None
    output: Any = None
