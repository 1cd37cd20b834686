"""The null backend: no detections, no work; what remains is the cost of the harness itself."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.errors import BackendError
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from replaybench.types import Frame

__all__ = ['NullBackend']

_RESULT = BackendResult(
    detections=(), stages=StageTimes(preprocess_ns=0, infer_ns=0, postprocess_ns=0)
)


class NullBackend:
    """Returns no detections for every frame.

    Its stage times are 0 (host stages) and None (device transfers): a replay through it
    measures decoding, scheduling and recording only.
    """

    name: ClassVar[str] = 'null'
    description: ClassVar[str] = 'no detections; measures the replay harness itself'
    #: ``detect`` never reads ``frame.camera_info``.
    reads_camera_info: ClassVar[bool] = False

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        if self.options.extra:
            msg = f'null: unknown option {sorted(self.options.extra)[0]!r} (it takes none)'
            raise BackendError(msg)

    @classmethod
    def available(cls) -> Availability:
        return Availability(ok=True)

    def open(self) -> None:
        """Nothing to load."""

    def detect(self, frame: Frame) -> BackendResult:  # noqa: ARG002  the protocol's signature
        return _RESULT

    def info(self) -> dict[str, Any]:
        return {'detections': 'none'}

    def close(self) -> None:
        """Nothing to release."""
