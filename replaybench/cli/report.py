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
    github_benchmark: Annotated[
        Path | None,
        typer.Option(
            '--github-benchmark',
            help="Also write the run's latencies (smaller_is_better.json) and throughput and "
            "accuracy (bigger_is_better.json) into DIR in github-action-benchmark's custom "
            'format.',
            metavar='DIR',
        ),
    ] = None,
) -> None:
    """Render report.html again from a run folder (run.json, frames.csv, samples/).

    Example: replaybench report replaybench-runs/20261122-101500
    """
    from replaybench.report import render_report

    try:
        path = render_report(run_dir)
        written = _github_benchmark(run_dir, github_benchmark) if github_benchmark else ()
    except ReplaybenchError as err:
        raise fail(err) from None
    echo(f'Report: {path}')
    for file in written:
        echo(f'Benchmark: {file}')


def _github_benchmark(run_dir: Path, out: Path) -> tuple[Path, ...]:
    """--github-benchmark DIR: the two files, from the run folder read once."""
    from replaybench.errors import UsageError
    from replaybench.report.github_benchmark import write_github_benchmark
    from replaybench.results.folder import load_run

    data = load_run(run_dir)
    try:
        return write_github_benchmark(data.run, out)
    except OSError as err:
        msg = f'cannot write into {out}: {err.strerror or err}'
        raise UsageError(msg) from err
