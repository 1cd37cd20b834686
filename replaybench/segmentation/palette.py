"""Display colours of class ids: id 0 black, the others spread evenly around the hue circle.

The same palette colours the rgb8 masks in outputs.mcap and the mask thumbnails of the
report, so a class has one colour everywhere. Colours depend on the id only.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ['colourise', 'palette']

_GOLDEN = 0.618033988749895


@cache
def _table() -> npt.NDArray[np.uint8]:
    import colorsys

    table = np.zeros((256, 3), dtype=np.uint8)
    for i in range(1, 256):
        hue = ((i - 1) * _GOLDEN) % 1.0
        value = 1.0 if i % 2 else 0.8
        red, green, blue = colorsys.hsv_to_rgb(hue, 0.85, value)
        table[i] = (round(red * 255), round(green * 255), round(blue * 255))
    table.setflags(write=False)
    return table


def palette() -> npt.NDArray[np.uint8]:
    """``[256, 3]`` RGB colour of every class id (read-only)."""
    return _table()


def colourise(labels: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """``H x W x 3`` RGB picture of a label mask."""
    return _table()[labels]
