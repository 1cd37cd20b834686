"""The ``brightness`` backend: each frame's mean grey level, plus ``offset`` (``--param
brightness.offset=4``, a sweep's axis; ``brightness-biased`` adds 4 by default)."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from replaybench.backends import Availability, BackendOptions
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from replaybench.types import Frame

__all__ = ['BiasedBrightnessBackend', 'BrightnessBackend']


class BrightnessBackend:
    """Mean grey level of the frame (the mean over every pixel and channel)."""

    name: ClassVar[str] = 'brightness'
    description: ClassVar[str] = 'mean grey level of each frame (a task from an entry point)'
    task: ClassVar[str] = 'brightness'
    reads_camera_info: ClassVar[bool] = False
    default_offset: ClassVar[float] = 0.0

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        self.offset = float(self.options.extra.get('offset', self.default_offset))

    @classmethod
    def available(cls) -> Availability:
        return Availability(ok=True)

    def open(self) -> None:
        """Nothing to load."""

    def detect(self, frame: Frame) -> BackendResult:
        began = time.perf_counter_ns()
        level = float(np.asarray(frame.image, dtype=np.float64).mean()) + self.offset
        took = time.perf_counter_ns() - began
        stages = StageTimes(preprocess_ns=0, infer_ns=took, postprocess_ns=0)
        return BackendResult(detections=(), stages=stages, output=level)

    def info(self) -> dict[str, Any]:
        return {'offset': self.offset}

    def close(self) -> None:
        """Nothing to release."""


class BiasedBrightnessBackend(BrightnessBackend):
    """The same, 4 grey levels too bright: what a gate on the task's metric should catch."""

    name: ClassVar[str] = 'brightness-biased'
    description: ClassVar[str] = 'mean grey level plus 4 (a task from an entry point)'
    default_offset: ClassVar[float] = 4.0
