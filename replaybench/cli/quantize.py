"""``replaybench quantize``: an INT8 model calibrated on a bag's own frames."""

from __future__ import annotations

from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import Annotated

import typer

from replaybench.cli._common import app, echo, fail
from replaybench.errors import ReplaybenchError

__all__: list[str] = []


@app.command()
def quantize(
    model: Annotated[
        Path,
        typer.Argument(
            help='The float ONNX model (MODEL.onnx), or "bundled": the model the backend runs '
            'by default (the bundled detector, segmenter or stereo model).',
            show_default=False,
        ),
    ],
    bag: Annotated[
        Path,
        typer.Argument(help='The bag (BAG) whose frames calibrate it.', show_default=False),
    ],
    out: Annotated[
        Path,
        typer.Option(
            '--out',
            '-o',
            help='The INT8 model to write (PATH.onnx; an ONNX model it replaces).',
            metavar='PATH',
        ),
    ],
    frames: Annotated[
        int,
        typer.Option('--frames', help='Calibration frames N, spread evenly over the bag.'),
    ] = 100,
    method: Annotated[
        str,
        typer.Option(
            '--method',
            help='Calibration method NAME: minmax, entropy or percentile.',
            metavar='NAME',
        ),
    ] = 'minmax',
    exclude: Annotated[
        list[str],
        typer.Option(
            '--exclude',
            help='Keep node NODE in float (repeat); "none" quantises every node. Default: the '
            'decode head (the last Conv of each output path and every node after it).',
            metavar='NODE',
        ),
    ] = [],  # noqa: B006
    holdout: Annotated[
        list[str],
        typer.Option(
            '--holdout',
            help='Leave the frames of START:END (or START:) seconds of log time out of the '
            'calibration, for scoring with run --start/--duration (repeat).',
            metavar='START:END',
        ),
    ] = [],  # noqa: B006
    topic: Annotated[
        list[str],
        typer.Option(
            '--topic',
            '-t',
            help='Image topic TOPIC to calibrate on (default: every one; a stereo model: '
            'LEFT then RIGHT).',
        ),
    ] = [],  # noqa: B006
    backend: Annotated[
        str | None,
        typer.Option(
            '--backend',
            '-b',
            help='The backend NAME whose preprocessing feeds the calibration: onnx-cpu, '
            'onnx-seg or onnx-stereo (default: from the model metadata, else onnx-cpu).',
        ),
    ] = None,
) -> None:
    """Quantise an ONNX model to INT8 (QDQ, per-channel), calibrated on frames of a bag.

    The frames go through the backend's own preprocessing; the provenance (bag sha256, topics,
    frames, method, nodes left in float) goes into the model's metadata, and `run` reports it.

    Exit status: 0 written, 2 bad input (one line), 1 the model could not be written.

    Example: replaybench quantize yolox_nano.onnx drive.mcap --out yolox.int8.onnx --holdout 60:
    """
    from replaybench.app.quantize import QuantizeSettings, parse_holdout, quantize_model

    try:
        if str(model) == 'bundled':
            model = _bundled(backend)
        if exclude == ['none']:
            excluded: tuple[str, ...] | None = ()
        elif 'none' in exclude:
            from replaybench.errors import UsageError

            msg = '--exclude none quantises every node; it takes no other --exclude'
            raise UsageError(msg)
        else:
            excluded = tuple(exclude) or None
        settings = QuantizeSettings(
            model=model,
            bag=bag,
            out=out,
            frames=frames,
            method=method,
            exclude=excluded,
            holdout=tuple(parse_holdout(h) for h in holdout),
            topics=tuple(topic),
            backend=backend,
        )
        outcome = quantize_model(settings)
    except ReplaybenchError as err:
        raise fail(err) from None
    for warning in outcome.warnings:
        echo(f'replaybench: warning: {warning}', err=True)
    record = outcome.provenance
    echo(
        f'{outcome.out}: INT8 ({record["format"]}, per-channel, {record["method"]}) calibrated '
        f'on {record["frames"]} frame(s) of {record["bag"]} through {record["backend"]}; '
        f'{len(record["excluded"])} node(s) in float; opset {record["opset_from"]}'
        + (f' -> {record["opset_to"]}' if record['opset_to'] != record['opset_from'] else '')
    )


def _bundled(backend: str | None) -> Path:
    """The model ``backend`` runs by default (``onnx-cpu`` where None); ``UsageError`` for a
    backend without one."""
    from replaybench.errors import UsageError

    name = backend or 'onnx-cpu'
    if name == 'onnx-cpu':
        from replaybench.detector.spec import DEFAULT_MODEL

        return DEFAULT_MODEL
    if name == 'onnx-seg':
        from replaybench.segmentation.spec import DEFAULT_SEG_MODEL

        return DEFAULT_SEG_MODEL
    if name == 'onnx-stereo':
        from replaybench.backends.onnx_stereo import DEFAULT_STEREO_MODEL

        return DEFAULT_STEREO_MODEL
    msg = f'no bundled model for --backend {name}: give onnx-cpu, onnx-seg or onnx-stereo'
    raise UsageError(msg)
