"""OpenCV's ArUco detector with an AprilTag (or ArUco) dictionary: tags, ids and poses.

Per frame: the image to 8-bit grey (``preprocess``); ``cv2.aruco.ArucoDetector.detectMarkers``
with sub-pixel corner refinement by default (``infer``; ``refine``: ``subpix``, ``apriltag``,
``contour`` or ``none``, OpenCV's ``CORNER_REFINE_*``; the default chosen from the figures in
docs/fiducials.md); undistortion with the frame's
CameraInfo and each pose solved (``postprocess``). Latency covers all three. Families: the
AprilTag ones (``tag36h11``, ``tag25h9``, ``tag16h5``, ``tag36h10``) and OpenCV's ArUco
dictionaries as ``aruco_4x4_50`` ... ``aruco_original``. ``decimation`` is
``aprilTagQuadDecimate``, used by the AprilTag refinement (default 1, none, as OpenCV's).
OpenCV's threads follow ``--threads``.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.fiducials.detect import RawTag, TagAssembler, gray8, tag_options
from replaybench.types import StageTimes

if TYPE_CHECKING:
    from replaybench.fiducials.types import Corners, TagResult
    from replaybench.types import Frame

__all__ = ['ARUCO_FAMILIES', 'ArucoBackend']


def _families() -> dict[str, str]:
    """Family name -> cv2.aruco dictionary constant name."""
    out = {f'tag{n}': f'DICT_APRILTAG_{n}' for n in ('36h11', '25h9', '16h5', '36h10')}
    for bits in (4, 5, 6, 7):
        for count in (50, 100, 250, 1000):
            out[f'aruco_{bits}x{bits}_{count}'] = f'DICT_{bits}X{bits}_{count}'
    out['aruco_original'] = 'DICT_ARUCO_ORIGINAL'
    out['aruco_mip_36h12'] = 'DICT_ARUCO_MIP_36h12'
    return out


#: Family name -> OpenCV dictionary.
ARUCO_FAMILIES: dict[str, str] = _families()

#: ``refine`` -> OpenCV's corner refinement; the first is the default: on the tag fixtures
#: subpix's corners are 0.29 px RMSE from the truth at 10.6 ms a 640x480 frame, apriltag's 0.16
#: px at 25.4 ms, and on a 1280x960 photo 21.6 ms against 228 ms (benchmarks/tag_refine.py)
_REFINE = {
    'subpix': 'CORNER_REFINE_SUBPIX',
    'apriltag': 'CORNER_REFINE_APRILTAG',
    'contour': 'CORNER_REFINE_CONTOUR',
    'none': 'CORNER_REFINE_NONE',
}


#: Where a refinement puts pixel centres, subtracted to reach CameraInfo's convention (centres
#: at integers): the AprilTag quad code's half pixel. Measured on the tag fixtures (mean corner
#: offset from the truth in x / y, after the shift): -0.06 / -0.05 px (AprilTag 3 itself:
#: -0.00 / +0.02).
PIXEL_CENTRE_SHIFT: dict[str, float] = {'apriltag': 0.5}


class ArucoBackend:
    """cv2.aruco detector (tag36h11, sub-pixel corner refinement by default) with poses."""

    name: ClassVar[str] = 'aruco'
    description: ClassVar[str] = 'OpenCV ArUco detector, AprilTag dictionary: ids, corners, poses'
    #: Its results are ``TagResult``s (``Backend.task``).
    task: ClassVar[str] = 'tags'

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        self.tags = tag_options(
            self.name,
            {**self.options.tag_options, **self.options.extra},
            threads=self.options.threads,
            config=self.options.config,
            families=ARUCO_FAMILIES,
            refinements=tuple(_REFINE),
            decimation=1.0,
            decimation_refine='apriltag',
        )
        self._detector: Any = None
        self._shift = 0.0
        self._assembler = TagAssembler(self.tags)

    @classmethod
    def available(cls) -> Availability:
        import cv2

        if not hasattr(cv2, 'aruco') or not hasattr(cv2.aruco, 'ArucoDetector'):
            return Availability(ok=False, reason='this OpenCV build has no cv2.aruco.ArucoDetector')
        return Availability(ok=True)

    def open(self) -> None:
        import cv2

        dictionary = cv2.aruco.getPredefinedDictionary(
            getattr(cv2.aruco, ARUCO_FAMILIES[self.tags.family])
        )
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = getattr(cv2.aruco, _REFINE[self.tags.refine])
        # OpenCV's default, 0, is no decimation, as 1 is
        params.aprilTagQuadDecimate = (
            float(self.tags.decimation) if self.tags.decimation > 1 else 0.0
        )
        self._detector = cv2.aruco.ArucoDetector(dictionary, params)
        self._shift = PIXEL_CENTRE_SHIFT.get(self.tags.refine, 0.0)

    def detect(self, frame: Frame) -> TagResult:
        t0 = time.perf_counter_ns()
        gray = gray8(frame.image, frame.encoding)
        t1 = time.perf_counter_ns()
        corners, ids, _ = self._detector.detectMarkers(gray)
        raw = []
        shift = self._shift
        if ids is not None:
            for quad, tag_id in zip(corners, ids.reshape(-1), strict=True):
                q = quad.reshape(4, 2)
                # ArUco's corners are already the canonical top-left, top-right,
                # bottom-right, bottom-left
                points: Corners = tuple(  # type: ignore[assignment]
                    (float(q[i][0]) - shift, float(q[i][1]) - shift) for i in range(4)
                )
                raw.append(RawTag(int(tag_id), points))
        t2 = time.perf_counter_ns()
        return self._assembler.result(frame, raw, StageTimes(t1 - t0, t2 - t1))

    def info(self) -> dict[str, Any]:
        import cv2

        return {
            'library': f'opencv {cv2.__version__} aruco',
            **self.tags.describe(),
            'frames_without_pose': self._assembler.frames_without_pose,
        }

    def close(self) -> None:
        self._detector = None
