"""The sweep benchmark (item g) is registered in the suite, run only when named."""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from benchmarks.suite import item_modules  # noqa: E402


def _names(selected: list[str] | None) -> list[str]:
    return [m.__name__ for m in item_modules(selected, lambda line: None)]


def test_the_sweep_benchmark_runs_only_when_named_by_letter_or_name() -> None:
    assert 'benchmarks.bench_sweep' not in _names(None)
    assert _names(['sweep']) == ['benchmarks.bench_sweep']
    assert _names(['g']) == ['benchmarks.bench_sweep']
    assert _names(['a', 'sweep']) == ['benchmarks.bench_reading', 'benchmarks.bench_sweep']
