"""The CI gate: conditions such as ``p99_ms > +10%`` judged against a comparison: each one
passed, failed or inconclusive (``verdict.py``)."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, NamedTuple

from replaybench.comparison.core import (
    METRICS,
    RECORDED_METRICS,
    RIG_METRICS,
    RIG_POINT_METRICS,
    TIMING_METRICS,
)
from replaybench.comparison.repeats import CAUTION_ADVICE
from replaybench.comparison.verdict import Verdict, decide, overall, past
from replaybench.errors import UsageError
from replaybench.results.blocks import change_interval, point_value
from replaybench.results.bootstrap import CONFIDENCE
from replaybench.results.model.summary import RIG_TOPIC
from replaybench.tasks import all_metrics

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from replaybench.comparison.core import Comparison, MetricComparison, Row
    from replaybench.tasks import MetricSpec

__all__ = [
    'CONDITION_GRAMMAR',
    'Condition',
    'GateResult',
    'Judgement',
    'evaluate_gate',
    'gate_failed',
    'gate_verdict',
    'judge_series',
    'method_text',
    'parse_condition',
]

#: The compared metrics' specs by name (``replaybench.tasks``): labels, units, formats.
_SPECS: dict[str, MetricSpec] = {m.name: m for m in all_metrics() if m.name in METRICS}
_ALIASES: dict[str, str] = {alias: m.name for m in _SPECS.values() for alias in m.aliases}

#: The condition language, as error messages and docs/compare.md state it.
CONDITION_GRAMMAR = (
    'METRIC OP SIGNED_NUMBER[%]  with METRIC one of '
    + ', '.join(METRICS)
    + ' (p50_ms = median_ms), OP one of > >= < <=, and a trailing % for a change relative to the '
    "baseline (else an absolute difference in the metric's unit), "
    "e.g. 'p99_ms > +10%', 'fps < -10%', 'map50 < -0.02', 'miou < -0.01', "
    "'recorded_pipeline_ms > +10%', 'rig_p99_ms > +10%', 'rig_drop_rate > +0.01' (the rig "
    'metrics are judged on rig rows, the others on camera rows)'
)

_PATTERN = re.compile(
    r'^\s*(?P<metric>[A-Za-z][A-Za-z0-9_]*)\s*(?P<op><=|>=|<|>)\s*'
    r'(?P<number>[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)\s*(?P<pct>%?)\s*$'
)


class Condition(NamedTuple):
    """A parsed condition: it holds (the gate fails) when ``change OP threshold``."""

    text: str
    metric: str
    op: str
    threshold: float
    relative: bool

    def describe(self) -> str:
        """The threshold as written: ``+10%`` or ``-0.02``."""
        return _signed(self.threshold, self.relative)


class GateResult(NamedTuple):
    """One condition judged on one candidate row.

    ``estimate``, ``ci_low`` and ``ci_high`` are in the threshold's unit: percent change for a
    relative condition, the metric's unit for an absolute one (None when not available).
    ``estimate`` is the change of the whole runs; the interval is that of the typical change
    (``method``: between blocks, or between frames for short runs). ``verdict`` is
    ``passed``, ``failed`` or ``inconclusive``; ``failed`` is ``verdict == 'failed'``.
    """

    condition: str
    backend: str
    topic: str
    estimate: float | None
    ci_low: float | None
    ci_high: float | None
    failed: bool
    explanation: str
    run: str = ''
    verdict: Verdict = 'passed'
    method: str = ''


class Judgement(NamedTuple):
    """``judge_series``: the verdict, the whole-series change, its interval and the method."""

    verdict: Verdict
    estimate: float | None
    interval: tuple[float, float] | None
    method: str


def parse_condition(text: str) -> Condition:
    """Parse ``METRIC OP SIGNED_NUMBER[%]``; UsageError with the grammar when it is not one."""
    found = _PATTERN.match(text)
    if found is None:
        msg = f'bad condition {text!r}: expected {CONDITION_GRAMMAR}'
        raise UsageError(msg)
    metric = found['metric'].lower()
    metric = _ALIASES.get(metric, metric)
    if metric not in METRICS:
        msg = (
            f'bad condition {text!r}: unknown metric {found["metric"]!r}; '
            f'expected {CONDITION_GRAMMAR}'
        )
        raise UsageError(msg)
    return Condition(
        text=' '.join(text.split()),
        metric=metric,
        op=found['op'],
        threshold=float(found['number']),
        relative=found['pct'] == '%',
    )


def _signed(value: float, relative: bool) -> str:
    return f'{value:+.4g}%' if relative else f'{value:+.4g}'


def _change(
    m: MetricComparison, condition: Condition
) -> tuple[float | None, tuple[float, float] | None]:
    """The change and its CI in the threshold's unit."""
    if condition.relative:
        if m.ratio is None:
            return None, None
        ci = None
        if m.ratio_ci is not None:
            ci = ((m.ratio_ci[0] - 1.0) * 100.0, (m.ratio_ci[1] - 1.0) * 100.0)
        return (m.ratio - 1.0) * 100.0, ci
    return m.diff, m.diff_ci


def _typical(m: MetricComparison, condition: Condition) -> float | None:
    if condition.relative:
        return None if m.typical_ratio is None else (m.typical_ratio - 1.0) * 100.0
    return m.typical_diff


def _value(metric: str, value: float | None) -> str:
    return 'n/a' if value is None else _SPECS[metric].value_text(value)


def _change_text(value: float, condition: Condition) -> str:
    if condition.relative:
        return f'{value:+.1f}%'
    unit = _SPECS[condition.metric].unit
    return f'{value:+.4g}{f" {unit}" if unit else ""}'


def method_text(m: MetricComparison) -> str:
    """``between-block 10/10`` or ``per-frame 10/10``: how the interval was made, from what."""
    if m.method is None:
        return ''
    if m.blocks is not None:
        return f'{m.method} {m.blocks[0]}/{m.blocks[1]}'
    return m.method


_UNIT = {'between-block': 'block', 'between-repeat': 'repeat'}


def _held_back(m: MetricComparison, row: Row, baseline: Row | None) -> str | None:
    """Why a failed timing condition is only inconclusive: a side is a short single pass with
    a stability warning (``repeats.single_pass_caution``); None when none is. Intervals between
    repeats already hold the variation between passes, and frame-by-frame intervals (under 20
    frames) fail only a change that nearly every frame shows (nine-fold on ten frames), so the
    rule holds for intervals between blocks."""
    if m.method != 'between-block':
        return None
    for side, which in ((row, 'the candidate'), (baseline, 'the baseline')):
        if side is not None and side.caution is not None:
            return f'{which} is {side.caution}: {CAUTION_ADVICE}'
    return None


_WORD: dict[Verdict, str] = {'failed': 'FAIL', 'passed': 'pass', 'inconclusive': 'INCONCLUSIVE'}
_SIDE = {'>': 'above', '>=': 'at or above', '<': 'below', '<=': 'at or below'}
_OTHER_SIDE = {'>': 'at or below', '>=': 'below', '<': 'at or above', '<=': 'above'}


def _missing_recorded(
    condition: Condition, m: MetricComparison, row: Row, baseline: Row | None
) -> tuple[Verdict, str] | None:
    """Why a recorded metric has no change, when a side is not a recording or refused it:
    inconclusive (the data cannot decide), never failed; None for the general reasons."""
    name = _SPECS[condition.metric].label
    for side, which, value in ((row, 'this row', m.value), (baseline, 'the baseline', m.baseline)):
        if side is None or value is not None:
            continue
        if side.recorded_note is None:
            return 'inconclusive', (
                f'{which} ({side.backend}) replays: it has no {name}, which only a recording '
                'holds (its own latency is median_ms)'
            )
        why = side.recorded_note or 'no recorded output with a latency'
        return 'inconclusive', f'{which} has no {name}: {why}'
    return None


def _missing(condition: Condition, m: MetricComparison) -> tuple[Verdict, str]:
    name = _SPECS[condition.metric].label
    if m.baseline is not None and m.value is None:
        return 'failed', f'the baseline has {name} but this run does not'
    if m.value is None:
        return 'inconclusive', f'{name} measured in neither run: nothing to judge'
    if m.baseline is None:
        return 'inconclusive', f'the baseline has no {name}: nothing to judge'
    return 'inconclusive', f'the baseline {name} is 0: a relative change is undefined'


def _no_interval(m: MetricComparison, row: Row, baseline: Row | None) -> str:
    if m.method == 'per-frame' and m.metric in RECORDED_METRICS:
        theirs = baseline.recorded_outputs if baseline is not None else '?'
        return (
            f'no CI: {theirs} baseline against {row.recorded_outputs} recorded outputs are too '
            f'few for a {CONFIDENCE:.0%} rank interval'
        )
    if m.method == 'per-frame':
        theirs = baseline.measured if baseline is not None else '?'
        return (
            f'no CI: {theirs} baseline against {row.measured} measured frames are too few for a '
            f'{CONFIDENCE:.0%} rank interval'
        )
    return 'no CI: a value is not positive and finite'


def _judge(
    row: Row, baseline: Row | None, condition: Condition, strict: bool, level: int
) -> GateResult:
    m = row.metrics[condition.metric]
    where = f'{row.backend} {row.topic} in {row.run_label}'
    name = _SPECS[condition.metric].label
    est, ci = _change(m, condition)
    method = method_text(m)
    if est is None:
        found = None
        if condition.metric in RECORDED_METRICS:
            found = _missing_recorded(condition, m, row, baseline)
        verdict, reason = found or _missing(condition, m)
        return GateResult(
            condition.text,
            row.backend,
            row.topic,
            None,
            None,
            None,
            verdict == 'failed',
            f'{_WORD[verdict]} {condition.text}: {where} ({condition.metric}): {reason}',
            row.run_label,
            verdict,
            method,
        )
    accuracy = _SPECS[condition.metric].accuracy or condition.metric in RIG_POINT_METRICS
    threshold = condition.describe()
    point_past = past(est, condition.op, condition.threshold)
    past_text = 'past' if point_past else 'not past'
    if strict or accuracy:
        verdict = decide(est, ci, condition.op, condition.threshold, point=True)
        if strict:
            why = f'strict: the point estimate is {past_text} {threshold}'
        elif ci is not None:
            # the paired interval over frames (comparison.paired) is shown, not judged
            why = f'accuracy is judged on the point estimate: it is {past_text} {threshold}'
        else:
            what = 'a drop rate' if condition.metric in RIG_POINT_METRICS else 'accuracy'
            why = f'{what} has no CI: the point estimate is {past_text} {threshold}'
    else:
        verdict = decide(est, ci, condition.op, condition.threshold)
        if ci is None:
            why = (
                f'{_no_interval(m, row, baseline)}: undecided (the point estimate is '
                f'{past_text} {threshold}; strict mode judges it)'
            )
        elif verdict == 'failed' and (held := _held_back(m, row, baseline)):
            verdict = 'inconclusive'
            why = f'the whole CI is {_SIDE[condition.op]} {threshold}, but {held}'
        elif verdict == 'failed':
            why = f'the whole CI is {_SIDE[condition.op]} {threshold}'
        elif verdict == 'passed':
            why = f'the whole CI is {_OTHER_SIDE[condition.op]} {threshold}'
        else:
            why = (
                f'the CI straddles {threshold}: the data cannot tell whether the change is past '
                f'it (the point estimate is {past_text}; strict mode judges it)'
            )
    shown = _change_text(est, condition)
    typical = _typical(m, condition)
    unit = _UNIT.get(m.method or '', 'frame')
    if condition.metric in RECORDED_METRICS and unit == 'frame':
        unit = 'output'
    detail = f'typical {unit} {_change_text(typical, condition)}, ' if typical is not None else ''
    if ci:
        ci_text = (
            f' ({detail}{level}% CI {_change_text(ci[0], condition)} … '
            f'{_change_text(ci[1], condition)})'
        )
    elif accuracy:
        ci_text = ' (no CI)'
    else:
        ci_text = f' ({detail}no CI)' if detail else ' (no CI)'
    text = (
        f'{_WORD[verdict]} {condition.text}: {where}: {name} {_value(condition.metric, m.value)} '
        f'vs {_value(condition.metric, m.baseline)} baseline ({row.baseline_backend}) = '
        f'{shown}{ci_text}; {why}'
    )
    return GateResult(
        condition.text,
        row.backend,
        row.topic,
        est,
        ci[0] if ci else None,
        ci[1] if ci else None,
        verdict == 'failed',
        text,
        row.run_label,
        verdict,
        method,
    )


def evaluate_gate(
    comparison: Comparison, conditions: Sequence[str], *, strict: bool = False
) -> list[GateResult]:
    """Judge each condition on every candidate row (condition order, then row order).

    A timing condition fails when its whole CI lies past the threshold, passes when none of it
    does, and is inconclusive otherwise or without a CI (``verdict.decide``); ``strict``
    judges the point estimate instead. Accuracy metrics have no CI and are judged on the point
    estimate. UsageError on a bad condition (all are parsed before any is judged).
    """
    parsed = [parse_condition(c) for c in conditions]
    candidates = [r for r in comparison.rows if r.role == 'candidate']
    level = round(comparison.confidence * 100)
    # a rig metric on the rig rows, every other on the camera rows: no frame judged twice
    return [
        _judge(row, comparison.baseline_row(row), condition, strict, level)
        for condition in parsed
        for row in candidates
        if (row.topic == RIG_TOPIC) == (condition.metric in RIG_METRICS)
    ]


def gate_failed(results: Sequence[GateResult]) -> bool:
    """True when any condition failed."""
    return any(r.failed for r in results)


def gate_verdict(results: Sequence[GateResult]) -> Verdict:
    """The gate's verdict over all its results (``verdict.overall``)."""
    return overall(r.verdict for r in results)


def judge_series(
    baseline_ms: npt.ArrayLike,
    candidate_ms: npt.ArrayLike,
    condition: str | Condition,
    *,
    baseline_intervals_s: npt.ArrayLike | None = None,
    candidate_intervals_s: npt.ArrayLike | None = None,
    confidence: float = CONFIDENCE,
    strict: bool = False,
) -> Judgement:
    """Judge a timing condition on two latency series (ms, replay order) as the gate does.

    ``*_intervals_s`` are completion-to-completion times (s), needed for ``fps``. The change is
    that of the whole series (as in summary.csv); the interval and the verdict are those of
    ``blocks.change_interval`` and ``verdict.decide``. UsageError for a bad condition or one on
    an accuracy metric.
    """
    parsed = condition if isinstance(condition, Condition) else parse_condition(condition)
    if parsed.metric not in TIMING_METRICS:
        msg = f'{parsed.text!r}: judge_series judges timing metrics ({", ".join(TIMING_METRICS)})'
        raise UsageError(msg)
    change = change_interval(
        parsed.metric,
        baseline_ms,
        candidate_ms,
        baseline_intervals_s=baseline_intervals_s,
        candidate_intervals_s=candidate_intervals_s,
        confidence=confidence,
    )
    base = point_value(parsed.metric, baseline_ms, baseline_intervals_s)
    cand = point_value(parsed.metric, candidate_ms, candidate_intervals_s)
    estimate: float | None = None
    interval: tuple[float, float] | None = None
    if parsed.relative:
        if base is not None and cand is not None and base > 0:
            estimate = (cand / base - 1.0) * 100.0
            if change.ratio_ci is not None:
                lo, hi = change.ratio_ci
                interval = ((lo - 1.0) * 100.0, (hi - 1.0) * 100.0)
    elif base is not None and cand is not None:
        estimate = cand - base
        interval = change.diff_ci
    verdict = decide(estimate, interval, parsed.op, parsed.threshold, point=strict)
    return Judgement(verdict, estimate, interval, change.method)
