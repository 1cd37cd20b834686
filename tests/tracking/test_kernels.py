"""The trackers' compiled loops (replaybench.tracking.kernels) give what the numpy forms they
replace give, bit for bit: the forms are kept here as they were in the trackers, and both run
on seeded random boxes and filters, with NaN, infinities, signed zeros, empty boxes and
boxes of zero height among them."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from replaybench.tracking import kernels

pytestmark = pytest.mark.filterwarnings('ignore:invalid value:RuntimeWarning')

F64 = npt.NDArray[np.float64]


# ---- the numpy forms, as the trackers had them ------------------------------------------------


def np_cost(a: F64, b: F64) -> F64:
    inter: F64 = np.minimum(a[2, :, None], b[2])
    inter -= np.maximum(a[0, :, None], b[0])
    np.maximum(inter, 0.0, out=inter)
    high = np.minimum(a[3, :, None], b[3])
    high -= np.maximum(a[1, :, None], b[1])
    np.maximum(high, 0.0, out=high)
    inter *= high
    size_a, size_b = a[2:4] - a[0:2], b[2:4] - b[0:2]
    union = (size_a[0] * size_a[1])[:, None] + size_b[0] * size_b[1]
    np.subtract(inter, union, out=union)
    if union.max() < 0.0:
        inter /= union
        return inter
    out: F64 = np.full_like(inter, -0.0)
    np.divide(inter, union, out=out, where=union < 0)
    return out


def np_sort_z(d: F64) -> F64:
    w, h = d[2] - d[0], d[3] - d[1]
    z = np.empty_like(d)
    np.add(d[0], w / 2, out=z[0])
    np.add(d[1], h / 2, out=z[1])
    np.multiply(w, h, out=z[2])
    np.divide(w, np.maximum(h, 1e-9), out=z[3])
    return z


def np_sort_boxes(s: F64) -> F64:
    area = np.maximum(s[2], 1e-9)
    w = np.sqrt(area * np.maximum(s[3], 1e-9))
    hh = area / w / 2
    hw = w / 2
    out = np.empty((4, s.shape[1]))
    np.subtract(s[0], hw, out=out[0])
    np.subtract(s[1], hh, out=out[1])
    np.add(s[0], hw, out=out[2])
    np.add(s[1], hh, out=out[3])
    return out


def np_bt_xyah(d: F64) -> F64:
    w, h = d[2] - d[0], d[3] - d[1]
    z = np.empty_like(d)
    np.add(d[0], w / 2, out=z[0])
    np.add(d[1], h / 2, out=z[1])
    np.divide(w, np.maximum(h, 1e-9), out=z[2])
    z[3] = h
    return z


def np_bt_boxes(m: F64) -> F64:
    hw = m[2] * m[3] / 2
    hh = m[3] / 2
    out = np.empty((4, m.shape[1]))
    np.subtract(m[0], hw, out=out[0])
    np.subtract(m[1], hh, out=out[1])
    np.add(m[0], hw, out=out[2])
    np.add(m[1], hh, out=out[3])
    return out


def np_predict(s: F64, q: F64) -> None:
    s[0:4] += s[4:8]
    s[8:12] += s[16:20]
    s[12:20].reshape(2, 4, -1)[:] += s[20:24]
    s[8:12] += s[12:16]
    s[8:24] += q


def np_update(s: F64, rows: npt.NDArray[np.intp], z: F64, r: F64) -> None:
    g = s[:, rows]
    sv = g[8:12] + r
    inv = 1.0 / sv
    ka = g[8:12] * inv
    kb = g[12:16] * inv
    y = z - g[0:4]
    g[0:4] += ka * y
    g[4:8] += kb * y
    kas = ka * sv
    kbs = kb * sv
    g[8:12] -= kas * ka
    g[12:16] -= kas * kb
    g[16:20] -= kbs * ka
    g[20:24] -= kbs * kb
    s[:, rows] = g


# ---- the data -------------------------------------------------------------------------------


def _boxes(rng: np.random.Generator, k: int, odd: bool) -> F64:
    """k boxes (4 x k, C-contiguous), overlapping one another now and then; with ``odd``
    some coordinates NaN or infinite, some boxes empty, inverted or of zero height, and
    signed zeros."""
    xy = rng.uniform(-10, 300, (2, k))
    wh = rng.uniform(0, 60, (2, k))
    boxes = np.vstack([xy, xy + wh])
    if odd and k:
        specials = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 1e-300, -5.0])
        hit = rng.random((4, k)) < 0.15
        boxes[hit] = rng.choice(specials, int(hit.sum()))
        flat = rng.random(k) < 0.2
        boxes[3, flat] = boxes[1, flat]  # zero height
    return np.ascontiguousarray(boxes)


def _filters(rng: np.random.Generator, k: int, odd: bool) -> F64:
    s = np.ascontiguousarray(rng.normal(0, 50, (24, k)))
    s[8:24] = np.abs(s[8:24]) + 0.5
    if odd and k:
        hit = rng.random((24, k)) < 0.05
        s[hit] = rng.choice(np.array([np.nan, np.inf, -0.0, 0.0]), int(hit.sum()))
    return s


def _same(got: F64, want: F64) -> None:
    """Equal values, NaN where NaN, and the same sign bit where a number (-0.0 is not 0.0; a
    NaN's sign means nothing)."""
    assert got.shape == want.shape
    assert got.flags.c_contiguous
    assert np.array_equal(got, want, equal_nan=True)
    number = ~np.isnan(want)
    assert np.array_equal(np.signbit(got[number]), np.signbit(want[number]))


CASES = [(seed, k, odd) for seed in range(6) for k in (0, 1, 7, 50) for odd in (False, True)]


@pytest.mark.parametrize(('seed', 'k', 'odd'), CASES)
def test_the_cost_matrix_is_numpys_bit_for_bit(seed: int, k: int, odd: bool) -> None:
    rng = np.random.default_rng(seed)
    a = _boxes(rng, k, odd)
    b = _boxes(rng, max(k - 2, 1), odd)
    if k > 2:
        b[:, : k // 3] = a[:, : k // 3] + rng.normal(0, 3, (4, k // 3))  # overlaps
    if k:
        _same(kernels.cost(a, b), np_cost(a, b))


@pytest.mark.parametrize(('seed', 'k', 'odd'), CASES)
def test_the_box_conversions_are_numpys_bit_for_bit(seed: int, k: int, odd: bool) -> None:
    rng = np.random.default_rng(100 + seed)
    d = _boxes(rng, k, odd)
    _same(kernels.sort_z(d), np_sort_z(d))
    _same(kernels.bt_xyah(d), np_bt_xyah(d))
    s = _filters(rng, k, odd)
    _same(kernels.sort_boxes(s), np_sort_boxes(s))
    _same(kernels.bt_boxes(s), np_bt_boxes(s))


@pytest.mark.parametrize(('seed', 'k', 'odd'), CASES)
def test_predict_and_update_are_numpys_bit_for_bit(seed: int, k: int, odd: bool) -> None:
    rng = np.random.default_rng(200 + seed)
    s = _filters(rng, k, odd)
    mine, theirs = s.copy(), s.copy()
    for q in (np.abs(rng.normal(0, 1, (16, 1))), np.abs(rng.normal(0, 1, (16, k)))):
        kernels.predict(mine, np.ascontiguousarray(q))
        np_predict(theirs, q)
        _same(mine, theirs)
    for picked in (k, k // 2):
        rows = np.ascontiguousarray(rng.permutation(k)[:picked], dtype=np.intp)
        z = np.ascontiguousarray(rng.normal(0, 50, (4, picked)))
        for r in (np.array([[1.0], [1.0], [10.0], [10.0]]), np.abs(rng.normal(1, 1, (4, picked)))):
            kernels.update(mine, rows, z, np.ascontiguousarray(r))
            np_update(theirs, rows, z, r)
            _same(mine, theirs)


def test_the_kernels_refuse_arrays_they_were_not_compiled_for() -> None:
    """No kernel compiles inside a timed frame: another layout or type is a TypeError."""
    columns = np.asfortranarray(np.ones((4, 3)))
    with pytest.raises(TypeError):
        kernels.sort_z(columns)
    with pytest.raises(TypeError):
        kernels.cost(np.ones((4, 3), np.float32), np.ones((4, 3)))
