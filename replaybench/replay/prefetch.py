"""Read and decode ahead of the backend in a bounded background thread (max-rate replay).

Decoding (cv2.imdecode, colour conversions) releases the GIL, so on two cores the next frame is
read and decoded while the backend works on this one. The buffer holds at most ``depth`` decoded
frames, so memory stays bounded whatever the bag's length.
"""

from __future__ import annotations

import contextlib
import queue
import threading
from typing import TYPE_CHECKING, NamedTuple

from replaybench.decode import decode_image
from replaybench.errors import DecodeError

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from types import TracebackType

    from replaybench.replay.clock import Clock
    from replaybench.types import Frame, RawMessage

__all__ = ['Prefetched', 'Prefetcher']


class Prefetched(NamedTuple):
    """A message read and decoded ahead: when reading began, and how long read + decode took."""

    raw: RawMessage
    decoded: Frame | DecodeError
    release: float
    read_decode_s: float


class _End(NamedTuple):
    error: BaseException | None


class Prefetcher:
    """Iterate ``Prefetched`` items produced by a reader thread, at most ``depth`` ahead.

    ``decode`` turns a message into a frame (``decode_image`` unless given) in that thread.
    """

    def __init__(
        self,
        messages: Iterator[RawMessage],
        clock: Clock,
        depth: int,
        decode: Callable[[RawMessage], Frame] = decode_image,
    ) -> None:
        self._messages = messages
        self._clock = clock
        self._decode = decode
        self._queue: queue.Queue[Prefetched | _End] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._produce, name='replaybench-prefetch', daemon=True
        )

    def __enter__(self) -> Iterator[Prefetched]:
        self._thread.start()
        return self._consume()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._stop.set()
        while self._thread.is_alive():
            with contextlib.suppress(queue.Empty):
                self._queue.get(timeout=0.05)
        self._thread.join()

    def _put(self, item: Prefetched | _End) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.05)
            except queue.Full:
                continue
            return True
        return False

    def _produce(self) -> None:
        clock = self._clock
        decode = self._decode
        try:
            while not self._stop.is_set():
                release = clock.now()
                raw = next(self._messages, None)
                if raw is None:
                    break
                try:
                    decoded: Frame | DecodeError = decode(raw)
                except DecodeError as err:
                    decoded = err
                if not self._put(Prefetched(raw, decoded, release, clock.now() - release)):
                    return
        except BaseException as err:  # noqa: BLE001  the consumer gets any end
            self._put(_End(err))
            return
        self._put(_End(None))

    def _consume(self) -> Iterator[Prefetched]:
        while True:
            item = self._queue.get()
            if isinstance(item, _End):
                if item.error is not None:
                    raise item.error
                return
            yield item
