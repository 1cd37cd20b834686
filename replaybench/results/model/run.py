"""run.json (``RunResult``): the run's settings, its backends and what they cost, its summary
rows, agreement between backends, counts and files."""

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from replaybench.results.model.common import (
    NOT_IN_FILE,
    OMIT_NONE,
    Environment,
    InputInfo,
    Tool,
    empty_mapping,
)
from replaybench.results.model.detections import AgreementRow
from replaybench.results.model.rig import RigReport
from replaybench.results.model.segmentation import SegmentationAgreementRow
from replaybench.results.model.stereo import StereoAgreementRow
from replaybench.results.model.summary import RepeatStats, SummaryRow
from replaybench.results.model.sync import SyncReport
from replaybench.results.records import FrameRecord
from replaybench.results.runfolder import OUTPUTS_MCAP

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    'RUN_SCHEMA_VERSION',
    'BackendFailure',
    'BackendRun',
    'Pipelines',
    'ReadAhead',
    'ResourcePoint',
    'ResourceSummary',
    'Resources',
    'RunCounts',
    'RunOutputs',
    'RunResult',
    'RunSettings',
]

#: Version of the run.json layout; readers refuse files with a newer one. 2: the run folder's
#: MCAP is outputs.mcap, named by ``outputs.outputs_mcap`` (1: detections.mcap, named by
#: ``outputs.detections_mcap``, which still reads).
RUN_SCHEMA_VERSION = 2


@dataclass(frozen=True, slots=True)
class Pipelines:
    """``--pipelines per-topic``: how the machine's cores were divided between the pipelines.

    ``pipelines``: backend instances per backend, one per camera topic, each in a worker thread
    of its own (1: the inputs held one camera topic, replayed as shared); ``threads_per_pipeline``:
    ``--threads`` (each pipeline's OpenCV and native thread pools; None: the libraries'
    defaults); ``cores``: the cores this process could run on."""

    mode: str = 'per-topic'
    pipelines: int = 1
    workers: str = 'threads'
    threads_per_pipeline: int | None = None
    cores: int = 1


@dataclass(frozen=True, slots=True)
class RunSettings:
    """The options the run was made with."""

    rate: str = 'max'
    queue_depth: int = 1
    warmup: int | None = None
    warmup_per_topic: Mapping[str, int] = field(default_factory=empty_mapping)
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
    #: ``--pipelines per-topic``: the pipelines and the cores they had; None: one shared
    #: backend instance per backend (``--pipelines shared``, and every run before it existed)
    pipelines: Pipelines | None = None
    #: ``--added-latency-ms``: waited after every detect (a testing aid, docs/streaming.md);
    #: absent where nothing was added
    added_latency_ms: float | None = field(default=None, metadata=OMIT_NONE)


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
    reason: str | None = field(default=None, metadata=OMIT_NONE)
    probe_frames: int | None = field(default=None, metadata=OMIT_NONE)
    probe_read_decode_ms: float | None = field(default=None, metadata=OMIT_NONE)
    threshold_ms: float | None = field(default=None, metadata=OMIT_NONE)


@dataclass(frozen=True, slots=True)
class BackendRun:
    """One backend of the run: its status, what it reported and what it cost."""

    #: the instance's name: ``--backend LABEL=NAME``'s label, or the backend's name
    name: str = ''
    label: str = ''
    #: the registered backend the instance is made of ('' in run folders written before it)
    backend: str = ''
    #: the instance's own ``--param`` values (key: text), applied on top of the run's options
    params: Mapping[str, str] = field(default_factory=empty_mapping)
    status: str = 'ok'
    error: BackendFailure | None = None
    info: Mapping[str, Any] = field(default_factory=empty_mapping)
    resources: Resources | None = None
    read_ahead: tuple[ReadAhead, ...] = ()
    record_s: float | None = None


@dataclass(frozen=True, slots=True)
class RunCounts:
    """frames.csv rows of the whole run, by status."""

    frames: int = 0
    processed: int = 0
    dropped: int = 0
    skipped: int = 0


@dataclass(frozen=True, slots=True)
class RunOutputs:
    """The run folder's files, relative to it (``report`` None without report.html).

    ``outputs_mcap`` reads the key ``detections_mcap`` of a run.json of schema_version 1
    (``'detections.mcap'``), so it names the MCAP of older run folders too.
    """

    outputs_mcap: str = field(default=OUTPUTS_MCAP, metadata={'json_older': 'detections_mcap'})
    frames_csv: str = 'frames.csv'
    summary_csv: str = 'summary.csv'
    report: str | None = None
    samples: tuple[str, ...] = ()

    @property
    def detections_mcap(self) -> str:
        """The older name of ``outputs_mcap`` (run.json schema_version 1)."""
        return self.outputs_mcap


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
    #: with two or more stereo backends: their disparities compared; absent otherwise
    stereo_agreement: tuple[StereoAgreementRow, ...] | None = field(
        default=None, metadata=OMIT_NONE
    )
    counts: RunCounts | None = None
    skipped: Mapping[str, int] = field(default_factory=empty_mapping)
    warnings: tuple[str, ...] = ()
    #: the run folder's files; None for a run kept in memory (``rb.run(..., out=None)``),
    #: which wrote none (run.json always holds them)
    outputs: RunOutputs | None = field(default=None, metadata=OMIT_NONE)
    #: ``replaybench sweep`` adds the cell's section to the run.json of each of its cells
    sweep: Mapping[str, Any] | None = field(default=None, metadata=OMIT_NONE)
    #: per pass of ``--repeat N`` (N > 1) and (backend, topic); absent for a single pass
    repeats: tuple[RepeatStats, ...] | None = field(default=None, metadata=OMIT_NONE)
    #: ``--sync``: the synchronised frame sets and each topic's unpaired frames; absent without
    sync: SyncReport | None = field(default=None, metadata=OMIT_NONE)
    #: a run replaying several camera topics of an input: each backend's rig (its cameras,
    #: the pipelines that served them, its worst cameras; docs/rigs.md); absent otherwise
    rig: RigReport | None = field(default=None, metadata=OMIT_NONE)
    #: frames.csv's rows as the file holds them (not in run.json): set by ``replaybench.run``
    #: and ``replaybench.load_run``, None on a RunResult read from run.json alone
    frame_records: tuple[FrameRecord, ...] | None = field(
        default=None, compare=False, repr=False, metadata=NOT_IN_FILE
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
