"""Sample thumbnails: one frame with every backend's boxes drawn in the backend's colour."""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.report.svg import colour

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.types import Detection

__all__ = ['JPEG_QUALITY', 'MAX_WIDTH', 'sample_canvas', 'sample_relpath', 'write_sample']

#: Largest thumbnail width in pixels.
MAX_WIDTH = 480
#: JPEG quality of the thumbnails.
JPEG_QUALITY = 85
#: Longest topic part of a sample's file name; longer topics are cut and given a hash.
_MAX_NAME = 96


def sample_relpath(input_index: int, topic: str) -> str:
    """The run-folder relative path of the sample of ``topic`` of input ``input_index``."""
    safe = ''.join(c if c.isascii() and c.isalnum() else '_' for c in topic).strip('_') or 'topic'
    if len(safe) > _MAX_NAME:
        digest = hashlib.sha256(topic.encode('utf-8', 'surrogatepass')).hexdigest()[:12]
        safe = f'{safe[: _MAX_NAME - 13]}_{digest}'
    return f'samples/input{input_index}_{safe}.jpg'


def _bgr(hex_colour: str) -> tuple[int, int, int]:
    value = hex_colour.lstrip('#')
    r, g, b = (int(value[i : i + 2], 16) for i in (0, 2, 4))
    return (b, g, r)


def _ascii(text: str) -> str:
    """OpenCV's Hershey fonts draw ASCII only."""
    return ''.join(c if 32 <= ord(c) < 127 else '?' for c in text)


def sample_canvas(
    image_bgr: Any,
    detections_by_backend: Mapping[str, Sequence[Detection]],
    title: str,
) -> Any:
    """The thumbnail ``write_sample`` writes, as a BGR uint8 array (at most ``MAX_WIDTH`` px
    wide, a title bar on top, a legend bar at the bottom)."""
    import cv2
    import numpy as np

    image = np.asarray(image_bgr)
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] == 0 or image.shape[1] == 0:
        msg = f'sample image must be HxWx3 BGR, got shape {image.shape}'
        raise ValueError(msg)
    if image.dtype != np.uint8:
        values = np.nan_to_num(image.astype(np.float64))
        lo, hi = float(values.min()), float(values.max())
        image = ((values - lo) * (255.0 / (hi - lo) if hi > lo else 0.0)).astype(np.uint8)
    height, width = image.shape[:2]
    scale = min(1.0, MAX_WIDTH / width)
    if scale < 1.0:
        size = (max(1, round(width * scale)), max(1, round(height * scale)))
        thumb = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    else:
        thumb = np.ascontiguousarray(image).copy()
    font = cv2.FONT_HERSHEY_SIMPLEX
    font_scale, thickness = 0.4, 1
    for index, (_backend, detections) in enumerate(detections_by_backend.items()):
        bgr = _bgr(colour(index))
        for det in detections:
            p0 = (round(det.x0 * scale), round(det.y0 * scale))
            p1 = (round(det.x1 * scale), round(det.y1 * scale))
            cv2.rectangle(thumb, p0, p1, bgr, 2, cv2.LINE_AA)
            text = _ascii(f'{det.label} {det.score:.2f}')
            (tw, th), _ = cv2.getTextSize(text, font, font_scale, thickness)
            ty = p0[1] - 3 if p0[1] - th - 4 >= 0 else p0[1] + th + 3
            cv2.rectangle(thumb, (p0[0], ty - th - 2), (p0[0] + tw + 2, ty + 2), bgr, -1)
            cv2.putText(thumb, text, (p0[0] + 1, ty), font, font_scale, (255, 255, 255), 1)
    bar_h = 20
    t_width = thumb.shape[1]
    header = np.full((bar_h, t_width, 3), 32, dtype=np.uint8)
    cv2.putText(header, _ascii(title), (5, 14), font, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    footer = np.full((bar_h, t_width, 3), 245, dtype=np.uint8)
    x = 5
    for index, backend in enumerate(detections_by_backend):
        text = _ascii(f'{backend} ({len(detections_by_backend[backend])})')
        cv2.rectangle(footer, (x, 5), (x + 10, 15), _bgr(colour(index)), -1)
        cv2.putText(footer, text, (x + 14, 14), font, font_scale, (40, 40, 40), 1, cv2.LINE_AA)
        x += 14 + cv2.getTextSize(text, font, font_scale, 1)[0][0] + 12
    return np.vstack([header, thumb, footer])


def write_sample(
    path: str | Path,
    image_bgr: Any,
    detections_by_backend: Mapping[str, Sequence[Detection]],
    title: str,
) -> None:
    """Write a thumbnail (at most ``MAX_WIDTH`` px wide) with each backend's boxes and labels.

    The n-th backend of ``detections_by_backend`` is drawn in palette colour n (the report uses
    the same order). A title bar on top and a legend bar at the bottom are added. ``.png``
    paths are written as PNG, anything else as JPEG (quality ``JPEG_QUALITY``); the file is
    replaced atomically.
    """
    import cv2

    canvas = sample_canvas(image_bgr, detections_by_backend, title)
    path = Path(path)
    ext = '.png' if path.suffix.lower() == '.png' else '.jpg'
    params = [] if ext == '.png' else [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]
    ok, encoded = cv2.imencode(ext, canvas, params)
    if not ok:
        msg = f'{path}: could not encode the sample image'
        raise ValueError(msg)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        with os.fdopen(fd, 'wb') as file:
            file.write(encoded.tobytes())
        Path(tmp).chmod(0o644)
        Path(tmp).replace(path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
