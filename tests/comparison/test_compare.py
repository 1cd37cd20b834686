from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from runbuilder import SHA, TOPIC, latencies, write_run

from replaybench.comparison import change_interval, compare_runs
from replaybench.errors import SourceError, UsageError

if TYPE_CHECKING:
    from pathlib import Path


def _pair(tmp_path: Path, base: np.ndarray, cand: np.ndarray, **cand_kwargs: object) -> list[Path]:
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): base})
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): cand}, **cand_kwargs)  # type: ignore[arg-type]
    return [a, b]


def test_identical_runs_have_ratio_one_with_a_ci_around_it(tmp_path: Path) -> None:
    series = latencies(800, 10.0, seed=1)
    comparison = compare_runs(_pair(tmp_path, series, series), n_boot=500)
    assert comparison.inputs_match is True
    base, cand = comparison.rows
    assert (base.role, cand.role) == ('baseline', 'candidate')
    for metric in ('median_ms', 'p99_ms', 'mean_ms', 'fps'):
        m = cand.metrics[metric]
        assert m.ratio == pytest.approx(1.0)
        assert m.ratio_ci is not None
        assert m.ratio_ci[0] < 1.0 < m.ratio_ci[1]
        assert m.significant is False
    assert not cand.flags


def test_runs_of_the_same_distribution_are_not_significantly_different(tmp_path: Path) -> None:
    comparison = compare_runs(
        _pair(tmp_path, latencies(1000, 10.0, seed=1), latencies(1000, 10.0, seed=3)),
        n_boot=1000,
    )
    cand = comparison.rows[1]
    for metric in ('median_ms', 'p99_ms', 'mean_ms', 'fps'):
        assert cand.metrics[metric].significant is False
        assert cand.metrics[metric].method == 'between-block'
        assert cand.metrics[metric].blocks == (20, 20)


def test_same_distribution_ratio_intervals_exclude_one_about_five_percent_of_the_time() -> None:
    misses = dict.fromkeys(('median_ms', 'p99_ms', 'mean_ms'), 0)
    for k in range(200):
        a = latencies(300, 10.0, seed=2 * k + 1000, rho=0.6)
        b = latencies(300, 10.0, seed=2 * k + 1001, rho=0.6)
        for metric in misses:
            interval = change_interval(metric, a, b, confidence=0.95).ratio_ci
            assert interval is not None
            misses[metric] += not interval[0] <= 1.0 <= interval[1]
    # nominal 10 of 200; these seeds give 7, 14 and 5 (frames with lag-1 correlation 0.6)
    assert all(count <= 20 for count in misses.values()), misses


def test_a_planted_regression_is_significant_in_every_timing_metric(tmp_path: Path) -> None:
    base = latencies(1000, 10.0, seed=1)
    cand = latencies(1000, 10.0, seed=2) * 1.5
    cand_row = compare_runs(_pair(tmp_path, base, cand), n_boot=1000).rows[1]
    for metric in ('median_ms', 'p99_ms', 'mean_ms'):
        m = cand_row.metrics[metric]
        assert m.significant is True
        assert m.ratio_ci is not None
        assert m.ratio_ci[0] > 1.3
        assert m.ratio == pytest.approx(m.value / m.baseline)  # type: ignore[operator]
    fps = cand_row.metrics['fps']
    assert fps.significant is True
    assert fps.ratio is not None
    assert fps.ratio < 0.75


def test_point_estimates_are_those_of_summary_csv(tmp_path: Path) -> None:
    series = latencies(300, 7.0, seed=4)
    comparison = compare_runs(_pair(tmp_path, series, series * 2), n_boot=100)
    run = comparison.runs[1].data.run
    summary = run.summary_rows[0]
    metrics = comparison.rows[1].metrics
    # frames.csv keeps 4 decimals of each latency; run.json was summarised before rounding
    assert metrics['median_ms'].value == pytest.approx(summary.latency_ms_p50, abs=1e-3)
    assert metrics['p99_ms'].value == pytest.approx(summary.latency_ms_p99, abs=1e-3)
    assert metrics['fps'].value == pytest.approx(summary.throughput_fps, rel=1e-4)
    assert metrics['median_ms'].baseline == pytest.approx(np.median(series), abs=1e-4)  # 4 decimals


def test_comparing_twice_gives_the_same_intervals(tmp_path: Path) -> None:
    dirs = _pair(tmp_path, latencies(500, 10.0, seed=1), latencies(500, 11.0, seed=2))
    first = compare_runs(dirs, n_boot=300, seed=5).rows[1].metrics['p99_ms']
    again = compare_runs(dirs, n_boot=300, seed=5).rows[1].metrics['p99_ms']
    other = compare_runs(dirs, n_boot=300, seed=6).rows[1].metrics['p99_ms']
    assert first == again
    # the bootstrap of the row's own value depends on the seed; the rank interval does not
    assert first.value_ci != other.value_ci
    assert first.ratio_ci == other.ratio_ci


def test_a_sha256_mismatch_is_flagged_and_still_compared(tmp_path: Path) -> None:
    series = latencies(300, 10.0, seed=1)
    comparison = compare_runs(
        _pair(tmp_path, series, series, sha256='cd' * 32, bag='/bags/other.mcap'), n_boot=100
    )
    assert comparison.inputs_match is False
    assert comparison.warnings[0].startswith('INPUTS DIFFER')
    assert '/bags/other.mcap' in comparison.warnings[0]
    cand = comparison.rows[1]
    assert cand.inputs_match is False
    assert 'inputs differ from the baseline (sha256)' in cand.flags
    assert cand.metrics['median_ms'].ratio == pytest.approx(1.0)


def test_a_missing_sha256_is_reported_as_not_checked(tmp_path: Path) -> None:
    series = latencies(100, 10.0, seed=1)
    comparison = compare_runs(_pair(tmp_path, series, series, sha256=None), n_boot=50)
    assert comparison.inputs_match is None
    assert any('not checked' in f for f in comparison.rows[1].flags)


def test_engine_mismatch_between_runs_of_one_backend_is_flagged(tmp_path: Path) -> None:
    series = latencies(200, 10.0, seed=1)
    a = write_run(
        tmp_path / 'a',
        {('cuda', TOPIC): series, ('hsv', TOPIC): series},
        info={'cuda': {'engine': 'ort', 'providers': ['CUDAExecutionProvider']}},
    )
    b = write_run(
        tmp_path / 'b',
        {('cuda', TOPIC): series, ('hsv', TOPIC): series},
        info={'cuda': {'engine': 'torch'}},
    )
    comparison = compare_runs([a, b], n_boot=50)
    flagged = {r.backend: r.flags for r in comparison.rows if r.run == 1}
    assert any('engine mismatch for backend cuda' in f for f in flagged['cuda'])
    assert any('engine=torch' in f and 'engine=ort' in f for f in flagged['cuda'])
    assert not any('engine' in f for f in flagged['hsv'])
    assert any('engine mismatch' in w for w in comparison.warnings)


def test_unstable_and_badly_set_up_runs_are_flagged(tmp_path: Path) -> None:
    base = write_run(tmp_path / 'a', {('hsv', TOPIC): latencies(300, 10.0, seed=1)})
    noisy = write_run(
        tmp_path / 'b',
        {('hsv', TOPIC): latencies(300, 10.0, seed=2, cv=0.4)},
        cpu={'governor': 'powersave', 'usable_cores': 4},
        load_average=(3.5, 1.0, 1.0),
        gpus=['NVIDIA H100'],
        settings={'rate': '30hz'},
    )
    comparison = compare_runs([base, noisy], n_boot=50)
    assert not comparison.rows[0].flags
    flags = ' | '.join(comparison.rows[1].flags)
    assert 'unstable latency: CV' in flags
    assert 'CPU governor powersave (not performance)' in flags
    assert 'load average 3.5 above half of 4 cores' in flags
    assert 'GPU differs from the baseline: NVIDIA H100 vs none' in flags
    assert 'settings differ from the baseline: rate 30hz vs max' in flags
    assert comparison.rows[1].latency_cv is not None
    assert comparison.rows[1].latency_cv > 0.1


def test_labels_name_the_machine_and_stay_unique(tmp_path: Path) -> None:
    series = latencies(50, 10.0, seed=1)
    a = write_run(tmp_path / 'x' / 'run', {('hsv', TOPIC): series}, gpus=['NVIDIA L4'])
    b = write_run(tmp_path / 'y' / 'run', {('hsv', TOPIC): series}, gpus=['NVIDIA L4'])
    c = write_run(tmp_path / 'cpu', {('hsv', TOPIC): series})
    labels = [r.label for r in compare_runs([a, b, c], n_boot=20).runs]
    assert labels == [
        'x/run (NVIDIA L4)',
        'y/run (NVIDIA L4)',
        'cpu (Intel Xeon Gold 6130 CPU @ 2.10GHz)',
    ]
    same = [r.label for r in compare_runs([a, a], n_boot=20).runs]
    assert len(set(same)) == 2


def test_one_run_compares_its_backends_with_the_first(tmp_path: Path) -> None:
    run = write_run(
        tmp_path / 'a',
        {('null', TOPIC): latencies(200, 1.0, seed=1), ('hsv', TOPIC): latencies(200, 4.0, seed=2)},
    )
    comparison = compare_runs([run], n_boot=200)
    assert comparison.baseline_backend == 'null'
    null, hsv = comparison.rows
    assert (null.role, hsv.role) == ('baseline', 'candidate')
    assert hsv.baseline_backend == 'null'
    assert hsv.metrics['median_ms'].ratio == pytest.approx(4.0, rel=0.1)
    assert hsv.metrics['median_ms'].significant is True


def test_a_backend_missing_from_the_baseline_is_unpaired_unless_a_baseline_backend_is_named(
    tmp_path: Path,
) -> None:
    a = write_run(
        tmp_path / 'a',
        {('null', TOPIC): latencies(100, 1.0, seed=1), ('hsv', TOPIC): latencies(100, 4.0, seed=2)},
    )
    b = write_run(tmp_path / 'b', {('onnx_cpu', TOPIC): latencies(100, 20.0, seed=3)})
    row = compare_runs([a, b], n_boot=50).rows[-1]
    assert row.role == 'unpaired'
    assert row.metrics['median_ms'].ratio is None
    named = compare_runs([a, b], n_boot=50, baseline_backend='hsv')
    onnx = named.rows[-1]
    assert (onnx.role, onnx.baseline_backend) == ('candidate', 'hsv')
    assert onnx.metrics['median_ms'].ratio == pytest.approx(5.0, rel=0.1)
    assert [r.role for r in named.rows[:2]] == ['candidate', 'baseline']


def test_a_single_backend_baseline_is_compared_across_backends(tmp_path: Path) -> None:
    a = write_run(tmp_path / 'a', {('onnx_cpu', TOPIC): latencies(100, 20.0, seed=1)})
    b = write_run(tmp_path / 'b', {('cuda', TOPIC): latencies(100, 2.0, seed=2)})
    row = compare_runs([a, b], n_boot=50).rows[1]
    assert (row.role, row.baseline_backend) == ('candidate', 'onnx_cpu')
    assert row.metrics['median_ms'].ratio == pytest.approx(0.1, rel=0.1)


def test_accuracy_deltas_are_point_estimates_without_ci(tmp_path: Path) -> None:
    series = latencies(100, 10.0, seed=1)
    acc_a = {('hsv', TOPIC): {'map50': 0.80, 'recall50': 0.9, 'precision50': 0.85}}
    acc_b = {('hsv', TOPIC): {'map50': 0.70, 'recall50': 0.9, 'precision50': 0.95}}
    a = write_run(tmp_path / 'a', {('hsv', TOPIC): series}, accuracy=acc_a)
    b = write_run(tmp_path / 'b', {('hsv', TOPIC): series}, accuracy=acc_b)
    metrics = compare_runs([a, b], n_boot=20).rows[1].metrics
    assert metrics['map50'].diff == pytest.approx(-0.10)
    assert metrics['precision50'].diff == pytest.approx(0.10)
    assert metrics['recall50'].diff == pytest.approx(0.0)
    assert metrics['map50'].ratio_ci is None
    assert metrics['map50'].significant is None


def test_a_few_frames_are_compared_frame_by_frame_and_flagged(tmp_path: Path) -> None:
    series = latencies(10, 10.0, seed=1)
    row = compare_runs(_pair(tmp_path, series, series * 2), n_boot=50).rows[1]
    median = row.metrics['median_ms']
    assert median.ratio == pytest.approx(2.0, rel=1e-4)
    assert median.method == 'per-frame'
    assert median.blocks is None
    assert median.value_ci is None  # no bootstrap of its own value
    assert median.ratio_ci is not None
    assert median.ratio_ci[0] > 1.5
    assert median.significant is True
    assert any('compared frame by frame' in f for f in row.flags)


def test_bad_arguments_are_usage_errors_and_bad_folders_source_errors(tmp_path: Path) -> None:
    run = write_run(tmp_path / 'a', {('hsv', TOPIC): latencies(30, 10.0, seed=1)})
    with pytest.raises(UsageError, match='nothing to compare'):
        compare_runs([run])
    with pytest.raises(UsageError, match='no run folder'):
        compare_runs([])
    with pytest.raises(UsageError, match='out of range'):
        compare_runs([run, run], baseline=2)
    with pytest.raises(UsageError, match="baseline backend 'cuda'"):
        compare_runs([run, run], baseline_backend='cuda')
    with pytest.raises(SourceError, match=r'no run\.json'):
        compare_runs([run, tmp_path])


def test_the_baseline_can_be_another_run(tmp_path: Path) -> None:
    dirs = _pair(tmp_path, latencies(200, 10.0, seed=1), latencies(200, 20.0, seed=2))
    comparison = compare_runs(dirs, baseline=1, n_boot=100)
    assert [r.role for r in comparison.rows] == ['candidate', 'baseline']
    assert comparison.rows[0].metrics['median_ms'].ratio == pytest.approx(0.5, rel=0.05)
    assert SHA in comparison.baseline_run.input_sha256
