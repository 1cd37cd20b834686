"""The backend seam: a Protocol every detector implements, and the options it is given."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, Protocol, runtime_checkable

from replaybench.errors import BackendUnavailableError

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

    from replaybench.decode.recorded import OutputReader, RecordedOutput
    from replaybench.types import BackendResult, Frame, FrameSet

__all__ = [
    'DEFAULT_TASK',
    'DEVICES',
    'Availability',
    'Backend',
    'BackendOptions',
    'BackendTraits',
    'FrameSetBackend',
    'RecordedDetections',
    'backend_task',
    'backend_traits',
]

#: Where a backend's ``detect`` runs (``Backend.device``): the CPU, or one CUDA GPU.
DEVICES: tuple[str, ...] = ('cpu', 'cuda')
#: The task of a backend that declares none (``Backend.task``): boxes.
DEFAULT_TASK = 'detections'


class Availability(NamedTuple):
    """Whether a backend can run on this machine, and why not."""

    ok: bool
    reason: str = ''


@dataclass(frozen=True, slots=True)
class BackendOptions:
    """Options common to all backends; backend-specific ones go in ``extra``.

    ``model`` / ``model_family`` / ``labels`` / ``conf`` / ``iou`` configure ONNX detectors
    (None: the backend's default); ``device`` / ``engine`` / ``precision`` the GPU ones;
    ``tag_options`` the tag detectors (``--tag-family``, ``--tag-size``, ...; keys as
    ``replaybench.fiducials.detect.TAG_OPTION_KEYS``), which other backends ignore.
    """

    threads: int | None = None
    config: Path | None = None
    model: Path | None = None
    model_family: str | None = None
    labels: str | None = None
    conf: float | None = None
    iou: float | None = None
    device: int = 0
    engine: str = 'auto'
    precision: str = 'fp32'
    extra: Mapping[str, str] = field(default_factory=dict)
    tag_options: Mapping[str, str] = field(default_factory=dict)


class RecordedDetections(NamedTuple):
    """What a backend with ``uses_recorded_detections`` is given before ``open()``.

    ``topic``: the recorded output topic(s) read (``--recorded-topic``, or the only candidate
    of each input); ``table``: their outputs keyed by (input index, frame_id, stamp_ns), each
    the ``BackendResult`` to return for the frame and the output's log time
    (``replaybench.decode.recorded``, which reads each message type); ``readers``: by input
    index, the reader of its topic's type (its task, what a frame without an output gets).
    """

    topic: str
    table: Mapping[tuple[int, str, int], RecordedOutput]
    readers: Mapping[int, OutputReader] | None = None


@runtime_checkable
class Backend(Protocol):
    """A detector the replay drives one frame at a time.

    Lifecycle: ``available()`` (class level, cheap, imports nothing heavy when it can) ->
    ``__init__(options)`` -> [``prepare(recorded)``] -> ``open()`` (load models, pick devices;
    may raise BackendError / BackendUnavailableError) -> ``detect(frame)`` per frame ->
    ``close()``.

    ``detect`` must time its own stages (``StageTimes``), synchronising any device first, and
    return boxes in source-image pixels. It must be deterministic: the same frame gives the same
    detections in the same order.

    What the runner needs to know besides the methods, a backend class states in class
    attributes; one it leaves out takes the default (``backend_traits`` reads them):

    * ``device``: ``'cpu'`` (default) or ``'cuda'``: ``detect`` runs on the GPU
      ``options.device``; the runner samples that GPU's use and a sweep cell holds one GPU.
    * ``measures_latency``: True (default); False for detections made elsewhere (``recorded``):
      its frames get no latency or stage times, and it gets no warm-up detect.
    * ``uses_recorded_detections``: False (default); True: before ``open()`` the runner reads
      the recorded Detection2DArray topic (``--recorded-topic``) of every input and calls
      ``prepare(RecordedDetections)``.
    * ``reads_camera_info``: True (default): ``detect`` may read ``frame.camera_info``; False:
      it never does, so its frames come without one (None) and a run of such backends reads
      the bag's CameraInfo messages only after its passes, for outputs.mcap.
    * ``task``: the task its results are of, a name in ``replaybench.tasks`` (``'detections'``,
      the default: boxes; ``'tags'``: a ``TagResult``; ``'segmentation'``: a ``mask``). A backend
      that knows its task only from its model sets ``self.task`` in ``open()`` (``cuda``); one
      whose task differs between inputs says it per input with ``task_of(input_index)``
      (``recorded``: each input's recorded topic). The runner reads it once per backend and
      input after ``open()`` (``backend_task``) and refuses a task that is not registered.
    * ``takes_frame_sets``: False (default): ``detect`` gets single frames, also with
      ``--sync``, which then pairs the topics' frames and reports the sets without changing
      what the backend gets; True: ``detect`` gets each synchronised set of ``--sync`` as one
      ``FrameSet`` (``FrameSetBackend``: its frames in the synced topics' order, the first the
      reference, whose key the result is recorded under); frames that found no partner are
      never given to it. A run without ``--sync`` refuses such a backend in one line.

    Optional methods: ``prepare(recorded)`` (above); ``forget_warmup()``: the runner calls it
    after detects that are neither timed nor recorded (the warm-up detect of a topic too short
    for warm-up frames); counters that ``info()`` reports (e.g. non-finite model outputs) start
    again from there.
    """

    name: ClassVar[str]
    description: ClassVar[str]

    @classmethod
    def available(cls) -> Availability: ...

    def open(self) -> None: ...

    def detect(self, frame: Frame) -> BackendResult: ...

    def info(self) -> dict[str, Any]:
        """Configuration and engine facts recorded in run.json (JSON-serialisable)."""
        ...

    def close(self) -> None: ...


class FrameSetBackend(Protocol):
    """What a backend with ``takes_frame_sets`` is called with: ``detect`` takes one
    synchronised ``FrameSet`` (``replaybench.types``) and returns one ``BackendResult`` for it,
    timing its stages as ``Backend.detect`` does. Its other methods are ``Backend``'s."""

    def detect(self, frame_set: FrameSet, /) -> BackendResult: ...


class BackendTraits(NamedTuple):
    """A backend's declared traits (see ``Backend``), defaults filled in."""

    device: str = 'cpu'
    measures_latency: bool = True
    uses_recorded_detections: bool = False
    reads_camera_info: bool = True
    #: the task declared by the class (``backend_task`` gives the one after ``open()``)
    task: str = DEFAULT_TASK
    #: the backend takes synchronised frame sets (``--sync``), not single frames
    takes_frame_sets: bool = False


def _task_name(name: str, task: object) -> str:
    if not isinstance(task, str) or not task:
        msg = f'backend {name!r} declares task {task!r}; it must be the name of a task'
        raise BackendUnavailableError(msg)
    return task


def backend_traits(backend: object) -> BackendTraits:
    """The traits a backend class (or instance) declares; ``BackendUnavailableError`` naming
    the backend when one has a value of the wrong kind."""
    name = getattr(backend, 'name', type(backend).__name__)
    device = getattr(backend, 'device', 'cpu')
    if device not in DEVICES:
        msg = f'backend {name!r} declares device {device!r}; use one of {", ".join(DEVICES)}'
        raise BackendUnavailableError(msg)
    flags: list[bool] = []
    for trait in (
        'measures_latency',
        'uses_recorded_detections',
        'reads_camera_info',
        'takes_frame_sets',
    ):
        value = getattr(backend, trait, BackendTraits._field_defaults[trait])
        if not isinstance(value, bool):
            msg = f'backend {name!r} declares {trait} {value!r}; it must be True or False'
            raise BackendUnavailableError(msg)
        flags.append(value)
    task = _task_name(name, getattr(backend, 'task', DEFAULT_TASK))
    measures_latency, uses_recorded_detections, reads_camera_info, takes_frame_sets = flags
    return BackendTraits(
        str(device),
        measures_latency,
        uses_recorded_detections,
        reads_camera_info,
        task,
        takes_frame_sets,
    )


def backend_task(backend: object, input_index: int) -> str:
    """The task of an opened backend's results on input ``input_index``: its ``task_of``
    where it has one, else its ``task`` (``'detections'`` where it declares none).

    ``BackendUnavailableError`` naming the backend when it is not a name; whether the task is
    registered the runner checks (``replaybench.replay.sessions.open_backends``)."""
    name = getattr(backend, 'name', type(backend).__name__)
    task_of = getattr(backend, 'task_of', None)
    if callable(task_of):
        return _task_name(name, task_of(input_index))
    return _task_name(name, getattr(backend, 'task', DEFAULT_TASK))
