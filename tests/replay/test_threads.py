"""``thread_limits``: --threads applied through the libraries, then put back."""

from __future__ import annotations

import os

import cv2
import pytest
from threadpoolctl import threadpool_info

from replaybench.replay.threads import thread_limits


def _pools() -> list[int]:
    return [info['num_threads'] for info in threadpool_info()]


def test_the_limits_hold_inside_and_are_restored_after_without_touching_the_environment():
    environ = dict(os.environ)
    before = (cv2.getNumThreads(), _pools())
    with thread_limits(1):
        assert cv2.getNumThreads() == 1
        assert set(_pools()) <= {1}
        assert dict(os.environ) == environ
    assert (cv2.getNumThreads(), _pools()) == before
    assert dict(os.environ) == environ


def test_they_are_restored_when_the_block_raises():
    before = (cv2.getNumThreads(), _pools())
    with pytest.raises(RuntimeError), thread_limits(1):
        raise RuntimeError
    assert (cv2.getNumThreads(), _pools()) == before


def test_none_changes_nothing():
    cv2.setNumThreads(3)
    try:
        with thread_limits(None):
            assert cv2.getNumThreads() == 3
    finally:
        cv2.setNumThreads(-1)
