"""The real stereo data of ``../shared/real`` (PROVENANCE.md section 6), when it is there."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from replaybench.types import CameraInfo

REAL = Path(__file__).resolve().parents[1].parent / 'shared' / 'real'
MOTORCYCLE = REAL / 'stereo' / 'motorcycle'
EUROC = REAL / 'euroc_micro'


def need(path: Path) -> None:
    if not path.is_dir():
        pytest.skip(f'{path} is absent (the shared real data is not checked out here)')


def motorcycle() -> tuple[Any, Any, Any]:
    """The Middlebury Motorcycle pair (BGR) and its truth (NaN/inf unknown)."""
    import cv2

    need(MOTORCYCLE)
    left = cv2.imread(str(MOTORCYCLE / 'motorcycle_left.png'))
    right = cv2.imread(str(MOTORCYCLE / 'motorcycle_right.png'))
    truth = np.load(MOTORCYCLE / 'motorcycle_disp.npz')['arr_0']
    return left, right, truth


def _sensor(name: str) -> dict[str, Any]:
    from ruamel.yaml import YAML

    text = (EUROC / name / 'sensor.yaml').read_text().split('\n', 1)[1]  # drop %YAML:1.0
    loaded: dict[str, Any] = YAML(typ='safe').load(text)
    return loaded


def euroc_camera_infos() -> tuple[CameraInfo, CameraInfo]:
    """cam0 (left) and cam1 (right) of EuRoC as a ROS calibrator writes them: each camera's K
    and D, R and P from ``cv2.stereoRectify`` of the extrinsics ``T_BS`` give (zero disparity,
    no scaling)."""
    import cv2

    need(EUROC)
    cams = [_sensor('cam0'), _sensor('cam1')]
    ks, ds, poses = [], [], []
    for cam in cams:
        fu, fv, cu, cv = cam['intrinsics']
        ks.append(np.array([[fu, 0, cu], [0, fv, cv], [0, 0, 1]], dtype=np.float64))
        ds.append(np.array([*cam['distortion_coefficients'], 0.0], dtype=np.float64))
        poses.append(np.array(cam['T_BS']['data'], dtype=np.float64).reshape(4, 4))
    size = tuple(cams[0]['resolution'])
    t_c1_c0 = np.linalg.inv(poses[1]) @ poses[0]  # cam0 coordinates -> cam1 coordinates
    r1, r2, p1, p2, *_ = cv2.stereoRectify(
        ks[0],
        ds[0],
        ks[1],
        ds[1],
        size,
        t_c1_c0[:3, :3],
        t_c1_c0[:3, 3].reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0,
    )
    infos = []
    for j, (k, d, r, p) in enumerate(zip(ks, ds, (r1, r2), (p1, p2), strict=True)):
        infos.append(
            CameraInfo(
                stamp_ns=0,
                frame_id=f'cam{j}',
                width=size[0],
                height=size[1],
                distortion_model='plumb_bob',
                d=tuple(d),
                k=tuple(k.reshape(-1)),
                r=tuple(r.reshape(-1)),
                p=tuple(p.reshape(-1)),
            )
        )
    return infos[0], infos[1]


def euroc_pair(index: int) -> tuple[Any, Any]:
    """The raw grey images of pair ``index``."""
    import cv2

    need(EUROC)
    names = sorted((EUROC / 'cam0' / 'data').glob('*.png'))
    name = names[index].name
    left = cv2.imread(str(EUROC / 'cam0' / 'data' / name), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(EUROC / 'cam1' / 'data' / name), cv2.IMREAD_GRAYSCALE)
    return left, right
