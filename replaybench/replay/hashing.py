"""The sha256 of a run's inputs, computed when nothing is timed.

run.json records each input's sha256 so that ``compare`` can tell whether two runs replayed the
same bytes. Hashing a large recording takes a while (12 GB: some 20 s), which must not hold up
the first frame, nor share the CPU and the disk with the measured frames: the run hashes its
inputs after the passes (``replaybench.replay.inputs``), one of at most ``INLINE_MAX_BYTES``
at once (a fraction of a second), a larger one with ``InputHash`` reading and digesting its
files in a thread of its own (file reads and hashlib's digest of a large buffer release the
GIL) that the run waits for; an interrupted run still hashes a small input, not a large one.

A hash started before the passes and still running while frames are measured would share the
CPU and the disk with them; the run records for how long (``overlap_s``) and says so in
run.json's warnings.
"""

from __future__ import annotations

import hashlib
import threading
import time
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

__all__ = [
    'ANNOUNCE_MIN_BYTES',
    'CHUNK_BYTES',
    'INLINE_MAX_BYTES',
    'InputHash',
    'describe_size',
]

#: Inputs up to this size are hashed at once, in the thread that asks (about 0.1 s).
INLINE_MAX_BYTES = 64 << 20
#: Inputs over this size are announced on the terminal when their hashing starts.
ANNOUNCE_MIN_BYTES = 1_000_000_000
#: Bytes read and digested at a time; hashlib releases the GIL for buffers this large.
CHUNK_BYTES = 1 << 20


class Digest(Protocol):
    """What ``InputHash`` needs of a hash object (``hashlib.sha256()``)."""

    def update(self, data: bytes, /) -> None: ...

    def hexdigest(self) -> str: ...


class InputHash:
    """The sha256 of an input's files (in order, as one stream), in a thread or at once.

    ``start()`` hashes inputs of at most ``inline_max_bytes`` before it returns and starts a
    daemon thread for larger ones. ``wait()`` returns the hex digest, or None when the hashing
    was cancelled or a file could not be read (``error`` says why). ``digest`` makes the hash
    object (tests give one that waits for an event).
    """

    def __init__(
        self,
        files: Sequence[Path],
        *,
        digest: Callable[[], Digest] = hashlib.sha256,
        inline_max_bytes: int = INLINE_MAX_BYTES,
        chunk_bytes: int = CHUNK_BYTES,
    ) -> None:
        self.files = tuple(files)
        self.size_bytes = sum(f.stat().st_size for f in self.files)
        self.background = self.size_bytes > inline_max_bytes
        self.error: str | None = None
        self.started_s: float | None = None
        self.finished_s: float | None = None
        self._digest = digest
        self._chunk = chunk_bytes
        self._cancel = threading.Event()
        self._finished = threading.Event()
        self._hex: str | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> InputHash:
        """Begin hashing (at once for a small input, else in a thread); returns ``self``."""
        self.started_s = time.perf_counter()
        if not self.background:
            self._work()
            return self
        self._thread = threading.Thread(target=self._work, name='replaybench-sha256', daemon=True)
        self._thread.start()
        return self

    @property
    def done(self) -> bool:
        """Whether the hashing has ended (finished, failed or cancelled)."""
        return self._finished.is_set()

    def wait(self) -> str | None:
        """The hex digest once the hashing has ended; None if cancelled or failed (``error``)."""
        if self._thread is not None:
            self._thread.join()
        return self._hex

    def request_cancel(self) -> None:
        """Ask the hashing to stop at its next chunk (the digest is then None); no wait."""
        self._cancel.set()

    def cancel(self) -> None:
        """Stop the hashing at its next chunk and wait for the thread; the digest is None."""
        self.request_cancel()
        if self._thread is not None:
            self._thread.join()

    def overlap_s(self, since: float) -> float:
        """Seconds the hashing ran after ``since`` (a ``time.perf_counter()``), 0 if none."""
        if self.finished_s is None:
            return 0.0
        return max(0.0, self.finished_s - since)

    def _work(self) -> None:
        from replaybench.sources.digest import HashCancelled, files_sha256

        try:  # the one definition of an input's digest (sources/digest.py)
            self._hex = files_sha256(
                self.files,
                digest=self._digest,
                chunk_bytes=self._chunk,
                cancelled=self._cancel.is_set,
            )
        except HashCancelled:
            self.error = 'cancelled'
        except OSError as err:
            self.error = f'cannot read {err.filename or "the input"}: {err.strerror or err}'
        except Exception as err:  # noqa: BLE001  an injected digest's failure: recorded
            self.error = f'{type(err).__name__}: {err}'
        finally:
            self.finished_s = time.perf_counter()
            self._finished.set()


def describe_size(size_bytes: int) -> str:
    """``12.0 GB``, ``712.3 MB``: decimal units, one decimal."""
    for unit, scale in (('GB', 1e9), ('MB', 1e6), ('kB', 1e3)):
        if size_bytes >= scale:
            return f'{size_bytes / scale:.1f} {unit}'
    return f'{size_bytes} B'
