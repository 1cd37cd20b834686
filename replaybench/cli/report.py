"""``replaybench report``: draw report.html again from a run folder."""

from __future__ import annotations

from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import Annotated

import typer

from replaybench.cli._common import app, echo, fail
from replaybench.errors import ReplaybenchError

__all__: list[str] = []


@app.command()
def report(
    run_dir: Annotated[
        Path, typer.Argument(help='A run folder written by `replaybench run`.', show_default=False)
    ],
) -> None:
    """Render report.html again from a run folder (run.json, frames.csv, samples/).

    Example: replaybench report replaybench-runs/20261122-101500
    """
    from replaybench.report import render_report

    try:
        path = render_report(run_dir)
    except ReplaybenchError as err:
        raise fail(err) from None
    echo(f'Report: {path}')
