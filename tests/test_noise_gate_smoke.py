"""The noise experiment (benchmarks/noise_gate.py) still runs end to end, on tiny settings."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.noise_gate import CONDITIONS, PHASE_S, hog_phases  # noqa: E402


def test_the_hog_schedule_is_seeded_alternating_and_50_to_300_ms_long() -> None:
    first = hog_phases(7)
    again = hog_phases(7)
    other = hog_phases(8)
    phases = [first() for _ in range(200)]
    assert phases == [again() for _ in range(200)]
    assert phases != [other() for _ in range(200)]
    assert all(PHASE_S[0] <= seconds <= PHASE_S[1] for _, seconds in phases)
    assert all(a[0] != b[0] for a, b in itertools.pairwise(phases))


def test_the_noise_experiment_writes_verdict_counts_for_every_pair_kind(tmp_path: Path) -> None:
    out = tmp_path / 'noise.json'
    proc = subprocess.run(
        [sys.executable, '-m', 'benchmarks.noise_gate', '--pairs', '1', '--frames', '20',
         '--hsv-pairs', '1', '--workers', '1', '--repeat', '2', '--out', str(out)],
        cwd=REPO,
        env={**os.environ, 'TMPDIR': str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    document = json.loads(out.read_text(encoding='utf-8'))
    assert document['settings']['frames'] == 20
    assert document['settings']['cost_ms'] == [1.0, 1.3]
    assert document['settings']['repeat'] == 2
    for name in ('aa', 'ab', 'hsv_aa'):
        block = document['results'][name]
        assert len(block['pairs']) == 1
        assert block['pairs'][0]['method'] == 'between-repeat 2/2'
        for method in ('gate', 'bootstrap'):
            counts = block['counts'][method]
            assert set(counts) == {*CONDITIONS, 'any'}
            assert all(sum(tally.values()) == 1 for tally in counts.values())
    assert 'A/A hsv' in proc.stdout
    summary = document['summary']
    assert summary['false_alarm']['pairs'] == 2
    assert summary['detection']['pairs'] == 1
    assert summary['targets']['aa_failed_of_first_7'][1] == 2
    assert 'false alarms' in proc.stdout


def test_the_rates_carry_exact_binomial_intervals() -> None:
    from benchmarks.noise_gate import _clopper_pearson

    stats = pytest.importorskip('scipy.stats')
    for k, n in ((0, 50), (50, 50), (3, 57), (1, 7)):
        low, high = _clopper_pearson(k, n)  # type: ignore[misc]
        want_low = stats.beta.ppf(0.025, k, n - k + 1) if k else 0.0
        want_high = stats.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
        assert low == pytest.approx(want_low, abs=1e-9)
        assert high == pytest.approx(want_high, abs=1e-9)
