"""Merge run folders and compare every (run, backend, topic) with its baseline."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal, NamedTuple

from replaybench.comparison.metric import MetricComparison
from replaybench.comparison.recorded import (
    RECORDED_METRICS,
    RecordedSeries,
    recorded_metric_parts,
    recorded_series,
)
from replaybench.comparison.repeats import (
    CAUTION_ADVICE,
    PassValues,
    pass_values,
    repeat_change,
    single_pass_caution,
)
from replaybench.comparison.runs import CV_LIMIT, engine_text, inputs_match, load_runs, run_flags
from replaybench.errors import UsageError
from replaybench.results.blocks import change_interval
from replaybench.results.bootstrap import (
    CONFIDENCE,
    DEFAULT_RESAMPLES,
    MIN_FRAMES,
    Replicates,
    percentile_interval,
    replicates,
)
from replaybench.results.intervals import interval_rng, measured_series
from replaybench.results.model.summary import RIG_TOPIC
from replaybench.results.rig import rig_groups, rig_summary
from replaybench.results.stats import summarize
from replaybench.tasks import all_metrics

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    import numpy as np
    import numpy.typing as npt

    from replaybench.comparison.paired import Paired
    from replaybench.comparison.runs import RunInfo
    from replaybench.results.blocks import ChangeInterval
    from replaybench.results.folder import RunData
    from replaybench.results.model import RunResult
    from replaybench.results.records import FrameRecord
    from replaybench.results.stats import Summary

__all__ = [
    'ACCURACY_METRICS',
    'METRICS',
    'RECORDED_METRICS',
    'RIG_METRICS',
    'RIG_POINT_METRICS',
    'TAG_METRICS',
    'TIMING_METRICS',
    'Comparison',
    'MetricComparison',
    'Role',
    'Row',
    'compare_runs',
]

_SPECS = [m for m in all_metrics() if m.gate]

#: Timing metrics: compared as candidate / baseline ratios with exact rank intervals.
TIMING_METRICS: tuple[str, ...] = tuple(m.name for m in _SPECS if m.kind == 'timing')

#: Accuracy metrics: compared as candidate - baseline differences of the run.json numbers (the
#: registered tasks' accuracy metrics that are not ``appended``: boxes and masks).
ACCURACY_METRICS: tuple[str, ...] = tuple(m.name for m in _SPECS if m.accuracy and not m.appended)

#: The accuracy metrics appended after them (comparison.csv: after ``flags``), compared as
#: accuracy is: point estimates, no interval. The built-in ones are the tag metrics (tag
#: backends against tag ground truth; the summary.csv names).
TAG_METRICS: tuple[str, ...] = tuple(m.name for m in _SPECS if m.accuracy and m.appended)

#: A rig row's metrics (``replaybench.results.rig``): compared and gated on rig rows alone
#: (topic ``rig``), every other metric on the camera rows alone, so that no frame is judged
#: twice. ``rig_p99_ms`` as ``p99_ms`` is, over every camera's measured frames; the drop rate
#: as accuracy is, a difference of point estimates (``RIG_POINT_METRICS``).
RIG_METRICS: tuple[str, ...] = tuple(m.name for m in _SPECS if m.kind == 'rig')
RIG_POINT_METRICS: tuple[str, ...] = ('rig_drop_rate',)

#: Every metric, in table order; the recorded outputs' latency (``recorded`` backend rows:
#: ``comparison.recorded``), compared as the timing metrics are, then the rig's.
METRICS: tuple[str, ...] = (
    TIMING_METRICS + ACCURACY_METRICS + TAG_METRICS + RECORDED_METRICS + RIG_METRICS
)

_REPLICATE: dict[str, str] = {'median_ms': 'p50', 'p99_ms': 'p99', 'mean_ms': 'mean', 'fps': 'fps'}
_SUMMARY: dict[str, str] = {
    'median_ms': 'latency_ms_p50',
    'p99_ms': 'latency_ms_p99',
    'mean_ms': 'latency_ms_mean',
    'fps': 'throughput_fps',
}

Role = Literal['baseline', 'candidate', 'unpaired']


@dataclass(frozen=True, slots=True)
class Row:
    """One (run, backend, topic) and its metrics against the baseline row."""

    run: int
    run_label: str
    backend: str
    topic: str
    role: Role
    #: The backend of the baseline row compared with (None when unpaired).
    baseline_backend: str | None
    measured: int
    latency_cv: float | None
    block_length: int | None
    inputs_match: bool | None
    metrics: dict[str, MetricComparison]
    flags: tuple[str, ...]
    #: why this row's timings cannot fail the gate by themselves (``repeats.single_pass_caution``)
    caution: str | None = None
    #: passes of ``--repeat`` (1 for a single pass)
    repeats: int = 1
    #: recorded outputs matched to measured frames (``recorded`` backend); None for a row
    #: that replays
    recorded_outputs: int | None = None
    #: summary.csv's ``recorded_latency_note`` (why a recorded figure is not reported; '' when
    #: nothing is said); None for a row that replays
    recorded_note: str | None = None
    #: a candidate row of boxes against its baseline row frame by frame (``comparison.paired``:
    #: the paired mAP@0.5 change and interval, the agreement of the two); None for other rows
    paired: Paired | None = None

    @property
    def name(self) -> str:
        """``run label · backend · topic``."""
        return f'{self.run_label} · {self.backend} · {self.topic}'


@dataclass(frozen=True, slots=True, eq=False)
class Comparison:
    """Every row of every run, the baseline choice, the warnings and the statistics used."""

    runs: tuple[RunInfo, ...]
    baseline: int
    baseline_backend: str | None
    rows: tuple[Row, ...]
    warnings: tuple[str, ...]
    inputs_match: bool | None
    seed: int
    n_boot: int
    confidence: float
    #: (run index, backend, topic) -> measured latencies (ms) in replay order
    latencies: dict[tuple[int, str, str], npt.NDArray[np.float64]] = field(repr=False)
    #: (run index, backend, topic) -> recorded pipeline latencies (ms) in log-time order, for
    #: the rows of recordings whose pipeline figure is reported
    recorded_latencies: dict[tuple[int, str, str], npt.NDArray[np.float64]] = field(
        default_factory=dict, repr=False
    )

    @property
    def baseline_run(self) -> RunInfo:
        """The run the others are compared with."""
        return self.runs[self.baseline]

    def baseline_row(self, row: Row) -> Row | None:
        """The row ``row`` is compared with (itself for a baseline row)."""
        if row.baseline_backend is None:
            return None
        for other in self.rows:
            if (
                other.run == self.baseline
                and other.backend == row.baseline_backend
                and other.topic == row.topic
            ):
                return other
        return None


class _Series(NamedTuple):
    latency: npt.NDArray[np.float64]
    intervals: npt.NDArray[np.float64] | None
    summary: Summary
    passes: PassValues | None = None  # --repeat: each pass's value per metric
    caution: str | None = None


def _series(records: Sequence[FrameRecord]) -> dict[tuple[str, str], _Series]:
    """Measured latencies and inter-completion intervals per (backend, topic), in replay order."""
    groups: dict[tuple[str, str], list[FrameRecord]] = {}
    for record in records:
        groups.setdefault((record.backend, record.topic), []).append(record)
    summaries = {(s.backend, s.topic): s for s in summarize(records)}
    # a run with a rig: each backend's rig row over all its cameras' frames
    for backend, pooled in rig_groups(records).items():
        cameras = [s for (b, _), s in summaries.items() if b == backend]
        summaries[backend, RIG_TOPIC] = rig_summary(pooled, cameras)
        groups[backend, RIG_TOPIC] = pooled
    result: dict[tuple[str, str], _Series] = {}
    for key, group in groups.items():
        # the series run reports take their own intervals from (results.intervals)
        latency, intervals = measured_series(group)
        summary = summaries[key]
        caution = single_pass_caution(group, latency, summary.throughput_fps)
        result[key] = _Series(latency, intervals, summary, pass_values(group), caution)
    return result


def _recorded(records: Sequence[FrameRecord], seed: int) -> dict[tuple[str, str], RecordedSeries]:
    """The recorded latencies of each (backend, topic) that replays recorded outputs."""
    groups: dict[tuple[str, str], list[FrameRecord]] = {}
    for record in records:
        groups.setdefault((record.backend, record.topic), []).append(record)
    found = {key: recorded_series(*key, group, seed=seed) for key, group in groups.items()}
    return {key: s for key, s in found.items() if s is not None}


def _recorded_flags(rec: RecordedSeries) -> list[str]:
    """A recorded row's flags: figures the run refused, and too few outputs for blocks."""
    flags = [
        f'recorded latency: {part}'
        for part in rec.note.split('; ')
        if 'not reported' in part or part.startswith('no recorded output')
    ]
    if 0 < rec.outputs < MIN_FRAMES:
        flags.append(
            f'{rec.outputs} recorded outputs: fewer than {MIN_FRAMES}, their latencies compared '
            'output by output (no blocks, no bootstrap CI of their own)'
        )
    return flags


def _accuracy(run: RunResult) -> dict[tuple[str, str], dict[str, float]]:
    """Each row's accuracy metrics (every task's, ``SummaryRow.metric``) that it has."""
    table: dict[tuple[str, str], dict[str, float]] = {}
    for row in run.summary_rows:
        values: dict[str, float] = {}
        for name in (*ACCURACY_METRICS, *TAG_METRICS):
            number = row.metric(name)
            if number is not None:
                values[name] = number
        table[(row.backend, row.topic)] = values
    return table


def _reps(reps: Replicates | None, metric: str) -> npt.NDArray[np.float64] | None:
    if reps is None:
        return None
    found: npt.NDArray[np.float64] | None = getattr(reps, _REPLICATE[metric])
    return found


def _timing(
    metric: str,
    value: float | None,
    own: Replicates | None,
    base_value: float | None,
    change: ChangeInterval | None,
    confidence: float,
) -> MetricComparison:
    """``change`` is None for a row without a baseline (baseline and unpaired rows)."""
    mine = _reps(own, metric)
    value_ci = percentile_interval(mine, confidence, point=value) if mine is not None else None
    if change is None:
        return MetricComparison(metric, value, value_ci)
    ratio = diff = None
    if value is not None and base_value is not None:
        diff = value - base_value
        ratio = value / base_value if base_value > 0 else None
    return MetricComparison(
        metric,
        value,
        value_ci,
        base_value,
        ratio,
        change.ratio_ci if ratio is not None else None,
        diff,
        change.diff_ci if diff is not None else None,
        change.ratio,
        change.diff,
        change.method,
        change.blocks,
    )


def _accuracy_metric(
    metric: str, value: float | None, base_value: float | None, paired: bool
) -> MetricComparison:
    if not paired or value is None or base_value is None:
        return MetricComparison(metric, value, baseline=base_value if paired else None)
    ratio = value / base_value if base_value > 0 else None
    return MetricComparison(metric, value, None, base_value, ratio, None, value - base_value)


def _rig_metric(
    metric: str,
    metrics: dict[str, MetricComparison],
    summary: Summary,
    base_series: _Series | None,
    *,
    paired: bool,
    rig: bool,
) -> MetricComparison:
    """A rig metric of a row: a rig row's p99 as its ``p99_ms`` (the same series, interval and
    change), its drop rate as a point estimate; nothing on a camera's row."""
    if not rig:
        return MetricComparison(metric, None)
    if metric not in RIG_POINT_METRICS:
        return replace(metrics['p99_ms'], metric=metric)
    base = base_series.summary.metric(metric) if base_series is not None else None
    return _accuracy_metric(metric, summary.metric(metric), base, paired)


def _reference(
    backend: str,
    topic: str,
    baseline_keys: Sequence[tuple[str, str]],
    baseline_backend: str | None,
) -> str | None:
    """The baseline run's backend this row is compared with, or None."""
    wanted = baseline_backend or backend
    if (wanted, topic) in baseline_keys:
        return wanted
    if baseline_backend is None:
        on_topic = [b for b, t in baseline_keys if t == topic]
        if len(on_topic) == 1:
            return on_topic[0]
    return None


def compare_runs(
    run_dirs: Sequence[str | Path | RunData],
    *,
    baseline: int = 0,
    baseline_backend: str | None = None,
    seed: int = 0,
    n_boot: int = DEFAULT_RESAMPLES,
    confidence: float = CONFIDENCE,
    paired_resamples: int | None = None,
) -> Comparison:
    """Compare every (run, backend, topic) of ``run_dirs`` with the baseline run.

    A row is compared with the baseline run's row of the same topic and of ``baseline_backend``
    (default: the same backend; when the baseline run has no such backend but exactly one on
    that topic, that one). With a single run folder the baseline backend defaults to its first
    backend, so the backends of one run are compared with each other.

    A candidate row over the same frames as its baseline row (the same run, or runs of the
    same inputs) is also compared frame by frame (``comparison.paired``), boxes on mAP@0.5
    and label masks on mIoU: the change gets the paired bootstrap interval
    (``paired_resamples`` draws, default ``PAIRED_RESAMPLES``) and the row the agreement of
    the two backends' outputs.

    Raises UsageError for bad arguments and SourceError for unreadable run folders.
    """
    if not run_dirs:
        msg = (
            'no run folder given: compare needs two or more run folders '
            '(or one with several backends)'
        )
        raise UsageError(msg)
    if not 0 <= baseline < len(run_dirs):
        msg = f'baseline index {baseline} out of range: {len(run_dirs)} run folder(s) given'
        raise UsageError(msg)
    if n_boot < 1:
        msg = f'n_boot must be at least 1, not {n_boot}'
        raise UsageError(msg)
    runs = load_runs(run_dirs)
    base_run = runs[baseline]
    series = [_series(r.data.frames) for r in runs]
    accuracy = [_accuracy(r.data.run) for r in runs]
    recorded = [_recorded(r.data.frames, seed) for r in runs]
    baseline_keys = list(series[baseline])
    if baseline_backend is None and len(runs) == 1:
        backends = list(dict.fromkeys(b for b, _ in baseline_keys))
        if len(backends) < 2:
            msg = (
                f'nothing to compare: {runs[0].dir} has one backend; give two or more run folders '
                'or one with several backends'
            )
            raise UsageError(msg)
        baseline_backend = backends[0]
    if baseline_backend is not None and baseline_backend not in {b for b, _ in baseline_keys}:
        known = ', '.join(dict.fromkeys(b for b, _ in baseline_keys)) or 'none'
        msg = f'baseline backend {baseline_backend!r} is not in {base_run.dir} (it has: {known})'
        raise UsageError(msg)

    cache: dict[tuple[int, str, str], Replicates | None] = {}

    def reps(run: int, backend: str, topic: str) -> Replicates | None:
        key = (run, backend, topic)
        if key not in cache:
            s = series[run][backend, topic]
            cache[key] = replicates(
                s.latency, s.intervals, n_boot=n_boot, rng=interval_rng(seed, run, backend, topic)
            )
        return cache[key]

    warnings: list[str] = []
    flags_of_run = {r.index: run_flags(r, base_run) for r in runs}
    engines = _engine_flags(runs, baseline)
    rows: list[Row] = []
    for run in runs:
        warnings.extend(f'{run.label}: {line}' for line in flags_of_run[run.index])
        match = inputs_match(run, base_run) if run.index != baseline else True
        for (backend, topic), s in series[run.index].items():
            ref = _reference(backend, topic, baseline_keys, baseline_backend)
            role: Role
            if ref is None:
                role = 'unpaired'
            elif run.index == baseline and ref == backend:
                role = 'baseline'
            else:
                role = 'candidate'
            paired = role == 'candidate'
            summary = s.summary
            mean, std = summary.latency_ms_mean, summary.latency_ms_std
            cv = std / mean if mean and std is not None and mean > 0 else None
            flags = list(flags_of_run[run.index])
            if cv is not None and cv > CV_LIMIT:
                flags.append(f'unstable latency: CV {cv:.3f} > {CV_LIMIT:g}')
            if s.caution is not None:
                flags.append(f'{s.caution}: {CAUTION_ADVICE}')
            rec = recorded[run.index].get((backend, topic))
            if rec is not None:
                flags += _recorded_flags(rec)
            elif s.latency.size < MIN_FRAMES:
                flags.append(
                    f'{s.latency.size} measured frames: fewer than {MIN_FRAMES}, compared frame by '
                    'frame (no blocks, no bootstrap CI of its own)'
                )
            engine = engines.get((run.index, backend))
            if engine:
                flags.append(engine)
            if role == 'unpaired':
                flags.append('no baseline row for this backend and topic')
            own = reps(run.index, backend, topic)
            base_series = series[baseline][ref, topic] if ref is not None else None
            metrics: dict[str, MetricComparison] = {}
            base_rec = recorded[baseline].get((ref, topic)) if ref is not None else None
            for metric in TIMING_METRICS:
                value = getattr(summary, _SUMMARY[metric])
                base_value = (
                    getattr(base_series.summary, _SUMMARY[metric])
                    if base_series is not None
                    else None
                )
                if metric == 'fps' and (rec is not None or base_rec is not None):
                    # a recording's FPS is how fast the bag was read, no detector's speed: it
                    # has none here, and no row's FPS is a ratio to it
                    metrics[metric] = _timing(
                        metric, None if rec is not None else value, own, None, None, confidence
                    )
                    continue
                change = None
                if paired and base_series is not None:
                    # both runs of --repeat: between passes (repeats.py); else between blocks
                    change = repeat_change(metric, base_series.passes, s.passes, confidence)
                if paired and base_series is not None and change is None:
                    change = change_interval(
                        metric,
                        base_series.latency,
                        s.latency,
                        baseline_intervals_s=base_series.intervals,
                        candidate_intervals_s=s.intervals,
                        confidence=confidence,
                    )
                metrics[metric] = _timing(metric, value, own, base_value, change, confidence)
            acc = accuracy[run.index].get((backend, topic), {})
            base_acc = accuracy[baseline].get((ref, topic), {}) if ref is not None else {}
            for metric in (*ACCURACY_METRICS, *TAG_METRICS):
                metrics[metric] = _accuracy_metric(
                    metric, acc.get(metric), base_acc.get(metric), paired
                )
            for metric in RECORDED_METRICS:
                metrics[metric] = recorded_metric_parts(
                    metric, rec, base_rec, paired=paired, confidence=confidence
                )
            for metric in RIG_METRICS:
                metrics[metric] = _rig_metric(
                    metric, metrics, summary, base_series, paired=paired, rig=topic == RIG_TOPIC
                )
            row = Row(
                run=run.index,
                run_label=run.label,
                backend=backend,
                topic=topic,
                role=role,
                baseline_backend=ref,
                measured=int(s.latency.size),
                latency_cv=cv,
                block_length=own.block if own is not None else None,
                inputs_match=match,
                metrics=metrics,
                flags=tuple(flags),
                caution=s.caution,
                repeats=len(next(iter(s.passes.values()))) if s.passes else 1,
                recorded_outputs=rec.outputs if rec is not None else None,
                recorded_note=rec.note if rec is not None else None,
            )
            rows.append(row)
            extra = [f for f in flags if f not in flags_of_run[run.index]]
            if extra:
                warnings.append(f'{row.name}: ' + '; '.join(extra))
    from replaybench.comparison.paired import with_paired

    rows = with_paired(
        rows, runs, baseline, seed=seed, confidence=confidence, resamples=paired_resamples
    )
    warnings.extend(
        f'{row.name}: {flag}' for row in rows for flag in row.flags if flag.startswith('paired')
    )
    candidates = [r for r in runs if r.index != baseline]
    matches = [inputs_match(r, base_run) for r in candidates]
    if any(m is False for m in matches):
        overall: bool | None = False
    elif not candidates or any(m is None for m in matches):
        overall = None
    else:
        overall = True
    for run, m in zip(candidates, matches, strict=True):
        if m is False:
            warnings.insert(0, _mismatch_line(run, base_run))
    return Comparison(
        runs=tuple(runs),
        baseline=baseline,
        baseline_backend=baseline_backend,
        rows=tuple(rows),
        warnings=tuple(dict.fromkeys(warnings)),
        inputs_match=overall,
        seed=seed,
        n_boot=n_boot,
        confidence=confidence,
        latencies={
            (run.index, b, t): s.latency for run in runs for (b, t), s in series[run.index].items()
        },
        recorded_latencies={
            (run.index, b, t): found
            for run in runs
            for (b, t), rec in recorded[run.index].items()
            if (found := rec.figures.get('pipeline_ms')) is not None
        },
    )


def _short(sha: str | None) -> str:
    return sha[:12] if sha else 'unknown'


def _mismatch_line(run: RunInfo, base: RunInfo) -> str:
    mine = ', '.join(
        f'{p} ({_short(s)})' for p, s in zip(run.input_paths, run.input_sha256, strict=True)
    )
    theirs = ', '.join(
        f'{p} ({_short(s)})' for p, s in zip(base.input_paths, base.input_sha256, strict=True)
    )
    return (
        f'INPUTS DIFFER: {run.label} replayed {mine or "nothing"} but the baseline '
        f'{base.label} replayed {theirs or "nothing"} (sha256 do not match); the comparison '
        'is still made, but it is not over the same data'
    )


def _engine_flags(runs: Sequence[RunInfo], baseline: int) -> dict[tuple[int, str], str]:
    """Per (run, backend): a flag when the backend ran on another engine than in the reference.

    The reference is the baseline run when it has the backend, else the first run that has it.
    """
    flags: dict[tuple[int, str], str] = {}
    backends = list(dict.fromkeys(b for r in runs for b in r.backend_info))
    for backend in backends:
        having = [r for r in runs if backend in r.backend_info]
        ref = next((r for r in having if r.index == baseline), having[0])
        ref_engine = engine_text(ref.backend_info[backend])
        for run in having:
            mine = engine_text(run.backend_info[backend])
            if run.index != ref.index and mine != ref_engine:
                flags[(run.index, backend)] = (
                    f'engine mismatch for backend {backend}: {mine or "not recorded"} here, '
                    f'{ref_engine or "not recorded"} in {ref.label}'
                )
    return flags
