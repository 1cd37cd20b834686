from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

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
