"""Stereo depth: pair geometry and rectification, matchers, metrics, files and messages.

The library under the stereo task and its backends; it imports nothing of the engine (see
docs/stereo.md, "Domain library"). ``calibration``: a pair's focal length, baseline and
rectification maps from its two CameraInfo; ``topics``: stereo_image_proc's topic naming and
``--stereo LEFT,RIGHT``; ``matchers``: OpenCV's StereoSGBM / StereoBM with
stereo_image_proc's defaults; ``metrics``: EPE, bad-1/2/3, D1-all, density, AbsRel as sums
over pixels; ``files``: Middlebury PFM and KITTI PNG; ``msgs``: stereo_msgs/DisparityImage;
``thumbnail``: colour pictures of a disparity and its error; ``output``: ``Disparity``, what a
backend of the stereo task returns in ``BackendResult.output``.
"""

from __future__ import annotations

from replaybench.stereo.calibration import (
    RECTIFY_MAPS,
    Rectifier,
    StereoPair,
    rectify_maps,
    stereo_pair,
)
from replaybench.stereo.matchers import DELTA_D, Matcher, StereoParams, to_mono8
from replaybench.stereo.metrics import DisparityCounts, StereoFigures, score_disparity
from replaybench.stereo.output import Disparity
from replaybench.stereo.topics import StereoTopics, find_pairs, pair_by_name, parse_stereo

__all__ = [
    'DELTA_D',
    'RECTIFY_MAPS',
    'Disparity',
    'DisparityCounts',
    'Matcher',
    'Rectifier',
    'StereoFigures',
    'StereoPair',
    'StereoParams',
    'StereoTopics',
    'find_pairs',
    'pair_by_name',
    'parse_stereo',
    'rectify_maps',
    'score_disparity',
    'stereo_pair',
    'to_mono8',
]
