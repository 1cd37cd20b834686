"""The Kalman filters of the trackers' tracks (``replaybench.tracking.trackers``), kept as
2x2 blocks: one array of 24 rows, a column a track.

Both trackers' filters have a constant-velocity F (state i + 4, the velocity of measured state
i, is added to it each frame), H measuring states 0-3, and diagonal Q, R and initial P. Their
covariance therefore stays block-diagonal: for each measured state i a 2x2 block of (i, i + 4),
every other entry an exact zero. The filters of a tracker's tracks are kept as one array of
24 rows, a column a track: the means x (rows 0-3) and v (4-7), then the blocks' entries
P[i, i] (8-11), P[i, i+4] (12-15), P[i+4, i] (16-19) and P[i+4, i+4] (20-23). Predict and
update are elementwise operations on these rows, in the order of the products and sums of
the matrix form (whose other terms add exact zeros); S^-1 is applied as the LAPACK solve of
a diagonal S does it, multiplying by 1/S. SORT's ratio has no velocity: its row 7 and its
block's velocity entries stay zero.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy.typing as npt

__all__ = ['ROWS', 'Filters', 'scattered']

ROWS = 24


class Filters:
    """The Kalman filters of a tracker's tracks (the layout above)."""

    def __init__(self) -> None:
        self.s: npt.NDArray[np.float64] = np.zeros((ROWS, 0))

    def add(self, z: npt.NDArray[np.float64], paa: npt.ArrayLike, pbb: npt.ArrayLike) -> None:
        """New tracks at ``z`` (4 x k), velocity zero, P diagonal: ``paa`` for the measured
        states, ``pbb`` for their velocities (4 x k or 4 x 1)."""
        new = np.zeros((ROWS, z.shape[1]))
        new[0:4] = z
        new[8:12] = paa
        new[20:24] = pbb
        self.s = np.concatenate([self.s, new], axis=1)

    def keep(self, mask: npt.NDArray[np.bool_]) -> None:
        self.s = self.s[:, mask]

    def predict(self) -> None:
        """x = F x, P = F P F^T (the process noise is added by the tracker, to rows 8-11 and
        20-23)."""
        s = self.s
        s[0:4] += s[4:8]
        # F P, then (F P) F^T: Paa = (Paa + Pba) + (Pab + Pbb), Pab += Pbb, Pba += Pbb
        s[8:12] += s[16:20]
        s[12:20].reshape(2, 4, -1)[:] += s[20:24]
        s[8:12] += s[12:16]

    def update(
        self,
        rows: npt.NDArray[np.intp],
        z: npt.NDArray[np.float64],
        r: npt.NDArray[np.float64] | Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]],
    ) -> None:
        """Tracks ``rows`` (distinct) measured ``z`` (4 x k) with noise variances ``r`` (4 x 1),
        or ``r(g)`` (4 x k) of the tracks' filters ``g`` (24 x k, in the order of ``rows``)."""
        k = len(rows)
        every = k == self.s.shape[1]
        if every:  # rows is a permutation: z put in the tracks' order, the filters in place
            g = self.s
            z = scattered(z, rows)
        else:
            g = self.s[:, rows]
        if callable(r):
            r = r(g)
        # one contiguous block of rows an operation (cheaper than a strided or 3-D one)
        s = g[8:12] + r
        inv = 1.0 / s
        ka = g[8:12] * inv  # K: Paa / S and Pab / S
        kb = g[12:16] * inv
        y = z - g[0:4]
        g[0:4] += ka * y  # x += Ka y, v += Kb y
        g[4:8] += kb * y
        # P -= K S K^T: (Ka S) Ka, (Ka S) Kb, (Kb S) Ka, (Kb S) Kb
        kas = ka * s
        kbs = kb * s
        g[8:12] -= kas * ka
        g[12:16] -= kas * kb
        g[16:20] -= kbs * ka
        g[20:24] -= kbs * kb
        if not every:
            self.s[:, rows] = g


def scattered(
    values: npt.NDArray[np.float64], rows: npt.NDArray[np.intp]
) -> npt.NDArray[np.float64]:
    """``values`` (m x k) with column j moved to column ``rows[j]``."""
    out = np.empty_like(values)
    out[:, rows] = values
    return out
