"""The typed results: what run.json, peak.json and comparison.json hold, as frozen dataclasses.

``RunResult`` is one run folder's run.json, ``PeakResult`` a ``replaybench peak`` folder's
peak.json and ``Comparison`` the comparison.json of ``replaybench compare``. Nested objects are
typed attributes (``res.settings.rate``, ``res.inputs[0].sha256``, ``res.backends[0].name``);
lists are tuples; objects whose keys are data (``skipped`` reasons, ``warmup_per_topic``) are
mappings, and so are the free-form ones a backend or a sweep fills (``BackendRun.info``,
``RunResult.sweep``).

The classes hold values only: ``replaybench.results.io`` writes them as JSON and reads them
back (``read_run(path) == result`` for a result written with ``write_run``), and the JSON
Schemas in ``replaybench/schemas/`` describe the files. Every field has a default, so a file
written by an older replaybench, which lacks a key, still reads; the schema says which keys a
file written now always has.

A field's JSON key is its name, except where ``metadata['json']`` says otherwise (the
``summary`` rows of run.json are ``RunResult.summary_rows`` and peak.json's ``trials`` are
``PeakResult.trial_rows``: ``summary`` and ``trials`` are kept for tables). A field with
``metadata['omit_none']`` is left out of the file when it is None.
"""

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from replaybench.results.records import FrameRecord

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    'COMPARISON_SCHEMA_VERSION',
    'PEAK_SCHEMA_VERSION',
    'RUN_SCHEMA_VERSION',
    'Accuracy',
    'AgreementRow',
    'BackendFailure',
    'BackendRun',
    'ComparedInput',
    'ComparedSettings',
    'Comparison',
    'ComparisonBaseline',
    'ComparisonGate',
    'ComparisonRow',
    'ComparisonRun',
    'ComparisonStatistics',
    'CpuInfo',
    'Environment',
    'GateCheck',
    'GpuInfo',
    'InputInfo',
    'MetricResult',
    'OpenCvInfo',
    'OsInfo',
    'Packages',
    'PeakResult',
    'PeakSettings',
    'PeakStart',
    'PeakTrial',
    'PythonInfo',
    'ReadAhead',
    'RepeatStats',
    'ResourcePoint',
    'ResourceSummary',
    'Resources',
    'RunCounts',
    'RunOutputs',
    'RunResult',
    'RunSettings',
    'SegmentationAgreementRow',
    'SegmentationSummary',
    'SummaryRow',
    'Tool',
    'TopicMeta',
]

#: Version of the run.json layout; readers refuse files with a newer one.
RUN_SCHEMA_VERSION = 1
#: Version of the peak.json layout.
PEAK_SCHEMA_VERSION = 1
#: Version of the comparison.json layout.
COMPARISON_SCHEMA_VERSION = 2

_OMIT_NONE: Mapping[str, Any] = {'omit_none': True}
#: A field that is not in the file (``metadata['json_skip']``): data the Python API carries.
_NOT_IN_FILE: Mapping[str, Any] = {'json_skip': True}


def _empty() -> dict[str, Any]:
    return {}


# --------------------------------------------------------------------------- shared


@dataclass(frozen=True, slots=True)
class Tool:
    """The program that wrote the file."""

    name: str = 'replaybench'
    version: str = ''


@dataclass(frozen=True, slots=True)
class TopicMeta:
    """An image topic of an input, as probed."""

    name: str = ''
    msgtype: str | None = None
    encoding: str | None = None
    width: int | None = None
    height: int | None = None
    count: int | None = None
    is_depth: bool = False
    camera_info_topic: str | None = None


@dataclass(frozen=True, slots=True)
class InputInfo:
    """One BAG argument: where it is, what it holds, and what reading it ran into."""

    index: int = 0
    path: str = ''
    format: str | None = None
    size_bytes: int | None = None
    sha256: str | None = None
    truncated: bool = False
    warnings: tuple[str, ...] = ()
    ground_truth_frames: int = 0
    topics: tuple[TopicMeta, ...] = ()


@dataclass(frozen=True, slots=True)
class CpuInfo:
    """The CPU; ``governor`` is None where it cannot be read."""

    model: str | None = None
    logical_cores: int | None = None
    usable_cores: int | None = None
    machine: str | None = None
    governor: str | None = None


@dataclass(frozen=True, slots=True)
class OsInfo:
    """``platform``'s view of the operating system."""

    system: str | None = None
    release: str | None = None
    version: str | None = None
    platform: str | None = None


@dataclass(frozen=True, slots=True)
class PythonInfo:
    """The interpreter that ran."""

    version: str | None = None
    implementation: str | None = None
    executable: str | None = None


@dataclass(frozen=True, slots=True)
class OpenCvInfo:
    """OpenCV's version and its thread count during the run."""

    version: str | None = None
    threads: int | None = None


@dataclass(frozen=True, slots=True)
class Packages:
    """Versions of the libraries that shape the measurements (None when not installed)."""

    replaybench: str | None = None
    numpy: str | None = None
    onnxruntime: str | None = None
    mcap: str | None = None
    rosbags: str | None = None
    opencv: OpenCvInfo = OpenCvInfo()


@dataclass(frozen=True, slots=True)
class GpuInfo:
    """One GPU as ``nvidia-smi`` lists it."""

    name: str | None = None
    driver_version: str | None = None
    memory_total: str | None = None


@dataclass(frozen=True, slots=True)
class Environment:
    """The machine a run (or a peak search) was measured on."""

    hostname: str | None = None
    cpu: CpuInfo = CpuInfo()
    memory_total_bytes: int | None = None
    os: OsInfo = OsInfo()
    python: PythonInfo = PythonInfo()
    packages: Packages = Packages()
    load_average: tuple[float, ...] | None = None
    gpus: tuple[GpuInfo, ...] = ()


# --------------------------------------------------------------------------- run.json


@dataclass(frozen=True, slots=True)
class RunSettings:
    """The options the run was made with."""

    rate: str = 'max'
    queue_depth: int = 1
    warmup: int | None = None
    warmup_per_topic: Mapping[str, int] = field(default_factory=_empty)
    threads: int | None = None
    max_frames: int | None = None
    start_s: float | None = None
    duration_s: float | None = None
    topics: tuple[str, ...] | None = None
    ground_truth_topic: str | None = None
    ground_truth_file: str | None = None
    ground_truth_match: str | None = None
    annotations: bool = False
    copy_images: bool = False
    detections_format: str = 'mcap'
    #: IoU at which backends' detections are paired (``results.agreement.AGREEMENT_IOU``; every
    #: run used it before run.json recorded it)
    agreement_iou: float = 0.5
    #: ``--repeat N``: passes of each backend over the inputs, interleaved (1 before it existed)
    repeat: int = 1


@dataclass(frozen=True, slots=True)
class BackendFailure:
    """Where and how a backend's ``detect`` raised (its status is then ``failed``)."""

    input: int = 0
    topic: str = ''
    seq: int = 0
    message: str = ''


@dataclass(frozen=True, slots=True)
class ResourceSummary:
    """A backend's resource use over its replay (``ResourceSampler.summary``)."""

    cpu_percent_mean: float | None = None
    cpu_percent_max: float | None = None
    private_mb_peak: float | None = None
    private_mb_mean: float | None = None
    mapped_mb_peak: float | None = None
    rss_mb_peak: float | None = None
    rss_mb_mean: float | None = None
    gpu_util_mean: float | None = None
    gpu_mem_mb_peak: float | None = None
    gpu_power_w_mean: float | None = None
    samples: int | None = None
    interval_s: float | None = None
    overhead_ms_per_sample: float | None = None
    overhead_cpu_percent: float | None = None
    duration_s: float | None = None
    cpu_source: str | None = None
    rss_source: str | None = None
    gpu_index: int | None = None
    gpu_name: str | None = None
    gpu_uuid: str | None = None
    gpu_pci_bus_id: str | None = None
    gpu_match: str | None = None
    #: highest current CPU frequency of the process's CPUs, over samples with >= 50 % of a core
    cpu_mhz_min: float | None = None
    cpu_mhz_max: float | None = None
    #: 'cpufreq', or None where no CPU frequency could be read
    cpu_freq_source: str | None = None
    #: thermal throttle events the kernel counted during the replay (None: no counters)
    cpu_throttle_events: int | None = None
    #: NVML clock throttle reasons seen (None: NVML gave none)
    gpu_throttle_reasons: tuple[str, ...] | None = None
    #: device memory used at the start of the backend's pass, and the pass's peak above it
    gpu_mem_mb_start: float | None = None
    gpu_mem_mb_pass_peak: float | None = None
    #: what gpu_mem_mb_pass_peak is measured against (``replay.resources.GPU_MEM_BASIS``)
    gpu_mem_basis: str | None = None


@dataclass(frozen=True, slots=True)
class ResourcePoint:
    """One point of a backend's resource series, ``t_s`` from its replay start."""

    t_s: float = 0.0
    cpu_percent: float | None = None
    private_mb: float | None = None
    mapped_mb: float | None = None
    rss_mb: float | None = None
    gpu_util: float | None = None
    gpu_mem_mb: float | None = None
    gpu_power_w: float | None = None
    cpu_mhz: float | None = None
    #: NVML clock event reason bits seen in the span of the point
    gpu_throttle: int | None = None


@dataclass(frozen=True, slots=True)
class Resources:
    """A backend's resource use: the summary and the (reduced) series."""

    summary: ResourceSummary | None = None
    series: tuple[ResourcePoint, ...] = ()


@dataclass(frozen=True, slots=True)
class ReadAhead:
    """What a max-rate pass decided about reading frames ahead, and on what figures.

    Either ``reason`` (nothing was measured: ``prefetch=0``, or the input ended in the probe)
    or the probe's figures are given; the others are left out of the file.
    """

    input: int = 0
    depth: int = 0
    used: bool = False
    reason: str | None = field(default=None, metadata=_OMIT_NONE)
    probe_frames: int | None = field(default=None, metadata=_OMIT_NONE)
    probe_read_decode_ms: float | None = field(default=None, metadata=_OMIT_NONE)
    threshold_ms: float | None = field(default=None, metadata=_OMIT_NONE)


@dataclass(frozen=True, slots=True)
class BackendRun:
    """One backend of the run: its status, what it reported and what it cost."""

    name: str = ''
    label: str = ''
    status: str = 'ok'
    error: BackendFailure | None = None
    info: Mapping[str, Any] = field(default_factory=_empty)
    resources: Resources | None = None
    read_ahead: tuple[ReadAhead, ...] = ()
    record_s: float | None = None


@dataclass(frozen=True, slots=True)
class Accuracy:
    """Accuracy of one (backend, topic) against ground truth (COCO-style, by class label).

    ``ap50`` / ``ap50_95`` map each label to its AP; -1 for a label without ground truth.
    """

    frames: int | None = None
    precision50: float | None = None
    recall50: float | None = None
    map50: float | None = None
    map50_95: float | None = None
    ap50: Mapping[str, float] = field(default_factory=_empty)
    ap50_95: Mapping[str, float] = field(default_factory=_empty)
    n_gt: int | None = None
    n_det: int | None = None


@dataclass(frozen=True, slots=True)
class SegmentationSummary:
    """A segmentation backend's accuracy on one topic (``replaybench.results.segmentation``):
    frames scored against a ground-truth mask, mIoU, pixel accuracy, IoU by class name (classes
    in the truth or the prediction), and the backend's class names by id."""

    frames: int = 0
    miou: float | None = None
    pixel_accuracy: float | None = None
    iou: Mapping[str, float] = field(default_factory=_empty)
    class_names: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class SegmentationAgreementRow:
    """Two segmentation backends on one topic: over the frames both labelled, the mIoU and
    pixel agreement of ``backend_b``'s masks taking ``backend_a``'s as ground truth."""

    backend_a: str = ''
    backend_b: str = ''
    topic: str = ''
    frames: int = 0
    miou: float | None = None
    pixel_agreement: float | None = None


@dataclass(frozen=True, slots=True)
class TagSizeHint:
    """One tag id whose distances one scale factor explains (replaybench.results.tags):
    ``scale`` the median of detected / true distance over its ``detections``, all within
    ``spread_pct`` of it; ``size_m`` the size its poses were solved with, ``suggested_size_m``
    the size that scale implies; ``line`` the sentence the terminal prints."""

    tag_id: int = 0
    detections: int = 0
    scale: float = 1.0
    spread_pct: float = 0.0
    size_m: float = 0.0
    suggested_size_m: float = 0.0
    line: str = ''


@dataclass(frozen=True, slots=True)
class TagAccuracy:
    """Tag accuracy of one (backend, topic) against tag ground truth (replaybench.results.tags).

    Counts over the frames with truth; errors over the matched tags (poses: where both have
    one); None where nothing was matched.
    """

    frames: int = 0
    n_truth: int = 0
    n_found: int = 0
    matched: int = 0
    recall: float | None = None
    wrong_ids: int = 0
    phantoms: int = 0
    corner_rmse_px: float | None = None
    trans_err_m: float | None = None
    trans_err_pct: float | None = None
    rot_err_deg: float | None = None
    rot_err_deg_p95: float | None = None
    rot_err_deg_max: float | None = None
    trans_err_m_max: float | None = None
    poses: int = 0
    #: ids whose distances are all off by one factor: a wrong tag size (``TagSizeHint``)
    size_hints: tuple[TagSizeHint, ...] = ()


@dataclass(frozen=True, slots=True)
class SummaryRow:
    """One (backend, topic): the summary.csv columns and the full ``accuracy``."""

    backend: str = ''
    topic: str = ''
    frames: int = 0
    processed: int = 0
    measured: int = 0
    warmup: int = 0
    dropped: int = 0
    skipped: int = 0
    throughput_fps: float | None = None
    latency_ms_mean: float | None = None
    latency_ms_std: float | None = None
    latency_ms_min: float | None = None
    latency_ms_p50: float | None = None
    latency_ms_p90: float | None = None
    latency_ms_p95: float | None = None
    latency_ms_p99: float | None = None
    latency_ms_max: float | None = None
    jitter_ms: float | None = None
    detections_per_frame: float | None = None
    queue_wait_ms_mean: float | None = None
    read_decode_ms_mean: float | None = None
    preprocess_ms_mean: float | None = None
    infer_ms_mean: float | None = None
    postprocess_ms_mean: float | None = None
    h2d_ms_mean: float | None = None
    d2h_ms_mean: float | None = None
    precision50: float | None = None
    recall50: float | None = None
    map50: float | None = None
    map50_95: float | None = None
    cpu_percent_mean: float | None = None
    private_mb_peak: float | None = None
    mapped_mb_peak: float | None = None
    rss_mb_peak: float | None = None
    gpu_util_mean: float | None = None
    gpu_mem_mb_peak: float | None = None
    gpu_power_w_mean: float | None = None
    #: 95 % block-bootstrap intervals (None below 20 measured frames)
    latency_ms_p50_ci_low: float | None = None
    latency_ms_p50_ci_high: float | None = None
    latency_ms_p99_ci_low: float | None = None
    latency_ms_p99_ci_high: float | None = None
    throughput_fps_ci_low: float | None = None
    throughput_fps_ci_high: float | None = None
    #: stability warnings (too few frames, CV, drift, throttling)
    warnings: tuple[str, ...] = ()
    accuracy: Accuracy | None = None
    #: segmentation backends: mIoU and pixel accuracy (summary.csv) and the full entry
    miou: float | None = None
    pixel_accuracy: float | None = None
    segmentation: SegmentationSummary | None = None

    #: recorded outputs (``recorded`` backend): their latency from the recording
    #: (replaybench.results.recorded_latency); None for replayed backends
    recorded_outputs: int | None = None
    recorded_outputs_dropped: int | None = None
    recorded_output_hz: float | None = None
    capture_to_output_ms_mean: float | None = None
    capture_to_output_ms_p50: float | None = None
    capture_to_output_ms_p50_ci_low: float | None = None
    capture_to_output_ms_p50_ci_high: float | None = None
    capture_to_output_ms_p99: float | None = None
    capture_to_output_ms_p99_ci_low: float | None = None
    capture_to_output_ms_p99_ci_high: float | None = None
    capture_to_output_ms_max: float | None = None
    pipeline_ms_mean: float | None = None
    pipeline_ms_p50: float | None = None
    pipeline_ms_p50_ci_low: float | None = None
    pipeline_ms_p50_ci_high: float | None = None
    pipeline_ms_p99: float | None = None
    pipeline_ms_p99_ci_low: float | None = None
    pipeline_ms_p99_ci_high: float | None = None
    pipeline_ms_max: float | None = None
    recorded_latency_note: str | None = None

    #: tag backends against tag ground truth (None otherwise)
    tag_recall: float | None = None
    tag_wrong_ids: int | None = None
    tag_phantoms: int | None = None
    tag_corner_rmse_px: float | None = None
    tag_trans_err_m: float | None = None
    tag_trans_err_pct: float | None = None
    tag_rot_err_deg: float | None = None
    tag_accuracy: TagAccuracy | None = None


@dataclass(frozen=True, slots=True)
class RepeatStats:
    """One pass (``--repeat``) of one (backend, topic): the statistics ``compare`` judges
    between repeats (``results.stats.repeat_statistics``)."""

    backend: str = ''
    topic: str = ''
    repeat: int = 0
    measured: int = 0
    latency_ms_p50: float | None = None
    latency_ms_p99: float | None = None
    latency_ms_mean: float | None = None
    throughput_fps: float | None = None
    #: the measured frames' processing window (s): completion to completion
    window_s: float | None = None


@dataclass(frozen=True, slots=True)
class AgreementRow:
    """How two backends agree on one topic (``replaybench.results.agreement``)."""

    backend_a: str = ''
    backend_b: str = ''
    topic: str = ''
    frames: int = 0
    n_a: int = 0
    n_b: int = 0
    matched: int = 0
    matched_frac_a: float | None = None
    matched_frac_b: float | None = None
    mean_iou: float | None = None
    mean_abs_score_diff: float | None = None
    #: (input, seq) of the frames with the most unmatched detections, worst first
    disagreeing_frames: tuple[tuple[int, int], ...] = ()


@dataclass(frozen=True, slots=True)
class RunCounts:
    """frames.csv rows of the whole run, by status."""

    frames: int = 0
    processed: int = 0
    dropped: int = 0
    skipped: int = 0


@dataclass(frozen=True, slots=True)
class RunOutputs:
    """The run folder's files, relative to it (``report`` None without report.html)."""

    detections_mcap: str = 'detections.mcap'
    frames_csv: str = 'frames.csv'
    summary_csv: str = 'summary.csv'
    report: str | None = None
    samples: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class RunResult:
    """run.json: everything needed to understand and reproduce one run (docs/outputs.md)."""

    schema_version: int = RUN_SCHEMA_VERSION
    tool: Tool = Tool()
    status: str = 'unknown'
    command: tuple[str, ...] = ()
    started_at: str | None = None
    finished_at: str | None = None
    wall_s: float | None = None
    settings: RunSettings = RunSettings()
    inputs: tuple[InputInfo, ...] = ()
    environment: Environment = Environment()
    backends: tuple[BackendRun, ...] = ()
    summary_rows: tuple[SummaryRow, ...] = field(default=(), metadata={'json': 'summary'})
    agreement: tuple[AgreementRow, ...] = ()
    #: with two or more segmentation backends: their masks compared
    segmentation_agreement: tuple[SegmentationAgreementRow, ...] = ()
    counts: RunCounts | None = None
    skipped: Mapping[str, int] = field(default_factory=_empty)
    warnings: tuple[str, ...] = ()
    #: the run folder's files; None for a run kept in memory (``rb.run(..., out=None)``),
    #: which wrote none (run.json always holds them)
    outputs: RunOutputs | None = field(default=None, metadata=_OMIT_NONE)
    #: ``replaybench sweep`` adds the cell's section to the run.json of each of its cells
    sweep: Mapping[str, Any] | None = field(default=None, metadata=_OMIT_NONE)
    #: per pass of ``--repeat N`` (N > 1) and (backend, topic); absent for a single pass
    repeats: tuple[RepeatStats, ...] | None = field(default=None, metadata=_OMIT_NONE)
    #: frames.csv's rows as the file holds them (not in run.json): set by ``replaybench.run``
    #: and ``replaybench.load_run``, None on a RunResult read from run.json alone
    frame_records: tuple[FrameRecord, ...] | None = field(
        default=None, compare=False, repr=False, metadata=_NOT_IN_FILE
    )

    @property
    def frames(self) -> 'pd.DataFrame':
        """frames.csv as a pandas DataFrame (``replaybench.results.tables``); ValueError when
        the result carries no frames (read from run.json alone)."""
        from replaybench.results.tables import frames_table

        if self.frame_records is None:
            msg = 'this RunResult carries no frames: read it with replaybench.load_run(folder)'
            raise ValueError(msg)
        return frames_table(self.frame_records)

    @property
    def summary(self) -> 'pd.DataFrame':
        """summary.csv as a pandas DataFrame, made from ``summary_rows``."""
        from replaybench.results.tables import summary_table

        return summary_table(self.summary_rows)

    def backend(self, label: str) -> BackendRun | None:
        """The backend with this label (or name), None when the run has none."""
        for entry in self.backends:
            if label in (entry.label, entry.name):
                return entry
        return None


# --------------------------------------------------------------------------- peak.json


@dataclass(frozen=True, slots=True)
class PeakSettings:
    """The options of the peak search."""

    max_drop: float = 0.05
    p99_bound_ms: float | None = None
    trial_frames: int | None = None
    warmup: int | None = None
    queue_depth: int = 1
    min_hz: float | None = None
    max_hz: float | None = None
    refine_steps: int | None = None
    confirm_trials: int | None = None
    topics: tuple[str, ...] | None = None
    threads: int | None = None


@dataclass(frozen=True, slots=True)
class PeakStart:
    """Where the search started and why (JSON key ``from`` is ``source``)."""

    hz: float | None = None
    source: str | None = field(default=None, metadata={'json': 'from'})
    probe_fps: float | None = None
    recorded_hz: float | None = None
    probe_run_dir: str | None = None


@dataclass(frozen=True, slots=True)
class PeakTrial:
    """One fixed-rate trial: frames and drops from the end of the warm-up on, its p99."""

    rate_hz: float = 0.0
    frames: int = 0
    dropped: int = 0
    drop_fraction: float = 0.0
    p99_ms: float | None = None
    ok: bool = False
    run_dir: str = ''
    attempt: int = 1


@dataclass(frozen=True, slots=True)
class PeakResult:
    """peak.json: the peak sustainable rate of one backend and every trial (docs/peak.md)."""

    schema_version: int = PEAK_SCHEMA_VERSION
    kind: str = 'peak'
    tool: Tool = Tool()
    status: str = 'complete'
    command: tuple[str, ...] = ()
    started_at: str | None = None
    finished_at: str | None = None
    wall_s: float | None = None
    backend: str = ''
    input: InputInfo = InputInfo()
    settings: PeakSettings = PeakSettings()
    start: PeakStart = PeakStart()
    peak_hz: float | None = None
    peak_confirmed: bool = False
    first_failing_hz: float | None = None
    resolution_hz: float | None = None
    limit_reached: bool = False
    warnings: tuple[str, ...] = ()
    trial_rows: tuple[PeakTrial, ...] = field(default=(), metadata={'json': 'trials'})
    environment: Environment = Environment()

    @property
    def trials(self) -> 'pd.DataFrame':
        """The trials as a pandas DataFrame (``rate_hz``, ``ok``, ...; run order)."""
        from replaybench.results.tables import trials_table

        return trials_table(self.trial_rows, PeakTrial)


# --------------------------------------------------------------------------- comparison.json


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
    backends: Mapping[str, Mapping[str, Any]] = field(default_factory=_empty)


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
    metrics: Mapping[str, MetricResult] = field(default_factory=_empty)


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
        default=None, compare=False, repr=False, metadata=_NOT_IN_FILE
    )
    #: comparison.csv's columns, in order (not in comparison.json)
    table_columns: tuple[str, ...] = field(
        default=(), compare=False, repr=False, metadata=_NOT_IN_FILE
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
