"""Synthetic frames for the backend tests: saturated shapes on a grey, noisy background."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from replaybench.types import Frame

#: Saturated BGR colours and the hsv class each one belongs to.
BGR = {
    'red': (0, 0, 220),
    'green': (0, 200, 0),
    'blue': (220, 40, 0),
    'yellow': (0, 220, 230),
}


class Scene:
    """A BGR canvas to draw on, turned into a Frame in any colour encoding."""

    def __init__(self, width: int = 320, height: int = 240, seed: int = 0, noise: float = 8.0):
        rng = np.random.default_rng(seed)
        self.image = np.clip(rng.normal(120.0, noise, (height, width, 3)), 0, 255).astype(np.uint8)

    def rect(self, colour: str | tuple[int, int, int], x0: int, y0: int, x1: int, y1: int) -> Scene:
        """A filled rectangle covering pixels [x0, x1) x [y0, y1)."""
        cv2.rectangle(self.image, (x0, y0), (x1 - 1, y1 - 1), _bgr(colour), -1)
        return self

    def disc(self, colour: str | tuple[int, int, int], cx: int, cy: int, r: int) -> Scene:
        cv2.circle(self.image, (cx, cy), r, _bgr(colour), -1)
        return self

    def poly(self, colour: str | tuple[int, int, int], points: list[tuple[int, int]]) -> Scene:
        cv2.fillPoly(self.image, [np.array(points, dtype=np.int32)], _bgr(colour))
        return self

    def pixels(self, encoding: str = 'bgr8') -> npt.NDArray[Any]:
        codes = {
            'bgr8': None,
            'rgb8': cv2.COLOR_BGR2RGB,
            'rgba8': cv2.COLOR_BGR2RGBA,
            'bgra8': cv2.COLOR_BGR2BGRA,
            'mono8': cv2.COLOR_BGR2GRAY,
        }
        code = codes[encoding]
        return self.image.copy() if code is None else cv2.cvtColor(self.image, code)

    def frame(self, encoding: str = 'bgr8', seq: int = 0) -> Frame:
        image = self.pixels(encoding)
        image.flags.writeable = False  # frames may be read-only views into a container
        return Frame('/camera/image', seq, seq, seq, 'camera', image, encoding, encoding)


def _bgr(colour: str | tuple[int, int, int]) -> tuple[int, int, int]:
    return BGR[colour] if isinstance(colour, str) else colour


@pytest.fixture
def scene() -> type[Scene]:
    return Scene
