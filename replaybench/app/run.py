"""``replaybench run`` as an application: the replay engine, then the report.

The engine (``replaybench.replay.runner``) opens the inputs, drives the backends and writes
what a run measures (outputs.mcap, frames.csv, summary.csv, run.json). This layer adds what
is drawn from those results, the sample pictures and report.html (``ReportRenderer``), so that
the engine imports nothing from ``replaybench.report``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.app.options import (
    BACKEND_OPTION_NAMES,
    RunOptions,
    check_gpu_options,
    run_options,
)
from replaybench.errors import UsageError
from replaybench.replay.runner import DEFAULT_GROUND_TRUTH_TOPIC, RunConfig, RunOutcome
from replaybench.replay.runner import run_benchmark as replay_run
from replaybench.results.runfolder import with_filename

if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Iterable, Sequence

    from replaybench.backends.base import Backend, BackendOptions
    from replaybench.replay.clock import Clock
    from replaybench.replay.runner import SampleImage
    from replaybench.results.model import RunResult

__all__ = [
    'ReportRenderer',
    'RunConfig',
    'RunOutcome',
    'backend_options',
    'check_gpu_options',
    'config_of',
    'input_paths',
    'name_list',
    'run_benchmark',
    'run_config',
]


def input_paths(value: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]) -> list[Path]:
    """One path or several (the BAG arguments), as a list of paths."""
    if isinstance(value, str | os.PathLike):
        return [Path(value)]
    return [Path(v) for v in value]


def name_list(value: str | Sequence[str] | None) -> list[str]:
    """One name or several (``--backend``, ``--topic``, ``--fail-if``), as a list."""
    if value is None:
        return []
    return [value] if isinstance(value, str) else list(value)


def backend_options(**options: Any) -> BackendOptions:
    """The options every backend is given (``threads``, ``config``, ``model``, ``model_family``,
    ``labels``, ``conf``, ``iou``, ``device``, ``engine``, ``precision``: ``RunOptions`` fields),
    checked (``UsageError`` naming the option)."""
    unknown = sorted(set(options) - set(BACKEND_OPTION_NAMES))
    if unknown:
        msg = f'unexpected keyword argument(s): {", ".join(unknown)} (not backend options)'
        raise TypeError(msg)
    return run_options(**options).backend_options()


def run_config(
    inputs: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    backends: str | Sequence[str] = ('hsv',),
    params: Sequence[str] = (),
    out: str | os.PathLike[str] | None = None,
    force: bool = False,
    command: Sequence[str] = (),
    **options: Any,
) -> RunConfig:
    """The ``RunConfig`` of ``replaybench run``'s options, checked: ``options`` are the
    ``RunOptions`` fields (``replaybench.app.options``), each the option of the same name in
    snake_case (``--max-frames`` is ``max_frames``, ``--topic`` is ``topics``, ``--format`` is
    ``detections_format``, ``--no-report`` is ``report=False``, ``--no-hash`` is
    ``hash_inputs=False``). ``rate`` is a ``--rate`` text or a number of Hz; ``out`` None runs
    in memory. ``backends`` are ``--backend`` texts, ``NAME`` or ``LABEL=NAME`` (an instance
    of backend NAME called LABEL), and ``params`` ``--param LABEL.KEY=VALUE`` texts, each one
    option of one instance (``replaybench.replay.instances``). Raises ``UsageError`` naming
    the option for a value out of range, ``TypeError`` for a keyword that is no run option."""
    return config_of(
        run_options(**options),
        inputs,
        backends=backends,
        params=params,
        out=out,
        force=force,
        command=command,
    )


def _topics(options: RunOptions) -> list[str] | None:
    """The topics to replay: ``--topic``'s, or the ``--stereo`` pair's (left, then right: the
    order of a frame set). ``StereoError`` for a malformed ``--stereo``, ``UsageError`` for
    ``--stereo`` with ``--topic``."""
    if options.stereo is None:
        return list(options.topics) or None
    if options.topics:
        msg = '--stereo names the topics to replay: give it without --topic'
        raise UsageError(msg)
    from replaybench.stereo.topics import parse_stereo

    pair = parse_stereo(options.stereo)
    return [pair.left, pair.right]


def config_of(
    options: RunOptions,
    inputs: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    backends: str | Sequence[str],
    out: str | os.PathLike[str] | None,
    force: bool = False,
    command: Sequence[str] = (),
    input_sha256: tuple[str | None, ...] | None = None,
    params: Sequence[str] = (),
) -> RunConfig:
    """The ``RunConfig`` of checked ``options`` for ``inputs`` and ``backends`` (what
    ``run_config`` builds, and each cell of a sweep); ``input_sha256``: the inputs' digests
    when already known (not computed again by the run); ``backends`` and ``params``: the
    instances' ``--backend`` and ``--param`` texts (``run_config``)."""
    from replaybench.replay.instances import parse_instances
    from replaybench.replay.rate import Rate, parse_rate
    from replaybench.replay.sync import parse_sync

    instances = parse_instances(name_list(backends), params)
    rate = options.rate
    if isinstance(rate, str):
        parsed = parse_rate(rate)
    elif isinstance(rate, int | float) and not isinstance(rate, bool) and rate > 0:
        parsed = Rate('fixed', hz=float(rate))
    else:
        msg = f'invalid rate {rate!r}: use a --rate text (max, recorded, 2x, 30hz) or Hz > 0'
        raise UsageError(msg)
    return RunConfig(
        inputs=input_paths(inputs),
        backends=[inst.label for inst in instances],
        instances={inst.label: inst for inst in instances},
        out_dir=Path(out) if out is not None else None,
        force=force,
        rate=parsed,
        queue_depth=options.queue_depth,
        added_latency_ms=options.added_latency_ms,
        warmup=options.warmup,
        threads=options.threads,
        max_frames=options.max_frames,
        start_s=options.start,
        duration_s=options.duration,
        topics=_topics(options),
        ground_truth_topic=options.ground_truth or DEFAULT_GROUND_TRUTH_TOPIC,
        ground_truth_explicit=options.ground_truth is not None,
        options=options.backend_options(),
        command=tuple(command),
        report=options.report,
        recorded_topic=options.recorded_topic,
        ground_truth_file=options.ground_truth_file,
        ground_truth_match=options.ground_truth_match,
        ground_truth_image_topic=options.ground_truth_image_topic,
        ground_truth_seq_offset=options.ground_truth_seq_offset,
        annotations=options.annotations,
        depth=options.depth,
        copy_images=options.copy_images,
        detections_format=options.detections_format,
        hash_inputs=options.hash_inputs,
        input_sha256=input_sha256,
        repeat=options.repeat,
        pipelines=options.pipelines,
        workers=options.workers,
        ground_truth_masks=(
            None if options.ground_truth_masks is None else str(options.ground_truth_masks)
        ),
        sync=parse_sync(options.sync) if options.sync is not None else None,
        ground_truth_disparity=options.ground_truth_disparity,
        ground_truth_depth=options.ground_truth_depth,
    )


def _task_samples(out: Path, sample: SampleImage) -> list[str]:
    """The pictures of what each backend's task drew of a sample frame beside its boxes (a
    segmentation backend's mask thumbnail): its task's ``TaskViews.sample_picture``."""
    from replaybench.tasks import get_task, load_view, task_views

    paths = []
    for backend, (name, drawn) in (sample.drawn or {}).items():
        task = get_task(name)
        target = task_views(task).sample_picture
        if target is None:
            continue
        paths.append(load_view(task, target)(out, sample, backend, drawn))
    return paths


class ReportRenderer:
    """Sample thumbnails (``samples/``) and report.html, drawn by ``replaybench.report``."""

    def samples(self, out: Path, samples: Iterable[SampleImage]) -> list[str]:
        """Each sample with every backend's boxes, as ``samples/input<i>_<topic>.jpg``."""
        from replaybench.report import sample_relpath, write_sample

        paths: list[str] = []
        (out / 'samples').mkdir(exist_ok=True)
        for sample in samples:
            rel = sample_relpath(sample.input, sample.topic)
            try:
                write_sample(out / rel, sample.image, sample.detections, sample.title)
            except OSError as err:
                raise with_filename(err, out / rel) from None
            paths.append(rel)
            paths += _task_samples(out, sample)
        return paths

    def report(self, out: Path, run: RunResult) -> None:
        """report.html from ``run`` (run.json to be) and its frames (frames.csv's rows)."""
        from replaybench.report import render_html
        from replaybench.results.atomic import write_text_atomic
        from replaybench.results.folder import RunData

        data = RunData(run=run, frames=list(run.frame_records or ()), dir=out)
        write_text_atomic(out / 'report.html', render_html(data))


def run_benchmark(
    config: RunConfig,
    *,
    clock: Clock | None = None,
    progress: Callable[[int, int], None] | None = None,
    backend_factory: Callable[[str, BackendOptions], Backend] | None = None,
    stop: threading.Event | None = None,
    notice: Callable[[str], None] | None = None,
) -> RunOutcome:
    """One run with its report: ``replaybench.replay.runner.run_benchmark`` (see there for the
    order of work, the errors, ``stop`` and ``notice``) with the samples and report.html
    drawn."""
    return replay_run(
        config,
        clock=clock,
        progress=progress,
        backend_factory=backend_factory,
        stop=stop,
        render=ReportRenderer(),
        notice=notice,
    )
