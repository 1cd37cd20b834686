"""``replaybench compare`` in one call: compare, gate, write the files, print the summary."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from replaybench.comparison.core import compare_runs
from replaybench.comparison.gate import evaluate_gate, gate_verdict, parse_condition
from replaybench.comparison.output import write_comparison
from replaybench.comparison.verdict import EXIT_STATUS
from replaybench.errors import ReplaybenchError
from replaybench.results.bootstrap import DEFAULT_RESAMPLES

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    from replaybench.comparison.core import Comparison, MetricComparison
    from replaybench.comparison.gate import GateResult

__all__ = ['EXIT_GATE_FAILED', 'EXIT_INCONCLUSIVE', 'format_summary', 'main_compare']

#: Exit status when a gate condition fails (bad input is ReplaybenchError.exit_code, 2).
EXIT_GATE_FAILED = EXIT_STATUS['failed']
#: Exit status when no condition failed but one could not be decided (0 with
#: ``allow_inconclusive``).
EXIT_INCONCLUSIVE = EXIT_STATUS['inconclusive']

_SHORT: dict[str, str] = {'median_ms': 'median', 'p99_ms': 'p99', 'mean_ms': 'mean', 'fps': 'fps'}


def _stderr(line: str) -> None:
    print(line, file=sys.stderr)


def _ratio(m: MetricComparison) -> str:
    if m.ratio is None:
        return 'n/a'
    text = f'×{m.ratio:.3f}'
    if m.ratio_ci is None:
        return text + ' (no CI)'
    lo, hi = m.ratio_ci
    mark = '' if m.significant else ' n.s.'
    return f'{text} [{lo:.3f}, {hi:.3f}]{mark}'


def format_summary(
    comparison: Comparison, gate: Sequence[GateResult] = (), *, allow_inconclusive: bool = False
) -> list[str]:
    """The human summary: one line per candidate row, then the gate's verdict."""
    level = round(comparison.confidence * 100)
    lines = [
        f'baseline: {comparison.baseline_run.label}'
        + (f' (backend {comparison.baseline_backend})' if comparison.baseline_backend else ''),
        (
            f'ratios candidate/baseline; {level}% CIs of the typical change, exact rank '
            'intervals between blocks of frames (n.s. = not significant):'
        ),
    ]
    for row in comparison.rows:
        if row.role != 'candidate':
            continue
        versus = f' vs {row.baseline_backend}' if row.baseline_backend != row.backend else ''
        parts = [f'{_SHORT[k]} {_ratio(row.metrics[k])}' for k in _SHORT]
        acc = row.metrics['map50']
        if acc.diff is not None:
            parts.append(f'map50 {acc.diff:+.4f} (no CI)')
        lines.append(f'  {row.name}{versus}: ' + ', '.join(parts))
    if not any(r.role == 'candidate' for r in comparison.rows):
        lines.append('  (no row to compare with the baseline)')
    if gate:
        failed = sum(r.verdict == 'failed' for r in gate)
        undecided = sum(r.verdict == 'inconclusive' for r in gate)
        verdict = gate_verdict(gate)
        if verdict == 'failed':
            extra = f', {undecided} inconclusive' if undecided else ''
            lines.append(f'gate: FAILED ({failed} of {len(gate)} checks{extra})')
        elif verdict == 'inconclusive':
            word = 'inconclusive' if allow_inconclusive else 'INCONCLUSIVE'
            allowed = '; allowed by --allow-inconclusive' if allow_inconclusive else ''
            lines.append(f'gate: {word} ({undecided} of {len(gate)} checks undecided{allowed})')
        else:
            lines.append(f'gate: passed ({len(gate)} checks)')
    return lines


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
    """Compare ``run_dirs``, judge ``fail_if`` and write the files into ``out`` (None: no
    files, the summary and the verdict only).

    Prints the summary through ``echo`` and warnings, failed and inconclusive conditions and
    errors through ``echo_err``. Returns the exit status: 0 when every condition passed, 1 when
    one failed, 3 when none failed but one was inconclusive (0 with ``allow_inconclusive``),
    2 on bad input (unreadable run folder, bad condition, unwritable ``out``).
    """
    try:
        for condition in fail_if:
            parse_condition(condition)
        comparison = compare_runs(
            run_dirs,
            baseline=baseline,
            baseline_backend=baseline_backend,
            seed=seed,
            n_boot=n_boot,
        )
        gate = evaluate_gate(comparison, fail_if, strict=strict)
    except ReplaybenchError as err:
        echo_err(f'replaybench: error: {err}')
        return err.exit_code
    for warning in comparison.warnings:
        echo_err(f'replaybench: warning: {warning}')
    written = None
    try:
        if out is not None:
            written = write_comparison(
                comparison,
                out,
                gate=gate,
                conditions=fail_if,
                strict=strict,
                allow_inconclusive=allow_inconclusive,
            )
    except OSError as err:
        echo_err(f'replaybench: error: cannot write into {out}: {err.strerror or err}')
        return 2
    for line in format_summary(comparison, gate, allow_inconclusive=allow_inconclusive):
        echo(line)
    for result in gate:
        if result.verdict != 'passed':
            echo_err(f'replaybench: gate: {result.explanation}')
    if written is not None:
        csv_path, html_path = written
        echo(f'Comparison: {html_path}')
        echo(f'CSV: {csv_path}')
        echo(f'JSON: {html_path.with_name("comparison.json")}')
    verdict = gate_verdict(gate)
    if verdict == 'inconclusive' and allow_inconclusive:
        return 0
    return EXIT_STATUS[verdict]
