"""Disparity files of the benchmarks: Middlebury ``.pfm`` and KITTI 16-bit ``.png``.

- PFM (Portable Float Map, Middlebury's ``disp0GT.pfm``): a ``Pf`` (grey) or ``PF`` (RGB)
  line, ``WIDTH HEIGHT``, a scale whose sign is the byte order (negative: little endian),
  then float32 rows from the BOTTOM row up. ``read_pfm`` gives the rows top first; Middlebury
  marks unknown truth with inf, which the metrics take as unknown.
- KITTI (``disp_occ_0/*.png``): uint16, disparity = value / 256, 0 = unknown (the devkit's
  ``disp_read``). ``read_kitti_png`` gives NaN for 0.

Both give float32 HxW disparities of the left image in pixels; a file that is not one is a
``StereoError`` (one line, exit 2).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.errors import StereoError

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ['read_disparity_file', 'read_kitti_png', 'read_pfm', 'write_kitti_png', 'write_pfm']

_PFM_HEADER = re.compile(rb'\A(P[Ff])\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)\s')


def read_pfm(source: str | Path | bytes) -> npt.NDArray[np.float32]:
    """A PFM file (or its bytes) as float32, rows top first (HxW, or HxWx3 for ``PF``)."""
    data = source if isinstance(source, bytes) else Path(source).read_bytes()
    name = '<bytes>' if isinstance(source, bytes) else str(source)
    match = _PFM_HEADER.match(data[:256])
    if match is None:
        msg = f'{name}: not a PFM file (no "Pf"/"PF" header)'
        raise StereoError(msg)
    colour = match.group(1) == b'PF'
    width, height = int(match.group(2)), int(match.group(3))
    try:
        scale = float(match.group(4))
    except ValueError:
        scale = 0.0
    if scale == 0.0 or width == 0 or height == 0:
        msg = f'{name}: a PFM header of {width}x{height}, scale {match.group(4).decode()!r}'
        raise StereoError(msg)
    channels = 3 if colour else 1
    count = width * height * channels
    body = data[match.end() :]
    if len(body) < count * 4:
        msg = f'{name}: a {width}x{height} PFM holds {len(body)} bytes, not {count * 4}'
        raise StereoError(msg)
    values = np.frombuffer(body, dtype='<f4' if scale < 0 else '>f4', count=count)
    shape = (height, width, 3) if colour else (height, width)
    return np.ascontiguousarray(values.reshape(shape)[::-1]).astype(np.float32)


def write_pfm(
    path: str | Path, image: npt.NDArray[np.floating[Any]], *, little_endian: bool = True
) -> Path:
    """Write a float32 HxW (or HxWx3) image as PFM, rows bottom first."""
    pixels = np.asarray(image, dtype=np.float32)
    kind = 'PF' if pixels.ndim == 3 else 'Pf'
    height, width = pixels.shape[:2]
    header = f'{kind}\n{width} {height}\n{-1.0 if little_endian else 1.0}\n'.encode()
    body = np.ascontiguousarray(pixels[::-1]).astype('<f4' if little_endian else '>f4').tobytes()
    target = Path(path)
    target.write_bytes(header + body)
    return target


def read_kitti_png(path: str | Path) -> npt.NDArray[np.float32]:
    """A KITTI 16-bit disparity PNG as float32 pixels (value / 256), NaN where it is 0."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint16 or image.ndim != 2:
        what = 'unreadable' if image is None else f'{image.dtype} with shape {image.shape}'
        msg = f'{path}: not a KITTI disparity PNG (16-bit grey), {what}'
        raise StereoError(msg)
    out = image.astype(np.float32) / np.float32(256.0)
    out[image == 0] = np.nan
    return out


def write_kitti_png(path: str | Path, disparity: npt.NDArray[np.floating[Any]]) -> Path:
    """Write a disparity as KITTI's PNG: ``round(d * 256)`` in 1..65535, 0 where there is
    none (not finite or <= 0)."""
    import cv2

    d = np.asarray(disparity, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        ok = np.isfinite(d) & (d > 0)
    values = np.zeros(d.shape, dtype=np.uint16)
    values[ok] = np.clip(np.rint(d[ok] * 256.0), 1, 65535).astype(np.uint16)
    target = Path(path)
    if not cv2.imwrite(str(target), values):
        msg = f'{target}: cannot write the PNG'
        raise StereoError(msg)
    return target


def read_disparity_file(path: str | Path) -> npt.NDArray[np.float32]:
    """A ``.pfm`` or KITTI ``.png`` disparity by its suffix (grey; a colour PFM's first channel)."""
    suffix = Path(path).suffix.lower()
    if suffix == '.pfm':
        image = read_pfm(path)
        return image[..., 0].copy() if image.ndim == 3 else image
    if suffix == '.png':
        return read_kitti_png(path)
    what = suffix or 'no suffix'
    msg = f'{path}: a disparity file is .pfm (Middlebury) or .png (KITTI), not {what}'
    raise StereoError(msg)
