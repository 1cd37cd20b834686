"""comparison.csv, comparison.json and comparison.html in an output folder."""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench._version import __version__
from replaybench.comparison.core import (
    ACCURACY_METRICS,
    RECORDED_METRICS,
    RIG_METRICS,
    RIG_POINT_METRICS,
    TAG_METRICS,
    TIMING_METRICS,
)
from replaybench.comparison.gate import gate_verdict, method_text
from replaybench.comparison.repeats import MIN_SINGLE_PASS_S
from replaybench.comparison.runs import CV_LIMIT, engine_text
from replaybench.comparison.verdict import EXIT_STATUS
from replaybench.results.atomic import write_text_atomic
from replaybench.results.blocks import BLOCK_FRAMES, MAX_BLOCKS, MIN_BLOCKS
from replaybench.results.bootstrap import MIN_FRAMES
from replaybench.results.io import from_document, write_comparison_result
from replaybench.results.model import COMPARISON_SCHEMA_VERSION
from replaybench.results.model import Comparison as ComparisonResult
from replaybench.results.records import csv_writer
from replaybench.textsafe import csv_text

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.comparison.core import Comparison, MetricComparison, Row
    from replaybench.comparison.gate import GateResult
    from replaybench.comparison.paired import Paired

__all__ = [
    'COMPARISON_SCHEMA_VERSION',
    'CSV_COLUMNS',
    'PAIRED_COLUMNS',
    'comparison_json',
    'csv_rows',
    'write_comparison',
]

_TIMING_SUFFIXES = (
    '',
    '_baseline',
    '_ratio',
    '_typical_ratio',
    '_ci_low',
    '_ci_high',
    '_significant',
)
_ACCURACY_SUFFIXES = ('', '_baseline', '_delta')

#: comparison.csv's paired columns (appended last): the metric paired (``map50`` for boxes,
#: ``miou`` for label masks), its change over the frames both backends output, its paired
#: bootstrap interval, and the agreement of their outputs.
PAIRED_COLUMNS: tuple[str, ...] = (
    'paired_metric',
    'paired_frames',
    'paired_delta',
    'paired_ci_low',
    'paired_ci_high',
    'paired_resamples',
    'paired_confidence',
    'agreement_matched',
    'agreement_iou',
    'agreement_matched_min',
    'agreement_full_frames',
    'paired_note',
)

#: Columns of comparison.csv, in order.
CSV_COLUMNS: tuple[str, ...] = (
    'run',
    'run_index',
    'run_dir',
    'role',
    'backend',
    'topic',
    'baseline_run',
    'baseline_backend',
    'measured',
    'block_length',
    'latency_cv',
    'inputs_match',
    'ci_method',
    *(m + s for m in TIMING_METRICS for s in _TIMING_SUFFIXES),
    *(m + s for m in ACCURACY_METRICS for s in _ACCURACY_SUFFIXES),
    'gate',
    'gate_conditions',
    'flags',
    # tag backends (appended, so that older readers keep their columns)
    *(m + s for m in TAG_METRICS for s in _ACCURACY_SUFFIXES),
    # the recorded outputs' latency (``recorded`` backend; appended likewise)
    *(m + s for m in RECORDED_METRICS for s in _TIMING_SUFFIXES),
    'recorded_ci_method',
    'recorded_outputs',
    'recorded_latency_note',
    # a rig row's metrics (appended likewise; empty on camera rows)
    *(
        m + s
        for m in RIG_METRICS
        for s in (_ACCURACY_SUFFIXES if m in RIG_POINT_METRICS else _TIMING_SUFFIXES)
    ),
    # a candidate row of boxes against its baseline frame by frame (comparison.paired)
    *PAIRED_COLUMNS,
)


def _yes_no(value: bool | None) -> str | None:
    return None if value is None else ('yes' if value else 'no')


def _row_gate(row: Row, gate: Sequence[GateResult]) -> tuple[str | None, str | None]:
    """The row's verdict over the conditions judged on it, and ``condition: verdict`` each."""
    mine = [
        r for r in gate if (r.run, r.backend, r.topic) == (row.run_label, row.backend, row.topic)
    ]
    if not mine:
        return None, None
    return gate_verdict(mine), '; '.join(f'{r.condition}: {r.verdict}' for r in mine)


def csv_rows(comparison: Comparison, gate: Sequence[GateResult] = ()) -> list[dict[str, Any]]:
    """One dict per row with the ``CSV_COLUMNS`` keys (None = empty cell)."""
    base = comparison.baseline_run
    out = []
    for row in comparison.rows:
        verdict, detail = _row_gate(row, gate)
        record: dict[str, Any] = {
            'run': row.run_label,
            'run_index': row.run,
            'run_dir': str(comparison.runs[row.run].dir),
            'role': row.role,
            'backend': row.backend,
            'topic': row.topic,
            'baseline_run': base.label if row.baseline_backend is not None else None,
            'baseline_backend': row.baseline_backend,
            'measured': row.measured,
            'block_length': row.block_length,
            'latency_cv': row.latency_cv,
            'inputs_match': _yes_no(row.inputs_match),
            'ci_method': method_text(row.metrics['median_ms']) or None,
            'gate': verdict,
            'gate_conditions': detail,
            'flags': '; '.join(row.flags),
            'recorded_ci_method': method_text(row.metrics['recorded_pipeline_ms']) or None,
            'recorded_outputs': row.recorded_outputs,
            'recorded_latency_note': row.recorded_note or None,
        }
        timed = [m for m in RIG_METRICS if m not in RIG_POINT_METRICS]
        for metric in (*TIMING_METRICS, *RECORDED_METRICS, *timed):
            m = row.metrics[metric]
            ci = m.ratio_ci
            record[metric] = m.value
            record[f'{metric}_baseline'] = m.baseline
            record[f'{metric}_ratio'] = m.ratio
            record[f'{metric}_typical_ratio'] = m.typical_ratio
            record[f'{metric}_ci_low'] = ci[0] if ci else None
            record[f'{metric}_ci_high'] = ci[1] if ci else None
            record[f'{metric}_significant'] = _yes_no(m.significant)
        for metric in (*ACCURACY_METRICS, *TAG_METRICS, *RIG_POINT_METRICS):
            m = row.metrics[metric]
            record[metric] = m.value
            record[f'{metric}_baseline'] = m.baseline
            record[f'{metric}_delta'] = m.diff
        record.update(_paired_cells(row.paired))
        out.append(record)
    return out


def _paired_cells(paired: Paired | None) -> dict[str, Any]:
    if paired is None:
        return dict.fromkeys(PAIRED_COLUMNS)
    ci = paired.ci
    return {
        'paired_metric': paired.metric,
        'paired_frames': paired.frames,
        'paired_delta': paired.change,
        'paired_ci_low': ci[0] if ci else None,
        'paired_ci_high': ci[1] if ci else None,
        'paired_resamples': paired.resamples or None,
        'paired_confidence': paired.confidence if ci else None,
        'agreement_matched': paired.matched_mean,
        'agreement_iou': paired.iou_mean,
        'agreement_matched_min': paired.matched_min,
        'agreement_full_frames': paired.agreeing_frames
        if paired.matched_mean is not None
        else None,
        'paired_note': paired.note or None,
    }


def _cell(value: Any) -> str:
    if value is None:
        return ''
    if isinstance(value, bool):
        return 'yes' if value else 'no'
    if isinstance(value, float):
        return format(value, '.6g') if math.isfinite(value) else ''
    return csv_text(value) if isinstance(value, str) else str(value)


def _csv_text(comparison: Comparison, gate: Sequence[GateResult]) -> str:
    buffer = io.StringIO()
    writer = csv_writer(buffer)
    writer.writerow(CSV_COLUMNS)
    for record in csv_rows(comparison, gate):
        writer.writerow([_cell(record[name]) for name in CSV_COLUMNS])
    return buffer.getvalue()


def _interval(ci: tuple[float, float] | None) -> list[float] | None:
    return [ci[0], ci[1]] if ci is not None else None


def _metric_json(m: MetricComparison) -> dict[str, Any]:
    return {
        'value': m.value,
        'value_ci': _interval(m.value_ci),
        'baseline': m.baseline,
        'ratio': m.ratio,
        'ratio_ci': _interval(m.ratio_ci),
        'diff': m.diff,
        'diff_ci': _interval(m.diff_ci),
        'typical_ratio': m.typical_ratio,
        'typical_diff': m.typical_diff,
        'method': m.method,
        'blocks': list(m.blocks) if m.blocks is not None else None,
        'significant': m.significant,
    }


def _row_json(row: Row) -> dict[str, Any]:
    return {
        'run': row.run_label,
        'run_index': row.run,
        'role': row.role,
        'backend': row.backend,
        'topic': row.topic,
        'baseline_backend': row.baseline_backend,
        'measured': row.measured,
        'block_length': row.block_length,
        'latency_cv': row.latency_cv,
        'inputs_match': row.inputs_match,
        'flags': list(row.flags),
        'metrics': {name: _metric_json(m) for name, m in row.metrics.items()},
        'paired': _paired_json(row.paired) if row.paired is not None else None,
    }


def _paired_json(paired: Paired) -> dict[str, Any]:
    return {
        'metric': paired.metric,
        'frames': paired.frames,
        'baseline': paired.baseline,
        'candidate': paired.candidate,
        'change': paired.change,
        'ci': _interval(paired.ci),
        'resamples': paired.resamples,
        'undefined': paired.undefined,
        'confidence': paired.confidence,
        'seed': paired.seed,
        'matched_mean': paired.matched_mean,
        'iou_mean': paired.iou_mean,
        'matched_min': paired.matched_min,
        'agreeing_frames': paired.agreeing_frames,
        'worst': [f._asdict() for f in paired.worst],
        'note': paired.note,
    }


def comparison_json(
    comparison: Comparison,
    *,
    gate: Sequence[GateResult] = (),
    conditions: Sequence[str] = (),
    strict: bool = False,
    allow_inconclusive: bool = False,
) -> dict[str, Any]:
    """The comparison.json document."""
    runs = [
        {
            'index': run.index,
            'label': run.label,
            'dir': str(run.dir),
            'status': run.status,
            'hostname': run.hostname,
            'cpu_model': run.cpu_model,
            'cores': run.cores,
            'governor': run.governor,
            'load_average': run.load_average,
            'gpus': list(run.gpus),
            'inputs': [
                {'path': p, 'sha256': s}
                for p, s in zip(run.input_paths, run.input_sha256, strict=True)
            ],
            'settings': run.settings,
            'backends': {
                label: {'engine': engine_text(info)} for label, info in run.backend_info.items()
            },
        }
        for run in comparison.runs
    ]
    return {
        'schema_version': COMPARISON_SCHEMA_VERSION,
        'tool': {'name': 'replaybench', 'version': __version__},
        'baseline': {
            'run': comparison.baseline_run.label,
            'index': comparison.baseline,
            'backend': comparison.baseline_backend,
        },
        'inputs_match': comparison.inputs_match,
        'statistics': {
            'ratio': 'candidate / baseline of the whole runs (summary.csv values)',
            'ratio_ci': (
                'exact Mann-Whitney (Moses) interval of the Hodges-Lehmann ratio between '
                'blocks of consecutive frames, each block summarised by the metric; '
                f'per frame below {MIN_FRAMES} measured frames; when both runs have two or more '
                '--repeat passes: Welch t interval between the passes (log values for ratios), '
                'the method named per row'
            ),
            'blocks': (
                f'clamp(n // {BLOCK_FRAMES}, {MIN_BLOCKS}, {MAX_BLOCKS}) blocks per series, '
                'in replay order'
            ),
            'significant': 'ratio CI excludes 1.0',
            'verdicts': (
                'failed: the whole CI past the threshold; passed: none of it; '
                'inconclusive: it straddles the threshold or there is no CI, or a failure rests '
                f'on a single pass shorter than {MIN_SINGLE_PASS_S:g} s with a stability warning'
            ),
            'value_ci': 'circular block bootstrap over measured frames in replay order',
            'block_length': 'max(ceil(n ** (1/3)), Politis-White estimate) frames, per series',
            'resamples': comparison.n_boot,
            'seed': comparison.seed,
            'confidence': comparison.confidence,
            'interval': 'percentile',
            'min_frames': MIN_FRAMES,
            'cv_limit': CV_LIMIT,
            'accuracy': (
                'point estimates from run.json; a candidate row of boxes over its baseline '
                "row's frames (one run, or runs of the same inputs) also gets the map50 "
                'change over the frames both output with a bootstrap interval paired by frame '
                '(rows[].paired: the same resampled frames scored for both backends by the '
                "run's own scoring, numpy default_rng(seed), percentile interval) and the "
                "agreement of the two backends' boxes per frame; the gate judges accuracy on "
                'the point estimate'
            ),
            'recorded': (
                "recorded_* metrics (recorded backend rows): the recorded outputs' pipeline "
                '(output log time - image log time) and capture-to-output (output log time - '
                'image header stamp) latency, median and p99 as in summary.csv; compared as '
                'the timing metrics, between blocks of consecutive outputs in log-time order, '
                f'output by output below {MIN_FRAMES}; null for a replayed row and for a '
                'figure the run refused (recorded_latency_note)'
            ),
        },
        'warnings': list(comparison.warnings),
        'runs': runs,
        'rows': [_row_json(r) for r in comparison.rows],
        'gate': _gate_json(gate, conditions, strict, allow_inconclusive) if conditions else None,
    }


def _gate_json(
    gate: Sequence[GateResult],
    conditions: Sequence[str],
    strict: bool,
    allow_inconclusive: bool,
) -> dict[str, Any]:
    verdict = gate_verdict(gate)
    code = EXIT_STATUS[verdict]
    if verdict == 'inconclusive' and allow_inconclusive:
        code = 0
    return {
        'conditions': list(conditions),
        'strict': strict,
        'allow_inconclusive': allow_inconclusive,
        'verdict': verdict,
        'passed': verdict == 'passed',
        'exit_status': code,
        'results': [r._asdict() for r in gate],
    }


def write_comparison(
    comparison: Comparison,
    out_dir: str | Path,
    *,
    gate: Sequence[GateResult] = (),
    conditions: Sequence[str] = (),
    strict: bool = False,
    allow_inconclusive: bool = False,
) -> tuple[Path, Path]:
    """Write comparison.csv, comparison.html and comparison.json into ``out_dir``.

    Returns the paths of the CSV and the HTML page; comparison.json lies beside them.
    """
    from replaybench.comparison.html import render_comparison_html

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / 'comparison.csv'
    html_path = out / 'comparison.html'
    write_text_atomic(csv_path, _csv_text(comparison, gate))
    document = comparison_json(
        comparison,
        gate=gate,
        conditions=conditions,
        strict=strict,
        allow_inconclusive=allow_inconclusive,
    )
    write_comparison_result(out / 'comparison.json', from_document(ComparisonResult, document))
    write_text_atomic(
        html_path,
        render_comparison_html(
            comparison,
            gate=gate,
            conditions=conditions,
            strict=strict,
            allow_inconclusive=allow_inconclusive,
        ),
    )
    return csv_path, html_path
