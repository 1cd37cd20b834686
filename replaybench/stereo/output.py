"""``Disparity``: what a backend of the ``stereo`` task returns for one stereo pair.

A backend that declares ``task = 'stereo'`` returns it in ``BackendResult.output``; the task's
recording writes it as a ``stereo_msgs/msg/DisparityImage`` (``replaybench.stereo.msgs``) and
scores it against the truth (``replaybench.stereo.metrics``). The fields are those of a
DisparityImage as stereo_image_proc fills them:

- ``disparity``: float32, H x W of the LEFT rectified image, ``d = x_left - x_right`` in
  pixels; NaN where the backend has no estimate (a value below ``min_disparity`` is no estimate
  too, as a DisparityImage marks it);
- ``f``: the focal length in pixels (the right camera's ``P[0]``), ``t``: the baseline
  (``-Tx / fx`` of the right camera's P, metres where the calibration is), both > 0;
- ``min_disparity`` / ``max_disparity``: the range searched; ``delta_d``: the smallest step
  of a value (1/16 for OpenCV's matchers; 0 where the values are continuous, a network's);
- ``valid_window``: (x_offset, y_offset, height, width) of the pixels that can hold a match;
  (0, 0, 0, 0) where the backend does not say;
- ``cx_offset``: ``cx_left - cx_right`` of the two P (0 for pairs rectified with
  ``CALIB_ZERO_DISPARITY``): depth is ``Z = f * t / (d - cx_offset)``.

A network that estimates at its own size rescales to the left image's size (and multiplies
the values by the width's ratio) before it returns.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.errors import StereoError

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.stereo.calibration import StereoPair
    from replaybench.stereo.msgs import DisparityMessage

__all__ = ['Disparity']


@dataclass(frozen=True, slots=True, eq=False)
class Disparity:
    """One pair's disparity of the left rectified image and its geometry (see the module)."""

    disparity: npt.NDArray[np.float32]
    f: float
    t: float
    min_disparity: float
    max_disparity: float
    delta_d: float
    valid_window: tuple[int, int, int, int] = (0, 0, 0, 0)
    cx_offset: float = 0.0

    def __post_init__(self) -> None:
        d = self.disparity
        if not isinstance(d, np.ndarray) or d.ndim != 2 or d.dtype != np.float32:
            shape = getattr(d, 'shape', None)
            dtype = getattr(d, 'dtype', type(d).__name__)
            msg = f'a Disparity holds a float32 H x W array, not {dtype} of shape {shape}'
            raise StereoError(msg)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height)."""
        return int(self.disparity.shape[1]), int(self.disparity.shape[0])

    def estimated(self) -> npt.NDArray[np.bool_]:
        """The pixels with an estimate: finite and at least ``min_disparity``."""
        with np.errstate(invalid='ignore'):
            out: npt.NDArray[np.bool_] = np.isfinite(self.disparity) & (
                self.disparity >= self.min_disparity
            )
        return out

    def depth(self) -> npt.NDArray[np.float32]:
        """Depth of each pixel in the baseline's unit, ``f * t / (d - cx_offset)``; NaN where
        there is no estimate or the point would be at or behind infinity."""
        d = np.where(self.estimated(), self.disparity.astype(np.float64) - self.cx_offset, np.nan)
        with np.errstate(divide='ignore', invalid='ignore'):
            z = np.where(d > 0, self.f * self.t / d, np.nan)
        return z.astype(np.float32)

    @classmethod
    def of_pair(
        cls,
        disparity: npt.NDArray[np.floating[Any]],
        pair: StereoPair,
        *,
        min_disparity: float,
        max_disparity: float,
        delta_d: float,
        valid_window: tuple[int, int, int, int] = (0, 0, 0, 0),
    ) -> Disparity:
        """A pair's disparity with the pair's focal length, baseline and offset."""
        return cls(
            disparity=np.asarray(disparity, dtype=np.float32),
            f=pair.focal_px,
            t=pair.baseline,
            min_disparity=float(min_disparity),
            max_disparity=float(max_disparity),
            delta_d=float(delta_d),
            valid_window=valid_window,
            cx_offset=pair.cx_offset,
        )

    @classmethod
    def of_message(cls, message: DisparityMessage) -> Disparity:
        """A recorded DisparityImage's fields (its values below min_disparity kept as they
        are: they are no estimate)."""
        return cls(
            disparity=message.disparity,
            f=message.f,
            t=message.t,
            min_disparity=message.min_disparity,
            max_disparity=message.max_disparity,
            delta_d=message.delta_d,
            valid_window=message.valid_window,
        )
