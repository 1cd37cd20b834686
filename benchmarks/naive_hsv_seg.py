"""Baseline: a straightforward per-class OpenCV port of HSV colour segmentation.

For every colour class, last first: ``cv2.inRange`` of the HSV frame per range, OR-ed, the
open and close on the full frame, then the class id written where the mask is set (so the
first class in configuration order wins an overlap). Thresholds, kernel and iterations are the
``hsv`` configuration's, so it gives the same label mask as the ``hsv-seg`` backend.

Run ``python benchmarks/naive_hsv_seg.py [--frames N]`` to time both on a synthetic 1080p frame.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from replaybench.backends.hsv import HsvConfig
from replaybench.backends.hsv_seg import HsvSegBackend

__all__ = ['naive_segment']


def naive_segment(
    bgr: npt.NDArray[np.uint8], config: HsvConfig | None = None
) -> npt.NDArray[np.uint8]:
    """The label mask of one BGR frame, the slow way."""
    config = config if config is not None else HsvConfig()
    params = config.detector
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (params.kernel, params.kernel))
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
    labels = np.zeros(bgr.shape[:2], dtype=np.uint8)
    for index in reversed(range(len(config.classes))):
        mask: npt.NDArray[Any] = np.zeros(bgr.shape[:2], dtype=np.uint8)
        for lower, upper in config.classes[index].ranges:
            mask = cv2.bitwise_or(mask, cv2.inRange(hsv, np.array(lower), np.array(upper)))
        if params.kernel > 1 and params.open_iterations > 0:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel, iterations=params.open_iterations)
        if params.kernel > 1 and params.close_iterations > 0:
            mask = cv2.morphologyEx(
                mask, cv2.MORPH_CLOSE, kernel, iterations=params.close_iterations
            )
        labels[mask > 0] = index + 1
    return labels


def main() -> None:
    from benchmarks.naive_hsv import synthetic_frame
    from replaybench.types import Frame

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=50)
    args = parser.parse_args()
    image = synthetic_frame()
    frame = Frame('/bench', 0, 0, 0, 'bench', image, 'bgr8', 'bgr8')
    backend = HsvSegBackend()
    backend.open()
    result = backend.detect(frame).mask
    assert result is not None
    print(f'identical masks: {np.array_equal(result.labels, naive_segment(image))}')
    for label, run in (
        ('naive', lambda: naive_segment(image)),
        ('hsv-seg', lambda: backend.detect(frame)),
    ):
        run()
        start = time.perf_counter()
        for _ in range(args.frames):
            run()
        per_frame = (time.perf_counter() - start) / args.frames * 1e3
        print(f'{label:>8}: {per_frame:7.2f} ms/frame ({image.shape[1]}x{image.shape[0]})')
    backend.close()


if __name__ == '__main__':
    main()
