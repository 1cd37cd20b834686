"""Value types of the fiducial (AprilTag / ArUco) task: a detected tag, its pose, a result.

Conventions, shared by every tag backend, the ground truth and the metrics:

* **corner order**: the tag's own top-left, top-right, bottom-right, bottom-left corner as the
  tag is printed (clockwise in an image of a tag seen from the front); pixel coordinates of the
  source image, corners of the outer black border, pixel centres at integers;
* **tag frame**: origin at the tag's centre, x towards its right edge, y towards its top edge,
  z out of the printed face towards the viewer (OpenCV's ArUco frame). The corners above sit at
  (-s/2, s/2, 0), (s/2, s/2, 0), (s/2, -s/2, 0), (-s/2, -s/2, 0) for edge length s: the order
  ``cv2.SOLVEPNP_IPPE_SQUARE`` documents;
* **pose**: the tag frame in the camera's optical frame (x right, y down, z forward; the
  CameraInfo's ``frame_id``), position in metres, orientation a unit quaternion (x, y, z, w).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from replaybench.types import BackendResult, Detection

__all__ = ['Corners', 'TagDetection', 'TagPose', 'TagResult', 'tag_box', 'tag_frame_name']

#: Four (x, y) pixel corners in the canonical order (see the module's description).
Corners = tuple[tuple[float, float], tuple[float, float], tuple[float, float], tuple[float, float]]


class TagPose(NamedTuple):
    """A tag's pose in the camera frame: position (m) and orientation (x, y, z, w)."""

    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]


class TagDetection(NamedTuple):
    """One detected (or ground-truth) tag.

    ``family``: ``tag36h11`` and the like (AprilTag names; ArUco dictionaries as
    ``aruco_5x5_1000``); ``center`` and ``corners`` in source-image pixels; ``pose`` None when
    the frame had no usable CameraInfo; ``size_m`` the edge length the pose was solved with;
    ``score``: the detector's own confidence (AprilTag decision margin; 1.0 where it has none).
    """

    family: str
    tag_id: int
    center: tuple[float, float]
    corners: Corners
    pose: TagPose | None = None
    size_m: float | None = None
    score: float = 1.0

    @property
    def label(self) -> str:
        """The tag as a class label and TF child frame: ``family:id`` (``tag36h11:14``)."""
        return tag_frame_name(self.family, self.tag_id)


def tag_box(tag: TagDetection) -> Detection:
    """The tag as a Detection2DArray consumer sees it: its corners' bounding box, labelled
    ``family:id``. Detection boxes put the origin at the top-left pixel's corner, tag corners
    at its centre: +0.5."""
    xs = [float(x) for x, _ in tag.corners]
    ys = [float(y) for _, y in tag.corners]
    x0, y0, x1, y1 = min(xs) + 0.5, min(ys) + 0.5, max(xs) + 0.5, max(ys) + 0.5
    return Detection(tag.tag_id, tag.label, tag.score, x0, y0, x1, y1)


def tag_frame_name(family: str, tag_id: int) -> str:
    """The TF child frame of a tag, as Isaac ROS names it.

    >>> tag_frame_name('tag36h11', 14)
    'tag36h11:14'
    """
    return f'{family}:{tag_id}'


@dataclass(frozen=True, slots=True)
class TagResult(BackendResult):
    """What a tag backend's ``detect`` returns: ``detections`` holds one box per tag (the
    corners' bounding box, the ``family:id`` label as class) so every consumer of detections
    works unchanged; ``tags`` the tags themselves, in the same order; ``camera_frame`` the
    CameraInfo's frame_id the poses are in ('' without one); ``note`` one line when the poses
    could not be solved (no CameraInfo, an unsupported distortion model), '' otherwise."""

    tags: tuple[TagDetection, ...] = ()
    camera_frame: str = ''
    note: str = ''
