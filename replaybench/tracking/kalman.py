"""The Kalman filters of the trackers' tracks (``replaybench.tracking.trackers``), kept as
2x2 blocks: one array of 24 rows, a column a track.

Both trackers' filters have a constant-velocity F (state i + 4, the velocity of measured state
i, is added to it each frame), H measuring states 0-3, and diagonal Q, R and initial P. Their
covariance therefore stays block-diagonal: for each measured state i a 2x2 block of (i, i + 4),
every other entry an exact zero. The filters of a tracker's tracks are kept as one array of
24 rows, a column a track: the means x (rows 0-3) and v (4-7), then the blocks' entries
P[i, i] (8-11), P[i, i+4] (12-15), P[i+4, i] (16-19) and P[i+4, i+4] (20-23). Predict and
update are elementwise operations on these rows (compiled loops,
``replaybench.tracking.kernels``), in the order of the products and sums of the matrix form
(whose other terms add exact zeros); S^-1 is applied as the LAPACK solve of a diagonal S does
it, multiplying by 1/S. SORT's ratio has no velocity: its row 7 and its
block's velocity entries stay zero.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from replaybench.tracking import kernels

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ['ROWS', 'Filters']

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
        """Only the tracks of ``mask``, the array C-contiguous as the kernels take it (where
        ``s[:, mask]`` would be laid out by columns)."""
        self.s = np.compress(mask, self.s, axis=1)

    def predict(self, q: npt.NDArray[np.float64]) -> None:
        """x = F x, P = F P F^T + Q, Q's rows 8-23 (Paa, Pab, Pba, Pbb) in ``q`` (16 x k, or
        16 x 1 for every track): ``kernels.predict``, in place."""
        if self.s.shape[1]:
            kernels.predict(self.s, q)

    def update(
        self,
        rows: npt.NDArray[np.intp],
        z: npt.NDArray[np.float64],
        r: npt.NDArray[np.float64],
    ) -> None:
        """Tracks ``rows`` (distinct) measured ``z`` (4 x k, in the order of ``rows``) with
        noise variances ``r`` (4 x k, or 4 x 1 for all): ``kernels.update``, in place."""
        kernels.update(
            self.s,
            np.ascontiguousarray(rows, dtype=np.intp),
            np.ascontiguousarray(z),
            np.ascontiguousarray(r),
        )
