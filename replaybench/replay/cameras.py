"""How many cameras a machine sustains: ``replaybench peak --cameras``.

The bag's camera set (``replaybench.replay.copies``) is replayed ``k`` times at its recorded
rate, copy ``j`` offset by ``j / k`` of a frame period, every camera of every copy in a
pipeline of its own (``--pipelines per-topic`` over k x the bag's cameras, each with a
subscriber queue of depth 1), and the search finds the largest ``k`` whose trials keep the
drops within ``max_drop`` (and the p99 latency within ``p99_bound_ms``), confirmed as the rate
search confirms its peak (``peak_rule`` over the copies). Beside it, the copies one camera's
service time predicts: ``floor(cores / (cameras x rate x service time))``, an upper bound (the
copies share the cores and pay for their contention). See docs/rigs.md.
"""

from __future__ import annotations

import datetime as dt
import math
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from replaybench._version import __version__
from replaybench.errors import SourceError, UsageError
from replaybench.replay.copies import camera_set, write_copies
from replaybench.replay.peak import (
    CONFIRM_TRIALS,
    DEFAULT_TRIAL_FRAMES,
    MIN_TRIAL_FRAMES,
    PeakResult,
    _in_run_folder,
    _prepare,
)
from replaybench.replay.rate import Rate
from replaybench.replay.runner import RunConfig, default_warmup, run_benchmark
from replaybench.replay.trials import Trial, peak_rule, trial_row, trial_verdict
from replaybench.results.io import write_peak_result
from replaybench.results.machine import describe_machine
from replaybench.results.model import (
    PEAK_SCHEMA_VERSION,
    InputInfo,
    PeakCameras,
    PeakSettings,
    PeakStart,
    Tool,
)
from replaybench.results.model import PeakResult as PeakRecord

if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Sequence

    from replaybench.backends.base import Backend, BackendOptions
    from replaybench.replay.clock import Clock
    from replaybench.replay.copies import CameraSet
    from replaybench.replay.instances import BackendInstance
    from replaybench.replay.runner import RunOutcome

__all__ = ['MAX_COPIES', 'find_peak_cameras', 'predicted_copies', 'service_time_s']

#: The most copies of the camera set a search tries unless told otherwise.
MAX_COPIES = 32
_SERVICE_DIR = 'trials/max'


def predicted_copies(cores: int, cameras: int, hz: float, service_s: float) -> int | None:
    """``floor(cores / (cameras x hz x service_s))``: the copies of a camera set of
    ``cameras`` at ``hz`` that ``cores`` cores could serve if each frame cost ``service_s`` of
    one core and the copies cost nothing more together. None without a service time."""
    if not service_s > 0 or not hz > 0 or cameras < 1:
        return None
    return math.floor(cores / (cameras * hz * service_s) + 1e-9)


def service_time_s(outcome: RunOutcome) -> float | None:
    """The mean decode + detect time of a max-rate run read inline (no read-ahead): each
    measured frame's latency, from its release (the previous frame done) to its detections."""
    latencies = [
        r.latency_ms
        for r in outcome.records
        if r.status == 'ok' and not r.warmup and r.latency_ms is not None
    ]
    return sum(latencies) / len(latencies) / 1e3 if latencies else None


def _usable_cores() -> int:
    if hasattr(os, 'sched_getaffinity'):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


class _InterruptedError(Exception):
    """A trial's run was interrupted: the search stops and writes what it has."""


class _Copies:
    """The trials of one search: once per count of copies, and again to confirm one."""

    def __init__(
        self,
        bag: Path,
        rig: CameraSet,
        frames: int,
        base: RunConfig,
        out_dir: Path | None,
        scratch: Path,
        *,
        max_drop: float,
        p99_bound_ms: float | None,
        clock: Clock | None,
        backend_factory: Callable[[str, BackendOptions], Backend] | None,
        progress: Callable[[Trial], None] | None,
        stop: threading.Event | None,
    ) -> None:
        self.bag = bag
        self.rig = rig
        self.frames = frames
        self.base = base
        self.out_dir = out_dir
        self.scratch = scratch
        self.max_drop = max_drop
        self.p99_bound_ms = p99_bound_ms
        self.clock = clock
        self.backend_factory = backend_factory
        self.progress = progress
        self.stop = stop
        self.trials: list[Trial] = []
        self.by_copies: dict[int, list[Trial]] = {}
        self.interrupted = False
        self.cut: Trial | None = None
        self.input_meta: InputInfo | None = None

    def _run(self, config: RunConfig) -> RunOutcome:
        outcome = run_benchmark(
            config, clock=self.clock, backend_factory=self.backend_factory, stop=self.stop
        )
        if outcome.status == 'interrupted':
            self.interrupted = True
        return outcome

    def service(self) -> float | None:
        """One camera's service time: its first camera alone at the max rate, read inline."""
        outcome = self._run(
            replace(
                self.base,
                inputs=[self.bag],
                topics=[self.rig.cameras[0]],
                max_frames=self.frames,
                rate=Rate('max'),
                pipelines='shared',
                prefetch=0,
                hash_inputs=True,
                out_dir=self.out_dir / _SERVICE_DIR if self.out_dir else None,
            )
        )
        if outcome.run.inputs:
            self.input_meta = outcome.run.inputs[0]
        if self.interrupted:
            raise _InterruptedError
        return service_time_s(outcome)

    def trial(self, copies: int, *, again: bool = False) -> Trial:
        """The first trial of ``copies`` copies (run when there is none), or a new one."""
        done = self.by_copies.get(copies, [])
        if done and not again:
            return done[0]
        attempt = len(done) + 1
        rel = f'trials/x{copies}' if attempt == 1 else f'trials/x{copies}-{attempt}'
        bag = write_copies(
            self.bag, self.scratch / f'copies-x{copies}.mcap', copies, self.rig, self.frames
        )
        try:
            outcome = self._run(
                replace(
                    self.base,
                    inputs=[bag],
                    out_dir=self.out_dir / rel if self.out_dir else None,
                )
            )
        finally:
            bag.unlink(missing_ok=True)
        frames, dropped, p99, ok = trial_verdict(
            list(outcome.run.frame_records or ()),
            max_drop=self.max_drop,
            p99_bound_ms=self.p99_bound_ms,
        )
        trial = Trial(
            rate_hz=self.rig.recorded_hz,
            frames=frames,
            dropped=dropped,
            drop_fraction=dropped / frames if frames else 0.0,
            p99_ms=p99,
            ok=ok and not self.interrupted,
            run_dir=rel,
            attempt=attempt,
            copies=copies,
        )
        self.trials.append(trial)
        self.by_copies.setdefault(copies, []).append(trial)
        if self.progress is not None:
            self.progress(trial)
        if self.interrupted:
            self.cut = trial
            raise _InterruptedError
        return trial


def _search(sweep: _Copies, start: int, max_copies: int, confirm_trials: int) -> bool:
    """From ``start`` copies: doubled while a trial passes (up to ``max_copies``), or halved
    while one fails (down to 1); then, until the rule gives a confirmed count or none, the
    count between the best passing and the lowest failing one is tried (bisection) and the
    best is tried again until it has passed ``confirm_trials`` trials, a failed one moving it
    down as ``peak``'s confirmation does. True when every count up to ``max_copies`` passed."""
    copies = start
    if sweep.trial(copies).ok:
        while copies < max_copies:
            copies = min(copies * 2, max_copies)
            if not sweep.trial(copies).ok:
                break
    else:
        while copies > 1:
            copies = max(copies // 2, 1)
            if sweep.trial(copies).ok:
                break
    while True:
        best, confirmed = peak_rule(sweep.trials, confirm_trials, by='copies')
        failing = min((t.copies or 0 for t in sweep.trials if not t.ok), default=None)
        if best is not None and failing is not None and failing - best > 1:
            sweep.trial(int(best + failing) // 2)
        elif best is not None and not confirmed:
            sweep.trial(int(best), again=True)
        elif best is None and failing is not None and failing > 1:
            sweep.trial(max(failing // 2, 1))
        else:
            return failing is None and best == max_copies


def _warnings(
    trials: Sequence[Trial],
    best: int | None,
    frames: int,
    interrupted: bool,
    confirmed: bool,
) -> list[str]:
    found = []
    if frames < MIN_TRIAL_FRAMES:
        found.append(
            f'trials of {frames} frames per camera are shorter than {MIN_TRIAL_FRAMES}: a '
            'backlog that grows slowly may not reach one frame period before a trial ends, so '
            'the copies found may be too many (use a longer bag or --trial-frames)'
        )
    if interrupted and best is not None and not confirmed:
        found.append(f'interrupted before {best} copies were confirmed: they passed one trial only')
    failed = [t.copies or 0 for t in trials if not t.ok]
    above = sorted(
        {t.copies or 0 for t in trials if t.ok and failed and (t.copies or 0) > min(failed)}
    )
    if best is not None and above:
        shown = ', '.join(str(k) for k in above)
        found.append(
            f'trials disagree: {shown} copies passed above the failing {min(failed)} (timing '
            'noise near the limit); the count found stays below every failing one'
        )
    return found


@_in_run_folder
def find_peak_cameras(
    bag: Path,
    backend: str,
    out_dir: Path | None,
    *,
    options: BackendOptions,
    topics: Sequence[str] | None = None,
    max_drop: float = 0.05,
    p99_bound_ms: float | None = None,
    trial_frames: int | None = None,
    max_copies: int = MAX_COPIES,
    confirm_trials: int = CONFIRM_TRIALS,
    cores: int | None = None,
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
    """Find the most copies of ``bag``'s camera set that ``backend`` sustains at the recorded
    rate; write peak.json (its ``cameras`` section) into ``out_dir``.

    The first camera alone at the max rate (``trials/max``) gives one camera's service time
    ``s``, and with ``cores`` (default: the cores this process may run on) the prediction
    ``floor(cores / (N x R x s))`` for N cameras at R Hz. The search starts there (at least 1,
    at most ``max_copies``; ``_search``). Each trial (``trials/xK``, ``trials/xK-2`` ...) is a
    per-topic run at ``--rate recorded`` with queues of depth 1 of a bag of K copies of the
    camera set (``write_copies``: each camera's first ``trial_frames`` frames, default up to
    300), written beside the trials and deleted after each. A trial passes as a rate trial
    does (``trial_verdict``: drops within ``max_drop`` and, with a bound, p99 within
    ``p99_bound_ms``, counted from the end of each camera's warm-up). ``out_dir`` None: in
    memory. ``stop`` ends the search as interrupted. ``instance``: what ``backend`` is when
    it is the label of an instance (``--backend LABEL=NAME``), as in ``find_peak_rate``.
    """
    bag = Path(bag)
    out_dir = Path(out_dir) if out_dir is not None else None
    problems = []
    if not 0 <= max_drop < 1:
        problems.append(f'--max-drop must be in [0, 1), not {max_drop}')
    if p99_bound_ms is not None and not p99_bound_ms > 0:
        problems.append(f'--p99-ms must be positive, not {p99_bound_ms}')
    if trial_frames is not None and trial_frames < 2:
        problems.append(f'--trial-frames must be at least 2, not {trial_frames}')
    if max_copies < 1:
        problems.append(f'--max-copies must be at least 1, not {max_copies}')
    if confirm_trials < 1:
        problems.append(f'confirmation trials must be 1 or more, not {confirm_trials}')
    if problems:
        raise UsageError('; '.join(problems))
    if not bag.exists():
        msg = f'{bag}: no such file or directory'
        raise SourceError(msg)
    rig = camera_set(bag, topics)
    n = min(rig.frames, trial_frames if trial_frames is not None else DEFAULT_TRIAL_FRAMES)
    warmup = default_warmup(n)
    cores = cores if cores is not None else _usable_cores()
    if out_dir is not None:
        _prepare(out_dir)
    started = dt.datetime.now(dt.UTC)
    t_start = time.perf_counter()
    base = RunConfig(
        inputs=[bag],
        backends=[backend],
        instances={backend: instance} if instance is not None else {},
        out_dir=None,
        rate=Rate('recorded'),
        queue_depth=1,
        warmup=warmup,
        threads=threads,
        ground_truth_topic=None,
        options=options,
        command=list(command),
        report=False,
        hash_inputs=False,
        pipelines='per-topic',
    )
    service_s: float | None = None
    predicted: int | None = None
    limit_reached = False
    with tempfile.TemporaryDirectory(prefix='.copies-', dir=out_dir) as scratch:
        sweep = _Copies(
            bag,
            rig,
            n,
            base,
            out_dir,
            Path(scratch),
            max_drop=max_drop,
            p99_bound_ms=p99_bound_ms,
            clock=clock,
            backend_factory=backend_factory,
            progress=progress,
            stop=stop,
        )
        try:
            service_s = sweep.service()
            predicted = predicted_copies(cores, len(rig.cameras), rig.recorded_hz, service_s or 0)
            start = min(max_copies, max(1, predicted if predicted is not None else 1))
            limit_reached = _search(sweep, start, max_copies, confirm_trials)
        except (_InterruptedError, KeyboardInterrupt):
            sweep.interrupted = True
    judged = [t for t in sweep.trials if t is not sweep.cut]
    found, confirmed = peak_rule(judged, confirm_trials, by='copies')
    best = int(found) if found is not None else None
    failing = min((t.copies or 0 for t in judged if not t.ok), default=None)
    limit_reached = limit_reached and failing is None
    warnings = _warnings(judged, best, n, sweep.interrupted, confirmed)
    status = 'interrupted' if sweep.interrupted else 'complete'
    result = PeakResult(
        backend=backend,
        peak_hz=None,
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
            confirm_trials=confirm_trials,
            topics=tuple(topics) if topics else None,
            threads=threads,
        ),
        start=PeakStart(
            hz=rig.recorded_hz,
            source='recorded rate',
            probe_fps=1 / service_s if service_s else None,
            recorded_hz=rig.recorded_hz,
            probe_run_dir=_SERVICE_DIR,
        ),
        peak_hz=None,
        peak_confirmed=confirmed,
        first_failing_hz=None,
        resolution_hz=None,
        limit_reached=limit_reached,
        warnings=tuple(warnings),
        trial_rows=tuple(trial_row(t) for t in sweep.trials),
        environment=describe_machine(),
        cameras=PeakCameras(
            cameras=rig.cameras,
            recorded_hz=rig.recorded_hz,
            service_ms=service_s * 1e3 if service_s is not None else None,
            service_run_dir=_SERVICE_DIR,
            cores=cores,
            predicted_copies=predicted,
            copies=best,
            first_failing_copies=failing,
            max_copies=max_copies,
        ),
    )
    if out_dir is not None:
        write_peak_result(out_dir / 'peak.json', record)
        if report and render_report is not None:
            render_report(out_dir, record)
    return result._replace(record=record)
