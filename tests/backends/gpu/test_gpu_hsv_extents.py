"""hsv-cuda's blob boxes come from one scatter-min and one scatter-max over all labelled pixels
(``label_extents``), not from a step per blob; checked with NumPy through the same array calls
CuPy runs (``minimum.at`` / ``maximum.at``), against a per-blob reference.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from replaybench.backends.gpu import _hsv_ops

ndi = pytest.importorskip('scipy.ndimage', reason='scipy is not installed')


def _reference(labels: np.ndarray, coords: list[np.ndarray], count: int) -> tuple[Any, Any]:
    low = np.full((len(coords), count), np.iinfo(np.int32).max, dtype=np.float64)
    high = np.full((len(coords), count), -1, dtype=np.float64)
    for label in range(1, count + 1):
        members = labels == label
        for row, values in enumerate(coords):
            if members.any():
                low[row, label - 1] = values[members].min()
                high[row, label - 1] = values[members].max()
    return low, high


@pytest.mark.parametrize('seed', range(5))
def test_label_extents_equal_a_min_and_max_per_label(seed):
    rng = np.random.default_rng(seed)
    count = int(rng.integers(1, 40))
    n = int(rng.integers(1, 5000))
    labels = rng.integers(1, count + 1, size=n)
    coords = [rng.integers(0, 4000, size=n) for _ in range(3)]
    low, high = _hsv_ops.label_extents(np, labels, coords, count)
    expected_low, expected_high = _reference(labels, coords, count)
    np.testing.assert_array_equal(low, expected_low)
    np.testing.assert_array_equal(high, expected_high)


def test_blob_boxes_match_per_blob_minima_and_maxima_on_many_blobs():
    rng = np.random.default_rng(7)
    masks = np.zeros((2, 240, 320), dtype=bool)
    for _ in range(300):
        z, y, x = int(rng.integers(0, 2)), int(rng.integers(0, 232)), int(rng.integers(0, 312))
        h, w = int(rng.integers(1, 8)), int(rng.integers(1, 8))
        masks[z, y : y + h, x : x + w] = True
    saturation = rng.integers(0, 256, size=(240, 320)).astype(np.uint8)
    rows = _hsv_ops.blob_stats(np, ndi, masks, saturation)
    filled = _hsv_ops.fill_holes(np, ndi, masks)
    eight = np.zeros((3, 3, 3), dtype=bool)
    eight[1] = True  # 8-connected within a class plane
    labels, count = ndi.label(filled, structure=eight)
    assert rows.shape == (count, len(_hsv_ops.STAT_COLUMNS))
    index = np.arange(1, count + 1)
    zs, ys, xs = np.indices(labels.shape)
    expected = np.stack(
        [
            ndi.minimum(zs, labels, index),
            ndi.minimum(xs, labels, index),
            ndi.minimum(ys, labels, index),
            ndi.maximum(xs, labels, index) + 1,
            ndi.maximum(ys, labels, index) + 1,
        ],
        axis=1,
    )
    np.testing.assert_array_equal(rows[:, :5], expected)


def test_box_extraction_makes_as_many_array_calls_for_2000_blobs_as_for_20():
    # a loop per blob would show as calls that grow with the label count; the scatter passes
    # make the same calls whatever the count (counted, not timed)
    rng = np.random.default_rng(1)
    few = rng.integers(1, 21, size=20_000)
    many = rng.integers(1, 2001, size=20_000)
    coords = [rng.integers(0, 2000, size=20_000) for _ in range(3)]

    class Counting:
        """numpy, counting every function and ufunc method the code reaches through it."""

        def __init__(self) -> None:
            self.calls = 0

        def __getattr__(self, name: str) -> object:
            target = getattr(np, name)
            if isinstance(target, np.ufunc):
                return _CountingUfunc(target, self)
            if callable(target) and not isinstance(target, type):

                def call(*args: object, **kwargs: object) -> object:
                    self.calls += 1
                    return target(*args, **kwargs)

                return call
            return target

    class _CountingUfunc:
        def __init__(self, ufunc: np.ufunc, counter: Counting) -> None:
            self._ufunc, self._counter = ufunc, counter

        def at(self, a: np.ndarray, indices: np.ndarray, b: np.ndarray) -> None:
            self._counter.calls += 1
            self._ufunc.at(a, indices, b)

    def calls(labels: np.ndarray, count: int) -> int:
        xp = Counting()
        low, high = _hsv_ops.label_extents(xp, labels, coords, count)
        assert low.shape == high.shape == (3, count)
        return xp.calls

    assert calls(many, 2000) == calls(few, 20) > 0
