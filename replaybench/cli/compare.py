"""``replaybench compare``: runs against a baseline, with a CI gate."""

from __future__ import annotations

from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import Annotated

import typer

from replaybench.cli._common import app, echo, fail
from replaybench.errors import ReplaybenchError

__all__: list[str] = []


@app.command()
def compare(
    run_dirs: Annotated[
        list[Path],
        typer.Argument(
            help='Run folders; the first is the baseline (see --baseline).', show_default=False
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option(
            '--out',
            '-o',
            help='Also write comparison.html/.csv/.json into this folder (default: print only).',
        ),
    ] = None,
    fail_if: Annotated[
        list[str],
        typer.Option(
            '--fail-if',
            help='Gate condition, e.g. "p99_ms > +10%" or "map50 < -0.02" (repeat).',
        ),
    ] = [],  # noqa: B006
    strict: Annotated[
        bool, typer.Option('--strict', help='Judge conditions on the point estimate, not the CI.')
    ] = False,
    allow_inconclusive: Annotated[
        bool,
        typer.Option(
            '--allow-inconclusive',
            help='Exit 0, not 3, when no condition failed but the data could not decide one.',
        ),
    ] = False,
    markdown: Annotated[
        Path | None,
        typer.Option(
            '--markdown',
            help='Also write the comparison and the verdict as a GitHub-flavoured Markdown '
            'table into FILE (a CI job summary or pull-request comment; under 1 MiB).',
            metavar='FILE',
        ),
    ] = None,
    baseline: Annotated[
        int,
        typer.Option('--baseline', min=0, help='Which run folder is the baseline, counted from 0.'),
    ] = 0,
    baseline_backend: Annotated[
        str | None,
        typer.Option(
            '--baseline-backend',
            help="Compare every row with this backend of the baseline run (default: the row's "
            'own backend; with one run folder, its first backend).',
        ),
    ] = None,
) -> None:
    """Compare runs across backends, machines or GPUs, with confidence intervals and a CI gate.

    Prints the table on stdout; with --out, also writes comparison.html, .csv and .json there.

    Exit status: 0 passed, 1 a condition failed, 2 bad input, 3 a condition inconclusive.

    Example: replaybench compare runs/main runs/branch --fail-if "p99_ms > +10%"
    """
    from replaybench.app.compare import compare_config, compare_lines, run_compare

    try:
        settings = compare_config(
            run_dirs,
            fail_if=fail_if,
            strict=strict,
            allow_inconclusive=allow_inconclusive,
            baseline=baseline,
            baseline_backend=baseline_backend,
            out=out,
            markdown=markdown,
        )
        outcome = run_compare(settings)
    except ReplaybenchError as err:
        raise fail(err) from None
    for to_stderr, line in compare_lines(outcome):
        echo(line, err=to_stderr)
    raise typer.Exit(outcome.exit_code)
