"""Fixtures of the sweep tests: small generated bags and one local Ray instance per module."""

from __future__ import annotations

import shutil
import tempfile
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path


@pytest.fixture(scope='module')
def ray_local() -> Iterator[None]:
    """A local Ray instance for the module, as `replaybench sweep` starts one (2 CPUs, one node
    slot); sweeps in the module use it, and it is shut down after the module."""
    pytest.importorskip('ray', reason='the sweep extra (Ray) is not installed')
    from replaybench.app.sweep import local_ray

    temp = tempfile.mkdtemp(prefix='rb-ray-')  # short: Ray's socket paths must stay < 108 chars
    try:
        with local_ray(num_cpus=2, temp_dir=temp):
            yield
    finally:
        shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture(scope='module')
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two small JPEG bags of 40 frames (enough for bootstrap intervals) and a corrupt one."""
    from replaybench.fixtures.writer import write_mcap

    folder = tmp_path_factory.mktemp('bags')
    found = {
        'a': write_mcap(folder / 'a.mcap', frames=40, size=(96, 72), encoding='jpeg'),
        'b': write_mcap(folder / 'b.mcap', frames=40, size=(96, 72), encoding='rgb8', seed=7),
    }
    corrupt = folder / 'corrupt.mcap'
    corrupt.write_bytes(b'\x89MCAP0\r\n' + b'\x00garbage' * 64)
    found['corrupt'] = corrupt
    return found
