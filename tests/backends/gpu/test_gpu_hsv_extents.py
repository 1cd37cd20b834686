"""hsv-cuda's blob boxes come from one scatter-min and one scatter-max over all labelled pixels
(``label_extents``), not from a step per blob; checked with NumPy through the same array calls
CuPy runs (``minimum.at`` / ``maximum.at``), against a per-blob reference.
"""

from __future__ import annotations

import time
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


def test_box_extraction_time_does_not_grow_with_a_loop_per_blob():
    # 2000 blobs and 20 blobs of the same total area: one scatter pass each
    rng = np.random.default_rng(1)
    few = rng.integers(1, 21, size=200_000)
    many = rng.integers(1, 2001, size=200_000)
    coords = [rng.integers(0, 2000, size=200_000) for _ in range(3)]

    def best(labels: np.ndarray, count: int) -> float:
        runs = []
        for _ in range(3):
            began = time.perf_counter()
            _hsv_ops.label_extents(np, labels, coords, count)
            runs.append(time.perf_counter() - began)
        return min(runs)

    assert best(many, 2000) < 3 * best(few, 20)
