"""``replaybench peak`` as an application: the peak-rate search, each trial a run with its
report, then peak.json and peak.html.

The search itself (start rate, coarse search, bisection, confirmation; ``peak_rule``) is the
engine's, ``replaybench.replay.peak``; this layer adds peak.html (``replaybench.report``).
The command line and ``replaybench.peak`` both parse their options into a ``PeakConfig``
(``peak_config``) and search with ``run_peak``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.app.run import backend_options, name_list
from replaybench.replay.peak import (
    CONFIRM_TRIALS,
    DEFAULT_TRIAL_FRAMES,
    MAX_DOUBLINGS,
    MIN_TRIAL_FRAMES,
    PEAK_SCHEMA_VERSION,
    PeakResult,
    Trial,
    check_search,
    peak_rule,
    trial_verdict,
)
from replaybench.replay.peak import find_peak_rate as search_peak_rate

if TYPE_CHECKING:
    import os
    import threading
    from collections.abc import Callable, Sequence

    from replaybench.backends.base import BackendOptions
    from replaybench.results.model import PeakResult as PeakRecord

__all__ = [
    'CONFIRM_TRIALS',
    'DEFAULT_TRIAL_FRAMES',
    'MAX_DOUBLINGS',
    'MIN_TRIAL_FRAMES',
    'PEAK_SCHEMA_VERSION',
    'PeakConfig',
    'PeakResult',
    'Trial',
    'find_peak_rate',
    'peak_config',
    'peak_rule',
    'run_peak',
    'trial_verdict',
]


def _render(out_dir: Path, record: PeakRecord) -> None:
    """peak.html beside peak.json, from the record peak.json was written from."""
    from replaybench.report import render_peak_html
    from replaybench.results.atomic import write_text_atomic

    write_text_atomic(out_dir / 'peak.html', render_peak_html(record))


def find_peak_rate(
    bag: Path, backend: str, out_dir: Path | None, *, report: bool = True, **options: Any
) -> PeakResult:
    """``replaybench.replay.peak.find_peak_rate`` (the options are its own) with peak.html
    written beside peak.json when ``report``."""
    return search_peak_rate(bag, backend, out_dir, report=report, render_report=_render, **options)


@dataclass(frozen=True, slots=True)
class PeakConfig:
    """``replaybench peak``'s options, checked (``peak_config``): what ``run_peak`` searches."""

    input: Path
    backend: str
    #: the peak folder; None keeps every trial in memory and writes nothing
    out: Path | None
    options: BackendOptions
    topics: tuple[str, ...] = ()
    max_drop: float = 0.05
    p99_bound_ms: float | None = None
    trial_frames: int | None = None
    min_hz: float = 1.0
    max_hz: float | None = None
    refine_steps: int = 4
    force: bool = False
    report: bool = True
    threads: int | None = None
    #: the command line recorded in peak.json and each trial's run.json
    command: tuple[str, ...] = ()


def peak_config(
    input: str | os.PathLike[str],
    *,
    backend: str = 'hsv',
    out: str | os.PathLike[str] | None = None,
    max_drop: float = 0.05,
    p99_ms: float | None = None,
    trial_frames: int | None = None,
    min_hz: float = 1.0,
    max_hz: float | None = None,
    refine_steps: int = 4,
    topics: str | Sequence[str] | None = None,
    threads: int | None = None,
    force: bool = False,
    report: bool = True,
    command: Sequence[str] = (),
    **options: Any,
) -> PeakConfig:
    """The ``PeakConfig`` of ``replaybench peak``'s options: each keyword is the flag of the
    same name in snake_case (``--topic`` is ``topics``, ``--no-report`` is ``report=False``);
    ``options`` are the backend options, the keywords of ``app.run.backend_options``
    (``config``, ``model``, ``conf``, ``engine``, ...). Raises ``UsageError`` naming the option
    for a value out of range, the backend options included, before anything runs."""
    check_search(max_drop, p99_ms, trial_frames, min_hz, max_hz, refine_steps)
    return PeakConfig(
        input=Path(input),
        backend=backend,
        out=Path(out) if out is not None else None,
        options=backend_options(threads=threads, **options),
        topics=tuple(name_list(topics)),
        max_drop=max_drop,
        p99_bound_ms=p99_ms,
        trial_frames=trial_frames,
        min_hz=min_hz,
        max_hz=max_hz,
        refine_steps=refine_steps,
        force=force,
        report=report,
        threads=threads,
        command=tuple(command),
    )


def run_peak(
    config: PeakConfig,
    *,
    progress: Callable[[Trial], None] | None = None,
    stop: threading.Event | None = None,
) -> PeakResult:
    """Search ``config``'s peak rate; peak.json (and peak.html unless ``config.report`` is
    False) written into ``config.out`` when it is set. ``progress(trial)`` after each trial;
    setting ``stop`` ends the search as interrupted."""
    return find_peak_rate(
        config.input,
        config.backend,
        config.out,
        report=config.report,
        options=config.options,
        topics=list(config.topics) or None,
        max_drop=config.max_drop,
        p99_bound_ms=config.p99_bound_ms,
        trial_frames=config.trial_frames,
        min_hz=config.min_hz,
        max_hz=config.max_hz,
        refine_steps=config.refine_steps,
        force=config.force,
        threads=config.threads,
        command=config.command,
        progress=progress,
        stop=stop,
    )
