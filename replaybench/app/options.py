"""The run options, declared once: what one run of one backend over one input is told.

``RunOptions`` is the table: each field is one option of ``replaybench run``, with its flag,
its help text and its bounds in the field's metadata (``RunOption``). Everything else derives
from it, so the commands and the library cannot drift apart:

* the command line: ``replaybench.cli.options`` adds one typer option per field to ``run``,
  ``sweep`` (every field: each cell is a run) and ``peak`` (the fields marked ``peak``: a peak
  search chooses its own rate, frames and warm-up);
* the configs: ``replaybench.app.run.run_config`` (``rb.run``), ``sweep_config`` (``rb.sweep``)
  and ``peak_config`` (``rb.peak``) take the fields as keyword arguments, checked by
  ``run_options``; a keyword no field has is a ``TypeError``, as for any Python function;
* a sweep's cells: the ``RunOptions`` every cell shares, recorded in sweep.json's ``settings``
  and in each cell's key.
"""

from __future__ import annotations

import math
import os
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.errors import UsageError

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping

    from replaybench.backends.base import BackendOptions

__all__ = [
    'BACKEND_OPTION_NAMES',
    'TAG_REFINEMENTS',
    'RunOption',
    'RunOptions',
    'check_gpu_options',
    'option_specs',
    'run_options',
]


#: ``--tag-refine``: every tag backend's corner refinements (aruco: none, subpix, contour,
#: apriltag; apriltag: edges, none); each backend refuses the ones it does not have.
TAG_REFINEMENTS = ('none', 'subpix', 'contour', 'apriltag', 'edges')


@dataclass(frozen=True, slots=True)
class RunOption:
    """How one ``RunOptions`` field is spelled and checked.

    ``flag``: the option on the command line (``--max-frames``); ``short``: its one-letter
    alias; ``cli_flag``: a boolean field whose flag turns it off (``--no-report`` for
    ``report``), so the command line's value is the field's negation; ``low`` / ``high``:
    inclusive bounds of a number; ``choices``: the values a text may take; ``path``: a file
    the cells of a sweep read (made absolute, hashed into the cell key); ``peak``: also an
    option of ``replaybench peak``; ``metavar``: the placeholder in help.
    """

    flag: str
    help: str
    short: str | None = None
    cli_flag: str | None = None
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    path: bool = False
    peak: bool = False
    metavar: str | None = None


def _opt(default: Any, flag: str, help: str, **spec: Any) -> Any:
    return field(default=default, metadata={'option': RunOption(flag, help, **spec)})


@dataclass(frozen=True, slots=True)
class RunOptions:
    """The options of one run (``replaybench run`` less the inputs, backends, ``--out`` and
    ``--force``): each field is the flag of the same name in snake_case, except ``topics``
    (``--topic``), ``detections_format`` (``--format``), ``report`` (``--no-report``) and
    ``hash_inputs`` (``--no-hash``)."""

    rate: str | float = _opt(
        'max', '--rate', 'max, recorded, 2x / 0.5x (scaled recorded), or 30hz (fixed).'
    )
    queue_depth: int = _opt(
        1, '--queue-depth', 'Per-topic queue depth in timed modes (newest kept).', low=1
    )
    added_latency_ms: float | None = _opt(
        None,
        '--added-latency-ms',
        'Testing aid: every detect waits MS more (a real wait, counted in its latency); '
        'docs/streaming.md.',
        low=0,
        metavar='MS',
    )
    warmup: int | None = _opt(
        None,
        '--warmup',
        'Warm-up frames per backend and topic (default 10, at most a tenth of the topic).',
        low=0,
    )
    threads: int | None = _opt(
        None, '--threads', 'CPU threads for OpenCV and the backends.', low=1, peak=True
    )
    max_frames: int | None = _opt(None, '--max-frames', 'At most N frames of each topic.', low=1)
    start: float | None = _opt(None, '--start', 'Skip the first S seconds of each bag.', low=0)
    duration: float | None = _opt(None, '--duration', 'Replay only S seconds.', low=0)
    topics: tuple[str, ...] = _opt(
        (),
        '--topic',
        'Image topic to replay (repeat; default: every non-depth image topic).',
        short='-t',
        peak=True,
    )
    ground_truth: str | None = _opt(
        None,
        '--ground-truth',
        'Detection2DArray topic holding ground truth (default: /ground_truth/detections when '
        'present).',
    )
    config: Path | None = _opt(  # noqa: RUF009 - a dataclasses.field
        None,
        '--config',
        'Backend configuration file (TOML), e.g. hsv colour classes.',
        path=True,
        peak=True,
    )
    model: Path | None = _opt(  # noqa: RUF009 - a dataclasses.field
        None,
        '--model',
        'ONNX model for the DNN backends (default: the bundled one).',
        path=True,
        peak=True,
    )
    model_family: str | None = _opt(
        None,
        '--model-family',
        'Output layout: yolox, yolov5, yolov8 or nms; segmentation: logits-nchw, logits-nhwc or '
        'labels.',
        peak=True,
    )
    labels: str | None = _opt(
        None, '--labels', 'Class names: coco, or a file with one name per line.', peak=True
    )
    conf: float | None = _opt(
        None, '--conf', 'Score threshold for DNN detections.', low=0, high=1, peak=True
    )
    iou: float | None = _opt(None, '--iou', 'IoU threshold for NMS.', low=0, high=1, peak=True)
    device: int = _opt(
        0,
        '--device',
        'GPU index (a sweep cell sees the one GPU Ray gives it as 0).',
        low=0,
        peak=True,
    )
    engine: str = _opt(
        'auto', '--engine', 'GPU engine for the cuda backend: auto, ort or torch.', peak=True
    )
    precision: str = _opt(
        'fp32',
        '--precision',
        'fp32 (TF32 off), tf32 or fp16 (GPU backends); int8 (tensorrt).',
        peak=True,
    )
    recorded_topic: str | None = _opt(
        None,
        '--recorded-topic',
        'Detection2DArray topic scored by the `recorded` backend (detections made on the robot).',
    )
    ground_truth_file: Path | None = _opt(  # noqa: RUF009 - a dataclasses.field
        None,
        '--ground-truth-file',
        'COCO JSON or CVAT XML ground truth, instead of a topic (docs/ground-truth.md).',
        path=True,
    )
    ground_truth_match: str = _opt(
        'stamp',
        '--ground-truth-match',
        'Match --ground-truth-file to frames by stamp (header stamp) or seq (index of the '
        'image within its topic).',
        choices=('stamp', 'seq'),
    )
    ground_truth_image_topic: str | None = _opt(
        None,
        '--ground-truth-image-topic',
        'The image topic --ground-truth-file annotates (needed with several topics).',
    )
    ground_truth_seq_offset: int = _opt(
        0,
        '--ground-truth-seq-offset',
        'Subtracted from image ids / frame numbers with --ground-truth-match seq (1 for COCO '
        'files whose ids start at 1).',
    )
    depth: bool = _opt(
        False,
        '--depth',
        "Also write each stereo backend's depth in metres as a 32FC1 Image into outputs.mcap "
        '(docs/stereo.md).',
    )
    annotations: bool = _opt(
        False,
        '--annotations',
        'Also write Foxglove ImageAnnotations (boxes and labels) into outputs.mcap.',
    )
    copy_images: bool = _opt(
        False,
        '--copy-images',
        'Copy the replayed image messages into outputs.mcap (docs/foxglove.md).',
    )
    detections_format: str = _opt(
        'mcap',
        '--format',
        'mcap, or rosbag2: also write metadata.yaml, so that the run folder opens as a rosbag2 '
        'bag (docs/foxglove.md).',
        choices=('mcap', 'rosbag2'),
    )
    report: bool = _opt(
        True,
        '--report',
        'Skip report.html.',
        cli_flag='--no-report',
        peak=True,
    )
    hash_inputs: bool = _opt(
        True,
        '--hash',
        "Do not compute the inputs' sha256 (run.json records null; compare cannot check the "
        'inputs).',
        cli_flag='--no-hash',
    )
    repeat: int = _opt(
        1,
        '--repeat',
        'Replay the inputs N times per backend, interleaved across backends, each pass with its '
        'own warm-up; compare then judges the variation between passes (docs/compare.md).',
        low=1,
    )
    pipelines: str = _opt(
        'shared',
        '--pipelines',
        'shared: one backend instance serves every camera topic in turn; per-topic: one '
        'instance per camera topic, each with its own queue and worker thread, replayed '
        'concurrently (docs/rigs.md).',
        choices=('shared', 'per-topic'),
        metavar='MODE',
    )
    workers: str = _opt(
        'threads',
        '--workers',
        "With --pipelines per-topic: threads: each pipeline's backend runs in its worker "
        'thread; processes: each in a worker process of its own, frames handed over in shared '
        'memory, for backends whose Python holds the GIL (docs/rigs.md).',
        choices=('threads', 'processes'),
        metavar='KIND',
    )
    ground_truth_masks: str | None = _opt(
        None,
        '--ground-truth-masks',
        'Ground-truth label masks for segmentation backends: a mono8 Image topic or a folder of '
        '<stamp_ns>.png (default: /ground_truth/labels when present).',
        metavar='TOPIC|DIR',
    )
    ground_truth_disparity: str | None = _opt(
        None,
        '--ground-truth-disparity',
        'Ground-truth disparity of the left image for stereo backends: a 32FC1 Image or '
        'DisparityImage topic, or a folder of <stamp_ns>.pfm (Middlebury) / .png (KITTI) files '
        '(default: /ground_truth/disparity when present; docs/stereo.md).',
        metavar='TOPIC|DIR',
    )
    ground_truth_depth: str | None = _opt(
        None,
        '--ground-truth-depth',
        'Ground-truth depth of the left rectified image for stereo backends, instead: a depth '
        'Image topic (32FC1 metres or 16UC1 millimetres), converted to disparity with each '
        "output's focal length and baseline.",
        metavar='TOPIC',
    )
    stereo: str | None = _opt(
        None,
        '--stereo',
        'The stereo pair to replay, LEFT,RIGHT image topics (docs/stereo.md): the run replays '
        'those two, paired by header stamp for the stereo backends.',
        metavar='LEFT,RIGHT',
    )
    sync: str | None = _opt(
        None,
        '--sync',
        "Group the replayed topics' frames into synchronised sets by header stamp: exact, or "
        'approx:SLOP_MS (message_filters ApproximateTime); frames without a partner are counted '
        'per topic (docs/rigs.md).',
        metavar='exact|approx:MS',
    )
    # the tag backends (apriltag, aruco; docs/fiducials.md): BackendOptions.tag_options
    tag_family: str | None = _opt(
        None,
        '--tag-family',
        'Tag family: tag36h11 (default), tag25h9, ...',
        peak=True,
        metavar='FAMILY',
    )
    tag_size: float | None = _opt(
        None,
        '--tag-size',
        'Tag edge length in metres for every tag (0.22).',
        low=0,
        peak=True,
        metavar='M',
    )
    tag_sizes: str | None = _opt(
        None,
        '--tag-sizes',
        'Edge lengths per tag id, e.g. 14=0.2,3=0.1.',
        peak=True,
        metavar='ID=M,...',
    )
    tag_decimation: float | None = _opt(
        None, '--tag-decimation', 'Quad decimation of the tag detectors (2).', low=1, peak=True
    )
    max_tags: int | None = _opt(
        None, '--max-tags', 'At most N tags a frame (64).', low=1, peak=True
    )
    tag_refine: str | None = _opt(
        None,
        '--tag-refine',
        'Corner refinement of the tag detectors: aruco: subpix (default), apriltag, contour, '
        'none; apriltag: edges (default), none.',
        choices=TAG_REFINEMENTS,
        peak=True,
        metavar='METHOD',
    )

    def backend_options(self) -> BackendOptions:
        """The options every backend of the run is given (checked by ``run_options``)."""
        from replaybench.backends.base import BackendOptions
        from replaybench.fiducials.detect import tag_extra

        return BackendOptions(
            **{name: getattr(self, name) for name in BACKEND_OPTION_NAMES},
            tag_options=tag_extra(
                family=self.tag_family,
                tag_size=self.tag_size,
                tag_sizes=self.tag_sizes,
                decimation=self.tag_decimation,
                max_tags=self.max_tags,
                refine=self.tag_refine,
            ),
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready, by field name: paths as strings, tuples as lists."""
        return {name: _plain(getattr(self, name)) for name in self.__dataclass_fields__}


#: The fields of ``RunOptions`` that are ``BackendOptions`` fields of the same name.
BACKEND_OPTION_NAMES = (
    'threads',
    'config',
    'model',
    'model_family',
    'labels',
    'conf',
    'iou',
    'device',
    'engine',
    'precision',
)


def _plain(value: Any) -> Any:
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, tuple):
        return list(value)
    return value


def option_specs() -> Iterator[tuple[str, RunOption, Any]]:
    """Each ``RunOptions`` field: its name, its ``RunOption`` and its default, in order."""
    for f in fields(RunOptions):
        assert f.default is not MISSING
        yield f.name, f.metadata['option'], f.default


def check_gpu_options(engine: str, precision: str) -> None:
    """Refuse an ``engine`` or ``precision`` no backend knows, whichever backends run: a typo
    must not pass silently because this run happens to use only CPU backends."""
    from replaybench.backends.gpu.choices import ENGINES, PRECISIONS

    for option, value, known in (
        ('--engine', engine, ENGINES),
        ('--precision', precision, PRECISIONS),
    ):
        if value not in known:
            msg = f'invalid {option} {value!r}: use {", ".join(known[:-1])} or {known[-1]}'
            raise UsageError(msg)


def _check(spec: RunOption, value: Any) -> None:
    if isinstance(value, int | float) and not isinstance(value, bool):
        if spec.high is not None and spec.low is not None:
            if not (math.isfinite(value) and spec.low <= value <= spec.high):
                msg = f'{spec.flag} must be between {spec.low:g} and {spec.high:g}, not {value!r}'
                raise UsageError(msg)
        elif spec.low is not None and not value >= spec.low:
            msg = f'{spec.flag} must be at least {spec.low:g}, not {value!r}'
            raise UsageError(msg)
    if spec.choices and value is not None and value not in spec.choices:
        msg = f'unknown {spec.flag} {value!r}: use {" or ".join(spec.choices)}'
        raise UsageError(msg)


def _value(name: str, value: Any, spec: RunOption) -> Any:
    if name == 'topics':
        if value is None:
            return ()
        return (value,) if isinstance(value, str) else tuple(value)
    if spec.path and isinstance(value, str | os.PathLike):
        return Path(value)
    return value


def run_options(given: Mapping[str, Any] | None = None, /, **values: Any) -> RunOptions:
    """``RunOptions`` of keyword values, checked (``UsageError`` naming the flag for a value out
    of range or not one of its choices; ``TypeError`` for a keyword no option has). ``topics``
    takes one name or several, the path options a ``str`` or a ``Path``, ``rate`` a ``--rate``
    text or a number of Hz."""
    merged = {**(given or {}), **values}
    known = {f.name: f for f in fields(RunOptions)}
    unknown = sorted(set(merged) - set(known))
    if unknown:
        msg = f'unexpected keyword argument(s): {", ".join(unknown)} (not run options)'
        raise TypeError(msg)
    checked: dict[str, Any] = {}
    for name, value in merged.items():
        spec: RunOption = known[name].metadata['option']
        checked[name] = _value(name, value, spec)
        if name != 'rate':
            _check(spec, checked[name])
    options = RunOptions(**checked)
    check_gpu_options(options.engine, options.precision)
    if options.sync is not None:
        from replaybench.replay.sync import parse_sync

        parse_sync(options.sync)  # a bad --sync is refused with the other options
    return options
