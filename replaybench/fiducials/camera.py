"""A camera's intrinsics and distortion from its CameraInfo, and undistortion of pixels.

``plumb_bob`` and ``rational_polynomial`` use OpenCV's radial-tangential model
(``cv2.undistortPoints``); ``equidistant`` (and its alias ``fisheye``) the Kannala-Brandt
model (``cv2.fisheye.undistortPoints``). Undistorted points are given back in pixels of the
same K (``P=K``), so a pose is solved from them with K and no distortion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from replaybench.errors import DecodeError

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.types import CameraInfo

__all__ = [
    'DISTORTION_MODELS',
    'UNDISTORT_CRITERIA',
    'CameraModel',
    'camera_model',
    'undistort_pixels',
]

#: The iterative undistortion runs to 1e-10 (normalised units) or 50 iterations: OpenCV's
#: default (5 iterations) leaves pixels of error near the edge of a strongly distorted lens.
UNDISTORT_CRITERIA = (3, 50, 1e-10)  # cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS

#: distortion_model values understood, and the model each is solved with.
DISTORTION_MODELS: dict[str, str] = {
    'plumb_bob': 'plumb_bob',
    'rational_polynomial': 'plumb_bob',
    'equidistant': 'equidistant',
    'fisheye': 'equidistant',
    '': 'none',
}


@dataclass(frozen=True, slots=True)
class CameraModel:
    """K (row-major 3x3), the distortion coefficients, the model and the camera's frame."""

    k: tuple[float, ...]
    d: tuple[float, ...]
    model: str  # 'plumb_bob' | 'equidistant' | 'none'
    frame_id: str = ''

    @property
    def matrix(self) -> npt.NDArray[np.float64]:
        """K as a 3x3 float64 array."""
        return np.asarray(self.k, dtype=np.float64).reshape(3, 3)

    @property
    def distorted(self) -> bool:
        return self.model != 'none' and any(v != 0.0 for v in self.d)


def camera_model(info: CameraInfo) -> CameraModel:
    """The CameraModel of a CameraInfo; ``DecodeError`` (one line) when K is not a camera
    matrix (zeros: an uncalibrated camera) or the distortion model is not one of
    ``DISTORTION_MODELS``."""
    k = tuple(float(v) for v in info.k)
    where = f'{info.topic or "CameraInfo"}'
    if len(k) != 9 or not all(np.isfinite(k)) or k[0] <= 0 or k[4] <= 0 or k[8] != 1.0:
        msg = f'{where}: K is not a calibrated camera matrix (fx, fy > 0, K[8] = 1): {k}'
        raise DecodeError(msg)
    name = info.distortion_model.strip().lower()
    model = DISTORTION_MODELS.get(name)
    if model is None:
        known = ', '.join(n for n in DISTORTION_MODELS if n)
        msg = f'{where}: distortion model {info.distortion_model!r} is not supported ({known})'
        raise DecodeError(msg)
    d = tuple(float(v) for v in info.d)
    if not all(np.isfinite(d)):
        msg = f'{where}: distortion coefficients are not finite: {d}'
        raise DecodeError(msg)
    if model == 'equidistant' and len(d) < 4:
        msg = f'{where}: equidistant distortion needs 4 coefficients, got {len(d)}'
        raise DecodeError(msg)
    if model == 'plumb_bob' and d and len(d) not in {4, 5, 8, 12, 14}:
        msg = f'{where}: {name} distortion has {len(d)} coefficients (4, 5, 8, 12 or 14)'
        raise DecodeError(msg)
    return CameraModel(k, d[:4] if model == 'equidistant' else d, model, info.frame_id)


def undistort_pixels(
    camera: CameraModel, points: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """(N, 2) distorted pixel coordinates -> (N, 2) undistorted pixels of the same K."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 1, 2)
    if not camera.distorted:
        return pts.reshape(-1, 2).copy()
    import cv2

    k = camera.matrix
    d = np.asarray(camera.d, dtype=np.float64)
    if camera.model == 'equidistant':
        out = cv2.fisheye.undistortPoints(
            pts, k, d.reshape(1, 4), R=np.eye(3), P=k, criteria=UNDISTORT_CRITERIA
        )
    else:
        out = cv2.undistortPoints(pts, k, d, R=np.eye(3), P=k, criteria=UNDISTORT_CRITERIA)
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)
