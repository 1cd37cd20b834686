"""Verdicts: ``passed``, ``failed`` or ``inconclusive`` — where every gate condition is decided.

A condition such as ``p99_ms > +10%`` names the changes that fail the gate. Given the
interval of the change (``blocks.py``), ``decide`` says

- **failed** when the whole interval is past the threshold: the change is there;
- **passed** when none of it is: the change, if any, stays within the threshold, which serves
  as the margin of practical equivalence (as in a two one-sided tests procedure, or the
  region of practical equivalence of Bayesian decision rules);
- **inconclusive** when the interval straddles the threshold, or there is no interval (too few
  frames): the data cannot tell, and the gate says so instead of passing.

Judged on a point estimate (``--strict``, and accuracy metrics, which have no interval) there
is no middle ground: past the threshold fails, anything else passes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = ['EXIT_STATUS', 'VERDICTS', 'Verdict', 'decide', 'overall', 'past']

Verdict = Literal['passed', 'failed', 'inconclusive']

#: Every verdict, from the best to the worst.
VERDICTS: tuple[Verdict, ...] = ('passed', 'inconclusive', 'failed')

#: Exit status of ``replaybench compare`` for the overall verdict of its conditions.
EXIT_STATUS: dict[Verdict, int] = {'passed': 0, 'failed': 1, 'inconclusive': 3}


def past(value: float, op: str, threshold: float) -> bool:
    """Whether ``value OP threshold`` holds; values within 1e-9 (relative) of the threshold
    count as equal to it (0.79 - 0.8 is -0.010000000000000009 in floating point)."""
    if abs(value - threshold) <= 1e-9 * max(1.0, abs(threshold)):
        return op in {'>=', '<='}
    if op in {'>', '>='}:
        return value > threshold
    return value < threshold


def decide(
    estimate: float | None,
    interval: tuple[float, float] | None,
    op: str,
    threshold: float,
    *,
    point: bool = False,
) -> Verdict:
    """The verdict on the condition ``change OP threshold``.

    ``interval`` (low, high) is the confidence interval of the change; with ``point`` the
    point ``estimate`` is judged instead. No interval (or, with ``point``, no estimate) is
    inconclusive.
    """
    if op not in {'>', '>=', '<', '<='}:
        msg = f'unknown comparison {op!r} (>, >=, < or <=)'
        raise ValueError(msg)
    if point:
        if estimate is None:
            return 'inconclusive'
        return 'failed' if past(estimate, op, threshold) else 'passed'
    if interval is None:
        return 'inconclusive'
    low, high = interval
    near, far = (low, high) if op in {'>', '>='} else (high, low)
    if past(near, op, threshold):
        return 'failed'
    if not past(far, op, threshold):
        return 'passed'
    return 'inconclusive'


def overall(verdicts: Iterable[Verdict]) -> Verdict:
    """The gate's verdict: failed when any condition failed, else inconclusive when any is,
    else passed (also when there is nothing to judge)."""
    seen = set(verdicts)
    worst: tuple[Verdict, ...] = ('failed', 'inconclusive')
    for verdict in worst:
        if verdict in seen:
            return verdict
    return 'passed'
