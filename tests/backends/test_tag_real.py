"""The aruco backend on a real recording: ../shared/real/bags/ros1/ubiquity_aruco_images.bag
(UbiquityRobotics/fiducials test data, BSD-3-Clause; PROVENANCE.md): a Raspberry Pi camera,
1280x960 JPEG, plumb_bob CameraInfo, a person holding a board of DICT_5X5_1000 markers.

There is no recorded truth, so the checks are what must hold of any right answer: the ids of
the board, each pose reprojecting onto its own corners through the bag's camera model, and the
four markers printed on one board (106, 107, 111, 112) facing the same way and lying in one
plane."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from replaybench.backends.aruco import ArucoBackend
from replaybench.backends.base import BackendOptions
from replaybench.decode import decode_camera_info, decode_image
from replaybench.fiducials.pose import object_corners, quaternion_to_matrix
from replaybench.sources import open_source

if TYPE_CHECKING:
    from pathlib import Path

BOARD = (106, 107, 111, 112)
SIZE = 0.14  # the fiducials package's default marker size (m); it scales distances only


def test_aruco_finds_the_board_of_a_real_recording_with_consistent_poses(
    shared_real: Path,
) -> None:
    source = open_source(shared_real / 'bags' / 'ros1' / 'ubiquity_aruco_images.bag')
    info = decode_camera_info(next(source.messages(topics=['/raspicam_node/camera_info'])))
    raw = next(source.messages(topics=['/raspicam_node/image/compressed']))
    frame = decode_image(raw)._replace(camera_info=info)
    source.close()
    options = BackendOptions(tag_options={'family': 'aruco_5x5_1000', 'tag_size': str(SIZE)})
    backend = ArucoBackend(options)
    backend.open()
    result = backend.detect(frame)
    tags = {t.tag_id: t for t in result.tags}
    assert set(BOARD) <= set(tags)
    assert result.camera_frame == 'raspicam'
    k = np.asarray(info.k).reshape(3, 3)
    d = np.asarray(info.d)
    for tag in result.tags:
        assert tag.pose is not None
        rvec, _ = cv2.Rodrigues(quaternion_to_matrix(tag.pose.orientation))
        projected, _ = cv2.projectPoints(
            object_corners(SIZE), rvec, np.asarray(tag.pose.position), k, d
        )
        # measured: 0.65 px at most
        assert np.abs(projected.reshape(4, 2) - np.asarray(tag.corners)).max() < 1.0
    normals = []
    centres = []
    for tag_id in BOARD:
        pose = tags[tag_id].pose
        assert pose is not None
        normals.append(quaternion_to_matrix(pose.orientation)[:, 2])
        centres.append(pose.position)
    mean = np.mean(normals, axis=0)
    mean /= np.linalg.norm(mean)
    angles = [np.degrees(np.arccos(np.clip(np.dot(n, mean), -1, 1))) for n in normals]
    assert max(angles) < 3.0  # measured: within 1 degree
    offsets = [abs(float(np.dot(np.subtract(c, centres[0]), mean))) for c in centres]
    assert max(offsets) < 0.02  # one plane, to 2 cm at 1.2 m
