"""Release frames at their replay times into per-topic queues served by one busy backend
(``replay_timed``), or by one backend per topic, each in a worker thread of its own
(``replay_lanes``, ``--pipelines per-topic``).

The scheduler knows nothing of bags or detectors: it moves opaque items through queues on a
``Clock``. With a ``VirtualClock`` (a ``ThreadVirtualClock`` for lanes: one time line per
worker) and a backend that advances it by a declared service time, drop accounting is exact
and testable without timing anything.
"""

from __future__ import annotations

import contextlib
import queue as queues_
import threading
from collections import deque
from itertools import chain
from typing import TYPE_CHECKING, Generic, NamedTuple, TypeVar

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator, Mapping

    from replaybench.replay.clock import Clock

__all__ = ['FEED_DEPTH', 'Lane', 'Pending', 'replay_lanes', 'replay_timed']

#: Items read ahead per lane before the reader waits for that lane's worker.
FEED_DEPTH = 64
_POLL_S = 0.05

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
    start: float | None = None,
) -> None:
    """Release items at ``start + offset`` and serve them one at a time, oldest release first.

    ``releases`` yields ``(offset_s, queue_key, item)`` with non-decreasing offsets. Each key has
    its own queue of ``queue_depth``; an item arriving at a full queue pushes the oldest waiting
    item out (newest kept, like a ROS subscription of that depth) and ``drop(item, release)`` is
    called for it. ``process(item, release, start)`` runs the backend and returns when it is done;
    the clock must have moved by the service time when it returns. ``start``: the time the
    offsets count from (None: now).
    """
    if queue_depth < 1:
        msg = f'queue depth must be at least 1, not {queue_depth}'
        raise ValueError(msg)
    queues: dict[str, deque[Pending[T]]] = {}
    order = 0
    t0 = clock.now() if start is None else start

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


class Lane(NamedTuple, Generic[T]):
    """One pipeline of ``replay_lanes``: what serves its items and what drops them."""

    process: Callable[[T, float, float], None]
    drop: Callable[[T, float], None]


class _Aborted(Exception):  # noqa: N818 - ends a lane, not an error of its own
    """Another lane failed, or the reader stopped: this lane ends where it is."""


_END = object()


def replay_lanes(
    releases: Iterable[tuple[float | None, str, T]],
    lanes: Mapping[str, Lane[T]],
    *,
    clock: Clock,
    queue_depth: int,
    start: float,
    feed_depth: int = FEED_DEPTH,
) -> None:
    """Each key's items served by its own lane, the lanes in worker threads of their own.

    ``releases`` yields ``(offset_s, key, item)`` as for ``replay_timed``; the calling thread
    reads them and hands each to its key's lane (at most ``feed_depth`` ahead of the lane's
    worker; a key without a lane is a ``KeyError``). A timed lane (offsets given) is
    ``replay_timed`` over its own items, on the lane's own queue of ``queue_depth``, offsets
    counted from ``start`` for every lane alike. With offsets None (the max rate) a lane
    serves its items back to back, each released when the lane's previous one is done: each
    key as fast as its own lane goes. Nothing is shared between lanes but the clock (a
    ``ThreadVirtualClock`` gives each worker its own time line, so the outcome does not
    depend on how the threads interleave).

    What a lane's ``process`` raises stops every lane (at its next item) and the reading, and
    is raised here once all workers have ended, the first lane's (in ``lanes`` order) if
    several raised; so is what reading ``releases`` raises.
    """
    if queue_depth < 1:
        msg = f'queue depth must be at least 1, not {queue_depth}'
        raise ValueError(msg)
    abort = threading.Event()
    feeds: dict[str, queues_.Queue[object]] = {key: queues_.Queue(feed_depth) for key in lanes}
    errors: dict[str, BaseException] = {}

    def fed(key: str) -> Iterator[tuple[float | None, str, T]]:
        feed = feeds[key]
        while True:
            if abort.is_set():
                raise _Aborted
            try:
                got = feed.get(timeout=_POLL_S)
            except queues_.Empty:
                continue
            if got is _END:
                return
            yield got  # type: ignore[misc]

    def work(key: str, lane: Lane[T]) -> None:
        try:
            clock.sleep_until(start)
            items = fed(key)
            first = next(items, None)
            if first is None:
                return
            if first[0] is None:  # the max rate: back to back
                _serve_back_to_back(first, items, clock, lane)
                return

            def timed() -> Iterator[tuple[float, str, T]]:
                for offset, k, item in chain((first,), items):
                    if offset is None:  # pragma: no cover - a pass gives all or none
                        msg = 'a lane got a release without an offset among timed ones'
                        raise ValueError(msg)
                    yield offset, k, item

            replay_timed(
                timed(),
                clock=clock,
                queue_depth=queue_depth,
                process=lane.process,
                drop=lane.drop,
                start=start,
            )
        except _Aborted:
            pass
        except BaseException as err:  # noqa: BLE001 - handed to the reading thread
            errors[key] = err
            abort.set()

    workers = [
        threading.Thread(target=work, args=(key, lane), name=f'lane {key}', daemon=True)
        for key, lane in lanes.items()
    ]
    for worker in workers:
        worker.start()
    try:
        for entry in releases:
            feed = feeds[entry[1]]
            while not abort.is_set():
                try:
                    feed.put(entry, timeout=_POLL_S)
                    break
                except queues_.Full:
                    continue
            if abort.is_set():
                break
    except BaseException:
        abort.set()
        raise
    finally:
        for feed in feeds.values():
            _put_end(feed, abort)
        for worker in workers:
            worker.join()
    for key in lanes:
        if key in errors:
            raise errors[key]


def _put_end(feed: queues_.Queue[object], abort: threading.Event) -> None:
    """The end of a lane's items, once its worker has room for it (or the lanes stopped)."""
    while not abort.is_set():
        with contextlib.suppress(queues_.Full):
            feed.put(_END, timeout=_POLL_S)
            return


def _serve_back_to_back(
    first: tuple[float | None, str, T],
    items: Iterator[tuple[float | None, str, T]],
    clock: Clock,
    lane: Lane[T],
) -> None:
    """The max rate: each item released when the previous one is done."""
    now = clock.now()
    lane.process(first[2], now, now)
    for _, _, item in items:
        now = clock.now()
        lane.process(item, now, now)
