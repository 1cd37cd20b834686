"""OpenCV's StereoSGBM and StereoBM with stereo_image_proc's parameters and conventions.

The defaults are those of ``stereo_image_proc``'s ``disparity_node`` (ROS 2,
``src/stereo_image_proc/disparity_node.cpp``): ``prefilter_size`` 9, ``prefilter_cap`` 31,
``correlation_window_size`` 15, ``min_disparity`` 0, ``disparity_range`` 64,
``texture_threshold`` 10, ``speckle_size`` 100, ``speckle_range`` 4, ``disp12_max_diff`` 0,
``uniqueness_ratio`` 15, ``P1`` 200, ``P2`` 400, ``full_dp`` false; the node hands them to
``cv::StereoBM`` / ``cv::StereoSGBM`` unchanged (``stereo_processor.hpp``), and so does
``Matcher``. Its parameters may be named as the node names them or by OpenCV's names
(``PARAMETER_NAMES``).

``Matcher.compute`` returns the disparity of the left image as float32 pixels,
``d = x_left - x_right``: OpenCV's fixed-point output divided by 16 (exact in float32), NaN
where OpenCV marks a pixel invalid (``(min_disparity - 1) * 16``, below the search range), so
that every finite value is a match. A ``stereo_msgs/DisparityImage`` marks the same pixels
with a value below its ``min_disparity`` (``replaybench.stereo.msgs``); the metrics take both.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from replaybench.errors import UsageError

if TYPE_CHECKING:
    from collections.abc import Mapping

    import numpy.typing as npt

__all__ = [
    'DELTA_D',
    'PARAMETER_NAMES',
    'Matcher',
    'MatcherKind',
    'StereoParams',
    'fixed_to_float',
    'to_mono8',
]

MatcherKind = Literal['sgbm', 'bm']

#: OpenCV's disparities are fixed point with 4 fractional bits: DisparityImage.delta_d.
DELTA_D = 1.0 / 16.0


@dataclass(frozen=True, slots=True)
class StereoParams:
    """The matcher's parameters, stereo_image_proc's defaults (see the module)."""

    min_disparity: int = 0
    disparity_range: int = 64
    correlation_window_size: int = 15
    prefilter_size: int = 9
    prefilter_cap: int = 31
    texture_threshold: int = 10
    uniqueness_ratio: int = 15
    speckle_size: int = 100
    speckle_range: int = 4
    disp12_max_diff: int = 0
    p1: int = 200
    p2: int = 400
    full_dp: bool = False

    @property
    def max_disparity(self) -> float:
        """DisparityImage.max_disparity as stereo_image_proc writes it."""
        return float(self.min_disparity + self.disparity_range - 1)

    def valid_window(self, width: int, height: int) -> tuple[int, int, int, int]:
        """DisparityImage.valid_window (x_offset, y_offset, height, width): the pixels a
        block of this size and search range can match, as ``disparity_node`` computes it."""
        border = self.correlation_window_size // 2
        left = self.disparity_range + self.min_disparity + border - 1
        inset = (
            border + self.min_disparity
            if self.min_disparity >= 0
            else max(border, -self.min_disparity)
        )
        right = width - 1 - inset
        top, bottom = border, height - 1 - border
        return left, top, max(0, bottom - top), max(0, right - left)


#: Every name a parameter may be given by (stereo_image_proc's, OpenCV's, short ones).
PARAMETER_NAMES: dict[str, str] = {
    **{f.name: f.name for f in fields(StereoParams)},
    'disparities': 'disparity_range',
    'num_disparities': 'disparity_range',
    'block_size': 'correlation_window_size',
    'P1': 'p1',
    'P2': 'p2',
    'uniqueness': 'uniqueness_ratio',
    'speckle_window': 'speckle_size',
    'speckle_window_size': 'speckle_size',
    'prefilter': 'prefilter_size',
    'pre_filter_size': 'prefilter_size',
    'pre_filter_cap': 'prefilter_cap',
}


def _int(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or value != int(value):
        msg = f'stereo parameter {name} must be a whole number, not {value!r}'
        raise UsageError(msg)
    return int(value)


def _check(kind: MatcherKind, p: StereoParams) -> None:
    problems: list[str] = []
    if p.disparity_range <= 0 or p.disparity_range % 16:
        problems.append(f'disparity_range {p.disparity_range} is not a positive multiple of 16')
    w = p.correlation_window_size
    if w % 2 == 0 or w < (5 if kind == 'bm' else 1) or w > 255:
        low = 5 if kind == 'bm' else 1
        problems.append(f'correlation_window_size {w} is not odd in {low}..255')
    if kind == 'bm' and (p.prefilter_size % 2 == 0 or not 5 <= p.prefilter_size <= 255):
        problems.append(f'prefilter_size {p.prefilter_size} is not odd in 5..255')
    if not 1 <= p.prefilter_cap <= 63:
        problems.append(f'prefilter_cap {p.prefilter_cap} is not in 1..63')
    negative = (
        'texture_threshold',
        'uniqueness_ratio',
        'speckle_size',
        'speckle_range',
        'p1',
        'p2',
    )
    problems.extend(f'{n} {getattr(p, n)} is negative' for n in negative if getattr(p, n) < 0)
    if problems:
        msg = f'{kind} parameters: {"; ".join(problems)}'
        raise UsageError(msg)


class Matcher:
    """A StereoSGBM (``sgbm``) or StereoBM (``bm``) matcher built once from ``StereoParams``."""

    __slots__ = ('_matcher', 'kind', 'params')

    def __init__(self, kind: MatcherKind, params: StereoParams | None = None) -> None:
        import cv2

        if kind not in ('sgbm', 'bm'):
            msg = f'unknown stereo matcher {kind!r}: sgbm or bm'
            raise UsageError(msg)
        p = params or StereoParams()
        _check(kind, p)
        self.kind: MatcherKind = kind
        self.params = p
        matcher: Any
        if kind == 'bm':
            matcher = cv2.StereoBM.create(p.disparity_range, p.correlation_window_size)
            matcher.setPreFilterSize(p.prefilter_size)
            matcher.setTextureThreshold(p.texture_threshold)
        else:
            matcher = cv2.StereoSGBM.create(
                minDisparity=p.min_disparity,
                numDisparities=p.disparity_range,
                blockSize=p.correlation_window_size,
                P1=p.p1,
                P2=p.p2,
                mode=cv2.STEREO_SGBM_MODE_HH if p.full_dp else cv2.STEREO_SGBM_MODE_SGBM,
            )
        matcher.setMinDisparity(p.min_disparity)
        matcher.setPreFilterCap(p.prefilter_cap)
        matcher.setUniquenessRatio(p.uniqueness_ratio)
        matcher.setSpeckleWindowSize(p.speckle_size)
        matcher.setSpeckleRange(p.speckle_range)
        matcher.setDisp12MaxDiff(p.disp12_max_diff)
        self._matcher = matcher

    @classmethod
    def from_mapping(cls, kind: MatcherKind, values: Mapping[str, object]) -> Matcher:
        """A matcher from a backend config's table; ``UsageError`` naming an unknown key."""
        changes: dict[str, Any] = {}
        for key, value in values.items():
            name = PARAMETER_NAMES.get(key)
            if name is None:
                known = ', '.join(sorted(PARAMETER_NAMES))
                msg = f'unknown {kind} parameter {key!r} (known: {known})'
                raise UsageError(msg)
            if name == 'full_dp':
                if not isinstance(value, bool):
                    msg = f'stereo parameter full_dp must be true or false, not {value!r}'
                    raise UsageError(msg)
                changes[name] = value
            else:
                changes[name] = _int(key, value)
        return cls(kind, replace(StereoParams(), **changes))

    def compute_fixed(
        self, left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8]
    ) -> npt.NDArray[np.int16]:
        """OpenCV's own output: int16, 16 times the disparity, invalid below min * 16."""
        out: npt.NDArray[np.int16] = self._matcher.compute(left, right)
        return out

    def compute(
        self, left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8]
    ) -> npt.NDArray[np.float32]:
        """The left image's disparity in pixels (float32, NaN where there is no match) of two
        rectified mono8 images of one size."""
        return fixed_to_float(self.compute_fixed(left, right), self.params.min_disparity)


def fixed_to_float(fixed: npt.NDArray[np.int16], min_disparity: int) -> npt.NDArray[np.float32]:
    """OpenCV's fixed-point disparity as float32 pixels, NaN below ``min_disparity``."""
    out = fixed.astype(np.float32) * np.float32(DELTA_D)
    out[fixed < min_disparity * 16] = np.nan
    return out


def to_mono8(image: npt.NDArray[Any], encoding: str = 'mono8') -> npt.NDArray[np.uint8]:
    """An image of one of the decoded encodings as mono8, as cv_bridge converts it for
    stereo_image_proc (``mono16`` by its top 8 bits)."""
    import cv2

    codes = {
        'rgb8': cv2.COLOR_RGB2GRAY,
        'bgr8': cv2.COLOR_BGR2GRAY,
        'rgba8': cv2.COLOR_RGBA2GRAY,
        'bgra8': cv2.COLOR_BGRA2GRAY,
    }
    if encoding == 'mono8':
        return np.ascontiguousarray(image, dtype=np.uint8)
    if encoding == 'mono16':
        return (np.asarray(image, dtype=np.uint16) >> 8).astype(np.uint8)
    if encoding in codes:
        return np.asarray(
            cv2.cvtColor(np.ascontiguousarray(image), codes[encoding]), dtype=np.uint8
        )
    msg = f'a stereo matcher takes 8-bit grey or colour images, not {encoding}'
    raise UsageError(msg)
