"""Verdicts that hold: small samples judged exactly, inconclusive as a verdict, a noise-robust
interval, and the one decision function behind them, table-driven."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from runbuilder import TOPIC, latencies, write_run
from typer.testing import CliRunner

from replaybench.app.compare import main_compare
from replaybench.cli import app
from replaybench.comparison import (
    EXIT_STATUS,
    compare_runs,
    decide,
    evaluate_gate,
    gate_verdict,
    judge_series,
    ratio_interval,
    shift_interval,
)
from replaybench.errors import UsageError
from replaybench.results.exact import mann_whitney_null, moses_cut

if TYPE_CHECKING:
    import numpy.typing as npt

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
GATE = ['p50_ms > +10%', 'p99_ms > +10%', 'mean_ms > +10%', 'fps < -10%']


# ---------------------------------------------------------------- the decision, table-driven


@pytest.mark.parametrize(
    ('interval', 'op', 'threshold', 'expected'),
    [
        ((12.0, 30.0), '>', 10.0, 'failed'),
        ((10.0, 30.0), '>', 10.0, 'inconclusive'),  # touching the threshold is not past it
        ((10.0, 30.0), '>=', 10.0, 'failed'),
        ((-5.0, 10.0), '>', 10.0, 'passed'),
        ((-5.0, 10.0), '>=', 10.0, 'inconclusive'),
        ((-5.0, 9.99), '>=', 10.0, 'passed'),
        ((5.0, 15.0), '>', 10.0, 'inconclusive'),
        ((-30.0, -12.0), '<', -10.0, 'failed'),
        ((-30.0, -10.0), '<', -10.0, 'inconclusive'),
        ((-30.0, -10.0), '<=', -10.0, 'failed'),
        ((-10.0, 5.0), '<', -10.0, 'passed'),
        ((-10.0 + 1e-12, 5.0), '<=', -10.0, 'inconclusive'),  # within rounding of the threshold
        (None, '>', 10.0, 'inconclusive'),
    ],
)
def test_an_interval_past_the_threshold_fails_one_short_of_it_passes_one_across_is_undecided(
    interval: tuple[float, float] | None, op: str, threshold: float, expected: str
) -> None:
    assert decide(None, interval, op, threshold) == expected


@pytest.mark.parametrize(
    ('estimate', 'op', 'expected'),
    [
        (10.5, '>', 'failed'),
        (10.0, '>', 'passed'),
        (10.0, '>=', 'failed'),
        (None, '>', 'inconclusive'),
    ],
)
def test_a_point_estimate_is_failed_or_passed_and_inconclusive_only_when_missing(
    estimate: float | None, op: str, expected: str
) -> None:
    assert decide(estimate, (0.0, 100.0), op, 10.0, point=True) == expected


def _series(n: int, median_ms: float, seed: int, noise: str) -> npt.NDArray[np.float64]:
    """Latencies of ``n`` frames: ``quiet`` (CV 0.05), ``noisy`` (CV 0.3), or ``phases``
    (CV 0.05, with two stretches of a fifth of the frames each slowed threefold, as a load
    phase slows a run)."""
    if noise == 'noisy':
        return latencies(n, median_ms, seed=seed, cv=0.3, rho=0.0)
    series = latencies(n, median_ms, seed=seed)
    if noise == 'phases':
        series = series.copy()
        stretch = n // 10
        for start in (n // 5, 3 * n // 5):
            series[start : start + stretch] *= 3.0
    return series


def _intervals(latency: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return latency / 1e3  # frames back to back, as at max rate


# (baseline frames, candidate frames, candidate / baseline, noise, condition) -> verdict
VERDICT_TABLE = [
    # nine times slower on every one of 10 frames: P = 2 / C(20, 10) = 1.1e-5
    (10, 10, 8.69, 'quiet', 'p50_ms > +10%', 'failed'),
    (10, 10, 8.69, 'quiet', 'p99_ms > +10%', 'failed'),
    (10, 10, 8.69, 'quiet', 'mean_ms > +10%', 'failed'),
    (10, 10, 8.69, 'quiet', 'fps < -10%', 'failed'),
    # the fewest frames that can decide anything: 4 against 4 (2 / 70), 2 against 8 (2 / 45),
    # 1 against 39 (2 / 40)
    (3, 3, 1.3, 'quiet', 'p50_ms > +10%', 'inconclusive'),
    (3, 3, 9.0, 'quiet', 'p50_ms > +10%', 'inconclusive'),
    (3, 4, 9.0, 'quiet', 'p50_ms > +10%', 'inconclusive'),  # 2 / 35 = 5.7 %
    (4, 4, 9.0, 'quiet', 'p50_ms > +10%', 'failed'),
    (2, 7, 9.0, 'quiet', 'p50_ms > +10%', 'inconclusive'),  # 2 / 36 = 5.6 %
    (2, 8, 9.0, 'quiet', 'p50_ms > +10%', 'failed'),
    (1, 38, 9.0, 'quiet', 'p50_ms > +10%', 'inconclusive'),  # one frame: 2 / 39 at best
    (1, 39, 9.0, 'quiet', 'p50_ms > +10%', 'failed'),  # 2 / 40 = 5 % exactly
    # small samples, small effects: equal passes, too noisy to tell is inconclusive
    (10, 10, 1.0, 'quiet', 'p50_ms > +10%', 'passed'),
    (10, 10, 1.0, 'noisy', 'p50_ms > +10%', 'inconclusive'),
    (10, 10, 0.5, 'quiet', 'p50_ms > +10%', 'passed'),  # an improvement
    # per frame below 20 frames, blocks from 20 on (4 against 4)
    (19, 19, 1.3, 'quiet', 'p50_ms > +10%', 'failed'),
    (20, 20, 1.3, 'quiet', 'p50_ms > +10%', 'failed'),
    (19, 19, 1.0, 'quiet', 'p99_ms > +10%', 'passed'),
    (20, 20, 1.0, 'quiet', 'p99_ms > +10%', 'passed'),
    # full runs
    (300, 300, 1.0, 'quiet', 'p50_ms > +10%', 'passed'),
    (300, 300, 1.3, 'quiet', 'p50_ms > +10%', 'failed'),
    (300, 300, 1.3, 'quiet', 'fps < -10%', 'failed'),
    (300, 300, 1.1, 'quiet', 'p50_ms > +10%', 'inconclusive'),  # a change right at the threshold
    (300, 300, 1.0, 'noisy', 'p99_ms > +10%', 'inconclusive'),
    (300, 300, 1.0, 'quiet', 'mean_ms > +2', 'passed'),  # absolute: ms
    (300, 300, 1.3, 'quiet', 'mean_ms > +2', 'failed'),  # +3 ms
    (300, 300, 1.3, 'quiet', 'mean_ms > +5', 'passed'),
    # load phases in the candidate only: its mean is +40 %, its typical block is unchanged
    (300, 300, 1.0, 'phases', 'mean_ms > +10%', 'passed'),
    (300, 300, 1.0, 'phases', 'p50_ms > +10%', 'passed'),
    (300, 300, 1.3, 'phases', 'mean_ms > +10%', 'failed'),
    (300, 300, 1.3, 'phases', 'p99_ms > +10%', 'failed'),
]


@pytest.mark.parametrize(
    ('n_base', 'n_cand', 'effect', 'noise', 'condition', 'expected'), VERDICT_TABLE
)
def test_the_verdict_follows_sample_sizes_effect_and_noise(
    n_base: int, n_cand: int, effect: float, noise: str, condition: str, expected: str
) -> None:
    base = _series(n_base, 10.0, 1, 'noisy' if noise == 'noisy' else 'quiet')
    cand = _series(n_cand, 10.0 * effect, 2, noise)
    judgement = judge_series(
        base,
        cand,
        condition,
        baseline_intervals_s=_intervals(base),
        candidate_intervals_s=_intervals(cand),
    )
    assert judgement.verdict == expected, judgement
    assert judgement.method == ('per-frame' if min(n_base, n_cand) < 20 else 'between-block')


def test_the_phases_row_of_the_table_has_a_mean_far_past_the_threshold() -> None:
    base = _series(300, 10.0, 1, 'quiet')
    cand = _series(300, 10.0, 2, 'phases')
    judgement = judge_series(base, cand, 'mean_ms > +10%')
    assert judgement.estimate is not None
    assert judgement.estimate > 35.0
    assert judgement.interval is not None
    assert judgement.interval[1] < 10.0
    assert judgement.verdict == 'passed'


def test_judge_series_refuses_accuracy_metrics_and_bad_conditions() -> None:
    with pytest.raises(UsageError, match='timing metrics'):
        judge_series([1.0], [1.0], 'map50 < -0.02')
    with pytest.raises(UsageError, match='bad condition'):
        judge_series([1.0], [1.0], 'p99 > lots')


# ------------------------------------------------------------------ the exact rank machinery


def test_the_exact_null_distribution_matches_enumeration_and_the_textbook_tails() -> None:
    from itertools import combinations

    for m, n in [(1, 1), (2, 5), (3, 3), (4, 6), (6, 5)]:
        counts = np.zeros(m * n + 1)
        for ranks in combinations(range(m + n), m):
            # U: pairs (x, y) with x above y
            counts[sum(r - i for i, r in enumerate(ranks))] += 1
        assert mann_whitney_null(m, n) == pytest.approx(counts / counts.sum(), abs=1e-15)
    assert mann_whitney_null(10, 10)[0] * math.comb(20, 10) == pytest.approx(1.0)
    # two-sided 5 % critical values of U (tables of Mann & Whitney): 23 for 10/10, 127 for 20/20
    assert moses_cut(10, 10, 0.95) == 24
    assert moses_cut(20, 20, 0.95) == 128
    assert moses_cut(3, 3, 0.95) == 0
    assert moses_cut(4, 4, 0.95) == 1


def test_the_ratio_interval_is_the_shift_interval_of_the_logarithms() -> None:
    rng = np.random.default_rng(3)
    x = rng.lognormal(2.0, 0.2, size=12)
    y = rng.lognormal(2.3, 0.2, size=15)
    estimate, interval = ratio_interval(x, y, 0.95)
    log_estimate, log_interval = shift_interval(np.log(x), np.log(y), 0.95)
    assert estimate == pytest.approx(math.exp(log_estimate))  # type: ignore[arg-type]
    assert interval is not None
    assert log_interval is not None
    assert interval == pytest.approx((math.exp(log_interval[0]), math.exp(log_interval[1])))
    assert ratio_interval([1.0, 0.0], [1.0, 2.0], 0.95) == (None, None)
    assert ratio_interval([], [1.0], 0.95) == (None, None)


# ----------------------------------------------------------------------- through the gate


def test_ten_frames_nine_times_slower_fail_every_timing_condition(tmp_path: Path) -> None:
    base = latencies(10, 10.0, seed=1)
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): base})
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): base * 8.69})
    out: list[str] = []
    err: list[str] = []
    code = main_compare(
        [a, b], tmp_path / 'cmp', GATE, n_boot=100, echo=out.append, echo_err=err.append
    )
    assert code == EXIT_STATUS['failed'] == 1
    assert 'gate: FAILED (4 of 4 checks)' in out
    failed = [line for line in err if line.startswith('replaybench: gate: FAIL ')]
    assert len(failed) == 4
    assert all('typical frame' in line and 'the whole CI is' in line for line in failed)


def test_three_frames_a_third_slower_are_inconclusive_everywhere_the_verdict_is_recorded(
    tmp_path: Path,
) -> None:
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): [1.0, 1.02, 0.98]})
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): [1.3, 1.32, 1.28]})
    out: list[str] = []
    err: list[str] = []
    cmp = tmp_path / 'cmp'
    code = main_compare([a, b], cmp, ['p50_ms > +10%'], echo=out.append, echo_err=err.append)
    assert code == 3
    assert 'gate: INCONCLUSIVE (1 of 1 checks undecided)' in out
    assert any(line.startswith('replaybench: gate: INCONCLUSIVE p50_ms > +10%') for line in err)
    doc = json.loads((cmp / 'comparison.json').read_text(encoding='utf-8'))
    assert doc['gate']['verdict'] == 'inconclusive'
    assert doc['gate']['passed'] is False
    assert doc['gate']['exit_status'] == 3
    assert [r['verdict'] for r in doc['gate']['results']] == ['inconclusive']
    with (cmp / 'comparison.csv').open(newline='', encoding='utf-8') as file:
        rows = list(csv.DictReader(file))
    assert [r['gate'] for r in rows] == ['', 'inconclusive']
    assert rows[1]['gate_conditions'] == 'p50_ms > +10%: inconclusive'
    assert rows[1]['ci_method'] == 'per-frame'
    html = (cmp / 'comparison.html').read_text(encoding='utf-8')
    assert 'Gate <span class="badge inconclusive">INCONCLUSIVE</span>' in html
    assert '<title>replaybench comparison · INCONCLUSIVE</title>' in html

    out.clear()
    allowed = main_compare(
        [a, b], tmp_path / 'cmp2', ['p50_ms > +10%'], allow_inconclusive=True,
        echo=out.append, echo_err=err.append,
    )  # fmt: skip
    assert allowed == 0
    assert any(
        line.startswith('gate: inconclusive (1 of 1 checks undecided; allowed') for line in out
    )
    doc = json.loads((tmp_path / 'cmp2' / 'comparison.json').read_text(encoding='utf-8'))
    assert (doc['gate']['verdict'], doc['gate']['exit_status']) == ('inconclusive', 0)


def test_a_failure_outranks_an_inconclusive_condition(tmp_path: Path) -> None:
    base = latencies(3, 10.0, seed=1)
    a = write_run(
        tmp_path / 'a', {('hsv', TOPIC): base, ('null', TOPIC): latencies(300, 1.0, seed=3)}
    )
    b = write_run(
        tmp_path / 'b', {('hsv', TOPIC): base * 1.3, ('null', TOPIC): latencies(300, 2.0, seed=4)}
    )
    gate = evaluate_gate(compare_runs([a, b], n_boot=50), ['p50_ms > +10%'])
    assert sorted(r.verdict for r in gate) == ['failed', 'inconclusive']
    assert gate_verdict(gate) == 'failed'
    out: list[str] = []
    code = main_compare(
        [a, b], tmp_path / 'cmp', ['p50_ms > +10%'], allow_inconclusive=True, n_boot=50,
        echo=out.append, echo_err=lambda _: None,
    )  # fmt: skip
    assert code == 1
    assert 'gate: FAILED (1 of 2 checks, 1 inconclusive)' in out


# ------------------------------------------------------- real runs of a backend of known cost


def _busy_run(tmp_path: Path, name: str, ms: float, *extra: str) -> Path:
    config = tmp_path / f'{name}.toml'
    config.write_text(f'ms = {ms}\n', encoding='utf-8')
    out = tmp_path / name
    result = CliRunner().invoke(
        app,
        ['run', str(RAW), '--backend', 'busy', '--config', str(config), '--out', str(out),
         '--no-report', *extra],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return out


def test_a_fixture_bag_replayed_nine_times_slower_fails_the_gate_on_the_command_line(
    tmp_path: Path,
) -> None:
    if not RAW.is_file():
        pytest.skip(f'{RAW} missing')
    fast = _busy_run(tmp_path, 'fast', 2.0)
    slow = _busy_run(tmp_path, 'slow', 18.0)
    args = ['compare', str(fast), str(slow), '--out', str(tmp_path / 'cmp')]
    for condition in GATE:
        args += ['--fail-if', condition]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1, result.output
    doc = json.loads((tmp_path / 'cmp' / 'comparison.json').read_text(encoding='utf-8'))
    assert [r['verdict'] for r in doc['gate']['results']] == ['failed'] * 4
    row = doc['rows'][1]
    assert row['measured'] == 9  # ten frames, one of them warm-up
    assert row['metrics']['median_ms']['method'] == 'per-frame'


def test_three_real_frames_a_third_slower_exit_3_unless_inconclusive_is_allowed(
    tmp_path: Path,
) -> None:
    if not RAW.is_file():
        pytest.skip(f'{RAW} missing')
    base = _busy_run(tmp_path, 'base', 1.0, '--max-frames', '3')
    cand = _busy_run(tmp_path, 'cand', 1.3, '--max-frames', '3')
    args = ['compare', str(base), str(cand), '--fail-if', 'p50_ms > +10%']
    result = CliRunner().invoke(app, [*args, '--out', str(tmp_path / 'c1')])
    assert result.exit_code == 3, result.output
    assert 'gate: INCONCLUSIVE' in result.output
    allowed = CliRunner().invoke(
        app, [*args, '--out', str(tmp_path / 'c2'), '--allow-inconclusive']
    )
    assert allowed.exit_code == 0, allowed.output
    assert 'gate: inconclusive' in allowed.output
