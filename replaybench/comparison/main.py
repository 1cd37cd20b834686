"""The summary ``replaybench compare`` prints: one line per candidate row, then the verdict
(``replaybench.app.compare`` runs the command)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.comparison.gate import gate_verdict, method_text
from replaybench.comparison.verdict import EXIT_STATUS

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.comparison.core import Comparison, MetricComparison, Row
    from replaybench.comparison.gate import GateResult
    from replaybench.comparison.paired import Paired

__all__ = [
    'EXIT_GATE_FAILED',
    'EXIT_INCONCLUSIVE',
    'RECORDED_SHORT',
    'agreement_text',
    'format_summary',
    'paired_text',
    'ratio_text',
    'recorded_parts',
]

#: Exit status when a gate condition fails (bad input is ReplaybenchError.exit_code, 2).
EXIT_GATE_FAILED = EXIT_STATUS['failed']
#: Exit status when no condition failed but one could not be decided (0 with
#: ``allow_inconclusive``).
EXIT_INCONCLUSIVE = EXIT_STATUS['inconclusive']

_SHORT: dict[str, str] = {'median_ms': 'median', 'p99_ms': 'p99', 'mean_ms': 'mean', 'fps': 'fps'}
#: The recorded latencies the summary and --markdown show (the medians; the p99s are in the
#: files): metric -> short name.
RECORDED_SHORT: dict[str, str] = {
    'recorded_pipeline_ms': 'recorded pipeline',
    'recorded_capture_ms': 'recorded capture-to-output',
}


def paired_text(row: Row) -> str:
    """The interval of a row's paired change (map50 or miou): the paired bootstrap's, or
    ``(no CI)``."""
    paired = row.paired
    if paired is None or paired.ci is None:
        return '(no CI)'
    lo, hi = paired.ci
    level = round(paired.confidence * 100)
    return f'[{lo:+.4f}, {hi:+.4f}] ({level}% paired bootstrap, {paired.frames} frames)'


def agreement_text(paired: Paired) -> str:
    """The agreement of a row's outputs with its baseline's, in a few words."""
    if paired.metric == 'miou':
        return (
            f'masks agree: pixels {paired.matched_mean:.4f}, mIoU {paired.iou_mean:.3f} '
            f'(lowest frame {paired.matched_min:.4f})'
        )
    return (
        f'boxes agree: matched {paired.matched_mean:.3f}, IoU {paired.iou_mean:.3f} '
        f'(lowest frame {paired.matched_min:.3f})'
    )


def ratio_text(m: MetricComparison) -> str:
    """A metric's change as the summary prints it: the whole-run ratio and the interval of the
    typical change (the one the gate judges). Where the whole-run ratio lies outside that
    interval (interference slowed a few stretches of one run: docs/compare.md), the interval is
    shown beside the typical ratio it is centred on, so no number sits outside its own
    brackets."""
    if m.ratio is None:
        return 'n/a'
    text = f'×{m.ratio:.3f}'
    if m.ratio_ci is None:
        return text + ' (no CI)'
    lo, hi = m.ratio_ci
    mark = '' if m.significant else ' n.s.'
    interval = f'[{lo:.3f}, {hi:.3f}]'
    if not lo <= m.ratio <= hi and m.typical_ratio is not None:
        return f'{text} (typical ×{m.typical_ratio:.3f} {interval}){mark}'
    return f'{text} {interval}{mark}'


def recorded_parts(row: Row) -> list[str]:
    """The recorded latencies of a candidate row as the summary shows them: the ratio and its
    interval where both rows are recordings; where only the baseline is (a replayed backend
    against a recording), the recording's values beside this row's own median latency."""
    parts = []
    beside = []
    for metric, short in RECORDED_SHORT.items():
        m = row.metrics[metric]
        if m.ratio is not None:
            parts.append(f'{short} {ratio_text(m)}')
        elif m.value is None and m.baseline is not None:
            beside.append(f'{short} {m.baseline:.4g} ms')
    if beside:
        own = row.metrics['median_ms'].value
        mine = f'this row replayed: median {own:.4g} ms' if own is not None else 'no latency here'
        parts.append(', '.join(beside) + f' in the baseline recording ({mine})')
    return parts


def format_summary(
    comparison: Comparison, gate: Sequence[GateResult] = (), *, allow_inconclusive: bool = False
) -> list[str]:
    """The human summary: one line per candidate row, then the gate's verdict."""
    level = round(comparison.confidence * 100)
    lines = [
        f'baseline: {comparison.baseline_run.label}'
        + (f' (backend {comparison.baseline_backend})' if comparison.baseline_backend else ''),
        (
            f'ratios candidate/baseline; {level}% CIs of the typical change: Welch t intervals '
            'between repeats when both runs have --repeat passes, else exact rank intervals '
            'between blocks of frames, or between frames below 20 (each row names its method; '
            'n.s. = not significant):'
        ),
    ]
    for row in comparison.rows:
        if row.role != 'candidate':
            continue
        versus = f' vs {row.baseline_backend}' if row.baseline_backend != row.backend else ''
        parts = [f'{_SHORT[k]} {ratio_text(row.metrics[k])}' for k in _SHORT]
        acc = row.metrics['map50']
        if acc.diff is not None:
            parts.append(f'map50 {acc.diff:+.4f} {paired_text(row)}')
        masks = row.metrics['miou']
        if row.paired is not None and row.paired.metric == 'miou' and masks.diff is not None:
            parts.append(f'miou {masks.diff:+.4f} {paired_text(row)}')
        if row.paired is not None and row.paired.matched_mean is not None:
            parts.append(agreement_text(row.paired))
        parts += recorded_parts(row)
        # a recording's row: the method of its recorded latency (its replay is not timed)
        timed = 'median_ms' if row.recorded_outputs is None else 'recorded_pipeline_ms'
        method = method_text(row.metrics[timed])
        how = f' [{method}]' if method else ''
        lines.append(f'  {row.name}{versus}: ' + ', '.join(parts) + how)
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
