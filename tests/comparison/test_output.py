from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest
from runbuilder import TOPIC, latencies, write_run

from replaybench.app.compare import main_compare
from replaybench.comparison import (
    COMPARISON_SCHEMA_VERSION,
    CSV_COLUMNS,
    compare_runs,
    evaluate_gate,
    write_comparison,
)

REPO = Path(__file__).resolve().parents[2]
HOSTILE = '<script>alert(1)</script>'


def _read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline='', encoding='utf-8') as file:
        return list(csv.DictReader(file))


def _regression(tmp_path: Path) -> list[Path]:
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): latencies(600, 10.0, seed=1)})
    b = write_run(
        tmp_path / 'b',
        {('hsv', TOPIC): latencies(600, 10.0, seed=2) * 1.5},
        sha256='cd' * 32,
        cpu={'governor': 'powersave'},
    )
    return [a, b]


def test_the_three_files_hold_rows_ratios_cis_flags_and_gate(tmp_path: Path) -> None:
    comparison = compare_runs(_regression(tmp_path), n_boot=300)
    conditions = ['p99_ms > +10%', 'fps < -50%']
    gate = evaluate_gate(comparison, conditions)
    csv_path, html_path = write_comparison(
        comparison, tmp_path / 'out', gate=gate, conditions=conditions
    )
    rows = _read_csv(csv_path)
    with csv_path.open(encoding='utf-8') as file:
        assert tuple(next(csv.reader(file))) == CSV_COLUMNS
    assert [(r['role'], r['backend'], r['topic']) for r in rows] == [
        ('baseline', 'hsv', TOPIC),
        ('candidate', 'hsv', TOPIC),
    ]
    cand = rows[1]
    assert float(cand['p99_ms_ci_low']) > 1.1
    assert (
        float(cand['p99_ms_ci_low']) < float(cand['p99_ms_ratio']) < float(cand['p99_ms_ci_high'])
    )
    assert cand['p99_ms_significant'] == 'yes'
    assert cand['inputs_match'] == 'no'
    assert 'CPU governor powersave' in cand['flags']
    assert rows[0]['p99_ms_ratio'] == ''

    doc = json.loads((tmp_path / 'out' / 'comparison.json').read_text(encoding='utf-8'))
    assert doc['schema_version'] == COMPARISON_SCHEMA_VERSION
    assert doc['inputs_match'] is False
    assert doc['statistics']['resamples'] == 300
    assert doc['statistics']['confidence'] == 0.95
    assert doc['gate']['passed'] is False
    assert [r['failed'] for r in doc['gate']['results']] == [True, False]
    p99 = doc['rows'][1]['metrics']['p99_ms']
    assert p99['significant'] is True
    assert len(p99['ratio_ci']) == 2
    assert doc['warnings'][0].startswith('INPUTS DIFFER')

    html = html_path.read_text(encoding='utf-8')
    assert 'sha256 mismatch' in html
    assert 'Gate <span class="badge fail">FAIL</span>' in html
    assert html.count('<svg') == 2  # the CDF and the p50/p99 whiskers of the one group
    assert 'significant</span>' in html


def test_identical_runs_show_not_significant_badges(tmp_path: Path) -> None:
    series = latencies(400, 10.0, seed=3)
    dirs = [
        write_run(tmp_path / 'a', {('hsv', TOPIC): series}),
        write_run(tmp_path / 'b', {('hsv', TOPIC): series}),
    ]
    _, html_path = write_comparison(compare_runs(dirs, n_boot=200), tmp_path / 'out')
    html = html_path.read_text(encoding='utf-8')
    assert html.count('not significant</span>') == 4  # median, p99, mean, fps
    assert 'inputs match' in html
    assert 'id="gate"' not in html


def test_html_is_self_contained_and_escapes_every_text_from_the_runs(tmp_path: Path) -> None:
    backend, topic = f'b{HOSTILE}', f'/cam/{HOSTILE}'
    series = latencies(100, 5.0, seed=1)
    a = write_run(
        tmp_path / 'a',
        {(backend, topic): series},
        cpu={'model': f'CPU {HOSTILE}', 'governor': HOSTILE},
        gpus=[HOSTILE],
        info={backend: {'engine': HOSTILE}},
        bag=f'/bags/{HOSTILE}.mcap',
    )
    b = write_run(
        tmp_path / f'run{HOSTILE.replace("/", "_")}',
        {(backend, topic): series * 1.2},
        sha256='ef' * 32,
        bag=f'/bags/{HOSTILE}2.mcap',
    )
    main_compare([a, b], tmp_path / 'out', ['p99_ms > +1%'], echo=lambda _: None,
                 echo_err=lambda _: None)  # fmt: skip
    html = (tmp_path / 'out' / 'comparison.html').read_text(encoding='utf-8')
    assert '<script' not in html
    assert html.count('&lt;script&gt;') > 10
    assert not re.search(r'(?:src|href)=["\']?(?:https?:)?//', html)
    assert '<link' not in html
    assert '@import' not in html
    # the same input gives the same bytes
    main_compare([a, b], tmp_path / 'out2', ['p99_ms > +1%'], echo=lambda _: None,
                 echo_err=lambda _: None)  # fmt: skip
    assert (tmp_path / 'out2' / 'comparison.html').read_text(encoding='utf-8') == html
    assert (tmp_path / 'out2' / 'comparison.json').read_bytes().replace(b'out2', b'out') == (
        tmp_path / 'out' / 'comparison.json'
    ).read_bytes()


def test_main_prints_the_summary_and_warnings(tmp_path: Path) -> None:
    out: list[str] = []
    err: list[str] = []
    code = main_compare(
        _regression(tmp_path), tmp_path / 'out', ['median_ms > +10%'], n_boot=200,
        echo=out.append, echo_err=err.append,
    )  # fmt: skip
    assert code == 1
    assert out[0].startswith('baseline: a (')
    assert any(re.search(r'· hsv · .*: median ×1\.[45]\d\d \[', line) for line in out)
    assert err[0].startswith('replaybench: warning: INPUTS DIFFER')
    # every file written is named
    assert out[-3:] == [
        f'Comparison: {tmp_path / "out" / "comparison.html"}',
        f'CSV: {tmp_path / "out" / "comparison.csv"}',
        f'JSON: {tmp_path / "out" / "comparison.json"}',
    ]


@pytest.fixture(scope='module')
def real_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from replaybench.app.run import RunConfig, run_benchmark

    bag = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
    if not bag.is_file():
        pytest.skip(f'{bag} missing')
    base = tmp_path_factory.mktemp('real')
    dirs: list[Path] = []
    for name in ('first', 'second'):
        outcome = run_benchmark(
            RunConfig(inputs=[bag], backends=['null', 'hsv'], out_dir=base / name, report=False)
        )
        assert outcome.run_dir is not None
        dirs.append(outcome.run_dir)
    return dirs[0], dirs[1]


def test_real_runs_of_the_same_bag_compare_per_backend(
    real_runs: tuple[Path, Path], tmp_path: Path
) -> None:
    comparison = compare_runs(list(real_runs), n_boot=200)
    assert comparison.inputs_match is True
    assert [(r.role, r.backend) for r in comparison.rows] == [
        ('baseline', 'null'),
        ('baseline', 'hsv'),
        ('candidate', 'null'),
        ('candidate', 'hsv'),
    ]
    hsv = comparison.rows[3]
    assert hsv.metrics['map50'].value is not None
    assert hsv.metrics['map50'].diff == pytest.approx(0.0)  # the same detections both times
    assert hsv.metrics['median_ms'].ratio is not None
    csv_path, html_path = write_comparison(comparison, tmp_path / 'out')
    assert len(_read_csv(csv_path)) == 4
    assert html_path.stat().st_size > 1000


def test_one_real_run_compares_hsv_with_null(real_runs: tuple[Path, Path], tmp_path: Path) -> None:
    out: list[str] = []
    code = main_compare(
        [real_runs[0]], tmp_path / 'out', ['map50 < -0.5'], echo=out.append,
        echo_err=lambda _: None,
    )  # fmt: skip
    assert code == 0  # hsv finds the fixture's blobs, null finds nothing: map50 goes up
    assert any('hsv' in line and 'vs null' in line for line in out)


def test_a_whole_run_ratio_outside_the_interval_is_printed_beside_the_typical_ratio() -> None:
    from replaybench.comparison.core import MetricComparison
    from replaybench.comparison.main import ratio_text

    inside = MetricComparison(
        'p99_ms', 9.0, ratio=1.02, ratio_ci=(0.8, 1.27), typical_ratio=1.03, method='per-frame'
    )
    assert ratio_text(inside) == '×1.020 [0.800, 1.270] n.s.'
    outside = MetricComparison(
        'p99_ms', 7.0, ratio=0.775, ratio_ci=(0.797, 1.267), typical_ratio=1.027
    )
    assert ratio_text(outside) == '×0.775 (typical ×1.027 [0.797, 1.267]) n.s.'
    slower = MetricComparison('median_ms', 20.0, ratio=2.0, ratio_ci=(1.9, 2.1), typical_ratio=2.0)
    assert ratio_text(slower) == '×2.000 [1.900, 2.100]'
    assert ratio_text(MetricComparison('mean_ms', None)) == 'n/a'
    assert ratio_text(MetricComparison('fps', 5.0, ratio=1.1)) == '×1.100 (no CI)'
