"""``compare --markdown FILE``: the comparison as GitHub-flavoured Markdown, for a CI job summary
(``$GITHUB_STEP_SUMMARY``) or a pull-request comment.

One line with the overall verdict, then a table of the candidate rows (whole-run ratios with the
interval the gate judges, and the method that made it), then a table of the gate's conditions
with the verdict of each, then the warnings. Text taken from run folders (labels, backends,
topics, warnings) is escaped so that it cannot break the table or inject HTML. The document
stays under ``MAX_BYTES`` (GitHub refuses a step summary over 1 MiB): past it, rows and warnings
are left out and the document says how many.
"""

from __future__ import annotations

import html
from typing import TYPE_CHECKING

from replaybench.comparison.core import ACCURACY_METRICS
from replaybench.comparison.gate import gate_verdict, method_text
from replaybench.comparison.main import RECORDED_SHORT, ratio_text

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.comparison.core import Comparison, Row
    from replaybench.comparison.gate import GateResult

__all__ = ['MAX_BYTES', 'comparison_markdown']

#: Largest document written (GitHub's step summary limit is 1 MiB; a margin for the job's own).
MAX_BYTES = 900 * 1024

_METRICS = (('median_ms', 'median'), ('p99_ms', 'p99'), ('mean_ms', 'mean'), ('fps', 'fps'))
_BADGE = {'passed': '✅ pass', 'failed': '❌ FAIL', 'inconclusive': '⚠️ inconclusive'}


def _cell(text: str) -> str:
    """A table cell holding ``text``: one line, HTML-escaped, pipes escaped."""
    flat = ' '.join(str(text).split())
    return html.escape(flat, quote=False).replace('|', '\\|')


def _headline(gate: Sequence[GateResult], allow_inconclusive: bool) -> str:
    if not gate:
        return '**replaybench compare**: no gate conditions (`--fail-if`): the changes only'
    verdict = gate_verdict(gate)
    failed = sum(r.verdict == 'failed' for r in gate)
    undecided = sum(r.verdict == 'inconclusive' for r in gate)
    if verdict == 'failed':
        extra = f', {undecided} inconclusive' if undecided else ''
        return f'❌ **replaybench gate: FAILED** ({failed} of {len(gate)} checks{extra})'
    if verdict == 'inconclusive':
        allowed = '; allowed by `--allow-inconclusive`' if allow_inconclusive else ''
        return (
            f'⚠️ **replaybench gate: INCONCLUSIVE** ({undecided} of {len(gate)} checks '
            f'undecided{allowed})'
        )
    return f'✅ **replaybench gate: passed** ({len(gate)} checks)'


def _recorded_text(row: Row, metric: str) -> str:
    m = row.metrics[metric]
    if m.ratio is not None:
        return ratio_text(m)
    if m.value is None and m.baseline is not None:
        return f'{m.baseline:.4g} ms in the baseline recording (this row replays)'
    return ''


def _row_line(row: Row, recorded: bool = False) -> str:
    cells = [_cell(row.run_label), _cell(row.backend), _cell(row.topic)]
    cells += [_cell(ratio_text(row.metrics[k])) for k, _ in _METRICS]
    acc = row.metrics['map50']
    text = ''
    if acc.diff is not None:
        text = f'{acc.diff:+.4f}'
        if acc.diff_ci is not None:
            text += f' [{acc.diff_ci[0]:+.4f}, {acc.diff_ci[1]:+.4f}] paired'
    paired = row.paired
    masks = row.metrics['miou']
    if paired is not None and paired.metric == 'miou' and masks.diff is not None:
        text = f'mIoU {masks.diff:+.4f}'
        if masks.diff_ci is not None:
            text += f' [{masks.diff_ci[0]:+.4f}, {masks.diff_ci[1]:+.4f}] paired'
    if paired is not None and paired.matched_mean is not None:
        what = 'pixels agree' if paired.metric == 'miou' else 'boxes agree'
        text += f'; {what} {paired.matched_mean:.3f}'
    cells.append(_cell(text))
    if recorded:
        cells += [_cell(_recorded_text(row, k)) for k in RECORDED_SHORT]
    # a recording's row: the method of its recorded latency (its replay is not timed)
    timed = 'median_ms' if row.recorded_outputs is None else 'recorded_pipeline_ms'
    method = method_text(row.metrics[timed])
    cells.append(_cell(method))
    return '| ' + ' | '.join(cells) + ' |'


def _gate_line(result: GateResult) -> str:
    unit = '%' if result.condition.rstrip().endswith('%') else ''
    # an accuracy difference is a fraction: four decimals, not one
    digits = 4 if not unit and result.condition.split()[0] in ACCURACY_METRICS else 1
    estimate = f'{result.estimate:+.{digits}f}{unit}' if result.estimate is not None else 'n/a'
    if result.ci_low is not None and result.ci_high is not None:
        interval = f'{result.ci_low:+.{digits}f}{unit} … {result.ci_high:+.{digits}f}{unit}'
    else:
        interval = 'none'
    cells = [
        _cell(result.condition),
        _cell(f'{result.run} · {result.backend} · {result.topic}'),
        _cell(estimate),
        _cell(interval),
        _cell(result.method),
        _BADGE[result.verdict],
    ]
    return '| ' + ' | '.join(cells) + ' |'


def comparison_markdown(
    comparison: Comparison,
    gate: Sequence[GateResult] = (),
    *,
    allow_inconclusive: bool = False,
    max_bytes: int = MAX_BYTES,
) -> str:
    """The Markdown document of ``comparison`` and its ``gate`` (in memory; nothing is read)."""
    level = round(comparison.confidence * 100)
    candidates = [r for r in comparison.rows if r.role == 'candidate']
    # the recorded latency's columns, when a candidate or its baseline is a recording
    recorded = any(
        r.metrics[k].value is not None or r.metrics[k].baseline is not None
        for r in candidates
        for k in RECORDED_SHORT
    )
    extra = ''.join(f' {name} |' for name in RECORDED_SHORT.values()) if recorded else ''
    head = [
        _headline(gate, allow_inconclusive),
        '',
        f'Baseline: {_cell(comparison.baseline_run.label)}'
        + (
            f' (backend {_cell(comparison.baseline_backend)})'
            if comparison.baseline_backend
            else ''
        )
        + f'. Ratios candidate / baseline of the whole runs, [{level} % interval of the typical '
        'change]: between repeats when both runs have `--repeat` passes, else between blocks '
        'of frames (n.s.: the interval holds 1).',
        '',
        f'| run | backend | topic | median | p99 | mean | fps | mAP@0.5 Δ |{extra} method |',
        '|---|---|---|---|---|---|---|---|' + '---|' * (len(RECORDED_SHORT) * recorded + 1),
    ]
    rows = [_row_line(r, recorded) for r in candidates]
    checks = [_gate_line(r) for r in gate]
    warnings = [f'- {_cell(w)}' for w in comparison.warnings]

    def document(n_rows: int, n_checks: int, n_warnings: int) -> str:
        lines = head + rows[:n_rows]
        if not rows:
            lines.append('| (no row to compare with the baseline) | | | | | | | | |')
        if n_rows < len(rows):
            lines += ['', f'*{len(rows) - n_rows} more rows left out (size limit).*']
        if gate:
            lines += [
                '',
                f'| condition | row | change | {level} % interval | method | verdict |',
                '|---|---|---|---|---|---|',
                *checks[:n_checks],
            ]
            if n_checks < len(checks):
                lines += ['', f'*{len(checks) - n_checks} more checks left out (size limit).*']
        if warnings:
            lines += ['', '<details><summary>Warnings</summary>', '', *warnings[:n_warnings]]
            if n_warnings < len(warnings):
                lines.append(f'- *{len(warnings) - n_warnings} more left out (size limit)*')
            lines += ['', '</details>']
        return '\n'.join(lines) + '\n'

    counts = [len(rows), len(checks), len(warnings)]
    text = document(*counts)
    while len(text.encode('utf-8')) > max_bytes and any(counts):
        # halve the longest list until the document fits
        longest = max(range(3), key=lambda i: counts[i])
        counts[longest] //= 2
        text = document(*counts)
    return text
