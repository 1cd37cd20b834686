"""``replaybench run``: replay bags through backends; print the table, warnings and folder."""

from __future__ import annotations

import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from replaybench.cli._common import (
    EXIT_FAILURE,
    EXIT_INTERRUPTED,
    app,
    echo,
    fail,
    fmt,
    with_instance_options,
    with_run_options,
)
from replaybench.cli.progress import RunProgress
from replaybench.errors import ReplaybenchError
from replaybench.textsafe import visible

if TYPE_CHECKING:
    from replaybench.replay.runner import RunConfig, RunOutcome
    from replaybench.results.model import RunResult
    from replaybench.results.stats import Summary
    from replaybench.tasks import MetricSpec

__all__: list[str] = []

#: After a figure of the terminal's table that was recorded in the bag, not measured here.
RECORDED_MARK = '*'


def _task_columns(summaries: list[Summary]) -> tuple[list[MetricSpec], list[MetricSpec]]:
    """The tasks' metrics in the summary table (``TaskViews.terminal_metrics``), in the tasks'
    order: (before the memory column: the tasks shown for every row, as boxes are; after it:
    the others, where some row has the task's summary, as a segmentation backend has)."""
    from replaybench.tasks import get_task, task_names, task_views

    always: list[MetricSpec] = []
    scored: list[MetricSpec] = []
    for name in task_names():
        task = get_task(name)
        views = task_views(task)
        specs = {m.name: m for m in task.metrics}
        shown = [specs[metric] for metric in views.terminal_metrics]
        if views.terminal == 'always':
            always += shown
        elif _has_task(views.summary_field, shown, summaries):
            scored += shown
    return always, scored


def _has_task(field: str | None, shown: list[MetricSpec], summaries: list[Summary]) -> bool:
    """Some row has the task's summary: its ``summary_field`` set, or for a task without
    fields of its own (``summary_field`` None) one of its shown metrics in ``task_metrics``."""
    if field is not None:
        return any(getattr(s, field, None) is not None for s in summaries)
    return any(s.metric(m.name) is not None for s in summaries for m in shown)


def _print_summary(summaries: list[Summary]) -> None:
    from replaybench.results.recorded_latency import replays_recording

    boxes, masks = _task_columns(summaries)
    header: tuple[str, ...] = (
        'backend',
        'topic',
        'frames',
        'drop',
        'skip',
        'fps',
        'p50 ms',
        'p99 ms',
        'det/frame',
        *(str(m.terminal_label) for m in boxes),
        'private MiB',
        *(str(m.terminal_label) for m in masks),
    )

    rows = []
    recorded = False
    for s in summaries:
        # private (anonymous) memory, not the RSS that counts the memory-mapped input
        private = s.private_mb_peak
        # a recording: its output rate and pipeline latency from the bag, marked (how fast the
        # bag was read is no detector's speed)
        speed = (
            (fmt(s.throughput_fps, 1), fmt(s.latency_ms_p50), fmt(s.latency_ms_p99))
            if not replays_recording(s)
            else tuple(
                f'{fmt(v, d)}{RECORDED_MARK}' if v is not None else '-'
                for v, d in (
                    (s.recorded_output_hz, 1),
                    (s.pipeline_ms_p50, 2),
                    (s.pipeline_ms_p99, 2),
                )
            )
        )
        recorded = recorded or replays_recording(s)
        rows.append(
            (
                visible(s.backend),
                visible(s.topic),
                str(s.measured),
                str(s.dropped),
                str(s.skipped),
                *speed,
                fmt(s.detections_per_frame),
                *(fmt(getattr(s, m.name), m.terminal_digits) for m in boxes),
                fmt(private, 0),
                *(fmt(s.metric(m.name), m.terminal_digits) for m in masks),
            )
        )
    widths = [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(header)]
    for row in (header, *rows):
        typer.echo(
            '  '.join(
                c.ljust(w) if i < 2 else c.rjust(w)
                for i, (c, w) in enumerate(zip(row, widths, strict=True))
            )
        )
    if recorded:
        typer.echo(
            f'{RECORDED_MARK} recorded: the output rate (Hz) and pipeline latency of the node that '
            'ran on the robot, from the bag; not a replay on this machine'
        )


@app.command()
@with_run_options('run')
@with_instance_options('run')
def run(
    bags: Annotated[
        list[Path],
        typer.Argument(
            help='Bag files or rosbag2 folders, replayed one after another.', show_default=False
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option(
            '--out', '-o', help='Run folder (default: a new folder under ./replaybench-runs/).'
        ),
    ] = None,
    force: Annotated[
        bool,
        typer.Option(
            '--force', help='Replace the run folder --out, once the new run has finished.'
        ),
    ] = False,
    tracker: Annotated[
        list[str],
        typer.Option(
            '--tracker',
            metavar='NAME',
            help='Tracker over every backend: a row DETECTOR+TRACKER beside each (iou, sort, '
            'bytetrack; repeat for several; docs/tracking.md).',
        ),
    ] = [],  # noqa: B006
    *,
    backend: list[str],
    param: list[str],
    options: dict[str, Any],
) -> None:
    """Replay bags through backends and write detections, CSVs, run.json and a report.

    Example: replaybench run fixtures/bags/rgb8_raw.mcap --backend hsv --backend null --out runs/a
    """
    from replaybench.app.run import run_config
    from replaybench.backends.tracked import with_trackers
    from replaybench.replay.runner import new_run_dir

    progress = RunProgress()
    try:
        settings = run_config(
            bags,
            backends=with_trackers(backend, tracker),
            params=param,
            out=out if out is not None else new_run_dir(),
            force=force,
            command=['replaybench', *sys.argv[1:]],
            **options,
        )
        outcome = _run_until_stopped(settings, progress)
    except ReplaybenchError as err:
        progress.close()
        raise fail(err) from None
    code = _show_run(outcome)
    if code:
        raise typer.Exit(code)


def _run_until_stopped(config: RunConfig, progress: RunProgress) -> RunOutcome:
    """The run, Ctrl-C and SIGTERM ending it as interrupted (a second one: at once)."""
    from replaybench.app.run import run_benchmark
    from replaybench.app.signals import stop_on_signals

    token = threading.Event()
    with stop_on_signals(token):
        return run_benchmark(config, progress=progress, stop=token, notice=progress.notice)


def _task_lines(run: RunResult) -> list[str]:
    """The lines each task prints after the table (``TaskViews.terminal_lines``: the tags'
    size hints), in the tasks' order."""
    from replaybench.tasks import get_task, load_view, task_names, task_views

    lines: list[str] = []
    for name in task_names():
        task = get_task(name)
        target = task_views(task).terminal_lines
        if target is not None:
            lines += load_view(task, target)(run)
    return lines


def _streaming_lines(outcome: RunOutcome) -> list[str]:
    """Per (backend, topic) with streaming scores: each beside its offline figure with the
    difference, and the output age's median and 90th percentile (docs/streaming.md)."""
    from replaybench.results.streaming import output_ages, streaming_pairs
    from replaybench.tasks import streaming_offline

    offline_of = streaming_offline()
    ages = output_ages(outcome.records)
    lines = []
    for s in outcome.summaries:
        pairs = streaming_pairs(s, offline_of)
        if not pairs:
            continue
        shown = ', '.join(
            f'{p.label.removeprefix("streaming ")} {p.offline_value:.3f} -> {p.value:.3f} '
            f'({p.change:+.3f})'
            for p in pairs
        )
        age = ages.get((s.backend, s.topic))
        aged = f'; output age p50 {age.p50_ms:.1f} ms, p90 {age.p90_ms:.1f} ms' if age else ''
        lines.append(f'streaming {visible(s.backend)} {visible(s.topic)}: {shown}{aged}')
    return lines


def _sync_lines(run: RunResult) -> list[str]:
    """--sync: per input, its sets and each topic's unpaired frames (full topic names)."""
    sync = run.sync
    if sync is None:
        return []
    lines = []
    names = {inp.index: inp.path for inp in run.inputs}
    for entry in sync.inputs:
        where = f' {visible(Path(names[entry.input]).name)}' if len(sync.inputs) > 1 else ''
        spread = (
            f', largest spread {entry.spread_ms_max:.3f} ms'
            if entry.spread_ms_max is not None and sync.mode == 'approx'
            else ''
        )
        unpaired = ', '.join(f'{visible(t.topic)} {t.unpaired}' for t in entry.topics)
        lines.append(
            f'replaybench: sync {sync.sync}{where}: {entry.sets} set(s) of '
            f'{len(entry.topics)} topic(s){spread}; unpaired frames: {unpaired}'
        )
    return lines


def _rig_lines(run: RunResult) -> list[str]:
    """A run with a rig: per backend, its rig row's figures and its worst cameras."""
    if run.rig is None:
        return []
    lines = []
    pipelines = run.settings.pipelines
    mode = run.rig.mode
    if pipelines is not None and pipelines.workers != 'threads':
        mode = f'{mode}, {pipelines.workers}'
    for rig in run.rig.backends:
        rate = f'{rig.drop_rate * 100:.1f} %' if rig.drop_rate is not None else 'n/a'
        p99 = f'{rig.latency_ms_p99:.2f} ms' if rig.latency_ms_p99 is not None else 'n/a'
        fps = f'{rig.throughput_fps:.1f} FPS' if rig.throughput_fps is not None else 'n/a FPS'
        worst_p99 = (
            f'{visible(rig.worst_p99.topic)} {rig.worst_p99.value:.2f} ms'
            if rig.worst_p99 is not None
            else 'none measured'
        )
        worst_drop = (
            f'{visible(rig.worst_drop_rate.topic)} {rig.worst_drop_rate.value * 100:.1f} %'
            if rig.worst_drop_rate is not None
            else 'no camera dropped a frame'
        )
        lines.append(
            f'rig {visible(rig.backend)}: {len(rig.cameras)} camera(s), {rig.pipelines} '
            f'pipeline(s) ({mode}): {rig.frames} frames, {rig.dropped} dropped ({rate}), '
            f'p99 {p99}, {fps}; worst p99: {worst_p99}; worst drop rate: {worst_drop}'
        )
    return lines


def _show_run(outcome: RunOutcome) -> int:
    """Print a finished run (the table, its warnings, the folder); its exit status."""
    from replaybench.backends.gpu import engine_lines
    from replaybench.detector.provenance import quantization_line
    from replaybench.report.recorded import recorded_latency_lines

    _print_summary(outcome.summaries)
    for line in _rig_lines(outcome.run):
        echo(line)
    for line in _streaming_lines(outcome):
        echo(line)
    for line, is_warning in recorded_latency_lines(outcome.summaries):
        echo(f'replaybench: warning: {line}' if is_warning else line, err=is_warning)
    for s in outcome.summaries:  # stability of each (backend, topic): intervals need not hold
        where = f'{s.backend} {s.topic}'
        for warning in s.warnings:
            echo(f'replaybench: warning: {where}: {warning}', err=True)
    for warning in (w for inp in outcome.run.inputs for w in inp.warnings):
        echo(f'replaybench: warning: {warning}', err=True)
    for reason, count in outcome.run.skipped.items():
        echo(f'replaybench: warning: skipped {count} message(s): {reason}', err=True)
    for warning in outcome.run.warnings:
        echo(f'replaybench: warning: {warning}', err=True)
    for line in _sync_lines(outcome.run):
        echo(line, err=True)
    for entry in outcome.run.backends:
        facts = entry.info
        if facts.get('nonfinite_dropped'):
            echo(
                f'replaybench: warning: {entry.name}: left out {facts["nonfinite_dropped"]} '
                f'candidate(s) with NaN or inf model outputs in {facts["nonfinite_frames"]} '
                'frame(s)',
                err=True,
            )
    for line in engine_lines(outcome.run):
        echo(line)
    for entry in outcome.run.backends:
        quantized = quantization_line(entry.name, entry.info)
        if quantized is not None:
            echo(quantized)
    for line in _task_lines(outcome.run):
        echo(line)
    assert outcome.run_dir is not None  # the command line always writes a folder
    report = outcome.run_dir / 'report.html'
    echo(f'Run folder: {outcome.run_dir}')
    if report.exists():
        echo(f'Report: {report}')
    if outcome.status == 'interrupted':
        typer.echo('replaybench: interrupted: outputs hold the frames done so far', err=True)
        return EXIT_INTERRUPTED
    if outcome.status == 'partial':
        failed = '; '.join(
            f'backend {b.name!r} raised on input {b.error.input} {b.error.topic} '
            f'seq {b.error.seq}: {b.error.message}'
            for b in outcome.run.backends
            if b.status == 'failed' and b.error is not None
        )
        echo(
            f'replaybench: error: {failed}; it was stopped there and the other backends '
            'finished (run.json status partial)',
            err=True,
        )
        return EXIT_FAILURE
    return 0
