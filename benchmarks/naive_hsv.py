"""Baseline: a naive port of the perception-lab colour-blob node, kept unchanged for comparison.

For every colour class it converts the BGR frame to HSV again, thresholds each range with a
3-channel ``cv2.inRange``, runs the open/close on the full frame, finds external contours and
scores each blob against a full-frame blob mask. Thresholds, kernel, minimum area and score
formula are those of replaybench's ``hsv`` backend, so both return the same detections.

Run ``python benchmarks/naive_hsv.py [--frames N]`` to time both on a synthetic 1080p frame.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from replaybench.backends.hsv import HsvBackend, HsvConfig
from replaybench.types import Detection, Frame

__all__ = ['naive_detect', 'synthetic_frame']


def _to_bgr(image: npt.NDArray[Any], encoding: str) -> npt.NDArray[Any]:
    """What cv_bridge's ``imgmsg_to_cv2(msg, 'bgr8')`` gives the lab node."""
    if encoding == 'bgr8':
        return image
    if encoding == 'rgb8':
        return cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    if encoding == 'rgba8':
        return cv2.cvtColor(image, cv2.COLOR_RGBA2BGR)
    if encoding == 'bgra8':
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    msg = f'naive hsv: unsupported encoding {encoding!r}'
    raise ValueError(msg)


def naive_detect(
    image: npt.NDArray[Any], encoding: str = 'bgr8', config: HsvConfig | None = None
) -> list[Detection]:
    """Detections for one frame, the slow way; sorted like the hsv backend's."""
    config = config if config is not None else HsvConfig()
    params = config.detector
    bgr = _to_bgr(image, encoding)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (params.kernel, params.kernel))
    detections = []
    for index, cls in enumerate(config.classes):
        hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
        mask: npt.NDArray[Any] = np.zeros(bgr.shape[:2], dtype=np.uint8)
        for lower, upper in cls.ranges:
            mask = cv2.bitwise_or(mask, cv2.inRange(hsv, np.array(lower), np.array(upper)))
        if params.kernel > 1 and params.open_iterations > 0:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel, iterations=params.open_iterations)
        if params.kernel > 1 and params.close_iterations > 0:
            mask = cv2.morphologyEx(
                mask, cv2.MORPH_CLOSE, kernel, iterations=params.close_iterations
            )
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        floor = min(lower[1] for lower, _ in cls.ranges)
        for contour in contours:
            if cv2.contourArea(contour) < params.min_area:
                continue
            x, y, w, h = cv2.boundingRect(contour)
            blob: npt.NDArray[Any] = np.zeros_like(mask)
            cv2.drawContours(blob, [contour], -1, 255, cv2.FILLED)
            blob = cv2.bitwise_and(blob, mask)
            pixels = cv2.countNonZero(blob)
            if pixels == 0:
                continue
            mean_s = cv2.mean(hsv, mask=blob)[1]
            fill = min(pixels / (w * h), 1.0)
            margin = 1.0 if floor >= 255 else (mean_s - floor) / (255 - floor)
            margin = min(max(margin, 0.0), 1.0)
            score = round(fill * (0.5 + 0.5 * margin), 6)
            box = (float(x), float(y), float(x + w), float(y + h))
            detections.append(Detection(index, cls.name, score, *box))
    detections.sort(key=lambda d: (d.class_index, -d.score, d.y0, d.x0, d.y1, d.x1))
    return detections


def synthetic_frame(width: int = 1920, height: int = 1080, seed: int = 0) -> npt.NDArray[np.uint8]:
    """A BGR frame: grey noisy background with saturated rectangles and discs of each colour."""
    rng = np.random.default_rng(seed)
    noise = rng.normal(120.0, 10.0, (height, width, 3))
    frame = np.clip(noise, 0, 255).astype(np.uint8)
    colours = [(0, 0, 230), (0, 200, 0), (220, 40, 0), (0, 220, 230)]
    for i in range(12):
        colour = colours[i % len(colours)]
        x = int(rng.integers(0, width - 200))
        y = int(rng.integers(0, height - 200))
        size = int(rng.integers(30, 160))
        if i % 2:
            cv2.circle(frame, (x + size // 2, y + size // 2), size // 2, colour, -1)
        else:
            cv2.rectangle(frame, (x, y), (x + size, y + size // 2 + 10), colour, -1)
    return frame


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=50)
    args = parser.parse_args()
    image = synthetic_frame()
    frame = Frame('/bench', 0, 0, 0, 'bench', image, 'bgr8', 'bgr8')
    backend = HsvBackend()
    backend.open()
    fast = list(backend.detect(frame).detections)
    naive = naive_detect(image)
    print(f'detections: {len(fast)}, identical: {fast == naive}')
    for label, run in (
        ('naive', lambda: naive_detect(image)),
        ('hsv', lambda: backend.detect(frame)),
    ):
        run()
        start = time.perf_counter()
        for _ in range(args.frames):
            run()
        per_frame = (time.perf_counter() - start) / args.frames * 1e3
        print(f'{label:>6}: {per_frame:7.2f} ms/frame ({image.shape[1]}x{image.shape[0]})')
    backend.close()


if __name__ == '__main__':
    main()
