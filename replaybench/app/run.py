"""``replaybench run`` as an application: the replay engine, then the report.

The engine (``replaybench.replay.runner``) opens the inputs, drives the backends and writes
what a run measures (detections.mcap, frames.csv, summary.csv, run.json). This layer adds what
is drawn from those results, the sample pictures and report.html (``ReportRenderer``), so that
the engine imports nothing from ``replaybench.report``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

from replaybench.backends.base import BackendOptions
from replaybench.errors import UsageError
from replaybench.replay.runner import DEFAULT_GROUND_TRUTH_TOPIC, RunConfig, RunOutcome
from replaybench.replay.runner import run_benchmark as replay_run
from replaybench.results.runfolder import with_filename

if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Iterable, Mapping, Sequence

    from replaybench.backends.base import Backend
    from replaybench.replay.clock import Clock
    from replaybench.replay.runner import SampleImage
    from replaybench.results.model import RunResult

__all__ = [
    'ReportRenderer',
    'RunConfig',
    'RunOutcome',
    'backend_options',
    'check_gpu_options',
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


def _at_least(flag: str, value: float | None, low: float) -> None:
    if value is not None and not value >= low:
        msg = f'{flag} must be at least {low:g}, not {value!r}'
        raise UsageError(msg)


def _fraction(flag: str, value: float | None) -> None:
    if value is not None and not (math.isfinite(value) and 0 <= value <= 1):
        msg = f'{flag} must be between 0 and 1, not {value!r}'
        raise UsageError(msg)


def check_gpu_options(engine: str, precision: str) -> None:
    """Refuse an ``engine`` or ``precision`` no backend knows, whichever backends run: a typo
    must not pass silently because this run happens to use only CPU backends."""
    from replaybench.backends.gpu.cuda import ENGINES, PRECISIONS

    for option, value, known in (
        ('--engine', engine, ENGINES),
        ('--precision', precision, PRECISIONS),
    ):
        if value not in known:
            msg = f'invalid {option} {value!r}: use {", ".join(known[:-1])} or {known[-1]}'
            raise UsageError(msg)


def backend_options(
    *,
    threads: int | None = None,
    config: str | Path | None = None,
    model: str | Path | None = None,
    model_family: str | None = None,
    labels: str | None = None,
    conf: float | None = None,
    iou: float | None = None,
    device: int = 0,
    engine: str = 'auto',
    precision: str = 'fp32',
    # the tag backends (apriltag, aruco): docs/fiducials.md
    tag_options: Mapping[str, str] | None = None,
) -> BackendOptions:
    """The options every backend is given, checked (``UsageError`` naming the option);
    ``tag_options``: the tag backends' (``BackendOptions.tag_options``)."""
    check_gpu_options(engine, precision)
    _at_least('--threads', threads, 1)
    _fraction('--conf', conf)
    _fraction('--iou', iou)
    _at_least('--device', device, 0)
    return BackendOptions(
        threads=threads,
        config=Path(config) if config is not None else None,
        model=Path(model) if model is not None else None,
        model_family=model_family,
        labels=labels,
        conf=conf,
        iou=iou,
        device=device,
        engine=engine,
        precision=precision,
        tag_options=dict(tag_options or {}),
    )


def run_config(
    inputs: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    backends: str | Sequence[str] = ('hsv',),
    out: str | os.PathLike[str] | None = None,
    force: bool = False,
    rate: str | float = 'max',
    queue_depth: int = 1,
    warmup: int | None = None,
    threads: int | None = None,
    max_frames: int | None = None,
    start: float | None = None,
    duration: float | None = None,
    topics: str | Sequence[str] | None = None,
    ground_truth: str | None = None,
    config: str | Path | None = None,
    model: str | Path | None = None,
    model_family: str | None = None,
    labels: str | None = None,
    conf: float | None = None,
    iou: float | None = None,
    device: int = 0,
    engine: str = 'auto',
    precision: str = 'fp32',
    recorded_topic: str | None = None,
    ground_truth_file: str | Path | None = None,
    ground_truth_match: str = 'stamp',
    ground_truth_image_topic: str | None = None,
    ground_truth_seq_offset: int = 0,
    annotations: bool = False,
    copy_images: bool = False,
    detections_format: str = 'mcap',
    report: bool = True,
    hash_inputs: bool = True,
    command: Sequence[str] = (),
    # the tag backends (apriltag, aruco): docs/fiducials.md
    tag_options: Mapping[str, str] | None = None,
) -> RunConfig:
    """The ``RunConfig`` of ``replaybench run``'s options, checked: each keyword is the option
    of the same name in snake_case (``--max-frames`` is ``max_frames``, ``--topic`` is
    ``topics``, ``--format`` is ``detections_format``, ``--no-report`` is ``report=False``,
    ``--no-hash`` is ``hash_inputs=False``).
    ``rate`` is a ``--rate`` text or a number of Hz; ``out`` None runs in memory;
    ``tag_options`` holds the tag options (``--tag-family``, ``--tag-size``, ``--tag-sizes``,
    ``--tag-decimation``, ``--max-tags``) by their keys (docs/fiducials.md). Raises
    ``UsageError`` naming the option for a value out of range."""
    from replaybench.replay.rate import Rate, parse_rate

    _at_least('--queue-depth', queue_depth, 1)
    _at_least('--warmup', warmup, 0)
    _at_least('--max-frames', max_frames, 1)
    _at_least('--start', start, 0)
    _at_least('--duration', duration, 0)
    if ground_truth_match not in ('stamp', 'seq'):
        msg = f'invalid --ground-truth-match {ground_truth_match!r}: use stamp or seq'
        raise UsageError(msg)
    if isinstance(rate, str):
        parsed = parse_rate(rate)
    elif isinstance(rate, int | float) and not isinstance(rate, bool) and rate > 0:
        parsed = Rate('fixed', hz=float(rate))
    else:
        msg = f'invalid rate {rate!r}: use a --rate text (max, recorded, 2x, 30hz) or Hz > 0'
        raise UsageError(msg)
    return RunConfig(
        inputs=input_paths(inputs),
        backends=name_list(backends),
        out_dir=Path(out) if out is not None else None,
        force=force,
        rate=parsed,
        queue_depth=queue_depth,
        warmup=warmup,
        threads=threads,
        max_frames=max_frames,
        start_s=start,
        duration_s=duration,
        topics=name_list(topics) or None,
        ground_truth_topic=ground_truth or DEFAULT_GROUND_TRUTH_TOPIC,
        ground_truth_explicit=ground_truth is not None,
        options=backend_options(
            threads=threads,
            config=config,
            model=model,
            model_family=model_family,
            labels=labels,
            conf=conf,
            iou=iou,
            device=device,
            engine=engine,
            precision=precision,
            tag_options=tag_options,
        ),
        command=tuple(command),
        report=report,
        recorded_topic=recorded_topic,
        ground_truth_file=Path(ground_truth_file) if ground_truth_file is not None else None,
        ground_truth_match=ground_truth_match,
        ground_truth_image_topic=ground_truth_image_topic,
        ground_truth_seq_offset=ground_truth_seq_offset,
        annotations=annotations,
        copy_images=copy_images,
        detections_format=detections_format,
        hash_inputs=hash_inputs,
    )


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
