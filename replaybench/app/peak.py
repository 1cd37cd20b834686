"""``replaybench peak`` as an application: the peak-rate search, each trial a run with its
report, then peak.json and peak.html.

The search itself (start rate, coarse search, bisection, confirmation; ``peak_rule``) is the
engine's, ``replaybench.replay.peak``; this layer adds peak.html (``replaybench.report``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.replay.peak import (
    CONFIRM_TRIALS,
    DEFAULT_TRIAL_FRAMES,
    MAX_DOUBLINGS,
    MIN_TRIAL_FRAMES,
    PEAK_SCHEMA_VERSION,
    PeakResult,
    Trial,
    peak_rule,
    trial_verdict,
)
from replaybench.replay.peak import find_peak_rate as search_peak_rate

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.results.model import PeakResult as PeakRecord

__all__ = [
    'CONFIRM_TRIALS',
    'DEFAULT_TRIAL_FRAMES',
    'MAX_DOUBLINGS',
    'MIN_TRIAL_FRAMES',
    'PEAK_SCHEMA_VERSION',
    'PeakResult',
    'Trial',
    'find_peak',
    'find_peak_rate',
    'peak_rule',
    'trial_verdict',
]


def _render(out_dir: Path) -> None:
    from replaybench.report import render_peak_report

    render_peak_report(out_dir)


def find_peak_rate(
    bag: Path, backend: str, out_dir: Path | None, *, report: bool = True, **options: Any
) -> PeakResult:
    """``replaybench.replay.peak.find_peak_rate`` (the options are its own) with peak.html
    written beside peak.json when ``report``."""
    return search_peak_rate(bag, backend, out_dir, report=report, render_report=_render, **options)


def find_peak(
    bag: Path, backend: str, out_dir: Path | None, *, report: bool = True, **options: Any
) -> PeakRecord:
    """``find_peak_rate``'s result as peak.json holds it (``replaybench.results.model``)."""
    result = find_peak_rate(bag, backend, out_dir, report=report, **options)
    assert result.record is not None  # find_peak_rate always sets it
    return result.record
