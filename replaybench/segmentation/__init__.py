"""Semantic segmentation: output decoding (argmax or class ids, back to the frame), colours.

``decoder`` reads segmentation model outputs (``[1, C, H, W]`` / ``[1, H, W, C]`` scores or
``[1, H, W]`` / ``[1, 1, H, W]`` / ``[1, H, W, 1]`` class ids) into a frame-sized uint8 label
mask; ``palette`` gives each class id a display colour. Backends (``hsv-seg``, ``onnx-seg``)
return the mask as ``BackendResult.mask``.
"""

from __future__ import annotations

from replaybench.segmentation.decoder import (
    LAYOUTS,
    SegLayout,
    SourceMapper,
    decode_labels,
    layout_from_shape,
    parse_layout,
)
from replaybench.segmentation.palette import colourise, palette

__all__ = [
    'LAYOUTS',
    'SegLayout',
    'SourceMapper',
    'colourise',
    'decode_labels',
    'layout_from_shape',
    'palette',
    'parse_layout',
]
