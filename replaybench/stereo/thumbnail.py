"""Pictures of a disparity and of its error, for the report's thumbnails.

``disparity_picture``: a disparity through OpenCV's TURBO colour map, 0 to ``max_disparity``
(near is red), black where there is no estimate. ``error_picture``: the error against truth
in KITTI's manner of showing it: green within 1 px, yellow within 3 px, red beyond, magenta
where truth has no estimate, black where there is no truth. Both are RGB uint8, reduced to at
most ``width`` pixels across by taking every n-th pixel (integer steps: the same bytes on
every machine).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.stereo.metrics import known_truth

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ['disparity_picture', 'error_picture']


def _shrink(image: npt.NDArray[Any], width: int | None) -> npt.NDArray[Any]:
    if width is None or image.shape[1] <= width:
        return image
    step = -(-image.shape[1] // width)
    return np.ascontiguousarray(image[::step, ::step])


def _estimated(d: npt.NDArray[np.float64], min_disparity: float) -> npt.NDArray[np.bool_]:
    with np.errstate(invalid='ignore'):
        return np.isfinite(d) & (d >= min_disparity)


def disparity_picture(
    disparity: npt.NDArray[np.floating[Any]],
    *,
    max_disparity: float | None = None,
    min_disparity: float = 0.0,
    width: int | None = 320,
) -> npt.NDArray[np.uint8]:
    """An RGB picture of a disparity (see the module); ``max_disparity`` None: its largest."""
    import cv2

    d = _shrink(np.asarray(disparity, dtype=np.float64), width)
    ok = _estimated(d, min_disparity)
    top = max_disparity if max_disparity is not None else (float(d[ok].max()) if ok.any() else 1.0)
    scaled = np.zeros(d.shape, dtype=np.uint8)
    if top > 0:
        scaled[ok] = np.clip(np.rint(d[ok] * (255.0 / top)), 0, 255).astype(np.uint8)
    bgr = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    rgb: npt.NDArray[np.uint8] = np.ascontiguousarray(bgr[..., ::-1], dtype=np.uint8)
    rgb[~ok] = 0
    return rgb


def error_picture(
    disparity: npt.NDArray[np.floating[Any]],
    truth: npt.NDArray[np.floating[Any]],
    *,
    min_disparity: float = 0.0,
    width: int | None = 320,
) -> npt.NDArray[np.uint8]:
    """An RGB picture of the error of a disparity against its truth (see the module)."""
    d = _shrink(np.asarray(disparity, dtype=np.float64), width)
    gt = _shrink(np.asarray(truth, dtype=np.float64), width)
    has_truth = known_truth(gt)
    ok = _estimated(d, min_disparity) & has_truth
    error = np.where(ok, np.abs(d - np.where(has_truth, gt, 0.0)), np.inf)
    out = np.zeros((*d.shape, 3), dtype=np.uint8)
    out[ok & (error <= 1.0)] = (40, 180, 60)
    out[ok & (error > 1.0) & (error <= 3.0)] = (230, 200, 40)
    out[ok & (error > 3.0)] = (215, 40, 40)
    out[has_truth & ~ok] = (200, 40, 200)
    return out
