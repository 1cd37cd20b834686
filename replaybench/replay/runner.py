"""The replay engine: inputs x backends -> run folder (outputs.mcap, frames.csv,
summary.csv, run.json), or a run held in memory.

Backends run one after another over the same frames (``--repeat N``: N times each, interleaved
across backends, A B A B ...); each (backend, input) pass reads the bag again, so every backend
is measured on the same path from container to detections. The stages,
in the order ``run_benchmark`` runs them:

* ``replaybench.replay.config``: the ``RunConfig``, and the part of it each stage gets;
* ``replaybench.replay.inputs``: the inputs opened and probed, their sha256 taken while nothing
  is timed (a small input's at once, a larger one's after the passes);
* ``replaybench.replay.sessions``: the backends made and opened, then driven pass by pass;
* ``replaybench.replay.passes``: the timed passes, which only read, decode, detect and log;
* ``replaybench.replay.recording``: each pass's log turned into records, detections messages,
  scores and samples;
* ``replaybench.replay.record``: the summaries and the typed ``RunResult`` (imported once the
  passes have ended, with the record's types: they do not delay the first frame);
* ``replaybench.replay.output``: the files of the run folder.

The sample pictures and report.html are drawn by the application's ``Renderer``
(``replaybench.app.run``); the run stops on a cancellation token, not on a signal handler.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from replaybench.backends import get_backend
from replaybench.backends.base import backend_traits
from replaybench.errors import (
    BackendFailedError,
    BackendUnavailableError,
    DecodeError,
    ReplaybenchError,
    SourceError,
    UsageError,
)
from replaybench.replay.clock import Clock, MonotonicClock
from replaybench.replay.config import (
    DEFAULT_GROUND_TRUTH_TOPIC,
    RunConfig,
    backend_label,
    default_warmup,
    new_run_dir,
)
from replaybench.replay.inputs import (
    deferred_hash,
    expected_frames,
    load_truths,
    open_input,
    settle_hash,
)
from replaybench.replay.instances import check_label, instance_options
from replaybench.replay.latency import with_added_latency
from replaybench.replay.output import (
    Renderer,
    SampleImage,
    camera_info_channels,
    copy_camera_infos,
    copy_images,
    draw_samples,
    finish_files,
    sample_images,
    write_detections_metadata,
    write_summary,
    writers,
)
from replaybench.replay.pairing import pair_inputs, sync_report
from replaybench.replay.passes import Replay, Stopped, Warmups
from replaybench.replay.recording import Recorder
from replaybench.replay.sessions import (
    hand_frame_sets,
    make_backend,
    make_backends,
    open_backends,
    open_pipelines,
    run_backend,
    run_repeated,
)
from replaybench.replay.threads import thread_limits
from replaybench.replay.workers import WORKERS
from replaybench.results.machine import describe_machine, load_snapshot
from replaybench.results.runfolder import RunFolder, check_out_dir

if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Mapping, Sequence

    from replaybench.backends.base import Backend, BackendOptions
    from replaybench.replay.config import InputOptions
    from replaybench.replay.hashing import InputHash
    from replaybench.replay.inputs import OpenedInput
    from replaybench.replay.pairing import Pairing
    from replaybench.replay.sessions import OpenBackend
    from replaybench.results.model import BackendRun, RunResult
    from replaybench.results.model.run import Pipelines
    from replaybench.results.records import FrameRecord
    from replaybench.results.stats import Summary

__all__ = [
    'DEFAULT_GROUND_TRUTH_TOPIC',
    'Renderer',
    'RunConfig',
    'RunOutcome',
    'SampleImage',
    'default_warmup',
    'new_run_dir',
    'run_benchmark',
]

_NS = 1_000_000_000


class RunOutcome(NamedTuple):
    """What a finished (or interrupted) run left behind."""

    run_dir: Path | None  # None: a run made in memory
    status: str
    summaries: list[Summary]
    run: RunResult  # with ``frame_records``, frames.csv's rows as the file holds them
    records: tuple[FrameRecord, ...] = ()  # frames.csv's rows, in the order written


class _Calls(NamedTuple):
    """What the caller of ``run_benchmark`` passed besides the config."""

    clock: Clock
    progress: Callable[[int, int], None] | None
    stop: threading.Event | None
    render: Renderer | None
    notice: Callable[[str], None] | None


def run_benchmark(
    config: RunConfig,
    *,
    clock: Clock | None = None,
    progress: Callable[[int, int], None] | None = None,
    backend_factory: Callable[[str, BackendOptions], Backend] | None = None,
    stop: threading.Event | None = None,
    render: Renderer | None = None,
    hasher: Callable[[Sequence[Path]], InputHash] | None = None,
    notice: Callable[[str], None] | None = None,
) -> RunOutcome:
    """Replay every input through every backend and write the run folder.

    Order of work: the options and ``config.out_dir`` are checked (nothing read or created
    yet); the folder is locked (``RunFolder``); the inputs are opened and probed; every
    backend is opened (models loaded); then the inputs are replayed (``config.repeat`` times
    per backend, interleaved). Each input's sha256 (``replaybench.replay.hashing``; ``hasher``
    makes the ``InputHash``, ``config.hash_inputs`` False skips it) is computed when nothing is
    timed: at once for an input of at most 64 MiB, after the passes for a larger one, whose
    size and mtime must not have changed meanwhile; ``notice`` gets the lines a person should
    see while it lasts (the hashing of an input over 1 GB). The run is
    written into a temporary folder beside ``out_dir`` and swapped in when it has ended, with
    run.json as its last file: whatever fails leaves ``out_dir`` as it was and nothing else.

    Raises ``ReplaybenchError`` subclasses: bad inputs and options, and a run that measured no
    frame (exit code 2); ``BackendFailedError`` when every backend raised in ``detect`` and
    ``OutputError`` when an output cannot be written (1). A backend that raises while others
    finish gives status ``partial``. Setting ``stop`` (a cancellation token; the command line
    sets it on Ctrl-C or SIGTERM, ``replaybench.app.signals``) ends the replay at the next
    frame: every output is finalised with the frames done so far and the run returns with
    status ``interrupted``; so does a ``KeyboardInterrupt`` raised while frames replay. No
    signal handler is installed. ``render`` draws the samples and report.html
    (``config.report``); without it the folder holds neither, and run.json says so.
    ``config.threads`` limits OpenCV's and the native thread pools'
    threads for the run (``thread_limits``); they are restored when it returns.
    """
    _check_config(config, check_available=backend_factory is None)
    factory: Callable[[str, BackendOptions], Backend] = backend_factory or make_backend
    truths = load_truths(config)
    started = dt.datetime.now(dt.UTC)
    t_start = time.perf_counter()
    calls = _Calls(clock or MonotonicClock(), progress, stop, render, notice)
    if config.added_latency_ms:  # every instance made, per-topic pipelines' too
        factory = _Slower(factory, config.added_latency_ms, calls.clock)
    input_options = config.input_options()
    # in memory (no out_dir): no folder, no file
    folder = RunFolder(config.out_dir, force=config.force) if config.out_dir is not None else None
    inputs: list[OpenedInput] = []
    opened: list[OpenBackend] = []
    limits = contextlib.ExitStack()
    limits.enter_context(thread_limits(config.threads))
    try:
        with folder if folder is not None else contextlib.nullcontext():
            base = _with_bag_sizes(config)
            made = make_backends(
                [config.instance(label) for label in config.backends], base, factory
            )
            config = _frame_set_sync(made, config, notice)
            input_options = _chosen_topics(made, config, input_options)
            recorded = any(backend_traits(b).uses_recorded_detections for _, b in made)
            for index, path in enumerate(config.inputs):
                inp = open_input(
                    index, Path(path), input_options, truths, recorded_detections=recorded
                )
                # small inputs hashed now, larger ones after the passes (deferred_hash)
                inputs.append(deferred_hash(inp, input_options, hasher))
            # --sync: the header stamps read and paired before any model loads
            pairing = (
                pair_inputs(inputs, config.sync, config.topics) if config.sync is not None else None
            )
            opened = open_backends(made, inputs, notice)
            for entry in opened:
                entry.instance = config.instance(entry.name)
            if pairing is not None:
                hand_frame_sets(opened, pairing, inputs)
            topics = _camera_topics(inputs)
            if config.pipelines == 'per-topic' and len(topics) > 1:
                open_pipelines(opened, topics, inputs, factory, base, workers=config.workers)
            outcome = _execute(
                config,
                calls,
                inputs=inputs,
                opened=opened,
                out=folder.path if folder is not None else None,
                started=started,
                t_start=t_start,
                pairing=pairing,
            )
            if folder is not None:
                folder.commit()
    except OSError as err:
        if folder is None:
            raise
        raise folder.output_error(err) from err
    finally:
        for inp in inputs:
            if inp.sha256 is not None:
                inp.sha256.cancel()  # a failed run does not wait for its hash
        for entry in opened:
            entry.close()  # those a failure left open
        for inp in inputs:
            inp.source.close()
        limits.close()
    return outcome._replace(run_dir=config.out_dir)


def _task_columns(opened: Sequence[OpenBackend], inputs: Sequence[OpenedInput]) -> tuple[str, ...]:
    """The frame columns of the tasks the run's backends declared (``tasks.frame_columns``),
    in the tasks' registry order: frames.csv's columns after the known ones."""
    from replaybench.tasks import frame_columns

    return frame_columns({entry.task(inp.number) for entry in opened for inp in inputs})


class _Slower:
    """``factory`` whose backends wait ``added_ms`` after each detect (``--added-latency-ms``,
    ``replaybench.replay.latency``); picklable, for ``--workers processes``."""

    def __init__(
        self, factory: Callable[[str, BackendOptions], Backend], added_ms: float, clock: Clock
    ) -> None:
        self.factory, self.added_ms, self.clock = factory, added_ms, clock

    def __call__(self, name: str, options: BackendOptions) -> Backend:
        return with_added_latency(self.factory(name, options), self.added_ms, self.clock)


def _refused(metrics: Mapping[str, float | None]) -> bool:
    """Whether a row's streaming metrics are there and empty (refused at --rate max)."""
    streaming = [v for k, v in metrics.items() if k.startswith('streaming_')]
    return bool(streaming) and all(v is None for v in streaming)


def _with_bag_sizes(config: RunConfig) -> BackendOptions:
    """The backend options with what each task reads of the inputs for its backends
    (``replaybench.tasks.backend_options``: the tag sizes the bags record)."""
    from replaybench.tasks import backend_options

    found: BackendOptions = backend_options(config.options, [Path(p) for p in config.inputs])
    return found


#: What ``--pipelines`` may name.
PIPELINES = ('shared', 'per-topic')


def _camera_topics(inputs: Sequence[OpenedInput]) -> list[str]:
    """The camera topics replayed, over every input, in the order first met."""
    return list(dict.fromkeys(t.name for inp in inputs for t in inp.topics))


def _pipelines(
    config: RunConfig, opened: Sequence[OpenBackend], inputs: Sequence[OpenedInput]
) -> tuple[Pipelines | None, str | None]:
    """run.json's ``settings.pipelines`` (None: shared), and the warning for per-topic over a
    single camera topic (replayed as shared)."""
    if config.pipelines != 'per-topic':
        return None, None
    import os

    from replaybench.results.model.run import Pipelines

    count = max((len(e.pipelines) for e in opened), default=0) or 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else os.cpu_count()
    settings = Pipelines(
        pipelines=count,
        workers=config.workers,
        threads_per_pipeline=config.threads,
        cores=max(1, cores or 1),
    )
    topics = _camera_topics(inputs)
    sets = [backend_label(e.name) for e in opened if e.frame_sets]
    if sets:
        # a set stream groups every camera topic's frames: one pipeline (sessions.open_pipelines)
        return settings, (
            f'--pipelines per-topic: {", ".join(sets)} take(s) frame sets of --sync: each '
            f"input's set stream ({', '.join(topics)}) is one pipeline"
        )
    if count > 1:
        return settings, None
    return settings, (
        f'--pipelines per-topic: the inputs hold one camera topic ({", ".join(topics)}): '
        'replayed as --pipelines shared'
    )


def _check_config(config: RunConfig, *, check_available: bool) -> None:
    """Refuse bad options, missing inputs, unavailable backends and an output folder that may
    not be written, before anything is read or created."""
    if not config.backends:
        msg = 'no backend given: add --backend NAME (see `replaybench backends`)'
        raise UsageError(msg)
    labels: dict[str, str] = {}
    for label in config.backends:
        written = backend_label(label)
        if written in labels:
            first = labels[written]
            msg = (
                f'two --backend instances have the label {label!r}'
                + (f' ({first!r} is written the same)' if first != label else '')
                + ': give each its own, --backend LABEL=NAME'
            )
            raise UsageError(msg)
        labels[written] = label
        if label != config.instance(label).backend:
            check_label(label, f'{label}={config.instance(label).backend}')
    if config.repeat < 1:
        msg = f'--repeat must be at least 1, not {config.repeat}'
        raise UsageError(msg)
    if config.pipelines not in PIPELINES:
        msg = f'unknown --pipelines {config.pipelines!r}: use shared or per-topic'
        raise UsageError(msg)
    if config.workers not in WORKERS:
        msg = f'unknown --workers {config.workers!r}: use threads or processes'
        raise UsageError(msg)
    if config.workers != 'threads' and config.pipelines != 'per-topic':
        msg = f'--workers {config.workers} runs the pipelines of --pipelines per-topic: give both'
        raise UsageError(msg)
    if config.detections_format not in {'mcap', 'rosbag2'}:
        msg = f'unknown --format {config.detections_format!r}: use mcap or rosbag2'
        raise UsageError(msg)
    for bag in config.inputs:
        if not Path(bag).exists():
            msg = f'{bag}: no such file or directory'
            raise SourceError(msg)
    if check_available:
        for name in dict.fromkeys(config.instance(label).backend for label in config.backends):
            status = get_backend(name).available()
            if not status.ok:
                msg = f'backend {name!r} is not available here: {status.reason}'
                raise BackendUnavailableError(msg)
    if config.out_dir is not None:
        check_out_dir(config.out_dir, force=config.force)


def _execute(
    config: RunConfig,
    calls: _Calls,
    *,
    inputs: Sequence[OpenedInput],
    opened: Sequence[OpenBackend],
    out: Path | None,
    started: dt.datetime,
    t_start: float,
    pairing: Pairing | None = None,
) -> RunOutcome:
    """Replay into the (temporary) folder ``out``, then record; run.json is its last file.
    ``out`` None: in memory, nothing is written. ``pairing``: the frame sets of --sync, put
    in run.json's ``sync`` section (a backend that takes frame sets gets them, the others
    their frames as without it).

    Raises ``BackendFailedError`` when every backend raised, and a ``ReplaybenchError`` saying
    why when no frame was measured (``_nothing_measured``).
    """
    topic_frames: dict[str, int] = {}
    for inp in inputs:
        for topic in inp.topics:
            topic_frames[topic.name] = topic_frames.get(topic.name, 0) + expected_frames(
                topic, config.max_frames
            )
    warmups = Warmups(config.warmup, topic_frames)
    replay = Replay(
        config.pass_options(),
        calls.clock,
        warmups,
        progress=calls.progress,
        stop=calls.stop,
        total=sum(topic_frames.values()) * len(config.backends) * config.repeat,
    )
    # the load average before the replay describes the machine, not us; the rest of the
    # machine is described after the passes, so that it does not delay the first frame
    load = load_snapshot()
    output = replace(config.output_options(out), task_columns=_task_columns(opened, inputs))
    warnings = list(warmups.warnings)
    if pairing is not None:
        warnings.extend(pairing.warnings)
    pipelines, one_topic = _pipelines(config, opened, inputs)
    if one_topic is not None:
        warnings.append(one_topic)
    backend_runs: list[BackendRun] = []
    copy_problems: dict[int, str] = {}
    status = 'complete'
    with writers(output) as (frames_csv, detections_out):
        recorder = Recorder(inputs, warmups, frames_csv, detections_out, len(config.backends))
        # their messages are read after the passes, unless a backend reads them (``decoder``)
        camera_info_channels(inputs, detections_out)
        passes_began = time.perf_counter()
        try:
            if config.repeat > 1:  # the backends' passes interleaved
                run_repeated(
                    replay,
                    recorder,
                    opened,
                    inputs,
                    gpu_index=lambda entry: _gpu_index(entry, config.options),
                    warnings=warnings,
                    runs=backend_runs,
                )
            else:  # one backend after the other
                for entry in opened:
                    run_backend(
                        replay,
                        recorder,
                        entry,
                        backend_label(entry.name),
                        inputs,
                        gpu_index=_gpu_index(entry, config.options),
                        warnings=warnings,
                        runs=backend_runs,
                    )
            for recording in recorder.task_recordings():
                recording.finish(detections_out)
            if config.copy_images:
                copy_problems = copy_images(inputs, detections_out)
        except (KeyboardInterrupt, Stopped):
            status = 'interrupted'
        # read here unless a backend read them: an interrupt now (a KeyboardInterrupt, or the
        # token set after passes that ended) ends the run as one in the passes does
        after = calls.stop if status != 'interrupted' else None
        if not copy_camera_infos(inputs, detections_out, after):
            status = 'interrupted'
    write_detections_metadata(output)
    from replaybench.replay.record import input_info, run_result, summaries
    from replaybench.results.agreement import AGREEMENT_IOU, agreement_table
    from replaybench.results.io import to_json

    machine = describe_machine(load)
    input_options = config.input_options()
    infos = [
        input_info(
            inp,
            settle_hash(
                inp,
                input_options,
                passes_began=passes_began,
                interrupted=status == 'interrupted',
                notice=calls.notice,
            ),
            copy_problem=copy_problems.get(inp.number),
            matched_frames=recorder.ground_truth_frames(inp.number),
            replayed_any=replay.done > 0,
        )
        for inp in inputs
    ]

    failed = [run for run in backend_runs if run.status == 'failed']
    if status == 'complete' and failed:
        if len(failed) == len(config.backends):
            msg = f'{_failures(failed)}; no other backend to finish the run, nothing was written'
            raise BackendFailedError(msg)
        status = 'partial'
    if status != 'interrupted' and not recorder.measured():
        raise _nothing_measured(recorder, inputs, config)

    resources = {
        run.label: to_json(run.resources.summary)
        for run in backend_runs
        if run.resources is not None and run.resources.summary is not None
    }
    for recording in recorder.task_recordings():
        warnings.extend(recording.warnings())
    summary = summaries(recorder, resources)
    if any(
        r.backend in recorder.streaming_refused and r.task_metrics and _refused(r.task_metrics)
        for r in summary
    ):
        from replaybench.replay.streaming import REFUSED_AT_MAX

        warnings.append(REFUSED_AT_MAX)
    agreements = (
        agreement_table(recorder.detections, iou=AGREEMENT_IOU) if len(config.backends) > 1 else []
    )
    write_summary(output, summary)
    sample_paths = draw_samples(output, calls.render, sample_images(recorder.samples, inputs))
    record = run_result(
        config,
        recorder,
        status=status,
        inputs=infos,
        backends=backend_runs,
        summary=summary,
        agreements=agreements,
        environment=machine,
        warmup_per_topic={t: warmups(t) for t in topic_frames},
        warnings=warnings,
        started=started,
        t_start=t_start,
        samples=sample_paths,
        report=config.report and calls.render is not None and out is not None,
        pipelines=pipelines,
    )
    if pairing is not None:
        record = replace(
            record,
            sync=sync_report(
                pairing,
                [
                    (backend_label(e.name), backend_traits(e.backend).takes_frame_sets)
                    for e in opened
                ],
                pairing.spec.policy,
            ),
        )
    finish_files(output, calls.render, record)
    return RunOutcome(out, status, summary, record, tuple(recorder.records))


def _chosen_topics(
    made: Sequence[tuple[str, Backend]], config: RunConfig, options: InputOptions
) -> InputOptions:
    """``options`` with ``choose_topics`` where no topic was named (``--topic``, ``--stereo``)
    and a backend of the run chooses the topics of its frame sets (``frame_set_topics``: a
    stereo matcher, the pair the names make); the first such backend's."""
    if config.topics:
        return options
    for _, backend in made:
        choose = getattr(backend, 'frame_set_topics', None)
        if backend_traits(backend).takes_frame_sets and callable(choose):
            return replace(options, choose_topics=choose)
    return options


def _frame_set_sync(
    made: Sequence[tuple[str, Backend]],
    config: RunConfig,
    notice: Callable[[str], None] | None,
) -> RunConfig:
    """A backend that takes frame sets (``BackendTraits.takes_frame_sets``) needs ``--sync``,
    which makes them. Without it: where every such backend declares the same ``default_sync``
    (a stereo matcher: ``exact``, a pair's two images share their stamp), the run is made with
    it and ``notice`` told in one line; otherwise ``UsageError`` in one line, before any input
    opens."""
    if config.sync is not None:
        return config
    taking = [(n, b) for n, b in made if backend_traits(b).takes_frame_sets]
    implied = {getattr(b, 'default_sync', None) for _, b in taking}
    if taking and len(implied) == 1 and None not in implied:
        (sync,) = implied
        if notice is not None:
            names = ', '.join(n for n, _ in taking)
            notice(f'replaybench: --sync {sync} for {names} (no --sync given)')
        from replaybench.replay.sync import parse_sync

        return replace(config, sync=parse_sync(str(sync)))
    if taking:
        msg = (
            f'backend {taking[0][0]!r} takes synchronised frame sets, which only --sync makes: '
            'add --sync exact (equal header stamps) or --sync approx:SLOP_MS'
        )
        raise UsageError(msg)
    return config


def _gpu_index(entry: OpenBackend, options: BackendOptions) -> int | None:
    """The GPU whose utilisation is sampled: --device (the instance's own, if it has one) for
    the GPU backends, none otherwise."""
    if backend_traits(entry.backend).device != 'cuda':
        return None
    return instance_options(options, entry.instance).device


def _failures(failed: Sequence[BackendRun]) -> str:
    """One line for the backends that raised: where and what."""
    parts = []
    for run in failed:
        where = run.error
        assert where is not None  # a failed backend says where
        parts.append(
            f'backend {run.name!r} raised on input {where.input} {where.topic} '
            f'seq {where.seq}: {where.message}'
        )
    return '; '.join(parts)


def _nothing_measured(
    recorder: Recorder, inputs: Sequence[OpenedInput], config: RunConfig
) -> ReplaybenchError:
    """Why a run measured no frame, as the error that refuses it (exit 2)."""
    head = 'no frame was measured'
    records = recorder.records
    if not records:
        if config.start_s is None and config.duration_s is None:
            return UsageError(f'{head}: the selected topics hold no image message')
        window = ' '.join(
            f'--{name} {value:g} s'
            for name, value in (('start', config.start_s), ('duration', config.duration_s))
            if value is not None
        )
        spans = []
        for inp in inputs:
            first = min((t.first_ns for t in inp.source.topics()), default=0)
            lo = min((t.first_ns for t in inp.topics), default=first) - first
            hi = max((t.last_ns for t in inp.topics), default=first) - first
            spans.append(f'{inp.path.name}: images from {lo / _NS:.3f} s to {hi / _NS:.3f} s')
        return UsageError(
            f'{head}: the time window {window} holds no image message of the selected topics '
            f'({"; ".join(spans)})'
        )
    if not any(r.status == 'ok' for r in records):
        reasons = '; '.join(f'{k} ({v})' for k, v in recorder.skipped.items())
        return DecodeError(
            f'{head}: not one frame of the selected topics could be decoded: {reasons}'
        )
    processed = sum(1 for r in records if r.status == 'ok')
    return UsageError(
        f'{head}: every processed frame ({processed} in all) was a warm-up frame: lower --warmup'
    )
