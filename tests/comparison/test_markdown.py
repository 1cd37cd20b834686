"""compare --markdown: a GitHub-flavoured table of the comparison and the gate, escaped, under
its size limit; report --github-benchmark: github-action-benchmark's custom format."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parent))

from runbuilder import TOPIC, latencies, write_run

from replaybench.cli import app
from replaybench.comparison import compare_runs, evaluate_gate
from replaybench.comparison.markdown import comparison_markdown
from replaybench.report.github_benchmark import github_benchmark
from replaybench.results.folder import load_run

runner = CliRunner()


def _pair(tmp_path: Path, slower: float, backend: str = 'hsv') -> tuple[Path, Path]:
    base = write_run(tmp_path / 'base', {(backend, TOPIC): latencies(300, 10.0, seed=1)})
    cand = write_run(tmp_path / 'cand', {(backend, TOPIC): latencies(300, 10.0 * slower, seed=2)})
    return base, cand


def test_the_markdown_has_the_verdict_line_the_rows_and_each_condition(tmp_path):
    base, cand = _pair(tmp_path, 1.5)
    comparison = compare_runs([base, cand])
    gate = evaluate_gate(comparison, ['median_ms > +10%', 'map50 < -0.02'])
    text = comparison_markdown(comparison, gate)
    lines = text.splitlines()
    assert lines[0].startswith('❌ **replaybench gate: FAILED** (1 of 2 checks, 1 inconclusive)')
    assert '| run | backend | topic | median | p99 | mean | fps | mAP@0.5 Δ | method |' in lines
    row = next(line for line in lines if line.startswith('| cand'))
    assert '| between-block 10/10 |' in row
    assert '×1.5' in row
    checks = [line for line in lines if line.startswith(('| median_ms', '| map50'))]
    assert len(checks) == 2
    assert checks[0].endswith('❌ FAIL |')
    assert checks[1].endswith('⚠️ inconclusive |')


def test_text_from_run_folders_cannot_break_the_table_or_inject_html(tmp_path):
    odd = 'a|b<script>'
    base, cand = _pair(tmp_path, 1.0, backend=odd)
    text = comparison_markdown(compare_runs([base, cand]))
    assert '<script>' not in text
    assert 'a\\|b&lt;script&gt;' in text
    assert text.startswith('**replaybench compare**: no gate conditions')


def test_the_markdown_stays_under_its_size_limit_and_says_what_it_left_out(tmp_path):
    base, cand = _pair(tmp_path, 1.0)
    comparison = compare_runs([base, cand])
    gate = evaluate_gate(comparison, ['median_ms > +10%'] * 50)
    text = comparison_markdown(comparison, gate, max_bytes=3000)
    assert len(text.encode()) <= 3000
    assert 'more checks left out (size limit)' in text


def test_compare_writes_the_markdown_file_and_an_unwritable_one_exits_2(tmp_path):
    base, cand = _pair(tmp_path, 1.5)
    out = tmp_path / 'summary.md'
    args = ['compare', str(base), str(cand), '--fail-if', 'median_ms > +10%']
    result = runner.invoke(app, [*args, '--markdown', str(out)])
    assert result.exit_code == 1
    assert f'Markdown: {out}' in result.output
    assert 'replaybench gate: FAILED' in out.read_text(encoding='utf-8')
    blocked = tmp_path / 'file'
    blocked.write_text('x')
    result = runner.invoke(app, [*args, '--markdown', str(blocked / 'summary.md')])
    assert result.exit_code == 2
    assert 'cannot write' in result.output


def test_github_benchmark_entries_come_from_the_run_in_memory(tmp_path):
    base, _ = _pair(tmp_path, 1.0)
    smaller, bigger = github_benchmark(load_run(base).run)
    names = [e['name'] for e in smaller]
    assert names == [
        f'hsv {TOPIC} p50 latency',
        f'hsv {TOPIC} p99 latency',
        f'hsv {TOPIC} mean latency',
    ]
    assert all(e['unit'] == 'ms' for e in smaller)
    assert not any('range' in e for e in smaller)  # this run.json holds no interval
    (fps,) = bigger
    assert fps['unit'] == 'frames/s'
    assert 90 < fps['value'] < 110  # 10 ms frames back to back
    assert '300 measured frames' in fps['extra']


def test_the_range_is_the_half_width_of_the_run_json_interval(tmp_path):
    base, _ = _pair(tmp_path, 1.0)
    run = load_run(base).run
    (row,) = run.summary_rows
    row = dataclasses.replace(row, latency_ms_p50_ci_low=9.5, latency_ms_p50_ci_high=10.5)
    smaller, _ = github_benchmark(dataclasses.replace(run, summary_rows=(row,)))
    assert smaller[0]['range'] == '± 0.5'
    assert 'range' not in smaller[2]  # the mean has no interval in run.json


def test_report_writes_both_benchmark_files(tmp_path):
    base, _ = _pair(tmp_path, 1.0)
    out = tmp_path / 'bench'
    result = runner.invoke(app, ['report', str(base), '--github-benchmark', str(out)])
    assert result.exit_code == 0, result.output
    for name in ('smaller_is_better.json', 'bigger_is_better.json'):
        entries = json.loads((out / name).read_text(encoding='utf-8'))
        assert isinstance(entries, list)
        assert entries
        assert all(isinstance(e['value'], float) for e in entries)
