"""OpenCV's StereoBM on a stereo pair, the stereo task: ``replaybench.backends.sgbm``'s
backend with the block matcher (stereo_image_proc's default algorithm)."""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

from replaybench.backends.sgbm import StereoMatcherBackend

if TYPE_CHECKING:
    from replaybench.stereo.matchers import MatcherKind

__all__ = ['BmBackend']


class BmBackend(StereoMatcherBackend):
    """OpenCV StereoBM with stereo_image_proc's defaults (CPU)."""

    name: ClassVar[str] = 'bm'
    description: ClassVar[str] = 'OpenCV StereoBM disparity of stereo pairs (CPU, --sync)'
    kind: ClassVar[MatcherKind] = 'bm'
