"""``replaybench run``: replay bags through backends; print the table, warnings and folder."""

from __future__ import annotations

import sys
import threading
from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import TYPE_CHECKING, Annotated

import typer

from replaybench.cli._common import EXIT_FAILURE, EXIT_INTERRUPTED, app, echo, fail, fmt
from replaybench.cli.progress import RunProgress
from replaybench.errors import ReplaybenchError
from replaybench.textsafe import visible

if TYPE_CHECKING:
    from replaybench.replay.runner import RunConfig, RunOutcome
    from replaybench.results.stats import Summary

__all__: list[str] = []


def _print_summary(summaries: list[Summary]) -> None:
    header = (
        'backend',
        'topic',
        'frames',
        'drop',
        'skip',
        'fps',
        'p50 ms',
        'p99 ms',
        'det/frame',
        'P@.5',
        'R@.5',
        'mAP@.5',
        'private MiB',
    )
    rows = []
    for s in summaries:
        # private (anonymous) memory, not the RSS that counts the memory-mapped input
        private = s.private_mb_peak
        rows.append(
            (
                visible(s.backend),
                visible(s.topic),
                str(s.measured),
                str(s.dropped),
                str(s.skipped),
                fmt(s.throughput_fps, 1),
                fmt(s.latency_ms_p50),
                fmt(s.latency_ms_p99),
                fmt(s.detections_per_frame),
                fmt(s.precision50, 3),
                fmt(s.recall50, 3),
                fmt(s.map50, 3),
                fmt(private, 0),
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


@app.command()
def run(
    bags: Annotated[
        list[Path],
        typer.Argument(
            help='Bag files or rosbag2 folders, replayed one after another.', show_default=False
        ),
    ],
    backend: Annotated[
        list[str],
        typer.Option(
            '--backend',
            '-b',
            help='Backend to run (repeat for several; see `replaybench backends`).',
        ),
    ] = [],  # noqa: B006
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
    rate: Annotated[
        str,
        typer.Option('--rate', help='max, recorded, 2x / 0.5x (scaled recorded), or 30hz (fixed).'),
    ] = 'max',
    queue_depth: Annotated[
        int,
        typer.Option(
            '--queue-depth', min=1, help='Per-topic queue depth in timed modes (newest kept).'
        ),
    ] = 1,
    warmup: Annotated[
        int | None,
        typer.Option(
            '--warmup',
            min=0,
            help='Warm-up frames per backend and topic (default 10, at most a tenth of the topic).',
        ),
    ] = None,
    threads: Annotated[
        int | None,
        typer.Option('--threads', min=1, help='CPU threads for OpenCV and the backends.'),
    ] = None,
    max_frames: Annotated[
        int | None, typer.Option('--max-frames', min=1, help='At most N frames of each topic.')
    ] = None,
    start: Annotated[
        float | None, typer.Option('--start', min=0.0, help='Skip the first S seconds of each bag.')
    ] = None,
    duration: Annotated[
        float | None, typer.Option('--duration', min=0.0, help='Replay only S seconds.')
    ] = None,
    topic: Annotated[
        list[str],
        typer.Option(
            '--topic',
            '-t',
            help='Image topic to replay (repeat; default: every non-depth image topic).',
        ),
    ] = [],  # noqa: B006
    ground_truth: Annotated[
        str | None,
        typer.Option(
            '--ground-truth',
            help='Detection2DArray topic holding ground truth '
            '(default: /ground_truth/detections when present).',
        ),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(
            '--config', help='Backend configuration file (TOML), e.g. hsv colour classes.'
        ),
    ] = None,
    model: Annotated[
        Path | None,
        typer.Option('--model', help='ONNX model for the DNN backends (default: the bundled one).'),
    ] = None,
    model_family: Annotated[
        str | None,
        typer.Option('--model-family', help='Output layout: yolox, yolov5, yolov8 or nms.'),
    ] = None,
    labels: Annotated[
        str | None,
        typer.Option('--labels', help='Class names: coco, or a file with one name per line.'),
    ] = None,
    conf: Annotated[
        float | None,
        typer.Option('--conf', min=0.0, max=1.0, help='Score threshold for DNN detections.'),
    ] = None,
    iou: Annotated[
        float | None, typer.Option('--iou', min=0.0, max=1.0, help='IoU threshold for NMS.')
    ] = None,
    device: Annotated[int, typer.Option('--device', min=0, help='GPU index.')] = 0,
    engine: Annotated[
        str, typer.Option('--engine', help='GPU engine for the cuda backend: auto, ort or torch.')
    ] = 'auto',
    precision: Annotated[
        str,
        typer.Option('--precision', help='fp32 (TF32 off), tf32 or fp16 (GPU backends).'),
    ] = 'fp32',
    recorded_topic: Annotated[
        str | None,
        typer.Option(
            '--recorded-topic',
            help='Detection2DArray topic scored by the `recorded` backend '
            '(detections made on the robot).',
        ),
    ] = None,
    ground_truth_file: Annotated[
        Path | None,
        typer.Option(
            '--ground-truth-file',
            help='COCO JSON or CVAT XML ground truth, instead of a topic (docs/ground-truth.md).',
        ),
    ] = None,
    ground_truth_match: Annotated[
        str,
        typer.Option(
            '--ground-truth-match',
            help='Match --ground-truth-file to frames by stamp (header stamp) or seq (index '
            'of the image within its topic).',
        ),
    ] = 'stamp',
    ground_truth_image_topic: Annotated[
        str | None,
        typer.Option(
            '--ground-truth-image-topic',
            help='The image topic --ground-truth-file annotates (needed with several topics).',
        ),
    ] = None,
    ground_truth_seq_offset: Annotated[
        int,
        typer.Option(
            '--ground-truth-seq-offset',
            help='Subtracted from image ids / frame numbers with --ground-truth-match seq '
            '(1 for COCO files whose ids start at 1).',
        ),
    ] = 0,
    annotations: Annotated[
        bool,
        typer.Option(
            '--annotations',
            help='Also write Foxglove ImageAnnotations (boxes and labels) into detections.mcap.',
        ),
    ] = False,
    copy_images: Annotated[
        bool,
        typer.Option(
            '--copy-images',
            help='Copy the replayed image messages into detections.mcap (docs/foxglove.md).',
        ),
    ] = False,
    detections_format: Annotated[
        str,
        typer.Option(
            '--format',
            help='mcap, or rosbag2: also write metadata.yaml, so that the run folder opens as a '
            'rosbag2 bag (docs/foxglove.md).',
        ),
    ] = 'mcap',
    no_report: Annotated[bool, typer.Option('--no-report', help='Skip report.html.')] = False,
    # the tag backends (apriltag, aruco): docs/fiducials.md
    tag_family: Annotated[
        str | None,
        typer.Option(
            '--tag-family', metavar='FAMILY', help='Tag family: tag36h11 (default), tag25h9, ...'
        ),
    ] = None,
    tag_size: Annotated[
        float | None,
        typer.Option(
            '--tag-size', metavar='M', help='Tag edge length in metres for every tag (0.22).'
        ),
    ] = None,
    tag_sizes: Annotated[
        str | None,
        typer.Option(
            '--tag-sizes', metavar='ID=M,...', help='Edge lengths per tag id, e.g. 14=0.2,3=0.1.'
        ),
    ] = None,
    tag_decimation: Annotated[
        float | None,
        typer.Option('--tag-decimation', help='Quad decimation of the tag detectors (2).'),
    ] = None,
    max_tags: Annotated[
        int | None, typer.Option('--max-tags', help='At most N tags a frame (64).')
    ] = None,
    no_hash: Annotated[
        bool,
        typer.Option(
            '--no-hash',
            help="Do not compute the inputs' sha256 (run.json records null; compare cannot "
            'check the inputs).',
        ),
    ] = False,
) -> None:
    """Replay bags through backends and write detections, CSVs, run.json and a report.

    Example: replaybench run fixtures/bags/rgb8_raw.mcap --backend hsv --backend null --out runs/a
    """
    from replaybench.app.run import run_config
    from replaybench.fiducials.detect import tag_extra
    from replaybench.replay.runner import new_run_dir

    progress = RunProgress()
    try:
        settings = run_config(
            bags,
            backends=backend,
            out=out if out is not None else new_run_dir(),
            force=force,
            rate=rate,
            queue_depth=queue_depth,
            warmup=warmup,
            threads=threads,
            max_frames=max_frames,
            start=start,
            duration=duration,
            topics=topic,
            ground_truth=ground_truth,
            config=config,
            model=model,
            model_family=model_family,
            labels=labels,
            conf=conf,
            iou=iou,
            device=device,
            engine=engine,
            precision=precision,
            recorded_topic=recorded_topic,
            ground_truth_file=ground_truth_file,
            ground_truth_match=ground_truth_match,
            ground_truth_image_topic=ground_truth_image_topic,
            ground_truth_seq_offset=ground_truth_seq_offset,
            annotations=annotations,
            copy_images=copy_images,
            detections_format=detections_format,
            report=not no_report,
            hash_inputs=not no_hash,
            command=['replaybench', *sys.argv[1:]],
            tag_options=tag_extra(
                family=tag_family,
                tag_size=tag_size,
                tag_sizes=tag_sizes,
                decimation=tag_decimation,
                max_tags=max_tags,
            ),
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


def _show_run(outcome: RunOutcome) -> int:
    """Print a finished run (the table, its warnings, the folder); its exit status."""
    from replaybench.backends.gpu import engine_lines
    from replaybench.results.tags import tag_lines

    _print_summary(outcome.summaries)
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
    for line in tag_lines(outcome.run):
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
