"""Hostile-input tests: mutants of the fixture bags replayed through the real CLI.

CI runs the derandomised ``ci`` hypothesis profile (a few hundred cases). The long run,
``make fuzz`` or ``REPLAYBENCH_FUZZ=long pytest tests/fuzz`` (or ``python tests/fuzz/run_long.py``),
uses the ``long`` profile: thousands of examples with fresh seeds and no deadline.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from fuzz.fuzzkit import fixture_digests

if TYPE_CHECKING:
    from collections.abc import Iterator


@pytest.fixture(scope='session', autouse=True)
def fixtures_stay_untouched() -> Iterator[None]:
    """Every fuzz case works on copies: the committed fixture bags must not change."""
    before = fixture_digests()
    yield
    assert fixture_digests() == before, 'a fuzz test modified fixtures/bags'
