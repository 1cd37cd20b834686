"""Compare run folders: latency and throughput ratios with exact rank intervals between blocks
of frames, accuracy deltas, stability flags, and a CI gate whose conditions pass, fail or are
inconclusive (``replaybench compare``)."""

from __future__ import annotations

from replaybench.comparison.core import (
    ACCURACY_METRICS,
    METRICS,
    RECORDED_METRICS,
    TIMING_METRICS,
    Comparison,
    MetricComparison,
    Row,
    compare_runs,
)
from replaybench.comparison.gate import (
    CONDITION_GRAMMAR,
    Condition,
    GateResult,
    Judgement,
    evaluate_gate,
    gate_failed,
    gate_verdict,
    judge_series,
    parse_condition,
)
from replaybench.comparison.main import (
    EXIT_GATE_FAILED,
    EXIT_INCONCLUSIVE,
    format_summary,
)
from replaybench.comparison.output import (
    COMPARISON_SCHEMA_VERSION,
    CSV_COLUMNS,
    comparison_json,
    write_comparison,
)
from replaybench.comparison.runs import CV_LIMIT, RunInfo
from replaybench.comparison.verdict import EXIT_STATUS, VERDICTS, Verdict, decide
from replaybench.results.blocks import (
    BLOCK_FRAMES,
    MAX_BLOCKS,
    MIN_BLOCKS,
    ChangeInterval,
    change_interval,
)
from replaybench.results.bootstrap import (
    CONFIDENCE,
    DEFAULT_RESAMPLES,
    MIN_FRAMES,
    Replicates,
    block_length,
    ratio_ci,
    replicates,
)
from replaybench.results.exact import ratio_interval, shift_interval

__all__ = [
    'ACCURACY_METRICS',
    'BLOCK_FRAMES',
    'COMPARISON_SCHEMA_VERSION',
    'CONDITION_GRAMMAR',
    'CONFIDENCE',
    'CSV_COLUMNS',
    'CV_LIMIT',
    'DEFAULT_RESAMPLES',
    'EXIT_GATE_FAILED',
    'EXIT_INCONCLUSIVE',
    'EXIT_STATUS',
    'MAX_BLOCKS',
    'METRICS',
    'MIN_BLOCKS',
    'MIN_FRAMES',
    'RECORDED_METRICS',
    'TIMING_METRICS',
    'VERDICTS',
    'ChangeInterval',
    'Comparison',
    'Condition',
    'GateResult',
    'Judgement',
    'MetricComparison',
    'Replicates',
    'Row',
    'RunInfo',
    'Verdict',
    'block_length',
    'change_interval',
    'compare_runs',
    'comparison_json',
    'decide',
    'evaluate_gate',
    'format_summary',
    'gate_failed',
    'gate_verdict',
    'judge_series',
    'parse_condition',
    'ratio_ci',
    'ratio_interval',
    'replicates',
    'shift_interval',
    'write_comparison',
]
