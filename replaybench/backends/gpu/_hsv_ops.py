"""The hsv algorithm as array operations, for CuPy on the GPU (and NumPy + SciPy to test it).

``xp`` is the array module (``cupy`` / ``numpy``), ``ndi`` its ``ndimage``
(``cupyx.scipy.ndimage`` / ``scipy.ndimage``). Steps, matching ``replaybench.backends.hsv``:

* ``to_hsv``: OpenCV's 8-bit RGB->HSV in integer arithmetic, bit-exact with ``cv2.cvtColor``;
* ``class_masks``: per class, the union over its ranges of the inclusive HSV box; then the
  morphological open and close with the elliptic kernel (outside the image never counts);
* ``blob_stats``: the outer blobs of every class mask (8-connected components with their
  holes filled, as ``findContours(RETR_EXTERNAL)`` + a filled ``drawContours`` give them) in
  one labelling pass, and per blob its class, box, mask pixels, filled area, boundary pixels
  and saturation sum: boxes by one scatter-min / scatter-max over the labelled pixels
  (``label_extents``), sums by ``bincount``, so the work does not grow with a loop per blob.

Contour tracing is replaced by labelling. OpenCV's ``contourArea`` of a blob's outer contour
is estimated with Pick's theorem as ``filled - boundary / 2 - 1``: exact where the contour
passes each boundary pixel once; one-pixel-wide parts, which the contour walks out and back,
add half a pixel per pixel to the estimate but nothing to ``contourArea`` (the default
open with a 5 px kernel removes them before).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from replaybench.backends.hsv import ColorClass

__all__ = [
    'STAT_COLUMNS',
    'BlobStat',
    'blob_stats',
    'class_masks',
    'contour_area_estimate',
    'fill_holes',
    'hsv_tables',
    'label_extents',
    'read_stats',
    'to_hsv',
]

_SHIFT = 12
_HALF = 1 << (_SHIFT - 1)
#: Columns of the ``blob_stats`` array.
STAT_COLUMNS = ('class', 'x0', 'y0', 'x1', 'y1', 'pixels', 'filled', 'boundary', 'sum_s')


def hsv_tables() -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int32]]:
    """OpenCV's fixed-point division tables (``sdiv_table``, ``hdiv_table180``)."""
    i = np.arange(256, dtype=np.float64)
    i[0] = 1.0
    sdiv = np.rint((255 << _SHIFT) / i).astype(np.int32)
    hdiv = np.rint((180 << _SHIFT) / (6.0 * i)).astype(np.int32)
    sdiv[0] = 0
    hdiv[0] = 0
    return sdiv, hdiv


def to_hsv(xp: Any, image: Any, blue: int, tables: tuple[Any, Any]) -> tuple[Any, Any, Any]:
    """H, S, V planes (uint8, OpenCV scale H 0..180) of an HxWx3+ uint8 image.

    ``blue`` is the channel index of blue: 0 for BGR(A), 2 for RGB(A). ``tables`` are
    ``hsv_tables()`` as arrays of ``xp``.
    """
    sdiv, hdiv = tables
    b = image[..., blue].astype(xp.int32)
    g = image[..., 1].astype(xp.int32)
    r = image[..., blue ^ 2].astype(xp.int32)
    v = xp.maximum(xp.maximum(b, g), r)
    diff = v - xp.minimum(xp.minimum(b, g), r)
    s = (diff * sdiv[v] + _HALF) >> _SHIFT
    h = xp.where(v == r, g - b, xp.where(v == g, b - r + 2 * diff, r - g + 4 * diff))
    h = (h * hdiv[diff] + _HALF) >> _SHIFT
    h = xp.where(h < 0, h + 180, h)
    return h.astype(xp.uint8), s.astype(xp.uint8), v.astype(xp.uint8)


def class_masks(
    xp: Any,
    ndi: Any,
    planes: tuple[Any, Any, Any],
    classes: Sequence[ColorClass],
    kernel: Any,
    open_iterations: int,
    close_iterations: int,
) -> Any:
    """A [classes, H, W] bool stack: each class's HSV mask after open then close.

    ``kernel`` is the 2-D structuring element (bool array of ``xp``) or None for no morphology.
    Erosion treats outside the image as set and dilation as unset, like OpenCV's default border.
    """
    h, s, v = planes
    masks = xp.zeros((len(classes), *h.shape), dtype=bool)
    for index, cls in enumerate(classes):
        mask = masks[index]
        for lo, hi in cls.ranges:
            mask |= (
                (h >= lo[0])
                & (h <= hi[0])
                & (s >= lo[1])
                & (s <= hi[1])
                & (v >= lo[2])
                & (v <= hi[2])
            )
    if kernel is None:
        return masks
    structure = kernel[None]  # never reaches across classes
    if open_iterations:
        masks = _erode(ndi, masks, structure, open_iterations)
        masks = _dilate(ndi, masks, structure, open_iterations)
    if close_iterations:
        masks = _dilate(ndi, masks, structure, close_iterations)
        masks = _erode(ndi, masks, structure, close_iterations)
    return masks


def _erode(ndi: Any, masks: Any, structure: Any, iterations: int) -> Any:
    """Erosion repeated ``iterations`` times; outside the image counts as set."""
    return ndi.binary_erosion(
        masks, structure, iterations=iterations, border_value=1, brute_force=True
    )


def _dilate(ndi: Any, masks: Any, structure: Any, iterations: int) -> Any:
    """Dilation repeated ``iterations`` times; outside the image counts as unset."""
    return ndi.binary_dilation(
        masks, structure, iterations=iterations, border_value=0, brute_force=True
    )


def _structures(xp: Any) -> tuple[Any, Any]:
    """3-D structures that connect pixels within a class plane only: 8- and 4-connectivity."""
    eight = np.zeros((3, 3, 3), dtype=bool)
    eight[1] = True
    four = np.zeros((3, 3, 3), dtype=bool)
    four[1, 1, :] = four[1, :, 1] = True
    return xp.asarray(eight), xp.asarray(four)


def fill_holes(xp: Any, ndi: Any, masks: Any) -> Any:
    """The masks with every hole filled: the regions that OpenCV's outer contours enclose.

    Background is 4-connected (the dual of 8-connected blobs); background components that
    touch the image edge are outside, all others are holes.
    """
    _, four = _structures(xp)
    background, count = ndi.label(~masks, structure=four)
    outside = xp.zeros(int(count) + 1, dtype=bool)
    outside[0] = True  # label 0: the mask pixels themselves
    for edge in (
        background[:, 0, :],
        background[:, -1, :],
        background[:, :, 0],
        background[:, :, -1],
    ):
        outside[edge.ravel()] = True
    return masks | ~outside[background]


def blob_stats(xp: Any, ndi: Any, masks: Any, saturation: Any) -> Any:
    """One row per outer blob of the class masks, columns ``STAT_COLUMNS``.

    A blob is an 8-connected component of a class mask with its holes filled (what
    ``findContours(RETR_EXTERNAL)`` + a filled ``drawContours`` give): ``pixels`` and
    ``sum_s`` count the mask pixels inside it, ``filled`` and ``boundary`` its filled area
    and the filled pixels with a 4-neighbour outside it. Rows are float64 (exact for the
    integers they hold); ``x1`` / ``y1`` are exclusive. The array stays on the device of
    ``xp``: only this small table is downloaded.
    """
    eight, four = _structures(xp)
    filled = fill_holes(xp, ndi, masks)
    labels, count = ndi.label(filled, structure=eight)
    n = int(count)
    if n == 0:
        return xp.zeros((0, len(STAT_COLUMNS)), dtype=xp.float64)
    interior = ndi.binary_erosion(filled, structure=four, border_value=0)
    zs, ys, xs = xp.nonzero(labels)
    lab = labels[zs, ys, xs]
    in_mask = masks[zs, ys, xs].astype(xp.float64)
    boundary = (~interior[zs, ys, xs]).astype(xp.float64)
    sat = saturation[ys, xs].astype(xp.float64) * in_mask
    low, high = label_extents(xp, lab, (zs, xs, ys), n)

    def total(weights: Any = None) -> Any:
        return xp.bincount(lab, weights=weights, minlength=n + 1)[1:].astype(xp.float64)

    columns = [
        low[0],
        low[1],
        low[2],
        high[1] + 1,
        high[2] + 1,
        total(in_mask),
        total(),
        total(boundary),
        total(sat),
    ]
    return xp.stack(columns, axis=1)


def label_extents(xp: Any, labels: Any, coordinates: Sequence[Any], count: int) -> tuple[Any, Any]:
    """Per label 1..count, the smallest and largest of each coordinate: two ``[len(coordinates),
    count]`` float64 arrays.

    One scatter-min and one scatter-max over all pixels (``ufunc.at``: ``numpy.minimum.at``,
    CuPy's ``cupy.minimum.at`` = ``cupyx.scatter_min``), whatever the number of labels: no
    loop over blobs. Coordinates are int32 (CuPy's atomics take it; images are far smaller).
    Labels without pixels keep int32's max / -1.
    """
    rows = len(coordinates)
    width = count + 1
    offsets = xp.arange(rows, dtype=xp.int64)[:, None] * width
    index = (offsets + labels.astype(xp.int64)[None, :]).ravel()
    values = xp.stack([xp.asarray(c).astype(xp.int32) for c in coordinates]).ravel()
    low = xp.full(rows * width, np.iinfo(np.int32).max, dtype=xp.int32)
    high = xp.full(rows * width, -1, dtype=xp.int32)
    xp.minimum.at(low, index, values)
    xp.maximum.at(high, index, values)
    low = low.reshape(rows, width)[:, 1:].astype(xp.float64)
    high = high.reshape(rows, width)[:, 1:].astype(xp.float64)
    return low, high


def contour_area_estimate(filled: float, boundary: float) -> float:
    """OpenCV's ``contourArea`` of a blob's outer contour from its filled area (Pick's theorem)."""
    return max(filled - boundary / 2.0 - 1.0, 0.0)


class BlobStat(NamedTuple):
    """One downloaded ``blob_stats`` row."""

    class_index: int
    x0: int
    y0: int
    x1: int
    y1: int
    pixels: int
    filled: int
    boundary: int
    sum_s: float


def read_stats(rows: npt.NDArray[np.float64]) -> list[BlobStat]:
    """Host rows of ``blob_stats`` as ``BlobStat`` values."""
    return [
        BlobStat(
            class_index=int(r[0]),
            x0=int(r[1]),
            y0=int(r[2]),
            x1=int(r[3]),
            y1=int(r[4]),
            pixels=int(r[5]),
            filled=int(r[6]),
            boundary=int(r[7]),
            sum_s=float(r[8]),
        )
        for r in rows.tolist()
    ]
