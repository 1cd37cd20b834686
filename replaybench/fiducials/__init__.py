"""Fiducials: tag value types, camera models from CameraInfo, and tag poses.

The library under the ``apriltag`` and ``aruco`` backends, the tag fixtures and the tag
metrics; it imports nothing of the engine (see docs/fiducials.md).
"""

from __future__ import annotations

from replaybench.fiducials.camera import CameraModel, camera_model, undistort_pixels
from replaybench.fiducials.pose import (
    DEFAULT_TAG_SIZE,
    TagSizes,
    object_corners,
    parse_tag_sizes,
    rotation_error_deg,
    solve_tag_pose,
)
from replaybench.fiducials.types import TagDetection, TagPose, TagResult, tag_frame_name

__all__ = [
    'DEFAULT_TAG_SIZE',
    'CameraModel',
    'TagDetection',
    'TagPose',
    'TagResult',
    'TagSizes',
    'camera_model',
    'object_corners',
    'parse_tag_sizes',
    'rotation_error_deg',
    'solve_tag_pose',
    'tag_frame_name',
    'undistort_pixels',
]
