"""What a run is asked to do: ``RunConfig``, and the part of it each stage of the engine uses.

``RunConfig`` is what the command line and the API build (``replaybench.app.run.run_config``);
the engine hands each stage only its own part, resolved: ``InputOptions`` to open the inputs
(``replaybench.replay.inputs``), ``PassOptions`` to the timed passes
(``replaybench.replay.passes``) and ``OutputOptions`` to the writers
(``replaybench.replay.output``).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from replaybench.backends.base import BackendOptions
from replaybench.replay.instances import BackendInstance, backend_label
from replaybench.replay.rate import Rate

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from replaybench.replay.sync import SyncSpec

__all__ = [
    'DEFAULT_GROUND_TRUTH_TOPIC',
    'InputOptions',
    'OutputOptions',
    'PassOptions',
    'RunConfig',
    'backend_label',
    'default_warmup',
    'new_run_dir',
]

DEFAULT_GROUND_TRUTH_TOPIC = '/ground_truth/detections'


def default_warmup(frames: int) -> int:
    """Warm-up frames for a topic of ``frames`` frames: 10, but never more than a tenth."""
    return min(10, frames // 10)


def new_run_dir(base: Path = Path('replaybench-runs')) -> Path:
    """A new timestamped folder name under ``base`` (not created)."""
    stamp = dt.datetime.now(dt.UTC).strftime('%Y%m%d-%H%M%S')
    candidate = base / stamp
    n = 1
    while candidate.exists():
        n += 1
        candidate = base / f'{stamp}-{n}'
    return candidate


@dataclass(frozen=True, slots=True)
class RunConfig:
    """Everything one ``replaybench run`` needs; the CLI builds it from its options."""

    inputs: Sequence[Path]
    #: the backends' instances by label (``--backend LABEL=NAME``; a registered name alone is
    #: an instance of that backend under its own name, unless ``instances`` says otherwise)
    backends: Sequence[str]
    out_dir: Path | None  # None: in memory, no file written
    force: bool = False
    rate: Rate = field(default_factory=lambda: Rate('max'))
    queue_depth: int = 1
    warmup: int | None = None
    threads: int | None = None
    max_frames: int | None = None
    start_s: float | None = None
    duration_s: float | None = None
    topics: Sequence[str] | None = None
    #: ``--added-latency-ms``: every backend's ``detect`` waits this long more
    #: (``replaybench.replay.latency``, a testing aid); None: nothing added
    added_latency_ms: float | None = None
    ground_truth_topic: str | None = DEFAULT_GROUND_TRUTH_TOPIC
    ground_truth_explicit: bool = False
    options: BackendOptions = field(default_factory=BackendOptions)
    command: Sequence[str] = ()
    report: bool = True
    prefetch: int = 4
    recorded_topic: str | None = None
    ground_truth_file: Path | None = None
    ground_truth_match: str = 'stamp'  # 'stamp' | 'seq'
    ground_truth_image_topic: str | None = None
    ground_truth_seq_offset: int = 0
    annotations: bool = False
    #: --depth: stereo outputs also as depth Images in metres
    depth: bool = False
    copy_images: bool = False
    detections_format: str = 'mcap'  # 'rosbag2': also a metadata.yaml, the run folder is a bag
    #: False (--no-hash): the inputs' sha256 is not computed; run.json records null and says so
    hash_inputs: bool = True
    #: the inputs' sha256 when already known (a peak search's later trials): not hashed again
    input_sha256: tuple[str | None, ...] | None = None
    #: --repeat N: every backend replays the inputs N times, interleaved across backends
    repeat: int = 1
    #: ground-truth label masks of segmentation backends: a topic, or a folder of
    #: <stamp_ns>.png files; None: /ground_truth/labels when present (tasks/segmentation/)
    ground_truth_masks: str | None = None
    #: the stereo task's truth: a disparity topic or folder of .pfm/.png files, or a depth
    #: topic (tasks/stereo/); None: /ground_truth/disparity when present
    ground_truth_disparity: str | None = None
    ground_truth_depth: str | None = None
    #: --sync: the replayed topics' frames grouped into synchronised sets by header stamp
    #: (``replaybench.replay.sync``); None: no pairing
    sync: SyncSpec | None = None
    #: --pipelines: 'shared' (one backend instance serves every camera topic's queue in turn)
    #: or 'per-topic' (one instance per camera topic, each in a worker thread of its own)
    pipelines: str = 'shared'
    #: --workers: how per-topic pipelines run their backends: 'threads' (in the pipeline's
    #: worker thread) or 'processes' (each in a worker process, ``replaybench.replay.workers``)
    workers: str = 'threads'
    #: the instances of ``backends`` by label (``replaybench.replay.instances``): the backend
    #: each is made of and its own ``--param`` values; a label not here is the backend of
    #: that name with no parameter of its own
    instances: Mapping[str, BackendInstance] = field(default_factory=dict)

    def instance(self, label: str) -> BackendInstance:
        """The instance labelled ``label``: its backend and its own parameters."""
        found = self.instances.get(label)
        return found if found is not None else BackendInstance(label, label)

    def input_options(self) -> InputOptions:
        """The part of the config that opens and reads the inputs."""
        return InputOptions(
            topics=tuple(self.topics) if self.topics else None,
            start_s=self.start_s,
            duration_s=self.duration_s,
            max_frames=self.max_frames,
            ground_truth_topic=self.ground_truth_topic,
            ground_truth_explicit=self.ground_truth_explicit,
            recorded_topic=self.recorded_topic,
            hash_inputs=self.hash_inputs,
            input_sha256=self.input_sha256,
            ground_truth_masks=self.ground_truth_masks,
            ground_truth_disparity=self.ground_truth_disparity,
            ground_truth_depth=self.ground_truth_depth,
        )

    def pass_options(self) -> PassOptions:
        """The part of the config that drives the timed passes."""
        return PassOptions(
            rate=self.rate,
            queue_depth=self.queue_depth,
            prefetch=self.prefetch,
            warmup=self.warmup,
            repeat=self.repeat,
            pipelines=self.pipelines,
        )

    def output_options(self, out: Path | None) -> OutputOptions:
        """The part of the config that writes the run folder (``out``: the temporary folder
        the run is written into, None in memory)."""
        return OutputOptions(
            out=out,
            backend_labels=tuple(backend_label(name) for name in self.backends),
            annotations=self.annotations,
            depth=self.depth,
            copy_images=self.copy_images,
            detections_format=self.detections_format,
            report=self.report,
        )


@dataclass(frozen=True, slots=True)
class InputOptions:
    """Which topics, which window, which recorded detections and ground-truth masks an input
    is read for, and whether its sha256 is computed."""

    topics: tuple[str, ...] | None = None
    start_s: float | None = None
    duration_s: float | None = None
    max_frames: int | None = None
    ground_truth_topic: str | None = DEFAULT_GROUND_TRUTH_TOPIC
    ground_truth_explicit: bool = False
    recorded_topic: str | None = None
    hash_inputs: bool = True
    input_sha256: tuple[str | None, ...] | None = None
    #: the ground-truth mask topic (not replayed) or folder (``RunConfig.ground_truth_masks``)
    ground_truth_masks: str | None = None
    #: the stereo task's truth (``RunConfig.ground_truth_disparity``, ``ground_truth_depth``)
    ground_truth_disparity: str | None = None
    ground_truth_depth: str | None = None
    #: no topic was named and a backend of the run chooses the topics of its frame sets
    #: (``Backend.frame_set_topics``, a stereo pair by name): each input's camera topics ->
    #: (those to replay, a note or None)
    choose_topics: Callable[[Sequence[str]], tuple[Sequence[str], str | None]] | None = None

    @property
    def windowed(self) -> bool:
        """--start or --duration cut a time window out of each input."""
        return self.start_s is not None or self.duration_s is not None


@dataclass(frozen=True, slots=True)
class PassOptions:
    """How the frames of a pass are released: the rate, the queues, the read-ahead and the
    warm-up asked for (None: the default per topic, in each pass), how many passes each
    backend makes over the inputs (``--repeat``) and whether each camera topic has a pipeline
    of its own (``--pipelines``)."""

    rate: Rate = field(default_factory=lambda: Rate('max'))
    queue_depth: int = 1
    prefetch: int = 4
    warmup: int | None = None
    repeat: int = 1
    pipelines: str = 'shared'


@dataclass(frozen=True, slots=True)
class OutputOptions:
    """What is written into the run folder ``out`` (None: nothing, the run is in memory)."""

    out: Path | None
    backend_labels: tuple[str, ...] = ()
    annotations: bool = False
    #: --depth: stereo outputs also as depth Images in metres
    depth: bool = False
    copy_images: bool = False
    detections_format: str = 'mcap'
    report: bool = True
    #: frames.csv's columns after the known ones: the frame columns of the run's backends'
    #: tasks that have no fields of their own (``Task.frame_columns``)
    task_columns: tuple[str, ...] = ()
