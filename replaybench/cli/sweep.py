"""``replaybench sweep``: every bag x backend x parameter combination on Ray."""

from __future__ import annotations

import sys
import threading
from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import Annotated

import typer

from replaybench.cli._common import app, echo, fail
from replaybench.errors import ReplaybenchError

__all__: list[str] = []


@app.command()
def sweep(
    bags: Annotated[
        list[Path],
        typer.Argument(
            help='Bags or rosbag2 folders, at the same path on every Ray node.', show_default=False
        ),
    ],
    out: Annotated[
        Path,
        typer.Option(
            '--out', '-o', help='Sweep folder; running the same command again resumes it.'
        ),
    ],
    backend: Annotated[
        list[str], typer.Option('--backend', '-b', help='Backend to sweep (repeat for several).')
    ] = [],  # noqa: B006
    param: Annotated[
        list[str],
        typer.Option(
            '--param',
            help='Grid of one backend option: BACKEND.KEY=V1,V2,... (repeat; one cell per '
            'combination), e.g. hsv.min_area=50,100,200.',
        ),
    ] = [],  # noqa: B006
    address: Annotated[
        str | None,
        typer.Option(
            '--address', help='Ray cluster to join (host:port); default: a local Ray instance.'
        ),
    ] = None,
    pack: Annotated[
        bool,
        typer.Option(
            '--pack', help='Fill every CPU instead of one timed cell per node (accuracy only).'
        ),
    ] = False,
    max_retries: Annotated[
        int,
        typer.Option(
            '--max-retries', min=0, help='Ray re-runs of a cell whose worker or node died.'
        ),
    ] = 3,
    rate: Annotated[
        str,
        typer.Option('--rate', help='max, recorded, 2x / 0.5x (scaled recorded), or 30hz (fixed).'),
    ] = 'max',
    queue_depth: Annotated[
        int, typer.Option('--queue-depth', min=1, help='Per-topic queue depth in timed modes.')
    ] = 1,
    warmup: Annotated[
        int | None, typer.Option('--warmup', min=0, help='Warm-up frames per backend and topic.')
    ] = None,
    threads: Annotated[
        int | None, typer.Option('--threads', min=1, help='CPU threads for OpenCV and backends.')
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
        list[str], typer.Option('--topic', '-t', help='Image topic(s) to replay.')
    ] = [],  # noqa: B006
    ground_truth: Annotated[
        str | None, typer.Option('--ground-truth', help='Detection2DArray ground-truth topic.')
    ] = None,
    config: Annotated[Path | None, typer.Option('--config', help='Backend TOML file.')] = None,
    model: Annotated[Path | None, typer.Option('--model', help='ONNX model.')] = None,
    model_family: Annotated[str | None, typer.Option('--model-family', help='Layout.')] = None,
    labels: Annotated[str | None, typer.Option('--labels', help='Class names.')] = None,
    conf: Annotated[float | None, typer.Option('--conf', min=0.0, max=1.0)] = None,
    iou: Annotated[float | None, typer.Option('--iou', min=0.0, max=1.0)] = None,
    engine: Annotated[str, typer.Option('--engine', help='auto, ort or torch.')] = 'auto',
    precision: Annotated[str, typer.Option('--precision', help='GPU precision.')] = 'fp32',
    recorded_topic: Annotated[
        str | None, typer.Option('--recorded-topic', help='Topic for the `recorded` backend.')
    ] = None,
    annotations: Annotated[
        bool, typer.Option('--annotations', help='Foxglove ImageAnnotations too.')
    ] = False,
    copy_images: Annotated[
        bool, typer.Option('--copy-images', help='Copy the images into detections.mcap.')
    ] = False,
    no_report: Annotated[
        bool, typer.Option('--no-report', help="Skip each cell's report.html.")
    ] = False,
) -> None:
    """Run every bag x backend x --param combination as one run, on a Ray cluster (docs/sweep.md).

    Example: replaybench sweep fixtures/bags/*.mcap --backend hsv --backend null --out sweeps/s1
    """
    from replaybench.app.signals import stop_on_signals
    from replaybench.app.sweep import progress_bar, result_lines, run_sweep, sweep_config

    bar = progress_bar(sys.stderr)
    token = threading.Event()
    try:
        settings = sweep_config(
            bags,
            backends=backend,
            out=out,
            params=param,
            address=address,
            pack=pack,
            max_retries=max_retries,
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
            engine=engine,
            precision=precision,
            recorded_topic=recorded_topic,
            annotations=annotations,
            copy_images=copy_images,
            report=not no_report,
            command=['replaybench', *sys.argv[1:]],
        )
        with stop_on_signals(token):
            result = run_sweep(settings, progress=bar, stop=token)
    except ReplaybenchError as err:
        raise fail(err) from None
    finally:
        if bar is not None:
            bar.close()
    lines, problems = result_lines(result)
    for line in lines:
        echo(line)
    for line in problems:
        echo(line, err=True)
    raise typer.Exit(result.exit_code)
