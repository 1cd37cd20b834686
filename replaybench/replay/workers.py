"""Worker processes for the per-topic pipelines (``--workers processes``).

With ``--pipelines per-topic`` each camera's pipeline is a thread of the run's process
(``replaybench.replay.scheduler.replay_lanes``). Where a backend's ``detect`` holds the GIL
for part of its time (its Python between native calls), the threads take turns for that
part. ``--workers processes`` gives each pipeline's backend a process of its own instead:
the pipeline's thread still decodes the frame, times it and records it, and its backend is
a ``ProcessBackend``, which hands each frame to a spawned process that made and opened the
same backend, and waits (without the GIL) for the result.

A hand-off: the frame is pickled (protocol 5) with its arrays out of band; their bytes are
copied into one ``multiprocessing.shared_memory`` block of the pipeline (grown when a frame
needs more), and the small rest goes down a pipe. The worker copies the arrays out of the
block (a backend may keep them past its call) and rebuilds the frame; the result comes back
pickled down the pipe. The latency the pipeline measures around ``detect`` includes this
hand-off both ways; the stage times are the worker's.

What ``detect`` raises in the worker is raised in the pipeline's thread (as itself when it
can be pickled, else as a ``BackendError`` with its text); a worker that dies is a
``BackendError`` naming its exit code.
"""

from __future__ import annotations

import multiprocessing
import pickle
import sys
from typing import TYPE_CHECKING, Any

from replaybench.errors import BackendError, one_line

if TYPE_CHECKING:
    from collections.abc import Callable
    from multiprocessing.connection import Connection
    from multiprocessing.shared_memory import SharedMemory

    from replaybench.backends.base import Backend, BackendOptions
    from replaybench.types import BackendResult, Frame

__all__ = ['WORKERS', 'ProcessBackend']

#: ``--workers``: how the per-topic pipelines run their backends
WORKERS: tuple[str, ...] = ('threads', 'processes')

_TRAITS = ('name', 'device', 'measures_latency', 'reads_camera_info', 'task')
#: the smallest shared-memory block a pipeline makes (a 640x480 BGR frame and some)
_MIN_BLOCK = 1 << 20


def _picklable(err: BaseException) -> BaseException:
    try:
        pickle.loads(pickle.dumps(err))
    except Exception:  # noqa: BLE001 - anything that does not survive the trip
        return BackendError(one_line(err))
    return err


def _attach(name: str) -> SharedMemory:
    """The pipeline's block, by name. Python 3.13 attaches without registering it with the
    resource tracker; before, attaching registers the name that the run's process (which
    spawned this one, and shares its tracker) registered already and unlinks."""
    from multiprocessing.shared_memory import SharedMemory

    if sys.version_info >= (3, 13):
        return SharedMemory(name=name, track=False)
    return SharedMemory(name=name)


def _serve(
    conn: Connection,
    factory: Callable[[str, BackendOptions], Backend],
    name: str,
    options: BackendOptions,
) -> None:
    """The worker: make and open the backend, then answer ``detect`` requests until told to
    close (or the pipe ends)."""
    try:
        backend = factory(name, options)
        backend.open()
    except BaseException as err:  # noqa: BLE001 - told to the run, one line
        conn.send(('failed', _picklable(err)))
        return
    traits = {key: getattr(backend, key) for key in _TRAITS if hasattr(backend, key)}
    conn.send(('opened', traits))
    block: SharedMemory | None = None
    try:
        while True:
            try:
                request = conn.recv()
            except EOFError:
                return
            kind = request[0]
            if kind == 'close':
                break
            if kind == 'info':
                conn.send(('info', backend.info()))
                continue
            if kind == 'forget_warmup':
                forget = getattr(backend, 'forget_warmup', None)
                if callable(forget):
                    forget()
                conn.send(('done', None))
                continue
            _, block_name, meta, spans = request
            if spans and (block is None or block.name != block_name):
                if block is not None:
                    block.close()
                block = _attach(block_name)
            view = block.buf if block is not None else None
            buffers = [bytearray(view[o : o + n]) for o, n in spans] if view is not None else []
            try:
                frame = pickle.loads(meta, buffers=buffers)
                result = backend.detect(frame)
            except Exception as err:  # noqa: BLE001 - raised in the pipeline's thread
                conn.send(('raised', _picklable(err)))
                continue
            conn.send(('result', result))
    finally:
        if block is not None:
            block.close()
        try:
            backend.close()
        finally:
            conn.send(('closed', None))


class ProcessBackend:
    """A backend run in a worker process of its own: made there with ``factory(name,
    options)`` (a picklable callable: the registry's ``make_backend``), opened by ``open()``,
    handed each frame by ``detect``. Its traits are the worker's backend's, read after it
    opened (``task`` included, which some backends set in ``open()``)."""

    takes_frame_sets = False
    uses_recorded_detections = False

    def __init__(
        self,
        name: str,
        options: BackendOptions,
        factory: Callable[[str, BackendOptions], Backend],
        traits: Backend,
    ) -> None:
        self._backend = name
        self._options = options
        self._factory = factory
        for key in _TRAITS:
            if hasattr(traits, key):
                setattr(self, key, getattr(traits, key))
        self._conn: Connection | None = None
        self._process: multiprocessing.process.BaseProcess | None = None
        self._block: SharedMemory | None = None

    def open(self) -> None:
        context = multiprocessing.get_context('spawn')
        mine, theirs = context.Pipe()
        process = context.Process(
            target=_serve,
            args=(theirs, self._factory, self._backend, self._options),
            name=f'replaybench worker {self._backend}',
            daemon=True,
        )
        process.start()
        theirs.close()
        self._conn, self._process = mine, process
        kind, value = self._reply()
        if kind == 'failed':
            self._stop()
            raise value
        for key, trait in value.items():
            setattr(self, key, trait)

    def _reply(self) -> tuple[str, Any]:
        conn = self._conn
        if conn is None:
            msg = f'{self._backend}: the worker process is not open'
            raise BackendError(msg)
        try:
            reply: tuple[str, Any] = conn.recv()
        except (EOFError, OSError) as err:
            raise self._ended() from err
        return reply

    def _ended(self) -> BackendError:
        process = self._process
        if process is not None:
            process.join(5)
        code = process.exitcode if process is not None else None
        return BackendError(f'{self._backend}: the worker process ended (exit code {code})')

    def _ask(self, request: tuple[Any, ...]) -> Any:
        conn = self._conn
        if conn is None:
            msg = f'{self._backend}: the worker process is not open'
            raise BackendError(msg)
        try:
            conn.send(request)
        except OSError as err:
            raise self._ended() from err
        kind, value = self._reply()
        if kind == 'raised':
            raise value
        return value

    def _block_for(self, size: int) -> SharedMemory:
        from multiprocessing.shared_memory import SharedMemory

        block = self._block
        if block is None or block.size < size:
            if block is not None:
                block.close()
                block.unlink()
            block = SharedMemory(create=True, size=max(size, _MIN_BLOCK))
            self._block = block
        return block

    def detect(self, frame: Frame) -> BackendResult:
        arrays: list[pickle.PickleBuffer] = []
        meta = pickle.dumps(frame, protocol=5, buffer_callback=arrays.append)
        try:
            raws = [array.raw() for array in arrays]
        except BufferError:  # a non-contiguous array: pickled in band, copied once more
            meta, raws = pickle.dumps(frame, protocol=5), []
        spans: list[tuple[int, int]] = []
        name = ''
        if raws:
            block = self._block_for(sum(raw.nbytes for raw in raws))
            name, view = block.name, block.buf
            if view is None:  # pragma: no cover - a block just made has its buffer
                msg = f'{self._backend}: shared memory block {name} has no buffer'
                raise BackendError(msg)
            offset = 0
            for raw in raws:
                view[offset : offset + raw.nbytes] = raw
                spans.append((offset, raw.nbytes))
                offset += raw.nbytes
        result: BackendResult = self._ask(('detect', name, meta, spans))
        return result

    def forget_warmup(self) -> None:
        self._ask(('forget_warmup',))

    def info(self) -> dict[str, Any]:
        if self._conn is None:
            return {}
        facts: dict[str, Any] = self._ask(('info',))
        return {**facts, 'worker': 'process'}

    def _stop(self) -> None:
        conn, process = self._conn, self._process
        self._conn = self._process = None
        if conn is not None:
            conn.close()
        if process is not None:
            process.join(10)
            if process.is_alive():
                process.kill()
                process.join()
        if self._block is not None:
            self._block.close()
            self._block.unlink()
            self._block = None

    def close(self) -> None:
        if self._conn is not None:
            try:
                self._conn.send(('close',))
                self._reply()
            except (BackendError, OSError):
                pass
        self._stop()
