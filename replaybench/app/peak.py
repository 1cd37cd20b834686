"""``replaybench peak`` as an application: the peak-rate search, each trial a run with its
report, then peak.json and peak.html.

The search itself (start rate, coarse search, bisection, confirmation; ``peak_rule``) is the
engine's, ``replaybench.replay.peak``; this layer adds peak.html (``replaybench.report``).
The command line and ``replaybench.peak`` both parse their options into a ``PeakConfig``
(``peak_config``) and search with ``run_peak``: the rate, or with ``cameras`` the copies of the
bag's camera set sustained at the recorded rate (``replaybench.replay.cameras``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.errors import UsageError
from replaybench.replay.cameras import MAX_COPIES
from replaybench.replay.cameras import find_peak_cameras as search_peak_cameras
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
    from replaybench.replay.instances import BackendInstance
    from replaybench.results.model import PeakResult as PeakRecord

__all__ = [
    'CONFIRM_TRIALS',
    'DEFAULT_TRIAL_FRAMES',
    'MAX_COPIES',
    'MAX_DOUBLINGS',
    'MIN_TRIAL_FRAMES',
    'PEAK_SCHEMA_VERSION',
    'PeakConfig',
    'PeakResult',
    'Trial',
    'find_peak_cameras',
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


def find_peak_cameras(
    bag: Path, backend: str, out_dir: Path | None, *, report: bool = True, **options: Any
) -> PeakResult:
    """``replaybench.replay.cameras.find_peak_cameras`` (the options are its own) with
    peak.html written beside peak.json when ``report``."""
    return search_peak_cameras(
        bag, backend, out_dir, report=report, render_report=_render, **options
    )


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
    #: --cameras: search the copies of the camera set sustained at the recorded rate
    cameras: bool = False
    max_copies: int = MAX_COPIES
    #: the instance ``backend`` labels (``--backend LABEL=NAME``, ``--param LABEL.KEY=VALUE``)
    instance: BackendInstance | None = None


def peak_config(
    input: str | os.PathLike[str],
    *,
    backend: str = 'hsv',
    params: Sequence[str] = (),
    out: str | os.PathLike[str] | None = None,
    max_drop: float = 0.05,
    p99_ms: float | None = None,
    trial_frames: int | None = None,
    min_hz: float = 1.0,
    max_hz: float | None = None,
    refine_steps: int = 4,
    force: bool = False,
    command: Sequence[str] = (),
    cameras: bool = False,
    max_copies: int = MAX_COPIES,
    **options: Any,
) -> PeakConfig:
    """The ``PeakConfig`` of ``replaybench peak``'s options: each keyword is the flag of the
    same name in snake_case; ``options`` are the run options a peak search takes (the
    ``RunOptions`` fields marked ``peak``: ``topics``, ``threads``, ``report``, and the backend
    options ``config``, ``model``, ``conf``, ``device``, ``engine``, ...). Raises ``UsageError``
    naming the option for a value out of range, before anything runs; ``TypeError`` for a
    keyword that is not an option of peak. ``cameras`` searches copies of the camera set at
    the recorded rate: the rate limits (``min_hz``, ``max_hz``, ``refine_steps``) are then
    refused when not at their defaults. ``backend`` is ``NAME`` or ``LABEL=NAME`` and
    ``params`` its ``--param LABEL.KEY=VALUE`` texts (``replaybench.replay.instances``)."""
    from replaybench.app.options import option_specs, run_options
    from replaybench.replay.instances import parse_instances

    takes = {name for name, spec, _ in option_specs() if spec.peak}
    unknown = sorted(set(options) - takes)
    if unknown:
        msg = (
            f'unexpected keyword argument(s): {", ".join(unknown)} (a peak search takes '
            f'{", ".join(sorted(takes))})'
        )
        raise TypeError(msg)
    check_search(max_drop, p99_ms, trial_frames, min_hz, max_hz, refine_steps)
    if cameras:
        given = [
            flag
            for flag, value, default in (
                ('--min-hz', min_hz, 1.0),
                ('--max-hz', max_hz, None),
                ('--refine-steps', refine_steps, 4),
            )
            if value != default
        ]
        if given:
            msg = (
                f'{", ".join(given)} limit(s) a rate search; --cameras replays the cameras at '
                'their recorded rate and searches the copies (bound them with --max-copies)'
            )
            raise UsageError(msg)
    if max_copies < 1:
        msg = f'--max-copies must be at least 1, not {max_copies}'
        raise UsageError(msg)
    checked = run_options(**options)
    (instance,) = parse_instances([backend], params)
    return PeakConfig(
        input=Path(input),
        backend=instance.label,
        instance=instance if instance.label != instance.backend or instance.params else None,
        out=Path(out) if out is not None else None,
        options=checked.backend_options(),
        topics=checked.topics,
        max_drop=max_drop,
        p99_bound_ms=p99_ms,
        trial_frames=trial_frames,
        min_hz=min_hz,
        max_hz=max_hz,
        refine_steps=refine_steps,
        force=force,
        report=checked.report,
        threads=checked.threads,
        command=tuple(command),
        cameras=cameras,
        max_copies=max_copies,
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
    if config.cameras:
        return find_peak_cameras(
            config.input,
            config.backend,
            config.out,
            report=config.report,
            options=config.options,
            topics=list(config.topics) or None,
            max_drop=config.max_drop,
            p99_bound_ms=config.p99_bound_ms,
            trial_frames=config.trial_frames,
            max_copies=config.max_copies,
            force=config.force,
            threads=config.threads,
            command=config.command,
            progress=progress,
            stop=stop,
            instance=config.instance,
        )
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
        instance=config.instance,
    )
