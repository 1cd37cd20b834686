from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from hypothesis import settings

from replaybench.results import machine

if TYPE_CHECKING:
    from collections.abc import Iterator

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


#: A host and a CPU as long and odd as a machine's names get: spaces, non-ASCII letters, an
#: emoji, HTML-special characters, over 80 characters each. Rendered reports and comparisons
#: are tested under them (``long_machine_name``), so that no assertion depends on the name of
#: the machine the tests run on, and a long name cannot cut what a label says.
LONG_HOSTNAME = (
    'ci runner «nœud-07» <b>&amp;</b> "quoted" \u2014 rack 12, bay 3 \U0001f680 '
    'build-farm.example.internal'
)
LONG_CPU_MODEL = (
    'Intel(R) Xeon(R) Platinum 8480+ CPU @ 2.00GHz <Sapphire & "Rapids"> '
    'with a vendor string of über-long, odd 名前 ×128 threads'
)


#: The test folders whose modules all run on the machine of the long name: the renderings.
LONG_NAME_FOLDERS = frozenset({'report', 'comparison'})


@pytest.fixture(scope='module')
def long_machine_name() -> Iterator[tuple[str, str]]:
    """While the module runs, the machine every run describes (run.json ``environment``:
    ``hostname``, ``cpu.model``) is named ``LONG_HOSTNAME`` and ``LONG_CPU_MODEL``."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(machine, '_hostname', lambda: LONG_HOSTNAME)
        patch.setattr(machine, '_cpu_model', lambda: LONG_CPU_MODEL)
        yield LONG_HOSTNAME, LONG_CPU_MODEL


@pytest.fixture(scope='module', autouse=True)
def _renderings_on_a_long_named_machine(request: pytest.FixtureRequest) -> Iterator[None]:
    """Every module of tests/report/ and tests/comparison/ runs under ``long_machine_name``
    (an autouse fixture comes before the module's own, so its run folders have the name)."""
    if request.path.parent.name not in LONG_NAME_FOLDERS:
        yield
        return
    request.getfixturevalue('long_machine_name')
    yield
