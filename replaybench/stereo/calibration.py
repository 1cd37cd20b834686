"""A stereo pair's geometry from its two CameraInfo messages, and rectification of raw pairs.

As ROS's ``image_geometry.StereoCameraModel`` reads a pair (and ``stereo_image_proc`` uses
it): the focal length is the right camera's ``P[0]`` (fx), the baseline ``B = -Tx / fx`` with
``Tx = P[3]`` of the right camera's P (``Tx = -fx * B``), metres where the calibration is in
metres. Disparity here is ``d = x_left - x_right`` in pixels of the rectified images; the
depth of a pixel is ``Z = f * B / (d - (cx_left - cx_right))`` (stereo_image_proc subtracts
the same principal-point offset; it is 0 for a pair rectified with ``CALIB_ZERO_DISPARITY``,
the ROS calibrator's default).

A pair is used as it is (``rectified``) when both cameras' R is the identity (or all zeros,
which image_geometry reads as unset), their distortion is zero and ``P[:3, :3]`` equals K:
rectifying would be the identity map. Otherwise each image is rectified with maps built once
from K, D, R and P, as ``image_geometry.PinholeCameraModel.initRectificationMaps`` builds them
(``cv2.initUndistortRectifyMap`` for ``plumb_bob`` / ``rational_polynomial``,
``cv2.fisheye.initUndistortRectifyMap`` for ``equidistant``; 16-bit fixed-point maps,
``cv2.remap`` with bilinear interpolation, image_proc's default). ``maps='float'`` builds
32-bit float maps instead: each source position as computed (the fixed-point maps round it to
1/32 px), which OpenCV's remap interpolates in floating point on a faster path (1.4 against
2.1 ms a 752x480 pair here). Its images differ a little from the fixed-point ones (EuRoC:
0.06 grey levels on average, at most 4) and may differ between CPUs (OpenCV picks its SIMD
code, with FMA or without, at run time); the fixed-point integer path gives the same bytes on
every CPU, hence the default. A topic named
``image_rect`` is rectified whatever its CameraInfo says (ROS publishes the raw camera's
CameraInfo beside it): ``stereo_pair(..., rectified=True)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.errors import DecodeError, StereoError
from replaybench.fiducials.camera import camera_model

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.types import CameraInfo

__all__ = ['RECTIFY_MAPS', 'Rectifier', 'StereoPair', 'rectify_maps', 'stereo_pair']

#: The kinds of rectification maps: ``fixed`` (16-bit fixed point, image_geometry's; the
#: default) and ``float`` (32-bit float, faster, not bit-exact across CPUs).
RECTIFY_MAPS = ('fixed', 'float')

_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
_TOLERANCE = 1e-9


def _is_identity(r: tuple[float, ...]) -> bool:
    return all(v == 0.0 for v in r) or (
        len(r) == 9 and all(abs(a - b) <= _TOLERANCE for a, b in zip(r, _IDENTITY, strict=True))
    )


def _name(info: CameraInfo, side: str) -> str:
    return info.topic or f'the {side} CameraInfo'


def _already_rectified(info: CameraInfo) -> bool:
    k = tuple(float(v) for v in info.k)
    p = tuple(float(v) for v in info.p)
    same_k = all(
        abs(k[i] - p[j]) <= _TOLERANCE
        for i, j in zip(range(9), (0, 1, 2, 4, 5, 6, 8, 9, 10), strict=True)
    )
    return _is_identity(tuple(float(v) for v in info.r)) and not any(info.d) and same_k


@dataclass(frozen=True, slots=True)
class StereoPair:
    """The geometry of a stereo pair, as image_geometry's StereoCameraModel gives it.

    ``focal_px``: the right camera's P[0]; ``baseline``: ``-Tx / fx`` of the right camera's
    P (> 0); ``cx_offset``: ``cx_left - cx_right`` of the two P (the ``doffs`` of Middlebury
    with the opposite sign); ``rectified``: the images are used as they are (no maps).
    """

    left: CameraInfo
    right: CameraInfo
    focal_px: float
    baseline: float
    cx_offset: float
    rectified: bool

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of both images."""
        return self.left.width, self.left.height

    def depth(self, disparity: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.float32]:
        """Depth (the baseline's unit) of each pixel of a disparity image; NaN where the
        disparity is not finite or the point would be at or behind infinity."""
        d = np.asarray(disparity, dtype=np.float64) - self.cx_offset
        with np.errstate(divide='ignore', invalid='ignore'):
            z = np.where(d > 0, self.focal_px * self.baseline / d, np.nan)
        return z.astype(np.float32)

    def disparity_of_depth(self, depth: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.float32]:
        """The disparity (px) of a depth image; NaN where the depth is not finite or <= 0."""
        z = np.asarray(depth, dtype=np.float64)
        with np.errstate(divide='ignore', invalid='ignore'):
            d = np.where(np.isfinite(z) & (z > 0), self.focal_px * self.baseline / z, np.nan)
        return (d + self.cx_offset).astype(np.float32)

    def rectifier(self, maps: str = 'fixed') -> Rectifier:
        """Rectification maps of both cameras, built now (once per pair); ``maps``: one of
        ``RECTIFY_MAPS``."""
        return Rectifier(self, maps)


def stereo_pair(
    left: CameraInfo | None, right: CameraInfo | None, *, rectified: bool | None = None
) -> StereoPair:
    """The StereoPair of two CameraInfo; ``StereoError`` (one line, exit 2) for a missing
    CameraInfo, images of different sizes, a P without a baseline, an uncalibrated camera.

    ``rectified``: True where the images are known to be rectified already (``image_rect``
    topics), False to rectify them whatever the CameraInfo says, None to decide from it.
    """
    if left is None or right is None:
        side = 'left' if left is None else 'right'
        msg = f'the {side} camera of the stereo pair has no CameraInfo'
        raise StereoError(msg)
    if (left.width, left.height) != (right.width, right.height):
        msg = (
            f'the stereo pair has images of different sizes: {left.width}x{left.height} '
            f'({_name(left, "left")}) and {right.width}x{right.height} ({_name(right, "right")})'
        )
        raise StereoError(msg)
    for info, side in ((left, 'left'), (right, 'right')):
        p = tuple(float(v) for v in info.p)
        if len(p) != 12 or not all(np.isfinite(p)) or p[0] <= 0 or p[5] <= 0:
            msg = f'{_name(info, side)}: P is not a projection matrix (fx, fy > 0): {p}'
            raise StereoError(msg)
        try:
            camera_model(info)
        except DecodeError as err:
            raise StereoError(str(err)) from None
    p_left, p_right = tuple(map(float, left.p)), tuple(map(float, right.p))
    fx, tx = p_right[0], p_right[3]
    baseline = -tx / fx
    if not baseline > 0:
        why = 'Tx is 0' if tx == 0 else f'Tx = {tx:g} > 0 (left and right swapped?)'
        msg = (
            f'{_name(right, "right")}: P has no baseline ({why}); the right camera of a '
            'stereo pair has Tx = -fx * baseline'
        )
        raise StereoError(msg)
    if rectified is None:
        rectified = _already_rectified(left) and _already_rectified(right)
    return StereoPair(
        left=left,
        right=right,
        focal_px=fx,
        baseline=baseline,
        cx_offset=p_left[2] - p_right[2],
        rectified=rectified,
    )


def rectify_maps(value: object, backend: str) -> str:
    """The kind of maps a backend option names (``fixed`` where it names none); ``StereoError``
    (one line, exit 2) for another value."""
    if value is None:
        return 'fixed'
    text = str(value).strip().lower()
    if text not in RECTIFY_MAPS:
        msg = f'{backend}: rectify_maps must be one of {", ".join(RECTIFY_MAPS)}, not {value!r}'
        raise StereoError(msg)
    return text


def _maps(info: CameraInfo, maps: str = 'fixed') -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
    """The remap maps of one camera: ``fixed``: CV_16SC2 + CV_16UC1 (image_geometry's);
    ``float``: two CV_32FC1."""
    import cv2

    camera = camera_model(info)
    k = camera.matrix
    d = np.asarray(camera.d, dtype=np.float64)
    r = np.asarray(info.r, dtype=np.float64).reshape(3, 3)
    if not r.any():
        r = np.eye(3)
    p = np.asarray(info.p, dtype=np.float64).reshape(3, 4)[:, :3]
    size = (info.width, info.height)
    kind = cv2.CV_32FC1 if maps == 'float' else cv2.CV_16SC2
    if camera.model == 'equidistant':
        map1, map2 = cv2.fisheye.initUndistortRectifyMap(k, d.reshape(1, 4), r, p, size, kind)
    else:
        map1, map2 = cv2.initUndistortRectifyMap(
            k, d if camera.model != 'none' else None, r, p, size, kind
        )
    if maps == 'float':
        return np.asarray(map1, dtype=np.float32), np.asarray(map2, dtype=np.float32)
    return np.asarray(map1, dtype=np.int16), np.asarray(map2, dtype=np.uint16)


class Rectifier:
    """Rectifies the images of a pair with maps built once (none for a rectified pair)."""

    __slots__ = ('_left', '_right', 'maps', 'pair')

    def __init__(self, pair: StereoPair, maps: str = 'fixed') -> None:
        if maps not in RECTIFY_MAPS:
            msg = f'rectify_maps must be one of {", ".join(RECTIFY_MAPS)}, not {maps!r}'
            raise StereoError(msg)
        self.pair = pair
        self.maps = maps
        self._left = None if pair.rectified else _maps(pair.left, maps)
        self._right = None if pair.rectified else _maps(pair.right, maps)

    def rectify(
        self, left: npt.NDArray[Any], right: npt.NDArray[Any]
    ) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
        """The rectified left and right images (the same arrays for a rectified pair);
        ``StereoError`` for an image not of the CameraInfo's size."""
        width, height = self.pair.size
        for image, side in ((left, 'left'), (right, 'right')):
            if image.shape[:2] != (height, width):
                msg = (
                    f'the {side} image is {image.shape[1]}x{image.shape[0]}, its CameraInfo '
                    f'says {width}x{height}'
                )
                raise StereoError(msg)
        if self._left is None or self._right is None:
            return left, right
        import cv2

        out_left = cv2.remap(left, *self._left, cv2.INTER_LINEAR)
        out_right = cv2.remap(right, *self._right, cv2.INTER_LINEAR)
        return out_left, out_right
