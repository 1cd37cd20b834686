"""AprilTag 3 (the C library, through ``pupil-apriltags``): tags, ids and poses on the CPU.

Per frame: the image to 8-bit grey (``preprocess``); the library's quad detection and decoding
(``infer``); the corners reordered to the canonical order, undistorted with the frame's
CameraInfo and each pose solved (``postprocess``). Latency covers all three. Options: see
``replaybench.fiducials.detect.TagOptions`` and docs/fiducials.md; ``threads`` is the
library's own thread count (``--threads``, default 1).
"""

from __future__ import annotations

import importlib.util
import time
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.errors import BackendError, BackendUnavailableError
from replaybench.fiducials.detect import RawTag, TagAssembler, gray8, tag_options
from replaybench.types import StageTimes

if TYPE_CHECKING:
    from replaybench.fiducials.types import Corners, TagResult
    from replaybench.types import Frame

__all__ = ['APRILTAG_FAMILIES', 'AprilTagBackend', 'release_detector']

#: The families AprilTag 3 decodes.
APRILTAG_FAMILIES: tuple[str, ...] = (
    'tag36h11',
    'tag25h9',
    'tag16h5',
    'tagCircle21h7',
    'tagCircle49h12',
    'tagStandard41h12',
    'tagStandard52h13',
    'tagCustom48h12',
)

#: pupil-apriltags gives the corners as the tag's top-right, top-left, bottom-left,
#: bottom-right (checked on OpenCV's own markers, tests/backends/test_tag_backends.py);
#: these indices put them in the canonical top-left, top-right, bottom-right, bottom-left.
CANONICAL_FROM_APRILTAG = (1, 0, 3, 2)
#: AprilTag 3 puts pixel centres at half-integers (a pixel spans [x, x + 1)); CameraInfo's K
#: puts them at integers. Measured on the tag fixtures: +0.48 px in x and y before the shift,
#: within 0.02 px after it.
PIXEL_CENTRE_SHIFT = 0.5


class AprilTagBackend:
    """AprilTag 3 detector (tag36h11 by default) with poses from the bag's CameraInfo."""

    name: ClassVar[str] = 'apriltag'
    description: ClassVar[str] = 'AprilTag 3 tags (pupil-apriltags): ids, corners, 6-DoF poses'
    #: Its results are ``TagResult``s (``Backend.task``).
    task: ClassVar[str] = 'tags'

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        self.tags = tag_options(
            self.name,
            {**self.options.tag_options, **self.options.extra},
            threads=self.options.threads,
            config=self.options.config,
            families=APRILTAG_FAMILIES,
            refinements=('edges', 'none'),
        )
        self._detector: Any = None
        self._assembler = TagAssembler(self.tags)
        self.frames = 0

    @classmethod
    def available(cls) -> Availability:
        if importlib.util.find_spec('pupil_apriltags') is None:
            return Availability(
                ok=False, reason="needs pupil-apriltags: pip install 'replaybench[apriltag]'"
            )
        return Availability(ok=True)

    def open(self) -> None:
        try:
            from pupil_apriltags import Detector
        except ImportError as err:
            msg = f"apriltag: cannot import pupil_apriltags ({err}); needs 'replaybench[apriltag]'"
            raise BackendUnavailableError(msg) from err
        try:
            self._detector = Detector(
                families=self.tags.family,
                nthreads=self.tags.threads,
                quad_decimate=self.tags.decimation,
                refine_edges=int(self.tags.refine == 'edges'),
            )
        except Exception as err:
            msg = f'apriltag: the detector could not be made: {err}'
            raise BackendError(msg) from err

    def detect(self, frame: Frame) -> TagResult:
        t0 = time.perf_counter_ns()
        gray = gray8(frame.image, frame.encoding)
        t1 = time.perf_counter_ns()
        found = self._detector.detect(gray)
        raw = []
        for tag in found:
            c = tag.corners - PIXEL_CENTRE_SHIFT
            corners: Corners = tuple(  # type: ignore[assignment]
                (float(c[i][0]), float(c[i][1])) for i in CANONICAL_FROM_APRILTAG
            )
            raw.append(RawTag(int(tag.tag_id), corners, round(float(tag.decision_margin), 4)))
        t2 = time.perf_counter_ns()
        self.frames += 1
        return self._assembler.result(frame, raw, StageTimes(t1 - t0, t2 - t1))

    def info(self) -> dict[str, Any]:
        from importlib.metadata import version

        return {
            'library': f'pupil-apriltags {version("pupil-apriltags")}',
            **self.tags.describe(),
            'frames_without_pose': self._assembler.frames_without_pose,
        }

    def __del__(self) -> None:
        # a backend dropped without close() still frees its detector in the right order
        self.close()

    def close(self) -> None:
        detector, self._detector = getattr(self, '_detector', None), None
        if detector is not None:
            release_detector(detector)


def release_detector(detector: Any) -> None:
    """Free a pupil-apriltags ``Detector`` in the right order: the detector, then its tag
    families.

    ``Detector.__del__`` (pupil-apriltags 1.0.4) frees the families first, and
    ``apriltag_detector_destroy`` then writes into them (``quick_decode_uninit``): a
    use-after-free that valgrind shows and that corrupted the heap of replaybench runs (glibc
    aborted with "malloc(): mismatching next->prev_size"). Freed here first, the detector is
    marked as freed so that ``__del__`` does nothing. A Detector without those internals is
    left to its own ``__del__``.
    """
    lib = getattr(detector, 'libc', None)
    pointer = getattr(detector, 'tag_detector_ptr', None)
    families = getattr(detector, 'tag_families', None)
    if lib is None or pointer is None or not isinstance(families, dict):
        return
    lib.apriltag_detector_destroy.restype = None
    lib.apriltag_detector_destroy(pointer)
    detector.tag_detector_ptr = None
    for family, handle in families.items():
        destroy = getattr(lib, f'{family}_destroy')
        destroy.restype = None
        destroy(handle)
    families.clear()
