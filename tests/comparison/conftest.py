"""The comparison tests' machine: a long, odd name (tests/conftest.py ``long_machine_name``)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope='module', autouse=True)
def _long_machine_name(long_machine_name: tuple[str, str]) -> tuple[str, str]:
    """Every comparison test runs on a machine with a long, odd name."""
    return long_machine_name
