"""Peak sustainable rate: the highest fixed input rate a backend keeps up with.

A sweep in the manner of ros2_benchmark: a max-rate probe run gives a start rate; a coarse
search doubles (or halves) the rate until one trial passes and one fails; bisection between
the highest passing and the lowest failing rate refines the answer; confirmation trials then
repeat the answer until it has passed ``confirm_trials`` trials, moving down when one fails.
Every trial is an ordinary run (``run_benchmark``) at ``Rate('fixed', hz=r)`` with a subscriber
queue of depth 1 over the first ``trial_frames`` frames of each selected topic, each frame once
(no looping), and keeps its run folder under ``out_dir/trials/``. See docs/peak.md.
"""

from __future__ import annotations

import datetime as dt
import functools
import inspect
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple, ParamSpec, cast

from replaybench._version import __version__
from replaybench.errors import OutputError, SourceError, UsageError
from replaybench.replay.rate import Rate
from replaybench.replay.runner import RunConfig, default_warmup, run_benchmark
from replaybench.replay.trials import Trial, peak_rule, trial_row, trial_verdict
from replaybench.results.io import write_peak_result
from replaybench.results.machine import describe_machine
from replaybench.results.model import (
    PEAK_SCHEMA_VERSION,
    InputInfo,
    PeakSettings,
    PeakStart,
    Tool,
)
from replaybench.results.model import PeakResult as PeakRecord
from replaybench.results.runfolder import RunFolder

if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Sequence

    from replaybench.backends.base import Backend, BackendOptions
    from replaybench.replay.clock import Clock
    from replaybench.replay.instances import BackendInstance
    from replaybench.replay.runner import RunOutcome

__all__ = [
    'CONFIRM_TRIALS',
    'DEFAULT_TRIAL_FRAMES',
    'MAX_DOUBLINGS',
    'MIN_TRIAL_FRAMES',
    'PEAK_SCHEMA_VERSION',
    'PeakResult',
    'Trial',
    'check_search',
    'find_peak_rate',
    'peak_rule',
    'trial_verdict',
]

#: Frames per topic and trial when ``trial_frames`` is not given (fewer when the bag is shorter).
DEFAULT_TRIAL_FRAMES = 300
#: Without ``max_hz``, the coarse search stops after this many doublings of the start rate.
MAX_DOUBLINGS = 12
#: Trials a rate must pass, every one of them, to be reported as the peak (the search's trial
#: counts as the first).
CONFIRM_TRIALS = 2
#: Trials over fewer frames than this get a warning: a backlog that grows by a fraction of a
#: frame per frame can stay under one frame period to the end of a short trial.
MIN_TRIAL_FRAMES = 100
_PROBE_DIR = 'trials/max'


class PeakResult(NamedTuple):
    """The peak (``peak_rule``; None when no rate qualifies) and every trial, in run order.

    ``confirmed``: the peak passed ``confirm_trials`` trials (False only when the sweep was
    interrupted before it could be confirmed); ``warnings``: why the result may mislead.
    """

    backend: str
    peak_hz: float | None
    max_drop: float
    p99_bound_ms: float | None
    trials: tuple[Trial, ...]
    status: str = 'complete'  # 'interrupted' when Ctrl-C / SIGTERM stopped the sweep
    confirmed: bool = True
    warnings: tuple[str, ...] = ()
    #: peak.json's contents (written into the peak folder unless the search ran in memory)
    record: PeakRecord | None = None


class _BagFacts(NamedTuple):
    frames: int  # most frames of one selected topic
    recorded_hz: float | None  # lowest recorded rate of the selected topics


def _bag_facts(bag: Path, topics: Sequence[str] | None) -> _BagFacts:
    from replaybench.decode.probe import probe_topics
    from replaybench.sources import open_source

    with open_source(bag) as source:
        found = probe_topics(source)
    if topics:
        chosen = [t for t in found if t.name in set(topics)]
    else:
        chosen = [t for t in found if not t.is_depth]
    if not chosen:
        # run_benchmark gives the precise message (unknown topic, depth only, no images)
        return _BagFacts(0, None)
    rates = [
        (t.count - 1) / ((t.last_ns - t.first_ns) / 1e9)
        for t in chosen
        if t.count > 1 and t.last_ns > t.first_ns
    ]
    return _BagFacts(max(t.count for t in chosen), min(rates) if rates else None)


def _round_rate(hz: float) -> float:
    """Rates are tested at millihertz resolution, so a rate and its folder name agree."""
    return round(hz, 3)


def _start_rate(hz: float) -> float:
    """Three significant digits: a readable first trial (47.6 Hz rather than 47.6190 Hz)."""
    return float(f'{hz:.3g}')


def _prepare(out_dir: Path) -> None:
    """The sweep's folder. ``find_peak_rate`` runs inside a ``RunFolder`` (``_in_run_folder``):
    ``out_dir`` is its new temporary folder, and ``force`` was applied when it was made."""
    out_dir.mkdir(parents=True, exist_ok=True)


_P = ParamSpec('_P')


def _in_run_folder(sweep: Callable[_P, PeakResult]) -> Callable[_P, PeakResult]:
    """``sweep`` writing into a temporary folder beside its ``out_dir``, swapped in when the
    sweep has ended (complete or interrupted): a failed sweep leaves ``out_dir`` as it was and
    nothing else. ``out_dir`` gets the checks and the lock of a run folder (``RunFolder``;
    ``force`` replaces a peak folder only, one holding peak.json)."""
    signature = inspect.signature(sweep)

    @functools.wraps(sweep)
    def staged(*args: _P.args, **kwargs: _P.kwargs) -> PeakResult:
        bound = signature.bind(*args, **kwargs)
        bound.apply_defaults()
        if bound.arguments['out_dir'] is None:  # in memory: no folder
            return cast('Callable[..., PeakResult]', sweep)(*bound.args, **bound.kwargs)
        folder = RunFolder(
            Path(bound.arguments['out_dir']),
            force=bool(bound.arguments['force']),
            marker='peak.json',
            kind='peak',
        )
        try:
            with folder:
                bound.arguments['out_dir'] = folder.path
                result = cast('Callable[..., PeakResult]', sweep)(*bound.args, **bound.kwargs)
                folder.commit()
        except OSError as err:
            raise folder.output_error(err) from err
        except OutputError as err:  # a trial's: its file named inside the temporary folder
            raise OutputError(str(err).replace(str(folder.path), str(folder.out))) from err
        return result

    return staged


def check_search(
    max_drop: float,
    p99_bound_ms: float | None,
    trial_frames: int | None,
    min_hz: float,
    max_hz: float | None,
    refine_steps: int,
) -> None:
    """``UsageError`` naming every search limit out of range."""
    problems = []
    if not 0 <= max_drop < 1:
        problems.append(f'--max-drop must be in [0, 1), not {max_drop}')
    if p99_bound_ms is not None and not p99_bound_ms > 0:
        problems.append(f'--p99-ms must be positive, not {p99_bound_ms}')
    if trial_frames is not None and trial_frames < 1:
        problems.append(f'--trial-frames must be at least 1, not {trial_frames}')
    if not min_hz >= 0.001:
        problems.append(f'the lowest rate must be at least 0.001 Hz, not {min_hz}')
    if max_hz is not None and not max_hz >= min_hz:
        problems.append(f'the highest rate ({max_hz}) is below the lowest ({min_hz})')
    if refine_steps < 0:
        problems.append(f'refinement steps must be 0 or more, not {refine_steps}')
    if problems:
        msg = '; '.join(problems)
        raise UsageError(msg)


class _Sweep:
    """The trials of one search: once per rate, and again to confirm one (``again``)."""

    def __init__(
        self,
        base: RunConfig,
        out_dir: Path | None,
        *,
        max_drop: float,
        p99_bound_ms: float | None,
        clock: Clock | None,
        backend_factory: Callable[[str, BackendOptions], Backend] | None,
        progress: Callable[[Trial], None] | None,
        stop: threading.Event | None = None,
    ) -> None:
        self.base = base
        self.out_dir = out_dir
        self.max_drop = max_drop
        self.p99_bound_ms = p99_bound_ms
        self.clock = clock
        self.backend_factory = backend_factory
        self.progress = progress
        self.stop = stop
        self.trials: list[Trial] = []
        self.by_rate: dict[float, list[Trial]] = {}
        self.interrupted = False
        self.cut: Trial | None = None  # the trial an interruption cut short
        self.input_meta: InputInfo | None = None

    def run(self, rate: Rate, rel: str) -> RunOutcome:
        outcome = run_benchmark(
            replace(self.base, rate=rate, out_dir=self.out_dir / rel if self.out_dir else None),
            clock=self.clock,
            backend_factory=self.backend_factory,
            stop=self.stop,
        )
        if outcome.status == 'interrupted':
            self.interrupted = True
        if self.input_meta is None and outcome.run.inputs:
            self.input_meta = outcome.run.inputs[0]
            # the later trials replay the same bytes: their runs record this sha256 instead of
            # hashing the input again beside their measurement
            self.base = replace(self.base, input_sha256=(self.input_meta.sha256,))
        return outcome

    def probe(self) -> float | None:
        """Throughput at max rate: the lowest over the topics (frames per second per topic)."""
        outcome = self.run(Rate('max'), _PROBE_DIR)
        if self.interrupted:
            raise _InterruptedError
        rates = [
            s.throughput_fps for s in outcome.summaries if s.throughput_fps and s.topic != 'rig'
        ]
        return min(rates) if rates else None

    def trial(self, hz: float, *, again: bool = False) -> Trial:
        """The first trial at ``hz`` (run when there is none), or with ``again`` a new one."""
        hz = _round_rate(hz)
        done = self.by_rate.get(hz, [])
        if done and not again:
            return done[0]
        attempt = len(done) + 1
        rel = f'trials/{hz:.3f}hz' if attempt == 1 else f'trials/{hz:.3f}hz-{attempt}'
        outcome = self.run(Rate('fixed', hz=hz), rel)
        # the rows as frames.csv holds them, whether or not it was written
        records = list(outcome.run.frame_records or ())
        frames, dropped, p99, ok = trial_verdict(
            records, max_drop=self.max_drop, p99_bound_ms=self.p99_bound_ms
        )
        trial = Trial(
            rate_hz=hz,
            frames=frames,
            dropped=dropped,
            drop_fraction=dropped / frames if frames else 0.0,
            p99_ms=p99,
            ok=ok and not self.interrupted,
            run_dir=rel,
            attempt=attempt,
        )
        self.trials.append(trial)
        self.by_rate.setdefault(hz, []).append(trial)
        if self.progress is not None:
            self.progress(trial)
        if self.interrupted:
            self.cut = trial
            raise _InterruptedError
        return trial


class _InterruptedError(Exception):
    """A trial's run was interrupted: the sweep stops and writes what it has."""


class _State:
    """Where the search stands: the highest passing and the lowest failing rate so far."""

    def __init__(self) -> None:
        self.best: float | None = None
        self.failing: float | None = None
        self.limit_reached = False


def _search(
    sweep: _Sweep,
    state: _State,
    start: float,
    *,
    min_hz: float,
    max_hz: float | None,
    refine_steps: int,
) -> None:
    """Coarse search from ``start``, then bisection; results land in ``state``."""
    rate = start
    if sweep.trial(rate).ok:
        state.best = _round_rate(rate)
        for doublings in range(MAX_DOUBLINGS + 1):
            if (max_hz is not None and rate >= max_hz) or doublings == MAX_DOUBLINGS:
                state.limit_reached = True
                break
            rate = rate * 2 if max_hz is None else min(rate * 2, max_hz)
            trial = sweep.trial(rate)
            if not trial.ok:
                state.failing = trial.rate_hz
                break
            state.best = trial.rate_hz
    else:
        state.failing = _round_rate(rate)
        while rate > min_hz:
            rate = max(rate / 2, min_hz)
            trial = sweep.trial(rate)
            if trial.ok:
                state.best = trial.rate_hz
                break
            state.failing = trial.rate_hz
    for _ in range(refine_steps):
        if state.best is None or state.failing is None:
            break
        mid = _round_rate((state.best + state.failing) / 2)
        if mid in (state.best, state.failing):
            break
        if sweep.trial(mid).ok:
            state.best = mid
        else:
            state.failing = mid


def _confirm(sweep: _Sweep, state: _State, *, confirm_trials: int, min_hz: float) -> None:
    """Trials until ``peak_rule`` gives a confirmed peak or none: the candidate is tried again
    until it has passed ``confirm_trials`` trials; when one fails, that rate is failing and the
    next candidate down is confirmed the same way; with none left below the lowest failing
    rate, that rate is halved (down to ``min_hz``) as the coarse search does."""
    while True:
        best, confirmed = peak_rule(sweep.trials, confirm_trials)
        failing = min((t.rate_hz for t in sweep.trials if not t.ok), default=None)
        state.best, state.failing = best, failing
        if failing is not None:
            state.limit_reached = False
        if best is not None and confirmed:
            return
        if best is not None:
            sweep.trial(best, again=True)
            continue
        if failing is None or failing <= min_hz:
            return
        sweep.trial(max(failing / 2, min_hz))


def _warnings(
    trials: Sequence[Trial], peak: float | None, frames: int, interrupted: bool, confirmed: bool
) -> list[str]:
    found = []
    if frames < MIN_TRIAL_FRAMES:
        found.append(
            f'trials of {frames} frames per topic are shorter than {MIN_TRIAL_FRAMES}: a backlog '
            'that grows slowly may not reach one frame period before a trial ends, so the peak '
            'may be too high (use a longer bag or --trial-frames)'
        )
    if interrupted and peak is not None and not confirmed:
        found.append(f'interrupted before {peak:g} Hz was confirmed: it passed one trial only')
    if peak is not None:
        failed = [t.rate_hz for t in trials if not t.ok]
        above = sorted({t.rate_hz for t in trials if t.ok and failed and t.rate_hz > min(failed)})
        if above:
            shown = ', '.join(f'{r:g}' for r in above)
            found.append(
                f'trials disagree: {shown} Hz passed above the failing {min(failed):g} Hz '
                '(timing noise near the limit); the peak stays below every failing rate'
            )
    return found


@_in_run_folder
def find_peak_rate(
    bag: Path,
    backend: str,
    out_dir: Path | None,
    *,
    options: BackendOptions,
    topics: Sequence[str] | None = None,
    max_drop: float = 0.05,
    p99_bound_ms: float | None = None,
    trial_frames: int | None = None,
    min_hz: float = 1.0,
    max_hz: float | None = None,
    refine_steps: int = 4,
    confirm_trials: int = CONFIRM_TRIALS,
    clock: Clock | None = None,
    backend_factory: Callable[[str, BackendOptions], Backend] | None = None,
    force: bool = False,  # noqa: ARG001  read by _in_run_folder from the bound arguments
    report: bool = True,
    threads: int | None = None,
    command: Sequence[str] = (),
    progress: Callable[[Trial], None] | None = None,
    stop: threading.Event | None = None,
    render_report: Callable[[Path, PeakRecord], object] | None = None,
    instance: BackendInstance | None = None,
) -> PeakResult:
    """Find the highest fixed rate at which ``backend`` keeps up with ``bag``; write peak.json.

    The start rate is the max-rate probe's throughput (else the bag's recorded rate, else
    ``min_hz``), clamped to ``[min_hz, max_hz]``. The coarse search doubles a passing rate until
    a trial fails (at most ``MAX_DOUBLINGS`` times, or up to ``max_hz``) or halves a failing
    one until a trial passes (down to ``min_hz``); ``refine_steps`` bisections follow, then
    confirmation trials (``peak_rule``: the peak passed ``confirm_trials`` trials, all it had,
    and lies below every rate that failed one; a failed confirmation moves it down). The
    rate applies to each selected topic. ``out_dir`` gets peak.json, peak.html (``report``) and
    ``trials/``: the probe's run folder (``trials/max``) and one per tested rate; peak.html is
    drawn by ``render_report(folder, record)`` from the record it was written from (the
    application's, ``replaybench.app.peak``).
    ``out_dir`` None: every trial runs in memory and nothing is written. Setting
    ``stop`` (a cancellation token) ends the trial under way and the search (status
    ``interrupted``). ``instance``: what ``backend`` is when it is the label of an instance
    (``--backend LABEL=NAME``, ``replaybench.replay.instances``): the registered backend the
    trials make and its own parameters.
    """
    bag = Path(bag)
    out_dir = Path(out_dir) if out_dir is not None else None
    check_search(max_drop, p99_bound_ms, trial_frames, min_hz, max_hz, refine_steps)
    if confirm_trials < 1:
        msg = f'confirmation trials must be 1 or more, not {confirm_trials}'
        raise UsageError(msg)
    if not bag.exists():
        msg = f'{bag}: no such file or directory'
        raise SourceError(msg)
    facts = _bag_facts(bag, topics)
    n = facts.frames if facts.frames else (trial_frames or DEFAULT_TRIAL_FRAMES)
    n = min(n, trial_frames if trial_frames is not None else DEFAULT_TRIAL_FRAMES)
    warmup = default_warmup(n)
    if out_dir is not None:
        _prepare(out_dir)
    started = dt.datetime.now(dt.UTC)
    t_start = time.perf_counter()
    base = RunConfig(
        inputs=[bag],
        backends=[backend],
        instances={backend: instance} if instance is not None else {},
        out_dir=out_dir,
        queue_depth=1,
        warmup=warmup,
        threads=threads,
        max_frames=n,
        topics=list(topics) if topics else None,
        ground_truth_topic=None,
        options=options,
        command=list(command),
        report=False,
    )
    sweep = _Sweep(
        base,
        out_dir,
        max_drop=max_drop,
        p99_bound_ms=p99_bound_ms,
        clock=clock,
        backend_factory=backend_factory,
        progress=progress,
        stop=stop,
    )
    state = _State()
    probe_fps: float | None = None
    start: float | None = None
    source = ''
    try:
        probe_fps = sweep.probe()
        if probe_fps is not None:
            start, source = probe_fps, 'max-rate probe'
        elif facts.recorded_hz is not None:
            start, source = facts.recorded_hz, 'recorded rate'
        else:
            start, source = min_hz, 'lowest rate'
        start = _start_rate(start)
        start = max(min_hz, start if max_hz is None else min(start, max_hz))
        _search(sweep, state, start, min_hz=min_hz, max_hz=max_hz, refine_steps=refine_steps)
        _confirm(sweep, state, confirm_trials=confirm_trials, min_hz=min_hz)
    except (_InterruptedError, KeyboardInterrupt):
        sweep.interrupted = True
    # the trial an interruption cut short neither passed nor failed
    judged = [t for t in sweep.trials if t is not sweep.cut]
    best, confirmed = peak_rule(judged, confirm_trials)
    failing = min((t.rate_hz for t in judged if not t.ok), default=None)
    limit_reached = state.limit_reached and failing is None
    warnings = _warnings(judged, best, n, sweep.interrupted, confirmed)

    status = 'interrupted' if sweep.interrupted else 'complete'
    result = PeakResult(
        backend=backend,
        peak_hz=best,
        max_drop=max_drop,
        p99_bound_ms=p99_bound_ms,
        trials=tuple(sweep.trials),
        status=status,
        confirmed=confirmed,
        warnings=tuple(warnings),
    )
    record = PeakRecord(
        schema_version=PEAK_SCHEMA_VERSION,
        kind='peak',
        tool=Tool(name='replaybench', version=__version__),
        status=status,
        command=tuple(command),
        started_at=started.isoformat(),
        finished_at=dt.datetime.now(dt.UTC).isoformat(),
        wall_s=time.perf_counter() - t_start,
        backend=backend,
        input=sweep.input_meta or InputInfo(path=str(bag)),
        settings=PeakSettings(
            max_drop=max_drop,
            p99_bound_ms=p99_bound_ms,
            trial_frames=n,
            warmup=warmup,
            queue_depth=1,
            min_hz=min_hz,
            max_hz=max_hz,
            refine_steps=refine_steps,
            confirm_trials=confirm_trials,
            topics=tuple(topics) if topics else None,
            threads=threads,
        ),
        start=PeakStart(
            hz=start,
            source=source,
            probe_fps=probe_fps,
            recorded_hz=facts.recorded_hz,
            probe_run_dir=_PROBE_DIR,
        ),
        peak_hz=best,
        peak_confirmed=confirmed,
        first_failing_hz=failing,
        resolution_hz=failing - best if best is not None and failing is not None else None,
        limit_reached=limit_reached,
        warnings=tuple(warnings),
        trial_rows=tuple(trial_row(t) for t in sweep.trials),
        environment=describe_machine(),
    )
    if out_dir is not None:
        write_peak_result(out_dir / 'peak.json', record)
        if report and render_report is not None:
            render_report(out_dir, record)
    return result._replace(record=record)
