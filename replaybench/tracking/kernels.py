"""The trackers' per-frame arithmetic as compiled loops (Numba): the IoU cost matrix, the box
conversions and the Kalman filters' predict and update (``replaybench.tracking.kalman``'s
layout).

Each function does, element by element, the operations of the numpy expressions it replaces,
in the same order (the products and sums of the matrix form, S^-1 applied as a multiplication
by 1/S), with numpy's NaN and signed-zero rules for ``maximum``/``minimum`` (``_max``,
``_min``): the results are equal (``==``) to the numpy forms', which
tests/tracking/test_kernels.py checks. Numba compiles without fast-math, so no operation is
reordered or fused (no FMA): the same bits on every CPU.

Why compiled: at 50 tracks a frame the numpy forms are some 90 small array operations, each
paying its call and, in a run where the detector's pass over the image came first, its
caches' misses; these loops are six calls. The signatures are given, so everything is
compiled when this module is imported (from Numba's cache after the first time), never
inside a timed frame; arrays must be C-contiguous float64 (and intp indices), which the
callers make sure of.

Numba comes with ``pip install "replaybench[tracking]"``; without it importing this module
is a ``MissingDependencyError`` naming the extra.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from replaybench.errors import MissingDependencyError

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy.typing as npt

try:
    import numba
except ImportError as err:  # pragma: no cover - the tracking extra brings it
    msg = (
        'the trackers need Numba: pip install "replaybench[tracking]" '
        f'({type(err).__name__}: {err})'
    )
    raise MissingDependencyError(msg) from err

__all__ = ['bt_boxes', 'bt_xyah', 'cost', 'predict', 'sort_boxes', 'sort_z', 'update']

_F = TypeVar('_F', bound='Callable[..., Any]')
_F2 = numba.float64[:, ::1]
_I1 = numba.intp[::1]


def _compiled(signature: Any = None) -> Callable[[_F], _F]:
    """``numba.njit``: compiled for ``signature`` at once (lazily for each caller's types
    without one), run without the GIL, cached on disk where Numba finds a folder it can write
    (beside this file, else the user's cache folder); where it finds none, compiled again at
    each import (the same code, a second or two more before the replay)."""

    def decorate(function: _F) -> _F:
        args = () if signature is None else (signature,)
        try:
            compiled: _F = numba.njit(*args, cache=True, nogil=True)(function)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            compiled = numba.njit(*args, nogil=True)(function)
        return compiled

    return decorate


@_compiled()
def _max(a: float, b: float) -> float:
    """``np.maximum(a, b)``: NaN if either is, ``b`` for equal values (0.0 for -0.0, 0.0)."""
    return a if (a > b or a != a) else b


@_compiled()
def _min(a: float, b: float) -> float:
    """``np.minimum(a, b)``: NaN if either is, ``b`` for equal values."""
    return a if (a < b or a != a) else b


@_compiled(_F2(_F2, _F2))
def cost(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """-IoU of each box of ``a`` (4 x N, x1 y1 x2 y2) with each of ``b`` (4 x M): the
    intersection's width and height clipped at 0, their product over the negated union (the
    intersection less the sum of the areas); -0.0 where that union is not negative (or
    NaN). ``trackers._cost``'s numpy form, element by element."""
    n, m = a.shape[1], b.shape[1]
    out = np.empty((n, m))
    size_b = np.empty(m)
    for j in range(m):
        size_b[j] = (b[2, j] - b[0, j]) * (b[3, j] - b[1, j])
    for i in range(n):
        size_a = (a[2, i] - a[0, i]) * (a[3, i] - a[1, i])
        for j in range(m):
            inter = _max(_min(a[2, i], b[2, j]) - _max(a[0, i], b[0, j]), 0.0)
            high = _max(_min(a[3, i], b[3, j]) - _max(a[1, i], b[1, j]), 0.0)
            inter *= high
            union = inter - (size_a + size_b[j])
            out[i, j] = inter / union if union < 0.0 else -0.0
    return out


@_compiled()
def _centre(d: npt.NDArray[np.float64], j: int, z: npt.NDArray[np.float64]) -> tuple[float, float]:
    """Box ``j`` of ``d``'s centre into rows 0-1 of ``z``'s column ``j``; its width, height."""
    w = d[2, j] - d[0, j]
    h = d[3, j] - d[1, j]
    z[0, j] = d[0, j] + w / 2
    z[1, j] = d[1, j] + h / 2
    return w, h


@_compiled()
def _corners(
    out: npt.NDArray[np.float64], j: int, cx: float, cy: float, hw: float, hh: float
) -> None:
    """The box of centre (cx, cy) and half sizes (hw, hh) as x1 y1 x2 y2 into column ``j``."""
    out[0, j] = cx - hw
    out[1, j] = cy - hh
    out[2, j] = cx + hw
    out[3, j] = cy + hh


@_compiled(_F2(_F2))
def sort_z(d: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Boxes (4 x k) as SORT's measurements (centre x, centre y, area, aspect ratio)."""
    z = np.empty((4, d.shape[1]))
    for j in range(d.shape[1]):
        w, h = _centre(d, j, z)
        z[2, j] = w * h
        z[3, j] = w / _max(h, 1e-9)
    return z


@_compiled(_F2(_F2))
def sort_boxes(s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """SORT's means (rows 0-3 of ``s``) as boxes (4 x k)."""
    out = np.empty((4, s.shape[1]))
    for j in range(s.shape[1]):
        area = _max(s[2, j], 1e-9)
        w = np.sqrt(area * _max(s[3, j], 1e-9))
        _corners(out, j, s[0, j], s[1, j], w / 2, area / w / 2)
    return out


@_compiled(_F2(_F2))
def bt_xyah(d: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Boxes (4 x k) as ByteTrack's measurements (centre x, centre y, aspect ratio, height)."""
    z = np.empty((4, d.shape[1]))
    for j in range(d.shape[1]):
        w, h = _centre(d, j, z)
        z[2, j] = w / _max(h, 1e-9)
        z[3, j] = h
    return z


@_compiled(_F2(_F2))
def bt_boxes(m: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """ByteTrack's means (rows 0-3 of ``m``) as boxes (4 x k)."""
    out = np.empty((4, m.shape[1]))
    for j in range(m.shape[1]):
        _corners(out, j, m[0, j], m[1, j], m[2, j] * m[3, j] / 2, m[3, j] / 2)
    return out


@_compiled(numba.void(_F2, _F2))
def predict(s: npt.NDArray[np.float64], q: npt.NDArray[np.float64]) -> None:
    """Every filter of ``s`` (24 x k) predicted in place: x = F x, P = F P F^T + Q, with Q's
    rows 8-23 (Paa, Pab, Pba, Pbb) in ``q`` (16 x k, or 16 x 1 for every track alike).
    ``Filters.predict``'s order: Paa = (Paa + Pba) + (Pab + Pbb), Pab += Pbb, Pba += Pbb, then
    Q added."""
    k = s.shape[1]
    shared = q.shape[1] == 1
    for j in range(k):
        c = 0 if shared else j
        for i in range(4):
            s[i, j] += s[4 + i, j]
            paa = s[8 + i, j] + s[16 + i, j]
            pbb = s[20 + i, j]
            pab = s[12 + i, j] + pbb
            s[12 + i, j] = pab
            s[16 + i, j] += pbb
            s[8 + i, j] = paa + pab
        for r in range(16):
            s[8 + r, j] += q[r, c]


@_compiled(numba.void(_F2, _I1, _F2, _F2))
def update(
    s: npt.NDArray[np.float64],
    rows: npt.NDArray[np.intp],
    z: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64],
) -> None:
    """The filters ``rows`` of ``s`` (distinct) updated in place with the measurements ``z``
    (4 x len(rows), in the order of ``rows``) of noise variances ``r`` (4 x len(rows), or
    4 x 1 for all alike). ``Filters.update``'s operations, column by column."""
    shared = r.shape[1] == 1
    for j in range(rows.shape[0]):
        t = rows[j]
        c = 0 if shared else j
        for i in range(4):
            paa = s[8 + i, t]
            pab = s[12 + i, t]
            sv = paa + r[i, c]
            inv = 1.0 / sv
            ka = paa * inv
            kb = pab * inv
            y = z[i, j] - s[i, t]
            s[i, t] += ka * y
            s[4 + i, t] += kb * y
            kas = ka * sv
            kbs = kb * sv
            s[8 + i, t] = paa - kas * ka
            s[12 + i, t] = pab - kas * kb
            s[16 + i, t] -= kbs * ka
            s[20 + i, t] -= kbs * kb
