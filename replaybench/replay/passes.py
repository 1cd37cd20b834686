"""The timed passes: one backend over one input, reading, decoding, detecting and timing.

A pass's loops do nothing but read, decode, detect, read the clock and append one ``LogEntry``
per frame to its log. Everything else a frame leads to (its ``FrameRecord`` and frames.csv row,
its detections message, scoring, the sample) is made from the log after the pass
(``replaybench.replay.recording``), so that none of it runs between two frames and the replay
measures the backend, not the harness's own record keeping.

Rates: ``run_max`` (every frame as fast as possible, read ahead in a thread where reading and
decoding cost enough to overlap) and ``run_timed`` (recorded, scaled or fixed-Hz releases
through per-topic queues, ``replaybench.replay.scheduler``). With ``--pipelines per-topic``
(``run_lanes``) each camera topic has a backend instance of its own, served in a worker thread
of its own at the same rates (``replay_lanes``).
A backend that takes frame sets has a pass of its own, ``replaybench.replay.setpass``.
"""

from __future__ import annotations

import math
import threading
from itertools import islice
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench.backends.base import DEFAULT_TASK, backend_traits
from replaybench.errors import DecodeError, one_line
from replaybench.replay.config import default_warmup
from replaybench.replay.inputs import decoder, replayed
from replaybench.replay.prefetch import Prefetched, Prefetcher
from replaybench.replay.scheduler import Lane, replay_lanes, replay_timed

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Mapping

    from replaybench.backends.base import Backend
    from replaybench.replay.clock import Clock
    from replaybench.replay.config import PassOptions
    from replaybench.replay.inputs import OpenedInput
    from replaybench.replay.rate import Rate
    from replaybench.types import BackendResult, RawMessage

__all__ = [
    'PROGRESS_EVERY',
    'PROGRESS_S',
    'READ_AHEAD_MIN_S',
    'READ_AHEAD_PROBE',
    'DetectFailed',
    'FrameKey',
    'LogEntry',
    'Pass',
    'Replay',
    'Stopped',
    'Warmups',
]

_NS = 1_000_000_000

#: Frames a max-rate pass reads inline first, timing reading + decoding (the first one, which
#: pays for opening the input, is not counted).
READ_AHEAD_PROBE = 16
#: Read-ahead in a thread pays when reading + decoding a frame takes at least this long (s).
READ_AHEAD_MIN_S = 0.2e-3
#: A max-rate pass reports progress every this many frames read inline, or sooner when they
#: have taken ``PROGRESS_S`` seconds.
PROGRESS_EVERY = 64
PROGRESS_S = 0.25

#: (topic, seq, log_time_ns, stamp_ns, frame_id): the first five fields of the ``Frame``, with
#: stamp None and frame_id '' where the frame did not decode
FrameKey = tuple[str, int, int, int | None, str]


class LogEntry(NamedTuple):
    """What a pass logs of one frame in its loop; turned into everything else afterwards.

    ``outcome`` is the backend's ``BackendResult``, the ``DecodeError`` of a frame that did not
    decode, or None for a frame pushed out of its queue. The times are clock readings:
    ``release`` (the frame was due), ``start`` (it was taken from its queue, or from the
    reader), ``t_detect`` (the backend was called) and ``done`` (it returned); ``read_decode_s``
    and ``queue_wait_s`` are durations in seconds.
    """

    key: FrameKey
    outcome: BackendResult | DecodeError | None
    release: float
    start: float
    read_decode_s: float
    t_detect: float
    done: float
    queue_wait_s: float = 0.0

    @classmethod
    def undecoded(
        cls,
        raw: RawMessage,
        error: DecodeError,
        release: float,
        start: float,
        done: float,
        read_decode_s: float,
        queue_wait_s: float = 0.0,
    ) -> LogEntry:
        """A frame that did not decode: skipped, its times up to the failed decode kept."""
        key = (raw.topic, raw.seq, raw.log_time_ns, None, '')
        return cls(key, error, release, start, read_decode_s, done, done, queue_wait_s)

    @classmethod
    def dropped(cls, raw: RawMessage, release: float) -> LogEntry:
        """A frame pushed out of its queue before the backend took it."""
        key = (raw.topic, raw.seq, raw.log_time_ns, None, '')
        return cls(key, None, release, release, 0.0, release, release)


class Stopped(Exception):  # noqa: N818 - a signal between the loops, not an error
    """The cancellation token was set: the replay ends here (status ``interrupted``)."""


class DetectFailed(Exception):  # noqa: N818 - carries where a backend's own error happened
    """A backend's ``detect`` raised: the pass stops there, and the backend with it."""

    def __init__(self, number: int, topic: str, seq: int, error: Exception) -> None:
        super().__init__(number, topic, seq, error)
        self.input = number
        self.topic = topic
        self.seq = seq
        self.message = one_line(error)


class Warmups:
    """Warm-up frames per topic: the default for its frame count, or --warmup clamped so that
    at least one frame of each topic is measured (with a warning)."""

    def __init__(self, wanted: int | None, topic_frames: Mapping[str, int]) -> None:
        self.wanted = wanted
        self.topic_frames = dict(topic_frames)
        self.per_topic: dict[str, int] = {}
        self.warnings: list[str] = []
        for topic, frames in self.topic_frames.items():
            if wanted is None:
                self.per_topic[topic] = default_warmup(frames)
            elif frames >= 1 and wanted > frames - 1:
                self.per_topic[topic] = frames - 1
                self.warnings.append(
                    f'--warmup {wanted} leaves no frame of {topic} to measure ({frames} '
                    f'frame(s) per backend): {frames - 1} warm-up frame(s) used'
                )
            else:
                self.per_topic[topic] = wanted

    def __call__(self, topic: str) -> int:
        """The warm-up frames of ``topic``."""
        found = self.per_topic.get(topic)
        if found is not None:
            return found
        if self.wanted is not None:
            return self.wanted
        return default_warmup(self.topic_frames.get(topic, 0))


class Replay:
    """What every pass of a run shares: the clock, the cancellation token, the progress
    callback and its count, and the warm-ups."""

    def __init__(
        self,
        options: PassOptions,
        clock: Clock,
        warmups: Warmups,
        *,
        progress: Callable[[int, int], None] | None = None,
        stop: threading.Event | None = None,
        total: int = 0,
    ) -> None:
        self.options = options
        self.clock = clock
        self.warmups = warmups
        self.progress = progress
        self.stop = stop
        self.done = 0
        self.total = total

    def check_stop(self) -> None:
        """``Stopped`` once the cancellation token is set."""
        if self.stop is not None and self.stop.is_set():
            raise Stopped

    def advance(self, frames: int) -> None:
        self.done += frames
        if self.progress is not None:
            self.progress(self.done, self.total)


class Pass:
    """One backend over one input: fetch, decode, detect; one ``LogEntry`` per frame in
    ``log``, whose times are relative to ``t0``. ``repeat``: which of the backend's passes over
    the inputs it is (``--repeat N``: 0 to N - 1). ``task``: the task of the backend's results
    on this input (``replaybench.backends.base.backend_task``, read once after ``open()``).
    ``pipelines``: one opened instance of the backend per camera topic (``--pipelines
    per-topic``; ``backend`` is one of them); where the input holds more than one of those
    topics, each is replayed by its own (``run_lanes``). A backend that takes frame sets has
    a pass of its own (``replaybench.replay.setpass.SetPass``)."""

    def __init__(
        self,
        replay: Replay,
        label: str,
        backend: Backend,
        inp: OpenedInput,
        repeat: int = 0,
        task: str = DEFAULT_TASK,
        pipelines: Mapping[str, Backend] | None = None,
    ) -> None:
        self.replay = replay
        self.task = task
        self.repeat = repeat
        self.label = label
        self.backend = backend
        self.inp = inp
        self.t0 = 0.0
        self.log: list[LogEntry] = []
        traits = backend_traits(backend)
        self.decode = decoder(inp, camera_info=traits.reads_camera_info)
        self.measures_latency = traits.measures_latency
        # at max rate: whether frames were read ahead in a thread, and why (run.json)
        self.read_ahead: dict[str, Any] | None = None
        names = [t.name for t in inp.topics]
        self.pipelines: dict[str, Backend] = (
            {name: pipelines[name] for name in names}
            if pipelines is not None and len(names) > 1
            else {}
        )
        # frames.csv's ``pipeline``: the index of the instance serving each topic among the
        # backend's instances (the run's camera topics' order); a topic served by ``backend``
        # alone is pipeline 0
        order = list(pipelines or ())
        self.pipeline_of: dict[str, int] = {name: order.index(name) for name in self.pipelines}

    def warmup_frames(self, topic: str) -> int:
        """The warm-up frames of ``topic`` in this pass."""
        return self.replay.warmups(topic)

    def run(self) -> None:
        """The pass at the run's rate, after warming up the topics too short for warm-up
        frames."""
        self.replay.check_stop()
        self.warm_short_topics()
        rate = self.replay.options.rate
        if self.pipelines:
            self.run_lanes(rate)
        elif rate.timed:
            self.run_timed(rate)
        else:
            self.run_max()

    def messages(self) -> Iterator[RawMessage]:
        return replayed(self.inp)

    def _detect_failed(self, topic: str, seq: int, err: Exception) -> DetectFailed:
        return DetectFailed(self.inp.number, topic, seq, err)

    def warm_short_topics(self) -> list[str]:
        """Before the pass, one detect on the first frame of each topic too short for warm-up
        frames (the default gives under 10 frames none): not timed, not recorded, not counted.
        An explicit ``--warmup`` is left as given, and a backend that is not timed (``recorded``)
        needs no warm-up. Returns the topics warmed."""
        if self.replay.options.warmup is not None or not self.measures_latency:
            return []
        warmups = self.replay.warmups
        pending = {t.name for t in self.inp.topics if warmups(t.name) == 0}
        warmed: list[str] = []
        if not pending:
            return warmed
        for raw in self.messages():
            if raw.topic not in pending:
                continue
            try:
                frame = self.decode(raw)
            except DecodeError:
                continue  # the next frame of the topic may decode
            backend = self.pipelines.get(raw.topic, self.backend)
            try:
                backend.detect(frame)
            except Exception as err:
                raise self._detect_failed(frame.topic, frame.seq, err) from err
            pending.discard(raw.topic)
            warmed.append(raw.topic)
            if not pending:
                break
        for backend in {
            id(b): b for b in (self.pipelines.get(t, self.backend) for t in warmed)
        }.values():
            forget = getattr(backend, 'forget_warmup', None)
            if callable(forget):
                forget()
        return warmed

    # -- the replay loops: nothing but read, decode, detect and one log entry per frame --------

    def run_max(self) -> None:
        """Every frame as fast as possible.

        The first ``READ_AHEAD_PROBE`` frames are read inline and timed; when reading and
        decoding a frame takes at least ``READ_AHEAD_MIN_S`` (compressed images, compressed
        chunks, colour conversions), the rest are read and decoded ahead in a bounded thread
        (``Prefetcher``), overlapping with the backend. Below that there is nothing to overlap
        (a raw frame mapped from the file is a few microseconds of Python, holding the GIL)
        and handing frames between threads would cost more than reading them.
        """
        self.t0 = self.replay.clock.now()
        messages = self.messages()
        depth = self.replay.options.prefetch
        if depth < 1:
            self.read_ahead = {'depth': 0, 'used': False, 'reason': 'prefetch=0'}
            self.inline_all(messages)
            return
        probed = self.inline(messages, READ_AHEAD_PROBE)
        if probed < READ_AHEAD_PROBE:
            self.read_ahead = {'depth': depth, 'used': False, 'reason': 'input ended in the probe'}
            return
        # the mean, not the median: a compressed chunk holding several frames is paid by one;
        # the first frame, which pays for opening the input, is left out
        typical = sum(entry.read_decode_s for entry in self.log[-probed + 1 :]) / (probed - 1)
        used = typical >= READ_AHEAD_MIN_S
        self.read_ahead = {
            'depth': depth,
            'used': used,
            'probe_frames': probed - 1,
            'probe_read_decode_ms': typical * 1e3,
            'threshold_ms': READ_AHEAD_MIN_S * 1e3,
        }
        if not used:
            self.inline_all(messages)
            return
        with Prefetcher(messages, self.replay.clock, depth, self.decode) as frames:
            self.consume(frames)

    def inline_all(self, messages: Iterator[RawMessage]) -> None:
        while self.inline(messages, PROGRESS_EVERY, PROGRESS_S):
            self.replay.check_stop()

    def inline(self, messages: Iterator[RawMessage], limit: int, seconds: float = math.inf) -> int:
        """Read, decode and detect up to ``limit`` frames in this thread, stopping early once
        ``seconds`` have passed; how many were read (0: the messages have run out).

        A frame is released when the previous one is done: its read + decode time runs from
        there to the detector's call, and its latency from there to the detections.
        """
        now = self.replay.clock.now
        decode = self.decode
        detect = self.backend.detect
        append = self.log.append
        entry = LogEntry
        before = len(self.log)
        done = now()
        until = done + seconds
        for raw in islice(messages, limit):
            release = done
            try:
                frame = decode(raw)
            except DecodeError as err:
                done = now()
                append(entry.undecoded(raw, err, release, release, done, done - release))
                continue
            t_detect = now()
            try:
                result = detect(frame)
            except Exception as err:
                raise self._detect_failed(frame.topic, frame.seq, err) from err
            done = now()
            append(entry(frame[:5], result, release, release, t_detect - release, t_detect, done))
            if done > until:
                break
        count = len(self.log) - before
        if count:
            self.replay.advance(count)
        return count

    def consume(self, frames: Iterator[Prefetched]) -> None:
        """Detect frames read and decoded ahead; their read + decode time is the reader's."""
        now = self.replay.clock.now
        detect = self.backend.detect
        append = self.log.append
        entry = LogEntry
        advance = self.replay.advance
        stop = self.replay.stop
        for raw, decoded, release, read_decode_s in frames:
            if stop is not None and stop.is_set():
                raise Stopped
            start = now()
            if isinstance(decoded, DecodeError):
                append(entry.undecoded(raw, decoded, release, start, start, read_decode_s))
            else:
                try:
                    result = detect(decoded)
                except Exception as err:
                    raise self._detect_failed(decoded.topic, decoded.seq, err) from err
                done = now()
                append(entry(decoded[:5], result, release, start, read_decode_s, start, done))
            advance(1)

    def process(self, raw: RawMessage, release: float, start: float) -> None:
        """Decode and detect one frame now (timed modes): queued from ``release`` to ``start``."""
        now = self.replay.clock.now
        try:
            frame = self.decode(raw)
        except DecodeError as err:
            done = now()
            self.log.append(
                LogEntry.undecoded(raw, err, release, start, done, done - start, start - release)
            )
        else:
            t_detect = now()
            try:
                result = self.backend.detect(frame)
            except Exception as err:
                raise self._detect_failed(frame.topic, frame.seq, err) from err
            done = now()
            self.log.append(
                LogEntry(
                    frame[:5],
                    result,
                    release,
                    start,
                    t_detect - start,
                    t_detect,
                    done,
                    start - release,
                )
            )
        self.replay.advance(1)

    def drop(self, raw: RawMessage, release: float) -> None:
        """A frame pushed out of its queue before the backend took it (timed modes)."""
        self.log.append(LogEntry.dropped(raw, release))
        self.replay.advance(1)

    def run_timed(self, rate: Rate) -> None:
        clock = self.replay.clock
        self.t0 = clock.now()
        replay_timed(
            self._releases(rate),
            clock=clock,
            queue_depth=self.replay.options.queue_depth,
            process=self.process,
            drop=self.drop,
        )

    def _releases(self, rate: Rate) -> Iterator[tuple[float, str, RawMessage]]:
        """Each frame's release offset (s from the pass's start) at a timed rate: log-time
        spacing (scaled) or the topic's k-th frame at k / Hz, never before the previous one."""
        first_log: int | None = None
        per_topic: dict[str, int] = {}
        last = 0.0
        for raw in self.messages():
            self.replay.check_stop()
            if rate.mode == 'fixed':
                k = per_topic.get(raw.topic, 0)
                per_topic[raw.topic] = k + 1
                offset = max(last, k / rate.hz)
            else:
                if first_log is None:
                    first_log = raw.log_time_ns
                offset = max(last, (raw.log_time_ns - first_log) / _NS / rate.scale)
            last = offset
            yield offset, raw.topic, raw

    def run_lanes(self, rate: Rate) -> None:
        """One worker per camera topic, each with its own backend instance, decoder, queue and
        log, replayed concurrently at the run's rate (``replay_lanes``): at a timed rate each
        frame released at its own time into its camera's queue, at ``max`` each camera's frames
        back to back as fast as its worker goes. The lanes' logs are joined in the bag's order
        of the frames (each camera's in its own order) when the pass ends, however it ends."""
        clock = self.replay.clock
        lanes = {topic: _PipelineLane(self, backend) for topic, backend in self.pipelines.items()}
        if any(lane.reads_camera_info for lane in lanes.values()):
            # a deferred CameraInfo index is read once, here, not by the first two workers
            self.inp.camera_infos.lookup(next(iter(lanes)), 0)
        progress = threading.Lock()

        def advance() -> None:
            with progress:
                self.replay.advance(1)

        for lane in lanes.values():
            lane.advance = advance
        self.t0 = clock.now()

        def releases() -> Iterator[tuple[float | None, str, tuple[int, RawMessage]]]:
            if rate.timed:
                for index, (offset, topic, raw) in enumerate(self._releases(rate)):
                    yield offset, topic, (index, raw)
                return
            for index, raw in enumerate(self.messages()):
                self.replay.check_stop()
                yield None, raw.topic, (index, raw)

        try:
            replay_lanes(
                releases(),
                {topic: Lane(lane.process, lane.drop) for topic, lane in lanes.items()},
                clock=clock,
                queue_depth=self.replay.options.queue_depth,
                start=self.t0,
            )
        finally:
            joined = sorted(
                (item for lane in lanes.values() for item in lane.log), key=lambda item: item[0]
            )
            self.log.extend(entry for _, entry in joined)


class _PipelineLane:
    """One camera's pipeline in a per-topic pass: its backend instance, decoder and log of
    ``(frame's index in the pass, LogEntry)``; ``process`` and ``drop`` as ``Pass``'s."""

    def __init__(self, owner: Pass, backend: Backend) -> None:
        self.owner = owner
        self.backend = backend
        self.reads_camera_info = backend_traits(backend).reads_camera_info
        self.decode = decoder(owner.inp, camera_info=self.reads_camera_info)
        self.log: list[tuple[int, LogEntry]] = []
        self.advance: Callable[[], None] = lambda: None

    def process(self, item: tuple[int, RawMessage], release: float, start: float) -> None:
        index, raw = item
        now = self.owner.replay.clock.now
        try:
            frame = self.decode(raw)
        except DecodeError as err:
            done = now()
            entry = LogEntry.undecoded(
                raw, err, release, start, done, done - start, start - release
            )
        else:
            t_detect = now()
            try:
                result = self.backend.detect(frame)
            except Exception as err:
                raise self.owner._detect_failed(frame.topic, frame.seq, err) from err
            done = now()
            entry = LogEntry(
                frame[:5], result, release, start, t_detect - start, t_detect, done, start - release
            )
        self.log.append((index, entry))
        self.advance()

    def drop(self, item: tuple[int, RawMessage], release: float) -> None:
        index, raw = item
        self.log.append((index, LogEntry.dropped(raw, release)))
        self.advance()
