"""A GPU tag detector as a replaybench plugin: the seam a cuAprilTags or VPI binding plugs into.

No GPU AprilTag detector is on the package registries (docs/fiducials.md), so this example
leaves the one device call, ``find_tags``, to the binding you have; everything else a tag
backend needs comes from replaybench: grey conversion (``gray8``), the ``max_tags`` cut,
undistortion and pose from the bag's CameraInfo, the boxes that Detection2DArray consumers
read, and the ``TagResult`` the tag outputs and metrics are made from (``TagAssembler``).

Register it from your package's pyproject.toml::

    [project.entry-points."replaybench.backends"]
    gpu-tags = "your_package.gpu_tags:GpuTagBackend"

then ``replaybench run BAG --backend gpu-tags --tag-size 0.16`` replays through it, scores it
against tag ground truth and compares it with ``apriltag`` and ``aruco`` like any backend.
tests/backends/test_gpu_tag_plugin.py runs this file with ``find_tags`` done by OpenCV on the
CPU in place of the device call.
"""

from __future__ import annotations

import importlib
import importlib.util
import time
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.fiducials.detect import RawTag, TagAssembler, gray8, tag_options
from replaybench.types import StageTimes

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from replaybench.fiducials.types import TagResult
    from replaybench.types import Frame


class GpuTagBackend:
    """tag36h11 on a GPU through a binding of cuAprilTags (or VPI's AprilTag detector)."""

    name: ClassVar[str] = 'gpu-tags'
    description: ClassVar[str] = 'AprilTag on the GPU (cuAprilTags binding; example plugin)'
    #: the runner samples this GPU and a sweep cell holds one
    device: ClassVar[str] = 'cuda'
    #: its results are ``TagResult``s: written and scored as tags (``Backend.task``)
    task: ClassVar[str] = 'tags'
    #: the Python module of the binding (an assumption of this example)
    binding: ClassVar[str] = 'cuapriltags'

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        self.tags = tag_options(
            self.name,
            {**self.options.tag_options, **self.options.extra},
            threads=self.options.threads,
            families=('tag36h11',),  # cuAprilTags decodes tag36h11 only
            refinements=('none',),
        )
        self._assembler = TagAssembler(self.tags)
        self._detector: Any = None

    @classmethod
    def available(cls) -> Availability:
        if importlib.util.find_spec(cls.binding) is None:
            return Availability(ok=False, reason=f'needs a GPU AprilTag binding ({cls.binding})')
        return Availability(ok=True)

    def open(self) -> None:
        binding = importlib.import_module(self.binding)
        self._detector = binding.Detector(device=self.options.device, max_tags=self.tags.max_tags)

    def find_tags(self, gray: npt.NDArray[np.uint8]) -> list[RawTag]:
        """The device call: tag ids and corners (canonical order: the tag's top-left, top-right,
        bottom-right, bottom-left; pixel centres at integers). Synchronise the device before
        returning, so that the stage time holds the GPU's work."""
        out = []
        for tag in self._detector.detect(gray):
            (x0, y0), (x1, y1), (x2, y2), (x3, y3) = tag.corners
            corners = ((x0, y0), (x1, y1), (x2, y2), (x3, y3))
            out.append(RawTag(int(tag.id), corners))
        return out

    def detect(self, frame: Frame) -> TagResult:
        t0 = time.perf_counter_ns()
        gray = gray8(frame.image, frame.encoding)
        t1 = time.perf_counter_ns()
        raw = self.find_tags(gray)
        t2 = time.perf_counter_ns()
        return self._assembler.result(frame, raw, StageTimes(t1 - t0, t2 - t1))

    def info(self) -> dict[str, Any]:
        return {'binding': self.binding, **self.tags.describe()}

    def close(self) -> None:
        self._detector = None
