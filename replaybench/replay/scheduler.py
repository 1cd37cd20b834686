"""Release frames at their replay times into per-topic queues served by one busy backend.

The scheduler knows nothing of bags or detectors: it moves opaque items through queues on a
``Clock``. With a ``VirtualClock`` and a backend that advances it by a declared service time,
drop accounting is exact and testable without timing anything.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Generic, NamedTuple, TypeVar

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    from replaybench.replay.clock import Clock

__all__ = ['Pending', 'replay_timed']

T = TypeVar('T')


class Pending(NamedTuple, Generic[T]):
    """A released item waiting for the backend: absolute release time and arrival order."""

    release: float
    order: int
    item: T


def replay_timed(
    releases: Iterable[tuple[float, str, T]],
    *,
    clock: Clock,
    queue_depth: int,
    process: Callable[[T, float, float], None],
    drop: Callable[[T, float], None],
) -> None:
    """Release items at ``start + offset`` and serve them one at a time, oldest release first.

    ``releases`` yields ``(offset_s, queue_key, item)`` with non-decreasing offsets. Each key has
    its own queue of ``queue_depth``; an item arriving at a full queue pushes the oldest waiting
    item out (newest kept, like a ROS subscription of that depth) and ``drop(item, release)`` is
    called for it. ``process(item, release, start)`` runs the backend and returns when it is done;
    the clock must have moved by the service time when it returns.
    """
    if queue_depth < 1:
        msg = f'queue depth must be at least 1, not {queue_depth}'
        raise ValueError(msg)
    queues: dict[str, deque[Pending[T]]] = {}
    order = 0
    t0 = clock.now()

    def oldest() -> deque[Pending[T]] | None:
        best: deque[Pending[T]] | None = None
        for queue in queues.values():
            if queue and (best is None or queue[0][:2] < best[0][:2]):
                best = queue
        return best

    for offset, key, item in releases:
        release = t0 + offset
        while (queue := oldest()) is not None and clock.now() < release:
            waiting = queue.popleft()
            process(waiting.item, waiting.release, clock.now())
        if clock.now() < release:
            clock.sleep_until(release)
        queue = queues.setdefault(key, deque())
        queue.append(Pending(release, order, item))
        order += 1  # noqa: SIM113 - counts arrivals, not loop turns
        if len(queue) > queue_depth:
            pushed_out = queue.popleft()
            drop(pushed_out.item, pushed_out.release)
    while (queue := oldest()) is not None:
        waiting = queue.popleft()
        process(waiting.item, waiting.release, clock.now())
