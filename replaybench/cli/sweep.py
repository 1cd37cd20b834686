"""``replaybench sweep``: every bag x backend x parameter combination on Ray."""

from __future__ import annotations

import sys
import threading
from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import Annotated, Any

import typer

from replaybench.cli._common import app, echo, fail, with_instance_options, with_run_options
from replaybench.errors import ReplaybenchError

__all__: list[str] = []


@app.command()
@with_run_options('sweep')
@with_instance_options('sweep')
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
    *,
    backend: list[str],
    param: list[str],
    options: dict[str, Any],
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
            command=['replaybench', *sys.argv[1:]],
            **options,
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
