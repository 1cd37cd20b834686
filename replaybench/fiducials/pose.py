"""A square tag's 6-DoF pose from its four corners: undistortion, then a PnP solve.

``solve_tag_pose`` undistorts the corners (``undistort_pixels``: pixels of the same K), then
solves ``cv2.solvePnP`` with K and no distortion, the object corners in the canonical corner
order of ``replaybench.fiducials.types`` (the order ``SOLVEPNP_IPPE_SQUARE`` documents).
Tag sizes per id: ``TagSizes``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from replaybench.errors import UsageError
from replaybench.fiducials.camera import undistort_pixels
from replaybench.fiducials.types import TagPose

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

    from replaybench.fiducials.camera import CameraModel

__all__ = [
    'DEFAULT_TAG_SIZE',
    'TagSizes',
    'matrix_to_quaternion',
    'object_corners',
    'parse_tag_sizes',
    'pose_matrix',
    'quaternion_to_matrix',
    'rotation_error_deg',
    'solve_tag_pose',
]

#: Tag edge length (m) when none is given: Isaac ROS apriltag's default ``size``.
DEFAULT_TAG_SIZE = 0.22


def object_corners(size: float) -> npt.NDArray[np.float64]:
    """The four corners of a tag of edge ``size`` in the tag frame, canonical order:
    (-s/2, s/2, 0), (s/2, s/2, 0), (s/2, -s/2, 0), (-s/2, -s/2, 0)."""
    h = size / 2
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]], dtype=np.float64)


@dataclass(frozen=True, slots=True)
class TagSizes:
    """Edge length (m) of each tag: ``per_id`` where given, ``default`` otherwise."""

    default: float = DEFAULT_TAG_SIZE
    per_id: Mapping[int, float] = field(default_factory=dict)

    def size(self, tag_id: int) -> float:
        return self.per_id.get(tag_id, self.default)


def _size(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        msg = f'{where}: a tag size is a positive length in metres, got {text!r}'
        raise UsageError(msg)
    return value


def parse_tag_sizes(default: str | None = None, per_id: str | None = None) -> TagSizes:
    """``--tag-size 0.16`` and ``--tag-sizes 14=0.2,3=0.1`` -> TagSizes; ``UsageError`` naming
    the option when one does not parse."""
    base = DEFAULT_TAG_SIZE if default in (None, '') else _size(str(default), '--tag-size')
    table: dict[int, float] = {}
    for item in (per_id or '').split(','):
        item = item.strip()
        if not item:
            continue
        key, sep, value = item.partition('=')
        if not sep or not key.strip().lstrip('-').isdigit():
            msg = f'--tag-sizes: expected ID=METRES items separated by commas, got {item!r}'
            raise UsageError(msg)
        tag_id = int(key)
        if tag_id < 0 or tag_id in table:
            what = 'negative' if tag_id < 0 else 'given twice'
            msg = f'--tag-sizes: tag id {tag_id} is {what}'
            raise UsageError(msg)
        table[tag_id] = _size(value.strip(), '--tag-sizes')
    return TagSizes(base, table)


def solve_tag_pose(
    corners: Sequence[tuple[float, float]] | npt.NDArray[np.float64],
    size: float,
    camera: CameraModel,
) -> TagPose | None:
    """The tag's pose in the camera frame from its corners (source-image pixels, canonical
    order); None when the solver finds none or it lies behind the camera."""
    import cv2

    image = undistort_pixels(camera, np.asarray(corners, dtype=np.float64).reshape(4, 2))
    # SOLVEPNP_ITERATIVE: for four coplanar points a homography start, then Levenberg-Marquardt
    # on the reprojection error. Not IPPE_SQUARE: OpenCV 5.0.0's IPPE loses the pose (NaN, or
    # up to 180 degrees off) in 570 of 2,500 exact synthetic views, among them tags facing the
    # camera squarely; this solver is within 1e-4 degrees in all of them (docs/fiducials.md).
    try:
        ok, rvec, tvec = cv2.solvePnP(
            object_corners(size),
            image.reshape(4, 1, 2),
            camera.matrix,
            None,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
    except cv2.error:
        return None
    if not ok:
        return None
    r = np.asarray(rvec, dtype=np.float64).reshape(3)
    t = np.asarray(tvec, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))) or t[2] <= 0:
        return None
    rotation, _ = cv2.Rodrigues(r)
    q = matrix_to_quaternion(np.asarray(rotation, dtype=np.float64))
    return TagPose((float(t[0]), float(t[1]), float(t[2])), q)


def matrix_to_quaternion(r: npt.NDArray[np.float64]) -> tuple[float, float, float, float]:
    """A rotation matrix as a unit quaternion (x, y, z, w) with w >= 0."""
    m = np.asarray(r, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = math.sqrt(trace + 1.0) * 2
        w, x = 0.25 * s, (m[2, 1] - m[1, 2]) / s
        y, z = (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x = (m[2, 1] - m[1, 2]) / s, 0.25 * s
        y, z = (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s
        y, z = 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s
        y, z = (m[1, 2] + m[2, 1]) / s, 0.25 * s
    x, y, z, w = float(x), float(y), float(z), float(w)
    # the norm written out, not np.linalg.norm: BLAS picks its kernel by the CPU, and the last
    # bit of the fixtures' truth quaternions with it
    n = math.sqrt(x * x + y * y + z * z + w * w)
    q = (x / n, y / n, z / n, w / n)
    if q[3] < 0:
        return (-q[0], -q[1], -q[2], -q[3])
    return q


def quaternion_to_matrix(q: Sequence[float]) -> npt.NDArray[np.float64]:
    """A quaternion (x, y, z, w), normalised first, as a 3x3 rotation matrix."""
    x, y, z, w = (float(v) for v in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ],
        dtype=np.float64,
    )


def pose_matrix(pose: TagPose) -> npt.NDArray[np.float64]:
    """The pose as a 4x4 homogeneous transform (tag frame -> camera frame)."""
    out = np.eye(4)
    out[:3, :3] = quaternion_to_matrix(pose.orientation)
    out[:3, 3] = pose.position
    return out


def rotation_error_deg(a: TagPose, b: TagPose) -> float:
    """The angle (degrees) of the rotation from one pose's orientation to the other's
    (``2 atan2(|v|, |w|)`` of the relative quaternion: exact for small angles too)."""
    ax, ay, az, aw = (float(v) for v in a.orientation)
    bx, by, bz, bw = (float(v) for v in b.orientation)
    # conj(a) * b
    w = aw * bw + ax * bx + ay * by + az * bz
    x = aw * bx - ax * bw - ay * bz + az * by
    y = aw * by + ax * bz - ay * bw - az * bx
    z = aw * bz - ax * by + ay * bx - az * bw
    return math.degrees(2 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w)))
