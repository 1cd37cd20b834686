"""comparison.json (``Comparison``): every compared row against the baseline, the compared
runs and the ``--fail-if`` gate (``replaybench.comparison`` makes it)."""

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from replaybench.results.model.common import NOT_IN_FILE, OMIT_NONE, Tool, empty_mapping

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    'COMPARISON_SCHEMA_VERSION',
    'ComparedInput',
    'ComparedSettings',
    'Comparison',
    'ComparisonBaseline',
    'ComparisonGate',
    'ComparisonRow',
    'ComparisonRun',
    'ComparisonStatistics',
    'GateCheck',
    'MetricResult',
    'PairedFrame',
    'PairedResult',
]

#: Version of the comparison.json layout.
COMPARISON_SCHEMA_VERSION = 2


@dataclass(frozen=True, slots=True)
class ComparisonBaseline:
    """The baseline: its run (label and index) and, when one was named, its backend."""

    run: str = ''
    index: int = 0
    backend: str | None = None


@dataclass(frozen=True, slots=True)
class ComparisonStatistics:
    """How the intervals and verdicts were computed (texts) and with what parameters."""

    ratio: str = ''
    ratio_ci: str = ''
    blocks: str = ''
    significant: str = ''
    verdicts: str = ''
    value_ci: str = ''
    block_length: str = ''
    resamples: int = 0
    seed: int = 0
    confidence: float = 0.95
    interval: str = 'percentile'
    min_frames: int = 0
    cv_limit: float = 0.0
    accuracy: str = ''
    #: the recorded_* metrics (the ``recorded`` backend's latency from the recording)
    recorded: str = ''


@dataclass(frozen=True, slots=True)
class ComparedInput:
    """An input of a compared run."""

    path: str = ''
    sha256: str | None = None


@dataclass(frozen=True, slots=True)
class ComparedSettings:
    """The run settings that must agree for timings to be comparable."""

    rate: str | None = None
    queue_depth: int | None = None
    warmup: int | None = None
    threads: int | None = None
    max_frames: int | None = None
    start_s: float | None = None
    duration_s: float | None = None


@dataclass(frozen=True, slots=True)
class ComparisonRun:
    """A compared run folder and the machine facts read from its run.json."""

    index: int = 0
    label: str = ''
    dir: str = ''
    status: str = ''
    hostname: str | None = None
    cpu_model: str | None = None
    cores: int | None = None
    governor: str | None = None
    load_average: float | None = None
    gpus: tuple[str, ...] = ()
    inputs: tuple[ComparedInput, ...] = ()
    settings: ComparedSettings = ComparedSettings()
    #: backend label -> ``{"engine": text or null}``
    backends: Mapping[str, Mapping[str, Any]] = field(default_factory=empty_mapping)


@dataclass(frozen=True, slots=True)
class MetricResult:
    """One metric of a row against its baseline row (``replaybench.comparison``)."""

    value: float | None = None
    value_ci: tuple[float, float] | None = None
    baseline: float | None = None
    ratio: float | None = None
    ratio_ci: tuple[float, float] | None = None
    diff: float | None = None
    diff_ci: tuple[float, float] | None = None
    typical_ratio: float | None = None
    typical_diff: float | None = None
    method: str | None = None
    blocks: tuple[int, int] | None = None
    significant: bool | None = None


@dataclass(frozen=True, slots=True)
class PairedFrame:
    """One frame where the two backends' boxes agree least."""

    frame_id: str = ''
    stamp_ns: int = 0
    matched: float = 0.0
    iou: float = 0.0
    n_baseline: int = 0
    n_candidate: int = 0


@dataclass(frozen=True, slots=True)
class PairedResult:
    """The paired accuracy change and the agreement of a row with its baseline row
    (``replaybench.comparison.paired``)."""

    metric: str = 'map50'
    frames: int = 0
    baseline: float | None = None
    candidate: float | None = None
    change: float | None = None
    ci: tuple[float, float] | None = None
    resamples: int = 0
    undefined: int = 0
    confidence: float = 0.95
    seed: int = 0
    matched_mean: float | None = None
    iou_mean: float | None = None
    matched_min: float | None = None
    agreeing_frames: int = 0
    worst: tuple[PairedFrame, ...] = ()
    note: str = ''


@dataclass(frozen=True, slots=True)
class ComparisonRow:
    """One (run, backend, topic) and its metrics."""

    run: str = ''
    run_index: int = 0
    role: str = ''
    backend: str = ''
    topic: str = ''
    baseline_backend: str | None = None
    measured: int = 0
    block_length: int | None = None
    latency_cv: float | None = None
    inputs_match: bool | None = None
    flags: tuple[str, ...] = ()
    metrics: Mapping[str, MetricResult] = field(default_factory=empty_mapping)
    #: a candidate row of boxes against its baseline row frame by frame (left out otherwise)
    paired: PairedResult | None = field(default=None, metadata=OMIT_NONE)


@dataclass(frozen=True, slots=True)
class GateCheck:
    """One ``--fail-if`` condition judged on one candidate row."""

    condition: str = ''
    backend: str = ''
    topic: str = ''
    estimate: float | None = None
    ci_low: float | None = None
    ci_high: float | None = None
    failed: bool = False
    explanation: str = ''
    run: str = ''
    verdict: str = 'passed'
    method: str = ''


@dataclass(frozen=True, slots=True)
class ComparisonGate:
    """The ``--fail-if`` gate: its conditions, the verdict and the exit status it gave."""

    conditions: tuple[str, ...] = ()
    strict: bool = False
    allow_inconclusive: bool = False
    verdict: str = 'passed'
    passed: bool = True
    exit_status: int = 0
    results: tuple[GateCheck, ...] = ()


@dataclass(frozen=True, slots=True)
class Comparison:
    """comparison.json: every compared row against the baseline, and the gate (docs/compare.md)."""

    schema_version: int = COMPARISON_SCHEMA_VERSION
    tool: Tool = Tool()
    baseline: ComparisonBaseline = ComparisonBaseline()
    inputs_match: bool | None = None
    statistics: ComparisonStatistics = ComparisonStatistics()
    warnings: tuple[str, ...] = ()
    runs: tuple[ComparisonRun, ...] = ()
    rows: tuple[ComparisonRow, ...] = ()
    gate: ComparisonGate | None = None
    #: comparison.csv's rows, one mapping per row with the file's columns as keys, in order
    #: (not in comparison.json): set by ``replaybench.compare``, None on a Comparison read from
    #: comparison.json
    table_rows: tuple[Mapping[str, Any], ...] | None = field(
        default=None, compare=False, repr=False, metadata=NOT_IN_FILE
    )
    #: comparison.csv's columns, in order (not in comparison.json)
    table_columns: tuple[str, ...] = field(
        default=(), compare=False, repr=False, metadata=NOT_IN_FILE
    )

    @property
    def table(self) -> 'pd.DataFrame':
        """comparison.csv's rows as a pandas DataFrame (``pip install 'replaybench[pandas]'``);
        ValueError on a Comparison read from comparison.json, which does not hold them."""
        if self.table_rows is None:
            msg = 'this Comparison holds no table: make it with rb.compare'
            raise ValueError(msg)
        from replaybench.results.tables import records_table

        return records_table(self.table_rows, self.table_columns)

    @property
    def verdict(self) -> str | None:
        """The gate's verdict (``passed``, ``failed``, ``inconclusive``); None without a gate."""
        return self.gate.verdict if self.gate is not None else None
