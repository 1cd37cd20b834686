"""One (backend, topic) summarised: summary.csv's row (``SummaryRow``) and one ``--repeat``
pass's statistics (``RepeatStats``).

``SummaryRow`` holds the common fields (counts, latency, throughput, stage means, resources,
intervals, warnings, the recorded outputs' latency) and each task's metrics: detection's
``precision50`` ... ``map50_95`` and ``accuracy``, segmentation's ``miou``,
``pixel_accuracy`` and ``segmentation``, the tags' ``tag_*`` and ``tag_accuracy``, the
tracks' ``track_timeline`` (its metrics are ``task_metrics``). The
order of the fields is the order of run.json's keys.
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields

from replaybench.results.model.common import OMIT_NONE
from replaybench.results.model.detections import Accuracy
from replaybench.results.model.segmentation import SegmentationSummary
from replaybench.results.model.tags import TagAccuracy
from replaybench.results.model.tracks import TrackTimeline

__all__ = ['RIG_METRICS', 'RIG_TOPIC', 'RepeatStats', 'SummaryRow']

#: The topic of a backend's rig row: all its camera topics of a run replaying several
#: (``replaybench.results.rig``); no camera topic of a ROS bag is named without a leading ``/``
RIG_TOPIC = 'rig'
#: The metrics only a rig row has (``SummaryRow.metric``): its p99 latency over all the
#: cameras' measured frames, and its dropped frames over its frames
RIG_METRICS: tuple[str, ...] = ('rig_p99_ms', 'rig_drop_rate')


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

    #: the metrics of a task that has no field of its own here (a task from an entry point),
    #: by metric name, in the order the task gave them; None (not in run.json) where the row
    #: has none. summary.csv writes them after the columns above.
    task_metrics: Mapping[str, float | None] | None = field(default=None, metadata=OMIT_NONE)
    #: a tracked row with truth ids: its id-switch timeline (report.html's Tracking section);
    #: absent otherwise, and in run.json files written before it
    track_timeline: TrackTimeline | None = field(default=None, metadata=OMIT_NONE)

    def metric(self, name: str) -> float | None:
        """The row's value of the metric ``name`` (a ``MetricSpec.name``): its field of that
        name, else its entry in ``task_metrics``; None where the row has none (a row of another
        task's backend) or the value is not finite. The one place that knows where a row keeps
        a task's metric, and of the rig metrics (``RIG_METRICS``), which only a rig row
        (topic ``rig``) has."""
        if name in RIG_METRICS:  # a rig row's alone: None on a camera's row
            if self.topic != RIG_TOPIC:
                return None
            if name == 'rig_p99_ms':
                return self.metric('latency_ms_p99')
            return self.dropped / self.frames if self.frames else None
        found = getattr(self, name, None) if name in _FIELDS else None
        if found is None and self.task_metrics is not None:
            found = self.task_metrics.get(name)
        if isinstance(found, bool) or not isinstance(found, int | float):
            return None
        value = float(found)
        return value if math.isfinite(value) else None


#: SummaryRow's fields that a metric may be (``SummaryRow.metric``)
_FIELDS: frozenset[str] = frozenset(f.name for f in fields(SummaryRow))


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
