"""``--added-latency-ms``: a testing aid that makes any backend slower by a set wait.

``AddedLatency`` wraps a backend: each ``detect`` calls the backend's, then waits ``added_ms``
more on the run's clock (a real wait on the monotonic clock, a jump on a virtual one). The wait
is inside ``detect``, so it is part of the frame's measured latency (and of what it costs the
queue: frames arriving meanwhile wait or drop, as behind any slower backend); the backend's
own stage times are left as it reported them. It exists to measure what latency alone costs an
accuracy figure (the streaming scores, docs/streaming.md): the same detections, later.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from replaybench.backends.base import Backend
    from replaybench.replay.clock import Clock
    from replaybench.types import BackendResult, Frame

__all__ = ['AddedLatency', 'with_added_latency']


class AddedLatency:
    """``backend`` with ``added_ms`` waited after each of its ``detect`` calls; every other
    attribute (its name, traits, task, ``info``) is the backend's own."""

    def __init__(self, backend: Backend, added_ms: float, clock: Clock) -> None:
        self._backend = backend
        self._added_s = added_ms / 1e3
        self._clock = clock

    def __getattr__(self, name: str) -> Any:
        return getattr(self._backend, name)

    def detect(self, frame: Frame) -> BackendResult:
        """The backend's result, returned ``added_ms`` after it gave it."""
        result = self._backend.detect(frame)
        clock = self._clock
        clock.sleep_until(clock.now() + self._added_s)
        return result


def with_added_latency(backend: Backend, added_ms: float | None, clock: Clock) -> Backend:
    """``backend`` wrapped in ``AddedLatency`` where ``added_ms`` is given and above 0."""
    if not added_ms:
        return backend
    wrapped: Backend = AddedLatency(backend, added_ms, clock)  # type: ignore[assignment]
    return wrapped
