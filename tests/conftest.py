from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# Every run.json, peak.json and comparison.json the tests write is checked against its JSON
# Schema as it is written (replaybench.results.io), in this process and in the CLI subprocesses
# that inherit the environment.
os.environ['REPLAYBENCH_CHECK_SCHEMAS'] = '1'

# Reproducible property tests: the same examples on every run (CI included).
settings.register_profile('repro', derandomize=True, database=None)
settings.load_profile('repro')

REPO = Path(__file__).resolve().parents[1]
FIXTURE_BAGS = REPO / 'fixtures' / 'bags'
SHARED_REAL = (REPO / '..' / 'shared' / 'real').resolve()


@pytest.fixture
def shared_real() -> Path:
    """The real third-party recordings beside the repository, or a skip."""
    if not SHARED_REAL.is_dir():
        pytest.skip(f'{SHARED_REAL} not present (real recordings are optional)')
    return SHARED_REAL


@pytest.fixture
def fixture_bags() -> Path:
    return FIXTURE_BAGS
