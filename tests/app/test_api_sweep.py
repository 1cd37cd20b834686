"""``rb.sweep``: a library call that starts its own Ray leaves the process as it found it."""

from __future__ import annotations

import os
import signal
import threading
from pathlib import Path

import pytest

import replaybench as rb

BAG = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags' / 'jpeg.mcap'


def test_a_sweep_that_starts_ray_puts_back_the_environment_and_the_signal_handlers(tmp_path):
    pytest.importorskip('ray', reason='the sweep extra (Ray) is not installed')
    import ray

    assert not ray.is_initialized()  # this call starts (and stops) its own local instance
    environ = dict(os.environ)
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    live = set(threading.enumerate())
    result = rb.sweep(
        BAG, backends='hsv', params=['hsv.min_area=50,100'], out=tmp_path / 'sweep', max_frames=5
    )
    assert list(result.cells['status']) == ['complete', 'complete']
    assert list(result.cells['params']) == ['min_area=50', 'min_area=100']
    assert not ray.is_initialized()
    assert dict(os.environ) == environ
    assert {s: signal.getsignal(s) for s in handlers} == handlers
    assert set(threading.enumerate()) == live
