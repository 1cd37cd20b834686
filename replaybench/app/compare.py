"""``replaybench compare`` as an application: read the runs, compare them with the baseline,
judge the gate, write comparison.csv/.html/.json when asked, and say what it found.

The command line and ``replaybench.compare`` both parse their options into a
``CompareConfig`` (``compare_config``) and compare with ``run_compare``; the statistics are
``replaybench.comparison``'s.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from replaybench.app.run import name_list
from replaybench.comparison.core import compare_runs
from replaybench.comparison.gate import evaluate_gate, gate_verdict, parse_condition
from replaybench.comparison.main import format_summary
from replaybench.comparison.output import write_comparison
from replaybench.comparison.verdict import EXIT_STATUS
from replaybench.errors import ReplaybenchError, UsageError
from replaybench.results.bootstrap import DEFAULT_RESAMPLES
from replaybench.results.folder import RunData

if TYPE_CHECKING:
    import os
    from collections.abc import Callable, Sequence

    from replaybench.comparison.core import Comparison
    from replaybench.comparison.gate import GateResult

__all__ = [
    'CompareConfig',
    'CompareOutcome',
    'compare_config',
    'compare_lines',
    'main_compare',
    'run_compare',
]


@dataclass(frozen=True, slots=True)
class CompareConfig:
    """``replaybench compare``'s options, checked (``compare_config``)."""

    #: run folders, or runs already read (``RunData``); the one at ``baseline`` is the baseline
    runs: tuple[Path | RunData, ...]
    #: gate conditions, each parsed once to check it
    fail_if: tuple[str, ...] = ()
    strict: bool = False
    allow_inconclusive: bool = False
    baseline: int = 0
    baseline_backend: str | None = None
    seed: int = 0
    n_boot: int = DEFAULT_RESAMPLES
    #: where comparison.csv/.html/.json go; None writes nothing
    out: Path | None = None


def compare_config(
    runs: Sequence[str | os.PathLike[str] | RunData],
    *,
    fail_if: str | Sequence[str] = (),
    strict: bool = False,
    allow_inconclusive: bool = False,
    baseline: int = 0,
    baseline_backend: str | None = None,
    seed: int = 0,
    n_boot: int = DEFAULT_RESAMPLES,
    out: str | os.PathLike[str] | None = None,
) -> CompareConfig:
    """The ``CompareConfig`` of ``replaybench compare``'s options (``--fail-if`` is
    ``fail_if``); ``UsageError`` for a condition that does not parse, before any run is read."""
    conditions = tuple(name_list(fail_if))
    for condition in conditions:
        parse_condition(condition)
    return CompareConfig(
        runs=tuple(r if isinstance(r, RunData) else Path(r) for r in runs),
        fail_if=conditions,
        strict=strict,
        allow_inconclusive=allow_inconclusive,
        baseline=baseline,
        baseline_backend=baseline_backend,
        seed=seed,
        n_boot=n_boot,
        out=Path(out) if out is not None else None,
    )


@dataclass(frozen=True, slots=True)
class CompareOutcome:
    """What ``run_compare`` found: the comparison, the gate's checks and the files written."""

    config: CompareConfig
    comparison: Comparison
    gate: tuple[GateResult, ...]
    #: comparison.csv, comparison.html and comparison.json; () when ``config.out`` is None
    written: tuple[Path, ...] = ()

    @property
    def verdict(self) -> str | None:
        """``passed``, ``failed`` or ``inconclusive``; None without conditions."""
        return gate_verdict(self.gate) if self.gate else None

    @property
    def exit_code(self) -> int:
        """0 passed (or no condition), 1 a condition failed, 3 one undecided (0 when
        ``allow_inconclusive``)."""
        verdict = gate_verdict(self.gate)
        if verdict == 'inconclusive' and self.config.allow_inconclusive:
            return 0
        return EXIT_STATUS[verdict]


def run_compare(config: CompareConfig) -> CompareOutcome:
    """Compare ``config.runs`` with the baseline, judge the gate, and write the three files
    into ``config.out`` when it is set. Raises ``ReplaybenchError`` (exit status 2) for a run
    that cannot be read or an ``out`` that cannot be written."""
    comparison = compare_runs(
        config.runs,
        baseline=config.baseline,
        baseline_backend=config.baseline_backend,
        seed=config.seed,
        n_boot=config.n_boot,
    )
    gate = tuple(evaluate_gate(comparison, config.fail_if, strict=config.strict))
    written: tuple[Path, ...] = ()
    if config.out is not None:
        try:
            csv_path, html_path = write_comparison(
                comparison,
                config.out,
                gate=gate,
                conditions=config.fail_if,
                strict=config.strict,
                allow_inconclusive=config.allow_inconclusive,
            )
        except OSError as err:
            msg = f'cannot write into {config.out}: {err.strerror or err}'
            raise UsageError(msg) from err
        written = (csv_path, html_path, html_path.with_name('comparison.json'))
    return CompareOutcome(config, comparison, gate, written)


def compare_lines(outcome: CompareOutcome) -> list[tuple[bool, str]]:
    """The command's output in order, each line with whether it goes to stderr: the warnings
    (stderr), the summary and verdict (stdout), each condition that did not pass (stderr),
    and the files written (stdout)."""
    comparison, gate = outcome.comparison, outcome.gate
    lines = [(True, f'replaybench: warning: {w}') for w in comparison.warnings]
    summary = format_summary(comparison, gate, allow_inconclusive=outcome.config.allow_inconclusive)
    lines += [(False, line) for line in summary]
    lines += [(True, f'replaybench: gate: {r.explanation}') for r in gate if r.verdict != 'passed']
    if outcome.written:
        csv_path, html_path, json_path = outcome.written
        for name, path in (('Comparison', html_path), ('CSV', csv_path), ('JSON', json_path)):
            lines.append((False, f'{name}: {path}'))
    return lines


def _stderr(line: str) -> None:
    print(line, file=sys.stderr)


def main_compare(
    run_dirs: Sequence[str | Path],
    out: str | Path | None,
    fail_if: Sequence[str] = (),
    strict: bool = False,
    *,
    baseline: int = 0,
    baseline_backend: str | None = None,
    seed: int = 0,
    n_boot: int = DEFAULT_RESAMPLES,
    allow_inconclusive: bool = False,
    echo: Callable[[str], None] = print,
    echo_err: Callable[[str], None] = _stderr,
) -> int:
    """``replaybench compare`` in one call: ``compare_config``, ``run_compare``, then the
    ``compare_lines`` through ``echo`` / ``echo_err``. Returns the exit status: 0 when every
    condition passed, 1 when one failed, 3 when none failed but one was inconclusive (0 with
    ``allow_inconclusive``), 2 on bad input (unreadable run folder, bad condition, unwritable
    ``out``)."""
    try:
        outcome = run_compare(
            compare_config(
                run_dirs,
                fail_if=fail_if,
                strict=strict,
                allow_inconclusive=allow_inconclusive,
                baseline=baseline,
                baseline_backend=baseline_backend,
                seed=seed,
                n_boot=n_boot,
                out=out,
            )
        )
    except ReplaybenchError as err:
        echo_err(f'replaybench: error: {err}')
        return err.exit_code
    for to_stderr, line in compare_lines(outcome):
        (echo_err if to_stderr else echo)(line)
    return outcome.exit_code
