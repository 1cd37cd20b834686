from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from runbuilder import TOPIC, latencies, write_run

from replaybench.app.compare import main_compare
from replaybench.comparison import (
    CONDITION_GRAMMAR,
    compare_runs,
    evaluate_gate,
    gate_failed,
    parse_condition,
)
from replaybench.errors import UsageError

if TYPE_CHECKING:
    from pathlib import Path


class Echo:
    def __init__(self) -> None:
        self.out: list[str] = []
        self.err: list[str] = []

    def run(
        self,
        dirs: list[Path],
        out: Path,
        fail_if: list[str],
        strict: bool = False,
        allow_inconclusive: bool = False,
    ) -> int:
        return main_compare(
            dirs, out, fail_if, strict, n_boot=500, allow_inconclusive=allow_inconclusive,
            echo=self.out.append, echo_err=self.err.append,
        )  # fmt: skip


@pytest.mark.parametrize(
    ('text', 'metric', 'op', 'threshold', 'relative'),
    [
        ('p99_ms > +10%', 'p99_ms', '>', 10.0, True),
        ('median_ms>+5%', 'median_ms', '>', 5.0, True),
        ('  fps < -10%  ', 'fps', '<', -10.0, True),
        ('map50 < -0.02', 'map50', '<', -0.02, False),
        ('recall50 <= -0.05', 'recall50', '<=', -0.05, False),
        ('p50_ms >= 2.5', 'median_ms', '>=', 2.5, False),
        ('MEAN_MS > 10 %', 'mean_ms', '>', 10.0, True),
    ],
)
def test_conditions_parse(
    text: str, metric: str, op: str, threshold: float, relative: bool
) -> None:
    condition = parse_condition(text)
    assert (condition.metric, condition.op, condition.threshold, condition.relative) == (
        metric,
        op,
        threshold,
        relative,
    )


@pytest.mark.parametrize(
    'text',
    ['', 'p99_ms', 'p99 > +10%', 'p99_ms >> 10%', 'p99_ms > ten', 'p99_ms > 10%%',
     'p99_ms = 10%', 'map50 < -0.02 or worse', 'p99_ms > +10%; rm -rf /'],
)  # fmt: skip
def test_bad_conditions_are_usage_errors_that_state_the_grammar(text: str) -> None:
    with pytest.raises(UsageError) as info:
        parse_condition(text)
    assert CONDITION_GRAMMAR in str(info.value)
    assert info.value.exit_code == 2


def test_identical_runs_pass_the_gate(tmp_path: Path) -> None:
    series = latencies(800, 10.0, seed=1)
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): series})
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): series})
    echo = Echo()
    conditions = ['p99_ms > +10%', 'median_ms > +5%', 'mean_ms > +10%', 'fps < -10%']
    assert echo.run([a, b], tmp_path / 'out', conditions) == 0
    assert 'gate: passed (4 checks)' in echo.out
    assert not [line for line in echo.err if 'gate:' in line]


def test_a_planted_regression_fails_the_gate_and_names_what_failed(tmp_path: Path) -> None:
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): latencies(1000, 10.0, seed=1)})
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): latencies(1000, 10.0, seed=2) * 1.5})
    echo = Echo()
    assert echo.run([a, b], tmp_path / 'out', ['p99_ms > +10%', 'map50 < -0.02']) == 1
    failed = [line for line in echo.err if line.startswith('replaybench: gate: FAIL')]
    assert len(failed) == 1
    assert 'p99_ms > +10%' in failed[0]
    assert 'hsv' in failed[0]
    assert TOPIC in failed[0]
    assert 'p99 latency' in failed[0]
    assert 'the whole CI is above +10%' in failed[0]
    # neither run has ground truth: the map50 condition cannot be judged
    assert 'gate: FAILED (1 of 2 checks, 1 inconclusive)' in echo.out
    assert any(line.startswith('replaybench: gate: INCONCLUSIVE map50') for line in echo.err)


def test_an_improvement_does_not_fail_a_regression_gate(tmp_path: Path) -> None:
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): latencies(500, 10.0, seed=1)})
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): latencies(500, 10.0, seed=2) * 0.5})
    comparison = compare_runs([a, b], n_boot=300)
    results = evaluate_gate(comparison, ['p99_ms > +10%', 'fps < -10%', 'median_ms < -20%'])
    assert [r.failed for r in results] == [False, False, True]
    assert results[2].estimate is not None
    assert results[2].estimate == pytest.approx(-50, abs=3)


def test_a_borderline_change_is_inconclusive_by_default_and_fails_when_strict(
    tmp_path: Path,
) -> None:
    base = latencies(100, 10.0, seed=1, cv=0.3, rho=0.0)
    cand = np.random.default_rng(9).permutation(base) * 1.06  # median exactly +6 %
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): base})
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): cand})
    comparison = compare_runs([a, b], n_boot=1000)
    (result,) = evaluate_gate(comparison, ['median_ms > +5%'])
    assert result.estimate is not None
    assert result.ci_low is not None
    assert result.estimate > 5.0 > result.ci_low  # past the threshold, its CI is not
    assert result.ci_high is not None
    assert result.ci_high > 5.0
    assert result.verdict == 'inconclusive'
    assert not result.failed
    assert 'the CI straddles +5%' in result.explanation
    (strict,) = evaluate_gate(comparison, ['median_ms > +5%'], strict=True)
    assert strict.failed
    assert strict.verdict == 'failed'
    assert (strict.estimate, strict.ci_low) == (result.estimate, result.ci_low)
    echo = Echo()
    assert echo.run([a, b], tmp_path / 'o1', ['median_ms > +5%']) == 3
    assert 'gate: INCONCLUSIVE (1 of 1 checks undecided)' in echo.out
    assert echo.run([a, b], tmp_path / 'o2', ['median_ms > +5%'], strict=True) == 1
    assert echo.run([a, b], tmp_path / 'o3', ['median_ms > +5%'], allow_inconclusive=True) == 0
    allowed = 'gate: inconclusive (1 of 1 checks undecided; allowed'
    assert any(line.startswith(allowed) for line in echo.out)


def test_absolute_thresholds_use_the_difference_in_the_metric_unit(tmp_path: Path) -> None:
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): latencies(500, 10.0, seed=1)})
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): latencies(500, 13.0, seed=2)})
    comparison = compare_runs([a, b], n_boot=300)
    over2, over5 = evaluate_gate(comparison, ['median_ms > +2', 'median_ms > 5'])
    assert over2.estimate == pytest.approx(3.0, abs=0.3)
    assert over2.failed
    assert not over5.failed
    assert '+3' in over2.explanation or '+2.9' in over2.explanation


def test_accuracy_conditions_are_judged_on_the_point_estimate(tmp_path: Path) -> None:
    series = latencies(100, 10.0, seed=1)
    a = write_run(
        tmp_path / 'a',
        {('hsv', TOPIC): series},
        accuracy={('hsv', TOPIC): {'map50': 0.8, 'recall50': 0.9, 'precision50': 0.9}},
    )
    b = write_run(
        tmp_path / 'b',
        {('hsv', TOPIC): series},
        accuracy={('hsv', TOPIC): {'map50': 0.75, 'recall50': 0.89, 'precision50': 0.9}},
    )
    c = write_run(tmp_path / 'c', {('hsv', TOPIC): series})
    comparison = compare_runs([a, b, c], n_boot=50)
    results = evaluate_gate(comparison, ['map50 < -0.02', 'recall50 < -0.05', 'map50 < -10%'])
    by = {(r.condition, r.run.split(' ')[0]): r for r in results}
    assert by['map50 < -0.02', 'b'].failed
    assert by['map50 < -0.02', 'b'].estimate == pytest.approx(-0.05)
    assert 'no CI' in by['map50 < -0.02', 'b'].explanation
    assert not by['recall50 < -0.05', 'b'].failed
    assert not by['map50 < -10%', 'b'].failed  # -6.25 %
    # the accuracy is gone in run c: that fails a gate on it
    assert by['map50 < -0.02', 'c'].failed
    assert 'the baseline has mAP@0.5 but this run does not' in by['map50 < -0.02', 'c'].explanation


def test_timing_without_ci_is_inconclusive_unless_strict(tmp_path: Path) -> None:
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): latencies(3, 10.0, seed=1)})
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): latencies(3, 10.0, seed=2) * 2})
    comparison = compare_runs([a, b], n_boot=50)
    (loose,) = evaluate_gate(comparison, ['p99_ms > +10%'])
    (strict,) = evaluate_gate(comparison, ['p99_ms > +10%'], strict=True)
    assert loose.verdict == 'inconclusive'
    assert not loose.failed
    assert 'no CI: 3 baseline against 3 measured frames are too few' in loose.explanation
    assert strict.failed
    assert gate_failed([loose, strict])


def test_bad_input_exits_2_before_writing_anything(tmp_path: Path) -> None:
    run = write_run(tmp_path / 'a', {('hsv', TOPIC): latencies(50, 10.0, seed=1)})
    echo = Echo()
    assert echo.run([run, run], tmp_path / 'out', ['p99_ms > lots']) == 2
    assert echo.err[-1].startswith('replaybench: error: bad condition')
    assert echo.run([run, tmp_path / 'missing'], tmp_path / 'out', []) == 2
    assert 'not a directory' in echo.err[-1]
    assert not (tmp_path / 'out').exists()
    blocker = tmp_path / 'file'
    blocker.write_text('x')
    assert echo.run([run, run], blocker, []) == 2
    assert echo.err[-1].startswith('replaybench: error: cannot write into')


def test_a_change_equal_to_the_threshold_is_not_past_it(tmp_path: Path) -> None:
    series = latencies(50, 10.0, seed=1)
    a = write_run(
        tmp_path / 'a', {('hsv', TOPIC): series}, accuracy={('hsv', TOPIC): {'map50': 0.8}}
    )
    b = write_run(
        tmp_path / 'b', {('hsv', TOPIC): series}, accuracy={('hsv', TOPIC): {'map50': 0.79}}
    )
    comparison = compare_runs([a, b], n_boot=20)
    below, at_or_below = evaluate_gate(comparison, ['map50 < -0.01', 'map50 <= -0.01'])
    assert not below.failed  # 0.79 - 0.8 is -0.010000000000000009 in floating point
    assert at_or_below.failed
