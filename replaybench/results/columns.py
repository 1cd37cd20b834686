"""summary.csv's columns and cells: what a summary row (``SummaryRow``) is written as.

Kept apart from the statistics and the model, so that the pandas tables
(``replaybench.results.tables``), which the model's DataFrame properties import, need neither.
"""

from __future__ import annotations

import math
from typing import Any

from replaybench.textsafe import csv_text

__all__ = [
    'ACCURACY_COLUMNS',
    'COUNT_COLUMNS',
    'INTEGER_COLUMNS',
    'INTERVAL_COLUMNS',
    'RECORDED_COLUMNS',
    'RESOURCE_COLUMNS',
    'SEGMENTATION_SUMMARY_COLUMNS',
    'STATISTICS_COLUMNS',
    'SUMMARY_CSV_COLUMNS',
    'TAG_SUMMARY_COLUMNS',
    'TEXT_COLUMNS',
    'summary_cell',
]

#: The (backend, topic) a row is about, and its frame counts.
COUNT_COLUMNS: tuple[str, ...] = (
    'frames',
    'processed',
    'measured',
    'warmup',
    'dropped',
    'skipped',
)

#: Throughput, latency and stage statistics over the measured frames.
STATISTICS_COLUMNS: tuple[str, ...] = (
    'throughput_fps',
    'latency_ms_mean',
    'latency_ms_std',
    'latency_ms_min',
    'latency_ms_p50',
    'latency_ms_p90',
    'latency_ms_p95',
    'latency_ms_p99',
    'latency_ms_max',
    'jitter_ms',
    'detections_per_frame',
    'queue_wait_ms_mean',
    'read_decode_ms_mean',
    'preprocess_ms_mean',
    'infer_ms_mean',
    'postprocess_ms_mean',
    'h2d_ms_mean',
    'd2h_ms_mean',
)

#: Accuracy keys flattened into summary.csv columns.
ACCURACY_COLUMNS: tuple[str, ...] = ('precision50', 'recall50', 'map50', 'map50_95')

#: Resource-use columns of summary.csv (from the backend's ResourceSampler summary).
RESOURCE_COLUMNS: tuple[str, ...] = (
    'cpu_percent_mean',
    'private_mb_peak',
    'mapped_mb_peak',
    'rss_mb_peak',
    'gpu_util_mean',
    'gpu_mem_mb_peak',
    'gpu_power_w_mean',
)

#: Interval columns of summary.csv (after the resource columns, before ``warnings``).
INTERVAL_COLUMNS: tuple[str, ...] = (
    'latency_ms_p50_ci_low',
    'latency_ms_p50_ci_high',
    'latency_ms_p99_ci_low',
    'latency_ms_p99_ci_high',
    'throughput_fps_ci_low',
    'throughput_fps_ci_high',
)

#: Segmentation columns of summary.csv (after ``warnings``): a segmentation backend's mIoU and
#: pixel accuracy against the ground-truth masks (``SummaryRow.segmentation`` has the rest).
SEGMENTATION_SUMMARY_COLUMNS: tuple[str, ...] = ('miou', 'pixel_accuracy')
#: Recorded outputs' latency (``recorded`` backend; replaybench.results.recorded_latency): the
#: outputs matched and dropped, their rate, capture-to-output and pipeline latency, and why any
#: is not reported. Empty for replayed backends.
RECORDED_COLUMNS: tuple[str, ...] = (
    'recorded_outputs',
    'recorded_outputs_dropped',
    'recorded_output_hz',
    'capture_to_output_ms_mean',
    'capture_to_output_ms_p50',
    'capture_to_output_ms_p50_ci_low',
    'capture_to_output_ms_p50_ci_high',
    'capture_to_output_ms_p99',
    'capture_to_output_ms_p99_ci_low',
    'capture_to_output_ms_p99_ci_high',
    'capture_to_output_ms_max',
    'pipeline_ms_mean',
    'pipeline_ms_p50',
    'pipeline_ms_p50_ci_low',
    'pipeline_ms_p50_ci_high',
    'pipeline_ms_p99',
    'pipeline_ms_p99_ci_low',
    'pipeline_ms_p99_ci_high',
    'pipeline_ms_max',
    'recorded_latency_note',
)
#: Tag accuracy of tag backends against tag ground truth (``replaybench.tasks.tags.scoring``), after
#: ``warnings``; empty for other backends.
TAG_SUMMARY_COLUMNS: tuple[str, ...] = (
    'tag_recall',
    'tag_wrong_ids',
    'tag_phantoms',
    'tag_corner_rmse_px',
    'tag_trans_err_m',
    'tag_trans_err_pct',
    'tag_rot_err_deg',
)

#: Columns of summary.csv, in order (later additions at the end, so older readers keep working).
SUMMARY_CSV_COLUMNS: tuple[str, ...] = (
    'backend',
    'topic',
    *COUNT_COLUMNS,
    *STATISTICS_COLUMNS,
    *ACCURACY_COLUMNS,
    *RESOURCE_COLUMNS,
    *INTERVAL_COLUMNS,
    'warnings',
    *SEGMENTATION_SUMMARY_COLUMNS,
    *RECORDED_COLUMNS,
    *TAG_SUMMARY_COLUMNS,
)

#: The columns holding text; ``INTEGER_COLUMNS`` hold integers, the others numbers.
TEXT_COLUMNS: tuple[str, ...] = ('backend', 'topic', 'warnings', 'recorded_latency_note')
#: The columns holding integers: the frame counts and the recorded outputs' counts.
INTEGER_COLUMNS: tuple[str, ...] = (*COUNT_COLUMNS, 'recorded_outputs', 'recorded_outputs_dropped')


def summary_cell(value: Any) -> str:
    """One summary.csv cell: floats to 4 decimals, non-finite and None empty, text escaped."""
    if value is None:
        return ''
    if isinstance(value, bool):
        return '1' if value else '0'
    if isinstance(value, float):
        return format(value, '.4f') if math.isfinite(value) else ''
    return csv_text(value) if isinstance(value, str) else str(value)
