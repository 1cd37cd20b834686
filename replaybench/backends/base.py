"""The backend seam: a Protocol every detector implements, and the options it is given."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, Protocol, runtime_checkable

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

    from replaybench.types import BackendResult, Frame

__all__ = ['Availability', 'Backend', 'BackendOptions']


class Availability(NamedTuple):
    """Whether a backend can run on this machine, and why not."""

    ok: bool
    reason: str = ''


@dataclass(frozen=True, slots=True)
class BackendOptions:
    """Options common to all backends; backend-specific ones go in ``extra``.

    ``model`` / ``model_family`` / ``labels`` / ``conf`` / ``iou`` configure ONNX detectors
    (None: the backend's default); ``device`` / ``engine`` / ``precision`` the GPU ones.
    """

    threads: int | None = None
    config: Path | None = None
    model: Path | None = None
    model_family: str | None = None
    labels: str | None = None
    conf: float | None = None
    iou: float | None = None
    device: int = 0
    engine: str = 'auto'
    precision: str = 'fp32'
    extra: Mapping[str, str] = field(default_factory=dict)


@runtime_checkable
class Backend(Protocol):
    """A detector the replay drives one frame at a time.

    Lifecycle: ``available()`` (class level, cheap, imports nothing heavy when it can) ->
    ``__init__(options)`` -> ``open()`` (load models, pick devices; may raise BackendError /
    BackendUnavailableError) -> ``detect(frame)`` per frame -> ``close()``.

    ``detect`` must time its own stages (``StageTimes``), synchronising any device first, and
    return boxes in source-image pixels. It must be deterministic: the same frame gives the same
    detections in the same order.

    Optional: ``forget_warmup()``: the runner calls it after detects that are neither timed nor
    recorded (the warm-up detect of a topic too short for warm-up frames); counters that
    ``info()`` reports (e.g. non-finite model outputs) start again from there.
    """

    name: ClassVar[str]
    description: ClassVar[str]

    @classmethod
    def available(cls) -> Availability: ...

    def open(self) -> None: ...

    def detect(self, frame: Frame) -> BackendResult: ...

    def info(self) -> dict[str, Any]:
        """Configuration and engine facts recorded in run.json (JSON-serialisable)."""
        ...

    def close(self) -> None: ...
