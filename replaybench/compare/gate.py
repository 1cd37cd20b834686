"""The CI gate: conditions such as ``p99_ms > +10%`` judged against a comparison."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, NamedTuple

from replaybench.compare.bootstrap import MIN_FRAMES
from replaybench.compare.core import ACCURACY_METRICS, METRICS
from replaybench.errors import UsageError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.compare.core import Comparison, MetricComparison, Row

__all__ = [
    'CONDITION_GRAMMAR',
    'Condition',
    'GateResult',
    'evaluate_gate',
    'gate_failed',
    'parse_condition',
]

_ALIASES: dict[str, str] = {'p50_ms': 'median_ms', 'throughput_fps': 'fps'}

#: The condition language, as error messages and docs/compare.md state it.
CONDITION_GRAMMAR = (
    'METRIC OP SIGNED_NUMBER[%]  with METRIC one of '
    + ', '.join(METRICS)
    + ' (p50_ms = median_ms), OP one of > >= < <=, and a trailing % for a change relative to the '
    "baseline (else an absolute difference in the metric's unit), "
    "e.g. 'p99_ms > +10%', 'fps < -10%', 'map50 < -0.02'"
)

_PATTERN = re.compile(
    r'^\s*(?P<metric>[A-Za-z][A-Za-z0-9_]*)\s*(?P<op><=|>=|<|>)\s*'
    r'(?P<number>[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)\s*(?P<pct>%?)\s*$'
)

_UNITS: dict[str, str] = {'median_ms': ' ms', 'p99_ms': ' ms', 'mean_ms': ' ms', 'fps': ' fps'}
_NAMES: dict[str, str] = {
    'median_ms': 'median latency',
    'p99_ms': 'p99 latency',
    'mean_ms': 'mean latency',
    'fps': 'throughput',
    'map50': 'mAP@0.5',
    'recall50': 'recall@0.5',
    'precision50': 'precision@0.5',
}


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


def _past(value: float, op: str, threshold: float) -> bool:
    # Values within rounding noise of the threshold count as equal to it (0.79 - 0.8 is -0.01).
    if abs(value - threshold) <= 1e-9 * max(1.0, abs(threshold)):
        return op in {'>=', '<='}
    if op in {'>', '>='}:
        return value > threshold
    return value < threshold


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


def _value(metric: str, value: float | None) -> str:
    if value is None:
        return 'n/a'
    if metric in ACCURACY_METRICS:
        return f'{value:.4f}'
    return f'{value:.4g}{_UNITS.get(metric, "")}'


def _change_text(value: float, condition: Condition) -> str:
    if condition.relative:
        return f'{value:+.1f}%'
    return f'{value:+.4g}{_UNITS.get(condition.metric, "")}'


def _judge(row: Row, condition: Condition, strict: bool, level: int) -> GateResult:
    m = row.metrics[condition.metric]
    where = f'{row.backend} {row.topic} in {row.run_label}'
    name = _NAMES[condition.metric]
    est, ci = _change(m, condition)
    if est is None:
        failed = m.baseline is not None and m.value is None
        if failed:
            reason = f'the baseline has {name} but this run does not'
        elif m.value is None:
            reason = f'{name} measured in neither run'
        elif m.baseline is None:
            reason = f'the baseline has no {name}'
        else:
            reason = f'the baseline {name} is 0: a relative change is undefined'
        verdict = 'FAIL' if failed else 'pass'
        return GateResult(
            condition.text,
            row.backend,
            row.topic,
            None,
            None,
            None,
            failed,
            f'{verdict} {condition.text}: {where} ({condition.metric}): {reason}',
            row.run_label,
        )
    shown = _change_text(est, condition)
    ci_text = (
        f' ({level}% CI {_change_text(ci[0], condition)} … {_change_text(ci[1], condition)})'
        if ci
        else ' (no CI)'
    )
    point_past = _past(est, condition.op, condition.threshold)
    past = 'past' if point_past else 'not past'
    if strict:
        failed = point_past
        why = f'strict: the point estimate is {past} {condition.describe()}'
    elif ci is None and condition.metric in ACCURACY_METRICS:
        failed = point_past
        why = f'accuracy has no CI: the point estimate is {past} {condition.describe()}'
    elif ci is None:
        failed = False
        why = (
            f'no CI (fewer than {MIN_FRAMES} measured frames here or in the baseline): not judged '
            f'(the point estimate is {past} {condition.describe()}; strict mode judges it)'
        )
    else:
        edge = ci[0] if condition.op in {'>', '>='} else ci[1]
        failed = _past(edge, condition.op, condition.threshold)
        side = 'above' if condition.op in {'>', '>='} else 'below'
        if failed:
            why = f'the whole CI is {side} {condition.describe()}'
        elif point_past:
            why = (
                f'the point estimate is past {condition.describe()} but the CI is not entirely '
                f'{side} it: within noise (strict mode would fail)'
            )
        else:
            why = f'not past {condition.describe()}'
    verdict = 'FAIL' if failed else 'pass'
    text = (
        f'{verdict} {condition.text}: {where}: {name} {_value(condition.metric, m.value)} vs '
        f'{_value(condition.metric, m.baseline)} baseline ({row.baseline_backend}) = '
        f'{shown}{ci_text}; {why}'
    )
    return GateResult(
        condition.text,
        row.backend,
        row.topic,
        est,
        ci[0] if ci else None,
        ci[1] if ci else None,
        failed,
        text,
        row.run_label,
    )


def evaluate_gate(
    comparison: Comparison, conditions: Sequence[str], *, strict: bool = False
) -> list[GateResult]:
    """Judge each condition on every candidate row (condition order, then row order).

    By default a condition fails only when the whole CI lies past the threshold; ``strict``
    judges the point estimate. Accuracy metrics have no CI and are judged on the point estimate;
    a timing metric without a CI (too few frames) does not fail unless ``strict``. UsageError
    on a bad condition (all are parsed before any is judged).
    """
    parsed = [parse_condition(c) for c in conditions]
    results: list[GateResult] = []
    candidates = [r for r in comparison.rows if r.role == 'candidate']
    level = round(comparison.confidence * 100)
    for condition in parsed:
        for row in candidates:
            results.append(_judge(row, condition, strict, level))
    return results


def gate_failed(results: Sequence[GateResult]) -> bool:
    """True when any condition failed."""
    return any(r.failed for r in results)
