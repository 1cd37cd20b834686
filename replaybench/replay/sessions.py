"""The backends of a run: made, opened before anything is measured, driven over every input
while their resource use is sampled, and closed once.

``make_backends`` makes every backend (checking its declared traits); ``open_backends`` opens
them (models loaded, recorded detections handed over) and reads the task each declares for
each input once it has opened (``backend_task``: a task that is not registered stops the run
in one line); ``run_backend`` runs one over every
input, then closes it and says what it reported and cost (a ``BackendRun``); ``run_repeated``
does the same for ``--repeat N``, the backends' passes interleaved.

The run record's types (``replaybench.results.model``) are imported where a pass has ended, not
with this module: nothing that only the record needs may delay the first frame.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Any

from replaybench.backends import get_backend
from replaybench.backends.base import (
    DEFAULT_TASK,
    RecordedDetections,
    backend_task,
    backend_traits,
)
from replaybench.errors import BackendError, ReplaybenchError, UsageError, one_line
from replaybench.replay.config import backend_label
from replaybench.replay.instances import BackendInstance, instance_options
from replaybench.replay.passes import DetectFailed, Pass
from replaybench.replay.resources import ResourceSampler
from replaybench.replay.setpass import SetPass

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Mapping, Sequence

    from replaybench.backends.base import Backend, BackendOptions
    from replaybench.replay.inputs import OpenedInput
    from replaybench.replay.pairing import InputPairing, Pairing
    from replaybench.replay.passes import Replay
    from replaybench.replay.recording import Recorder
    from replaybench.results.model import BackendFailure, BackendRun, Resources, ResourceSummary

__all__ = [
    'SLOW_OPEN_S',
    'OpenBackend',
    'hand_frame_sets',
    'make_backend',
    'make_backends',
    'open_backends',
    'open_pipelines',
    'run_backend',
    'run_repeated',
]

#: A backend still opening after this many seconds is announced through ``notice``.
SLOW_OPEN_S = 2.0


class OpenBackend:
    """A backend made and opened before the replay; closed once, after its pass. ``tasks``:
    the task of its results by input number, as it declared it once opened. ``pipelines``
    (``--pipelines per-topic``): an opened instance per camera topic, ``backend`` the first
    topic's; empty for one shared instance. ``frame_sets`` (a backend that takes frame sets,
    with ``--sync``): each input's synchronised sets by input number (``hand_frame_sets``),
    each handed to it as one ``FrameSet``; empty: single frames. ``instance``: the instance it
    is (``name`` is its label), the registered backend it was made of and its own ``--param``
    values."""

    def __init__(self, name: str, backend: Backend, tasks: Mapping[int, str] | None = None) -> None:
        self.name = name
        self.backend = backend
        self.instance = BackendInstance(name, name)
        self.tasks: Mapping[int, str] = tasks if tasks is not None else {}
        self.pipelines: dict[str, Backend] = {}
        self.frame_sets: Mapping[int, InputPairing] = {}
        self.closed = False

    def task(self, input_number: int) -> str:
        """The task of its results on input ``input_number`` (boxes where none was read)."""
        return self.tasks.get(input_number, DEFAULT_TASK)

    def close(self) -> str | None:
        """Close it (the first call only); what ``close()`` raised, as one line, or None."""
        if self.closed:
            return None
        self.closed = True
        problems: list[str] = []
        others = [b for b in self.pipelines.values() if b is not self.backend]
        for backend in (self.backend, *others):
            try:
                backend.close()
            except Exception as err:  # noqa: BLE001  a plugin's close() must not lose the run
                problems.append(one_line(err))
        return '; '.join(problems) if problems else None


def make_backend(name: str, options: BackendOptions) -> Backend:
    """The registered backend ``name``, made with ``options`` (not opened)."""
    cls = get_backend(name)
    backend: Backend = cls(options)  # type: ignore[call-arg]
    return backend


def _could_not_open(name: str, err: Exception) -> BackendError:
    return BackendError(f'backend {name!r} could not be opened: {one_line(err)}')


def _params_text(instance: BackendInstance) -> str:
    return ' '.join(f'--param {instance.label}.{k}={v}' for k, v in instance.params)


def make_backends(
    instances: Sequence[BackendInstance],
    options: BackendOptions,
    factory: Callable[[str, BackendOptions], Backend],
) -> list[tuple[str, Backend]]:
    """Every instance's backend made (not opened yet) by label, of its registered backend with
    ``options`` and its own parameters (``instance_options``), its traits checked
    (``backend_traits``). An instance with parameters that its backend refuses (an unknown
    key, a bad value): ``UsageError`` in one line naming the instance and its parameters."""
    made: list[tuple[str, Backend]] = []
    for instance in instances:
        name = instance.label
        try:
            backend = factory(instance.backend, instance_options(options, instance))
            backend_traits(backend)
        except ReplaybenchError as err:
            if not instance.params or err.exit_code != UsageError.exit_code:
                raise
            msg = f'backend {name!r} ({instance.backend} {_params_text(instance)}): {err}'
            raise UsageError(msg) from err
        except Exception as err:  # a plugin's own error: one line
            raise _could_not_open(name, err) from err
        made.append((name, backend))
    return made


@contextlib.contextmanager
def _announced_if_slow(notice: Callable[[str], None] | None, line: str) -> Iterator[None]:
    """``notice(line)`` from a timer thread if the block is still running after
    ``SLOW_OPEN_S``."""
    from threading import Timer

    if notice is None:
        yield
        return
    timer = Timer(SLOW_OPEN_S, notice, (line,))
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


def _recorded_detections(inputs: Sequence[OpenedInput]) -> RecordedDetections:
    return RecordedDetections(
        ', '.join(sorted({i.recorded_topic or '' for i in inputs})),
        {(inp.number, *key): dets for inp in inputs for key, dets in inp.recorded.items()},
        {inp.number: inp.recorded_reader for inp in inputs if inp.recorded_reader is not None},
    )


def declared_tasks(name: str, backend: Backend, inputs: Sequence[OpenedInput]) -> dict[int, str]:
    """The task an opened backend declares for each input (``backend_task``), each checked
    against the task registry (a built-in task is not imported, and the registry not at all
    for the default task, boxes: nothing of it before the first frame); ``BackendError`` in one
    line naming the backend and the known tasks for one that is not registered."""
    tasks = {inp.number: backend_task(backend, inp.number) for inp in inputs}
    for task in sorted(set(tasks.values()) - {DEFAULT_TASK}):
        from replaybench.tasks import require_task

        try:
            require_task(task)
        except ReplaybenchError as err:
            msg = f'backend {name!r} declares task {task!r}: {err}'
            raise BackendError(msg) from err
    return tasks


def open_backends(
    made: list[tuple[str, Backend]],
    inputs: Sequence[OpenedInput],
    notice: Callable[[str], None] | None = None,
) -> list[OpenBackend]:
    """Every backend prepared and opened (models loaded) before anything is measured, and the
    task it declares for each input read (``declared_tasks``); one still opening after
    ``SLOW_OPEN_S`` (a model conversion, an engine build) is announced through ``notice``. On
    failure those already opened are closed again."""
    opened: list[OpenBackend] = []
    try:
        for name, backend in made:
            try:
                if backend_traits(backend).uses_recorded_detections:
                    prepare = getattr(backend, 'prepare', None)
                    if not callable(prepare):
                        msg = f'backend {name!r} uses recorded detections but has no prepare()'
                        raise BackendError(msg)
                    prepare(_recorded_detections(inputs))
                slow = (
                    f'replaybench: opening backend {name} (loading its model; a conversion or '
                    'an engine build can take minutes)'
                )
                with _announced_if_slow(notice, slow):
                    backend.open()
            except ReplaybenchError:
                raise
            except Exception as err:  # a plugin's own error: one line
                raise _could_not_open(name, err) from err
            entry = OpenBackend(name, backend)
            opened.append(entry)  # closed again if its task is refused
            try:
                entry.tasks = declared_tasks(name, backend, inputs)
            except ReplaybenchError:
                raise
            except Exception as err:  # a plugin's own task_of() error: one line
                msg = f'backend {name!r}: its task could not be read: {one_line(err)}'
                raise BackendError(msg) from err
    except BaseException:
        for entry in opened:
            entry.close()
        raise
    return opened


def open_pipelines(
    opened: Sequence[OpenBackend],
    topics: Sequence[str],
    inputs: Sequence[OpenedInput],
    factory: Callable[[str, BackendOptions], Backend],
    options: BackendOptions,
    *,
    workers: str = 'threads',
) -> None:
    """``--pipelines per-topic``: each opened backend gets an instance per camera topic in
    ``topics`` (its own for the first topic, the others made with ``factory`` and opened as
    ``open_backends`` opens one). A backend that takes frame sets keeps its one instance: the
    input's set stream, every camera topic's frames grouped, is one pipeline. With
    ``workers='processes'`` every topic's instance is a ``ProcessBackend`` (made and opened in
    a worker process of its own with ``factory``, which must then be picklable), the first
    topic's too; the backend opened here stays for what the run asks of it besides frames.
    What fails is raised in one line; the caller closes them."""
    in_processes = workers == 'processes'
    if in_processes:
        from replaybench.replay.workers import ProcessBackend
    for entry in opened:
        if backend_traits(entry.backend).takes_frame_sets:
            continue
        if in_processes and backend_traits(entry.backend).uses_recorded_detections:
            msg = (
                f'--workers processes: backend {entry.name!r} replays recorded detections, '
                'which have nothing to compute: use --workers threads'
            )
            raise UsageError(msg)
        entry.pipelines = {} if in_processes else {topics[0]: entry.backend}
        for topic in topics if in_processes else topics[1:]:
            made_options = instance_options(options, entry.instance)
            try:
                if in_processes:
                    backend: Backend = ProcessBackend(  # type: ignore[assignment]
                        entry.instance.backend, made_options, factory, entry.backend
                    )
                else:
                    backend = factory(entry.instance.backend, made_options)
                backend_traits(backend)
            except ReplaybenchError:
                raise
            except Exception as err:  # a plugin's own error: one line
                raise _could_not_open(entry.name, err) from err
            try:
                if backend_traits(backend).uses_recorded_detections:
                    backend.prepare(_recorded_detections(inputs))  # type: ignore[attr-defined]
                backend.open()
            except ReplaybenchError:
                raise
            except Exception as err:  # a plugin's own error: one line
                raise _could_not_open(entry.name, err) from err
            finally:
                entry.pipelines[topic] = backend  # closed with the others, opened or not


def hand_frame_sets(
    opened: Sequence[OpenBackend], pairing: Pairing, inputs: Sequence[OpenedInput] = ()
) -> list[str]:
    """Each opened backend that takes frame sets gets every input's sets (``--sync``); the
    names of those that do. A backend with a ``check_frame_set(topics, camera_infos)`` method
    is shown each input's topics with the CameraInfo of its first set's frames (None for a
    topic without one) before any frame is replayed, and refuses what it cannot take with a
    ``ReplaybenchError`` (a stereo pair without a baseline: one line, exit status 2)."""
    taking: list[str] = []
    by_number = {inp.number: inp for inp in inputs}
    for entry in opened:
        if backend_traits(entry.backend).takes_frame_sets:
            entry.frame_sets = {p.input: p for p in pairing.inputs}
            taking.append(entry.name)
            check = getattr(entry.backend, 'check_frame_set', None)
            if not callable(check):
                continue
            for p in pairing.inputs:
                inp = by_number.get(p.input)
                if inp is None or not p.grouping.sets:
                    continue
                first = p.grouping.sets[0]
                infos = tuple(
                    inp.camera_infos.lookup(topic, stamp)
                    for topic, stamp in zip(p.grouping.topics, first.stamps, strict=True)
                )
                check(p.grouping.topics, infos)
    return taking


def run_backend(
    replay: Replay,
    recorder: Recorder,
    entry: OpenBackend,
    label: str,
    inputs: Sequence[OpenedInput],
    *,
    gpu_index: int | None,
    warnings: list[str],
    runs: list[BackendRun],
) -> None:
    """One opened backend over every input, sampled for resource use (``gpu_index``: the GPU
    whose use is sampled), then closed; its ``BackendRun`` appended to ``runs`` even if cut
    short. A ``detect`` that raises stops the backend: the frames before it are kept and the
    error recorded (``status`` 'failed', ``error``); what ``close()`` raised goes to
    ``warnings``."""
    done = _BackendPasses()
    with ResourceSampler(gpu_index=gpu_index) as sampler:
        try:
            done.run(replay, recorder, entry, label, inputs, repeat=0)
        finally:
            # after the passes: what the backend actually used and counted
            sampler.stop()
            done.resources = _resources(sampler)
            runs.append(done.backend_run(entry, label, warnings))


def run_repeated(
    replay: Replay,
    recorder: Recorder,
    opened: Sequence[OpenBackend],
    inputs: Sequence[OpenedInput],
    *,
    gpu_index: Callable[[OpenBackend], int | None],
    warnings: list[str],
    runs: list[BackendRun],
) -> None:
    """``--repeat N``: every opened backend over every input, N times, interleaved across the
    backends (A B A B ...: a phase of background load falls on both, not on one backend's
    passes). Each pass has its own warm-up (``Recorder``) and its own resource sampler
    (``gpu_index`` gives a backend's GPU); run.json keeps the first pass's resources. A backend
    whose ``detect`` raises stops there, the others go on. Each backend that ran is closed and
    its ``BackendRun`` appended to ``runs`` once every pass has ended (or the run was cut
    short), as ``run_backend`` does for a single pass; one that never ran is left to the
    caller to close."""
    done = {entry.name: _BackendPasses() for entry in opened}
    try:
        for repeat in range(replay.options.repeat):
            for entry in opened:
                mine = done[entry.name]
                if mine.error is not None:
                    continue
                label = backend_label(entry.name)
                with ResourceSampler(gpu_index=gpu_index(entry)) as sampler:
                    try:
                        mine.run(replay, recorder, entry, label, inputs, repeat=repeat)
                    finally:
                        sampler.stop()
                        if mine.resources is None:
                            mine.resources = _resources(sampler)
    finally:
        for entry in opened:
            mine = done[entry.name]
            if mine.passes:  # one that never ran (the run was interrupted) stays open here
                runs.append(mine.backend_run(entry, backend_label(entry.name), warnings))


class _BackendPasses:
    """What one backend's passes left: the passes, the error that stopped them, the seconds
    spent making records after them and its resource use (of its first pass)."""

    def __init__(self) -> None:
        self.passes: list[Pass] = []
        self.error: BackendFailure | None = None
        self.record_s = 0.0
        self.resources: Resources | None = None

    def run(
        self,
        replay: Replay,
        recorder: Recorder,
        entry: OpenBackend,
        label: str,
        inputs: Sequence[OpenedInput],
        *,
        repeat: int,
    ) -> None:
        """One pass of the opened backend over every input, of the task it declared for the
        input; each pass's log is recorded after it. A ``detect`` that raises is kept as
        ``error`` and ends the passes."""
        try:
            for inp in inputs:
                sets = entry.frame_sets.get(inp.number)
                p = (
                    Pass(
                        replay,
                        label,
                        entry.backend,
                        inp,
                        repeat,
                        entry.task(inp.number),
                        pipelines=entry.pipelines or None,
                    )
                    if sets is None
                    else SetPass(
                        replay, label, entry.backend, inp, sets, repeat, entry.task(inp.number)
                    )
                )
                self.passes.append(p)
                try:
                    p.run()
                finally:
                    self.record_s += recorder.take(p)
        except DetectFailed as failure:
            from replaybench.results.model import BackendFailure

            self.error = BackendFailure(
                input=failure.input, topic=failure.topic, seq=failure.seq, message=failure.message
            )

    def backend_run(self, entry: OpenBackend, label: str, warnings: list[str]) -> BackendRun:
        """The backend's run.json entry, once its passes have ended; it is closed (what
        ``close()`` raised goes to ``warnings``)."""
        try:
            info: Any = entry.backend.info()
        except Exception as err:  # noqa: BLE001  a plugin's info() must not lose the run
            info = {'error': one_line(err)}
        closing = entry.close()
        if closing is not None:
            warnings.append(f'backend {entry.name!r}: close() raised {closing}')
        from replaybench.results.io import to_json
        from replaybench.results.model import BackendRun, ReadAhead

        return BackendRun(
            name=entry.name,
            label=label,
            backend=entry.instance.backend,
            params=dict(entry.instance.params),
            status='ok' if self.error is None else 'failed',
            error=self.error,
            info=to_json(info),
            resources=self.resources,
            read_ahead=tuple(
                ReadAhead(input=p.inp.number, **_plain(p.read_ahead))
                for p in self.passes
                if p.read_ahead is not None and p.repeat == 0
            ),
            # records, frames.csv rows, detections messages: made after each pass
            record_s=self.record_s,
        )


def _resources(sampler: ResourceSampler) -> Resources:
    """What the sampler measured, stopped, as run.json holds it."""
    from replaybench.results.model import ResourcePoint, Resources

    return Resources(
        summary=resource_summary(sampler.summary()),
        series=tuple(ResourcePoint(**_plain(p)) for p in sampler.series()),
    )


def _plain(values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` with each value as run.json holds it (NaN and infinities None, numpy scalars
    Python numbers, sequences tuples)."""
    from replaybench.results.io import to_json

    return {
        key: tuple(to_json(value)) if isinstance(value, list | tuple) else to_json(value)
        for key, value in values.items()
    }


def resource_summary(values: Mapping[str, Any]) -> ResourceSummary:
    """A ``ResourceSampler.summary()`` as the typed ``ResourceSummary``."""
    from replaybench.results.model import ResourceSummary

    return ResourceSummary(**_plain(values))
