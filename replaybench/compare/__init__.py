"""Compare run folders: latency and throughput ratios with block-bootstrap CIs, accuracy
deltas, stability flags, and a CI gate (``replaybench compare``)."""

from __future__ import annotations

from replaybench.compare.bootstrap import (
    CONFIDENCE,
    DEFAULT_RESAMPLES,
    MIN_FRAMES,
    Replicates,
    block_length,
    ratio_ci,
    replicates,
)
from replaybench.compare.core import (
    ACCURACY_METRICS,
    METRICS,
    TIMING_METRICS,
    Comparison,
    MetricComparison,
    Row,
    compare_runs,
)
from replaybench.compare.gate import (
    CONDITION_GRAMMAR,
    Condition,
    GateResult,
    evaluate_gate,
    gate_failed,
    parse_condition,
)
from replaybench.compare.main import EXIT_GATE_FAILED, format_summary, main_compare
from replaybench.compare.output import (
    COMPARISON_SCHEMA_VERSION,
    CSV_COLUMNS,
    comparison_json,
    write_comparison,
)
from replaybench.compare.runs import CV_LIMIT, RunInfo

__all__ = [
    'ACCURACY_METRICS',
    'COMPARISON_SCHEMA_VERSION',
    'CONDITION_GRAMMAR',
    'CONFIDENCE',
    'CSV_COLUMNS',
    'CV_LIMIT',
    'DEFAULT_RESAMPLES',
    'EXIT_GATE_FAILED',
    'METRICS',
    'MIN_FRAMES',
    'TIMING_METRICS',
    'Comparison',
    'Condition',
    'GateResult',
    'MetricComparison',
    'Replicates',
    'Row',
    'RunInfo',
    'block_length',
    'compare_runs',
    'comparison_json',
    'evaluate_gate',
    'format_summary',
    'gate_failed',
    'main_compare',
    'parse_condition',
    'ratio_ci',
    'replicates',
    'write_comparison',
]
