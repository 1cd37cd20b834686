"""The replay engine: inputs x backends -> run folder (detections.mcap, frames.csv,
summary.csv, run.json), or a run held in memory.

Backends run one after another over the same frames; each (backend, input) pass reads the bag
again, so every backend is measured on the same path from container to detections. The sample
pictures and report.html are drawn by the application's ``Renderer``
(``replaybench.app.run``); the run stops on a cancellation token, not on a signal handler.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import math
import time
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol, cast

from replaybench._version import __version__
from replaybench.backends import get_backend
from replaybench.backends.base import BackendOptions, RecordedDetections, backend_traits
from replaybench.decode import (
    decode_detections,
    decode_image,
    message_kind,
    to_bgr8,
)
from replaybench.decode.camera_info import CameraInfoIndex
from replaybench.decode.probe import CameraTopic, probe_topics, unreadable_image_topics
from replaybench.errors import (
    BackendError,
    BackendFailedError,
    BackendUnavailableError,
    DecodeError,
    ReplaybenchError,
    SourceError,
    UsageError,
)
from replaybench.replay.clock import Clock, MonotonicClock
from replaybench.replay.hashing import ANNOUNCE_MIN_BYTES, InputHash, describe_size
from replaybench.replay.prefetch import Prefetched, Prefetcher
from replaybench.replay.rate import Rate
from replaybench.replay.resources import ResourceSampler
from replaybench.replay.scheduler import replay_timed
from replaybench.replay.tags import TagRun
from replaybench.replay.threads import thread_limits
from replaybench.results.agreement import AGREEMENT_IOU, Agreement, agreement_table
from replaybench.results.intervals import with_intervals
from replaybench.results.io import from_document, write_run_result
from replaybench.results.model import (
    RUN_SCHEMA_VERSION,
    AgreementRow,
    BackendRun,
    Environment,
    InputInfo,
    RunCounts,
    RunOutputs,
    RunResult,
    RunSettings,
    SummaryRow,
    Tool,
)
from replaybench.results.records import FrameRecord, FramesCsvWriter
from replaybench.results.runfile import (
    environment,
    write_summary_csv,
)
from replaybench.results.runfolder import RunFolder, check_out_dir, with_filename
from replaybench.results.stats import Summary, summarize, summary_json
from replaybench.sources import Source, open_source
from replaybench.types import BackendResult, Detection, Frame, StageTimes, TopicInfo

if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence

    from replaybench.backends.base import Backend
    from replaybench.results.groundtruth import ExternalGroundTruth, MatchMode
    from replaybench.types import RawMessage, SkippedTopic

__all__ = [
    'DEFAULT_GROUND_TRUTH_TOPIC',
    'RunConfig',
    'RunOutcome',
    'default_warmup',
    'new_run_dir',
    'run_benchmark',
]

DEFAULT_GROUND_TRUTH_TOPIC = '/ground_truth/detections'
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


def default_warmup(frames: int) -> int:
    """Warm-up frames for a topic of ``frames`` frames: 10, but never more than a tenth."""
    return min(10, frames // 10)


def new_run_dir(base: Path = Path('replaybench-runs')) -> Path:
    """A new timestamped folder name under ``base`` (not created)."""
    stamp = dt.datetime.now(dt.UTC).strftime('%Y%m%d-%H%M%S')
    candidate = base / stamp
    n = 1
    while candidate.exists():
        n += 1
        candidate = base / f'{stamp}-{n}'
    return candidate


@dataclass(frozen=True, slots=True)
class RunConfig:
    """Everything one ``replaybench run`` needs; the CLI builds it from its options."""

    inputs: Sequence[Path]
    backends: Sequence[str]
    out_dir: Path | None  # None: in memory, no file written
    force: bool = False
    rate: Rate = field(default_factory=lambda: Rate('max'))
    queue_depth: int = 1
    warmup: int | None = None
    threads: int | None = None
    max_frames: int | None = None
    start_s: float | None = None
    duration_s: float | None = None
    topics: Sequence[str] | None = None
    ground_truth_topic: str | None = DEFAULT_GROUND_TRUTH_TOPIC
    ground_truth_explicit: bool = False
    options: BackendOptions = field(default_factory=BackendOptions)
    command: Sequence[str] = ()
    report: bool = True
    prefetch: int = 4
    recorded_topic: str | None = None
    ground_truth_file: Path | None = None
    ground_truth_match: str = 'stamp'  # 'stamp' | 'seq'
    ground_truth_image_topic: str | None = None
    ground_truth_seq_offset: int = 0
    annotations: bool = False
    copy_images: bool = False
    detections_format: str = 'mcap'  # 'rosbag2': also a metadata.yaml, the run folder is a bag
    #: False (--no-hash): the inputs' sha256 is not computed; run.json records null and says so
    hash_inputs: bool = True
    #: the inputs' sha256 when already known (a peak search's later trials): not hashed again
    input_sha256: tuple[str | None, ...] | None = None


class SampleImage(NamedTuple):
    """The sample frame of one topic, read again after the passes, with every backend's
    detections on it (by backend label, in run order)."""

    input: int
    topic: str
    image: Any  # BGR8 ndarray
    detections: Mapping[str, tuple[Detection, ...]]
    title: str


class Renderer(Protocol):
    """What the application draws into the run folder besides the engine's files: the sample
    pictures and report.html (``replaybench.app.run.ReportRenderer``). The engine calls it in
    the temporary folder, before run.json is written."""

    def samples(self, out: Path, samples: Iterable[SampleImage]) -> list[str]:
        """Draw each sample into ``out``; the files written, relative to ``out``."""
        ...

    def report(self, out: Path, run: RunResult) -> None:
        """Write report.html into ``out`` from ``run`` (run.json to be) and its frames.csv."""
        ...


class RunOutcome(NamedTuple):
    """What a finished (or interrupted) run left behind."""

    run_dir: Path | None  # None: a run made in memory
    status: str
    summaries: list[Summary]
    run: RunResult
    records: tuple[FrameRecord, ...] = ()  # frames.csv's rows, in the order written


class _Input(NamedTuple):
    number: int
    path: Path
    source: Source
    topics: list[CameraTopic]
    camera_infos: CameraInfoIndex
    ground_truth: dict[tuple[str, int], tuple[Detection, ...]]
    start_ns: int | None
    end_ns: int | None
    sample_index: dict[str, int]  # per topic: index among the replayed frames of the sample frame
    recorded: dict[tuple[str, int], tuple[Detection, ...]]  # for the `recorded` backend
    recorded_topic: str | None
    external: ExternalGroundTruth | None = None  # --ground-truth-file; replaces ground_truth
    notes: tuple[str, ...] = ()  # warnings found while opening (detections left out)
    sha256: InputHash | None = None  # started when the input opened (``_start_hash``)


class _Sample:
    """The frame drawn for a topic (by its seq and log time), with each backend's detections.

    The replay keeps no image: ``_write_samples`` reads the frame again after the passes.
    """

    def __init__(self, seq: int, log_time_ns: int, title: str) -> None:
        self.seq = seq
        self.log_time_ns = log_time_ns
        self.title = title
        self.detections: dict[str, tuple[Detection, ...]] = {}


def _start_hash(
    inp: _Input,
    config: RunConfig,
    hasher: Callable[[Sequence[Path]], InputHash] | None,
    notice: Callable[[str], None] | None,
) -> InputHash | None:
    """The input's sha256, started now: in a thread for a large input, announced on the
    terminal (``notice``) over ``ANNOUNCE_MIN_BYTES``; None when not computed here (--no-hash,
    or known already)."""
    if not config.hash_inputs or config.input_sha256 is not None:
        return None
    found = (hasher or InputHash)(list(inp.source.files))
    if notice is not None and found.size_bytes > ANNOUNCE_MIN_BYTES:
        size = describe_size(found.size_bytes)
        notice(f'replaybench: hashing {inp.path.name} ({size}, sha256) in the background')
    return found.start()


def _record_hash(
    inp: _Input,
    meta: dict[str, Any],
    config: RunConfig,
    *,
    passes_began: float,
    interrupted: bool,
    notice: Callable[[str], None] | None,
) -> None:
    """Put the input's sha256 into its run.json entry once the passes have ended; a hash that
    ran while frames were measured, was cut short or failed is a warning of the input."""
    if not config.hash_inputs:
        meta['sha256'] = None
        meta['warnings'].append(
            'not hashed (--no-hash): sha256 is null, so compare cannot check that other runs '
            'replayed the same input'
        )
        return
    if config.input_sha256 is not None:
        meta['sha256'] = config.input_sha256[inp.number]
        return
    found = inp.sha256
    if found is None:  # pragma: no cover - started for every input that is hashed
        return
    if interrupted and not found.done:
        found.cancel()
        meta['sha256'] = None
        meta['warnings'].append('sha256 not computed: the run was interrupted before it ended')
        return
    if not found.done and notice is not None:
        notice(f'replaybench: waiting for the sha256 of {inp.path.name}')
    meta['sha256'] = found.wait()
    if found.error is not None:
        meta['warnings'].append(f'sha256 not computed: {found.error}')
    overlap = found.overlap_s(passes_began)
    if found.background and overlap > 0:
        meta['warnings'].append(
            f'its sha256 was computed during the first {overlap:.1f} s of the measured passes, '
            'sharing the CPU and the disk with them (--no-hash leaves it out)'
        )


def _select_topics(
    path: Path,
    found: list[CameraTopic],
    wanted: Sequence[str] | None,
    unreadable: Sequence[SkippedTopic] = (),
) -> list[CameraTopic]:
    """The camera topics to replay; ``unreadable``: image topics in an unsupported encoding."""
    if wanted and (asked := [t for t in unreadable if t.name in wanted]):
        t = asked[0]
        msg = f'{path}: topic {t.name} cannot be replayed: {t.reason} ({t.count} messages)'
        raise UsageError(msg)
    if not found:
        msg = f'{path}: no image messages (sensor_msgs Image / CompressedImage) in this file'
        if unreadable:
            held = '; '.join(f'{t.name}: {t.count} messages, {t.reason}' for t in unreadable)
            msg = f'{path}: no readable image topic ({held})'
        raise SourceError(msg)
    if wanted:
        by_name = {t.name: t for t in found}
        missing = [w for w in wanted if w not in by_name]
        if len(missing) == len(wanted):
            names = ', '.join(t.name for t in found)
            msg = f'{path}: no image topic named {", ".join(missing)}; image topics: {names}'
            raise UsageError(msg)
        return [by_name[w] for w in wanted if w in by_name]
    colour = [t for t in found if not t.is_depth]
    if not colour:
        names = ' '.join(f'--topic {t.name}' for t in found)
        msg = (
            f'{path}: only depth image topics ({", ".join(t.name for t in found)}); depth is not '
            f'sent to detectors unless selected: add {names}'
        )
        raise UsageError(msg)
    return colour


def _open_input(
    index: int,
    path: Path,
    config: RunConfig,
    external: ExternalGroundTruth | None = None,
    *,
    recorded_detections: bool = False,
) -> _Input:
    """Open and probe one input; ``recorded_detections``: a backend replays the recorded
    Detection2DArray topic (``Backend.uses_recorded_detections``), which is read here."""
    source = open_source(path)
    try:
        skipped = source.skipped_topics()
        if not any(t.count for t in source.topics()) and not any(t.count for t in skipped):
            damaged = ' before the damage' if source.truncated else ' in this file'
            msg = f'{path}: no messages{damaged}'
            raise SourceError(msg)
        found = probe_topics(source)
        topics = _select_topics(path, found, config.topics, unreadable_image_topics(source))
        if external is not None:
            _check_external_topics(path, external, [t.name for t in topics])
        all_topics = source.topics()
        first = min((t.first_ns for t in all_topics), default=0)
        start_ns = first + round(config.start_s * _NS) if config.start_s else None
        end_ns = None
        if config.duration_s is not None:
            end_ns = (start_ns if start_ns is not None else first) + round(config.duration_s * _NS)
        info_topics = [t.name for t in all_topics if message_kind(t.msgtype) == 'camera_info']
        camera_infos = CameraInfoIndex.from_source(source, info_topics)
        notes: list[str] = []
        ground_truth: dict[tuple[str, int], tuple[Detection, ...]] = {}
        gt_topic = config.ground_truth_topic
        gt_present = any(t.name == gt_topic for t in all_topics)
        if gt_topic and not gt_present and config.ground_truth_explicit:
            msg = f'{path}: ground-truth topic {gt_topic} is not in this file'
            raise UsageError(msg)
        if gt_topic and gt_present and external is None:
            ground_truth = _read_detections(source, gt_topic, notes)
        recorded: dict[tuple[str, int], tuple[Detection, ...]] = {}
        recorded_topic = None
        if recorded_detections:
            recorded_topic = _recorded_topic(path, all_topics, config)
            recorded = _read_detections(source, recorded_topic, notes)
        # the frame drawn in samples/: the middle one of the replayed frames (the first one when
        # --start/--duration cut a window whose size is unknown before reading)
        windowed = config.start_s is not None or config.duration_s is not None
        sample_index = {
            t.name: 0 if windowed else min(t.count, config.max_frames or t.count) // 2
            for t in topics
        }
        return _Input(
            index,
            path,
            source,
            topics,
            camera_infos,
            ground_truth,
            start_ns,
            end_ns,
            sample_index,
            recorded,
            recorded_topic,
            external,
            tuple(notes),
        )
    except BaseException:
        source.close()
        raise


def _check_external_topics(
    path: Path, external: ExternalGroundTruth, replayed: Sequence[str]
) -> None:
    """Refuse a ground-truth file that cannot tell which replayed topic it annotates."""
    if external.topic is not None and external.topic not in replayed:
        msg = (
            f'{path}: --ground-truth-image-topic {external.topic} is not replayed; '
            f'replayed image topics: {", ".join(replayed)}'
        )
        raise UsageError(msg)
    if external.topic is None and not external.topics and len(replayed) > 1:
        msg = (
            f'{external.path} does not say which image topic it annotates and {path} replays '
            f'{len(replayed)}: add --ground-truth-image-topic (one of {", ".join(replayed)})'
        )
        raise UsageError(msg)


def _read_detections(
    source: Source, topic: str, notes: list[str] | None = None
) -> dict[tuple[str, int], tuple[Detection, ...]]:
    """Detection2DArray messages of a topic keyed by (frame_id, stamp); bad messages skipped.

    Detections with a NaN or infinite box or score are left out; ``notes`` gets a line
    saying how many.
    """
    table: dict[tuple[str, int], tuple[Detection, ...]] = {}
    nonfinite = messages = 0
    for raw in source.messages(topics=[topic]):
        try:
            found = decode_detections(raw)
        except DecodeError:
            continue
        table[(found.frame_id, found.stamp_ns)] = found.detections
        if found.nonfinite:
            nonfinite += found.nonfinite
            messages += 1
    if nonfinite and notes is not None:
        notes.append(
            f'{topic}: left out {nonfinite} detection(s) with a NaN or infinite box or score '
            f'in {messages} message(s)'
        )
    return table


def _recorded_topic(path: Path, topics: Sequence[TopicInfo], config: RunConfig) -> str:
    """The Detection2DArray topic the `recorded` backend replays: given, or the only candidate."""
    candidates = [
        t.name
        for t in topics
        if message_kind(t.msgtype) == 'detections' and t.name != config.ground_truth_topic
    ]
    if config.recorded_topic is not None:
        if config.recorded_topic not in {t.name for t in topics}:
            msg = f'{path}: --recorded-topic {config.recorded_topic} is not in this file'
            raise UsageError(msg)
        return config.recorded_topic
    if len(candidates) == 1:
        return candidates[0]
    found = ', '.join(candidates) if candidates else 'none'
    msg = (
        f'{path}: the recorded backend needs --recorded-topic TOPIC '
        f'(Detection2DArray topics besides the ground truth: {found})'
    )
    raise UsageError(msg)


#: A frame's log entry (``_Pass.log``), made in the replay loop and turned into everything else
#: by ``_Pass.finalize``: ``(key, outcome, release, start, queue_wait_s, read_decode_s,
#: t_detect, done)``. ``key`` is (topic, seq, log_time_ns, stamp_ns, frame_id), the first five
#: fields of the ``Frame`` (stamp None and frame_id '' where the frame did not decode);
#: ``outcome`` is the ``BackendResult``, the ``DecodeError`` of a skipped frame, or None for a
#: dropped one; the times are clock readings, ``*_s`` durations in seconds.
_Key = tuple[str, int, int, int | None, str]
_Entry = tuple[_Key, BackendResult | DecodeError | None, float, float, float, float, float, float]


def _raw_key(raw: RawMessage) -> _Key:
    return (raw.topic, raw.seq, raw.log_time_ns, None, '')


def _decoder(inp: _Input) -> Callable[[RawMessage], Frame]:
    """RawMessage -> the Frame a backend gets: ``decode_image``, plus camera info and the
    input's index where there are any to add."""
    number = inp.number
    lookup = inp.camera_infos.lookup
    if number == 0 and all(inp.camera_infos.topic_for(t.name) is None for t in inp.topics):
        return decode_image

    def decode(raw: RawMessage) -> Frame:
        frame = decode_image(raw)
        return frame._replace(camera_info=lookup(frame.topic, frame.stamp_ns), input_index=number)

    return decode


class _Discard:
    """The frames.csv and detections.mcap writers of a run made in memory: nothing is kept."""

    def __enter__(self) -> _Discard:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def write(self, *args: object) -> None:
        """A frames.csv row: dropped."""

    def add(self, *args: object) -> None:
        """A detections message: dropped."""

    def add_camera_info(self, *args: object) -> None:
        """A camera info message: dropped."""

    def add_raw(self, *args: object) -> None:
        """A copied image message: dropped."""


class _Stopped(Exception):  # noqa: N818 - a signal between the loops, not an error
    """The cancellation token was set: the replay ends here (status ``interrupted``)."""


class _DetectError(Exception):
    """A backend's ``detect`` raised: the pass stops there, and the backend with it."""

    def __init__(self, number: int, topic: str, seq: int, error: Exception) -> None:
        super().__init__(number, topic, seq, error)
        self.where = {
            'input': number,
            'topic': topic,
            'seq': seq,
            'message': f'{type(error).__name__}: {error}'.splitlines()[0],
        }


class _Pass:
    """One backend over one input: fetch, decode, detect; then record and write.

    The replay loops only read, decode, time and detect, appending one entry per frame to
    ``log``. Everything else a frame leads to (its ``FrameRecord`` and frames.csv row, its
    detections message, scoring, the sample) is done by ``finalize`` after the loop, so that
    none of it runs between two frames and the replay measures the backend, not the harness's
    own record keeping.
    """

    def __init__(
        self,
        run: _Run,
        label: str,
        backend: Backend,
        inp: _Input,
    ) -> None:
        self.run = run
        self.label = label
        self.backend = backend
        self.inp = inp
        self.t0 = 0.0
        self.log: list[_Entry] = []
        self.record_s = 0.0  # spent by finalize (wall clock)
        self.decode = _decoder(inp)
        self.taken: dict[str, int] = {}
        self.measures_latency = backend_traits(backend).measures_latency
        # at max rate: whether frames were read ahead in a thread, and why (run.json)
        self.read_ahead: dict[str, Any] | None = None

    def messages(self) -> Iterator[RawMessage]:
        return _replayed(self.inp, self.run.config)

    def warm_short_topics(self) -> list[str]:
        """Before the pass, one detect on the first frame of each topic too short for warm-up
        frames (the default gives under 10 frames none): not timed, not recorded, not counted.
        An explicit ``--warmup`` is left as given, and a backend that is not timed (``recorded``)
        needs no warm-up. Returns the topics warmed."""
        if self.run.config.warmup is not None or not self.measures_latency:
            return []
        pending = {t.name for t in self.inp.topics if self.run.warmup_for(t.name) == 0}
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
            try:
                self.backend.detect(frame)
            except Exception as err:
                raise _DetectError(self.inp.number, frame.topic, frame.seq, err) from err
            pending.discard(raw.topic)
            warmed.append(raw.topic)
            if not pending:
                break
        forget = getattr(self.backend, 'forget_warmup', None)
        if warmed and callable(forget):
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
        self.t0 = self.run.clock.now()
        messages = self.messages()
        depth = self.run.config.prefetch
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
        typical = sum(entry[5] for entry in self.log[-probed + 1 :]) / (probed - 1)
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
        with Prefetcher(messages, self.run.clock, depth, self.decode) as frames:
            self.consume(frames)

    def inline_all(self, messages: Iterator[RawMessage]) -> None:
        while self.inline(messages, PROGRESS_EVERY, PROGRESS_S):
            self.run.check_stop()

    def inline(self, messages: Iterator[RawMessage], limit: int, seconds: float = math.inf) -> int:
        """Read, decode and detect up to ``limit`` frames in this thread, stopping early once
        ``seconds`` have passed; how many were read (0: the messages have run out).

        A frame is released when the previous one is done: its read + decode time runs from
        there to the detector's call, and its latency from there to the detections.
        """
        now = self.run.clock.now
        decode = self.decode
        detect = self.backend.detect
        append = self.log.append
        before = len(self.log)
        done = now()
        until = done + seconds
        for raw in islice(messages, limit):
            release = done
            try:
                frame = decode(raw)
            except DecodeError as err:
                done = now()
                append((_raw_key(raw), err, release, release, 0.0, done - release, done, done))
                continue
            t_detect = now()
            try:
                result = detect(frame)
            except Exception as err:
                raise _DetectError(self.inp.number, frame.topic, frame.seq, err) from err
            done = now()
            append((frame[:5], result, release, release, 0.0, t_detect - release, t_detect, done))
            if done > until:
                break
        count = len(self.log) - before
        if count:
            self.run.advance(count)
        return count

    def consume(self, frames: Iterator[Prefetched]) -> None:
        """Detect frames read and decoded ahead; their read + decode time is the reader's."""
        now = self.run.clock.now
        detect = self.backend.detect
        append = self.log.append
        advance = self.run.advance
        stop = self.run.stop
        for raw, decoded, release, read_decode_s in frames:
            if stop is not None and stop.is_set():
                raise _Stopped
            start = now()
            if isinstance(decoded, DecodeError):
                append((_raw_key(raw), decoded, release, start, 0.0, read_decode_s, start, start))
            else:
                try:
                    result = detect(decoded)
                except Exception as err:
                    number = self.inp.number
                    raise _DetectError(number, decoded.topic, decoded.seq, err) from err
                done = now()
                append((decoded[:5], result, release, start, 0.0, read_decode_s, start, done))
            advance(1)

    def process(self, raw: RawMessage, release: float, start: float) -> None:
        """Decode and detect one frame now (timed modes): queued from ``release`` to ``start``."""
        now = self.run.clock.now
        try:
            frame = self.decode(raw)
        except DecodeError as err:
            done = now()
            self.log.append(
                (_raw_key(raw), err, release, start, start - release, done - start, done, done)
            )
        else:
            t_detect = now()
            try:
                result = self.backend.detect(frame)
            except Exception as err:
                raise _DetectError(self.inp.number, frame.topic, frame.seq, err) from err
            done = now()
            self.log.append(
                (
                    frame[:5],
                    result,
                    release,
                    start,
                    start - release,
                    t_detect - start,
                    t_detect,
                    done,
                )
            )
        self.run.advance(1)

    def drop(self, raw: RawMessage, release: float) -> None:
        """A frame pushed out of its queue before the backend took it (timed modes)."""
        self.log.append((_raw_key(raw), None, release, release, 0.0, 0.0, release, release))
        self.run.advance(1)

    def run_timed(self, rate: Rate) -> None:
        clock = self.run.clock
        self.t0 = clock.now()

        def releases() -> Iterator[tuple[float, str, RawMessage]]:
            first_log: int | None = None
            per_topic: dict[str, int] = {}
            last = 0.0
            for raw in self.messages():
                self.run.check_stop()
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

        replay_timed(
            releases(),
            clock=clock,
            queue_depth=self.run.config.queue_depth,
            process=self.process,
            drop=self.drop,
        )

    # -- after the loop --------------------------------------------------------------------

    def finalize(self) -> None:
        """Turn the log into records and frames.csv rows, detections messages, scores and the
        sample; the log is emptied. Runs after the pass, also when it was cut short."""
        began = time.perf_counter()
        entries, self.log = self.log, []
        for key, outcome, release, start, queue_wait_s, read_decode_s, t_detect, done in entries:
            if isinstance(outcome, BackendResult):
                self.record_processed(
                    key, outcome, release, start, queue_wait_s, read_decode_s, t_detect, done
                )
            else:
                self.record_unprocessed(
                    key, outcome, release, start, queue_wait_s, read_decode_s, done
                )
        self.record_s += time.perf_counter() - began

    def record(self, rec: FrameRecord) -> None:
        self.run.records.append(rec)
        self.run.frames_csv.write(rec)

    def record_unprocessed(
        self,
        key: _Key,
        error: DecodeError | None,
        release: float,
        start: float,
        queue_wait_s: float,
        read_decode_s: float,
        done: float,
    ) -> None:
        """A frame the backend never saw: pushed out of its queue (``error`` None) or skipped
        because it did not decode (its times up to the failed decode are kept)."""
        topic, seq, log_time_ns, _, _ = key
        t0 = self.t0
        dropped = error is None
        note = 'pushed out of the queue' if error is None else str(error)
        if not dropped:
            self.run.skip(note)
        self.record(
            FrameRecord(
                input=self.inp.number,
                backend=self.label,
                topic=topic,
                seq=seq,
                log_time_ns=log_time_ns,
                stamp_ns=None,
                status='dropped' if dropped else 'skipped',
                note=note,
                warmup=False,
                dropped=dropped,
                release_s=release - t0,
                start_s=None if dropped else start - t0,
                done_s=None if dropped else done - t0,
                queue_wait_ms=None if dropped else queue_wait_s * 1e3,
                read_decode_ms=None if dropped else read_decode_s * 1e3,
            )
        )

    def record_processed(
        self,
        key: _Key,
        result: BackendResult,
        release: float,
        start: float,
        queue_wait_s: float,
        read_decode_s: float,
        t_detect: float,
        done: float,
    ) -> None:
        """``latency = queue wait + read/decode + backend``: the backend part runs from the
        detector's call to its detections; read/decode was measured where it ran."""
        run = self.run
        topic, seq, log_time_ns, stamp_ns, frame_id = key
        assert stamp_ns is not None  # a processed frame decoded
        number = self.inp.number
        label_key = (self.label, topic)
        detections = result.detections
        run.detections.setdefault(label_key, {})[(number, seq)] = detections
        n_done = run.processed.get(label_key, 0)
        run.processed[label_key] = n_done + 1
        run.detections_out.add(self.label, topic, log_time_ns, stamp_ns, frame_id, detections)
        tag_columns = run.tags.frame(
            self.label, number, topic, log_time_ns, stamp_ns, frame_id, result, run.detections_out
        )
        if self.inp.external is not None:
            truth = self.inp.external.lookup(topic, seq, stamp_ns)
            if truth is not None:
                frame_key = (number, topic, seq)
                run.ground_truth[frame_key] = truth
                run.scored.setdefault(label_key, {})[frame_key] = detections
        elif (frame_id, stamp_ns) in self.inp.ground_truth:
            run.scored.setdefault(label_key, {})[(number, frame_id, stamp_ns)] = detections
        self.sample(topic, seq, log_time_ns, detections)
        t0 = self.t0
        timed = self.measures_latency
        stages = result.stages if timed else _NOT_TIMED
        self.record(
            FrameRecord(
                number,
                self.label,
                topic,
                seq,
                log_time_ns,
                stamp_ns,
                'ok',
                '' if timed else 'recorded detections: latency not measured',
                timed and n_done < run.warmup_for(topic),
                False,
                release - t0,
                start - t0,
                done - t0,
                queue_wait_s * 1e3,
                read_decode_s * 1e3,
                _ms(stages.preprocess_ns),
                _ms(stages.infer_ns),
                _ms(stages.postprocess_ns),
                _ms(stages.h2d_ns),
                _ms(stages.d2h_ns),
                (queue_wait_s + read_decode_s + done - t_detect) * 1e3 if timed else None,
                len(detections),
                _ms(stages.preprocess_device_ns),
                _ms(stages.infer_device_ns),
                _ms(stages.postprocess_device_ns),
                _ms(stages.h2d_device_ns),
                _ms(stages.d2h_device_ns),
                **tag_columns,
            )
        )

    def sample(
        self, topic: str, seq: int, log_time_ns: int, detections: tuple[Detection, ...]
    ) -> None:
        """Choose the sample frame of this topic (the first backend does) and keep its boxes."""
        key = (self.inp.number, topic)
        taken = self.taken.get(topic, 0)
        self.taken[topic] = taken + 1
        sample = self.run.samples.get(key)
        if sample is None and taken == self.inp.sample_index.get(topic):
            sample = self.run.samples[key] = _Sample(seq, log_time_ns, f'{topic} #{seq}')
        if sample is not None and sample.seq == seq:
            sample.detections[self.label] = detections


_NOT_TIMED = StageTimes()


def _ms(ns: int | None) -> float | None:
    return None if ns is None else ns / 1e6


class _Run:
    """State shared by the passes of one run."""

    def __init__(
        self,
        config: RunConfig,
        clock: Clock,
        progress: Callable[[int, int], None] | None,
        stop: threading.Event | None = None,
    ) -> None:
        self.config = config
        self.clock = clock
        self.progress = progress
        self.stop = stop
        self.records: list[FrameRecord] = []
        self.processed: dict[tuple[str, str], int] = {}
        self.scored: dict[tuple[str, str], dict[tuple[int, str, int], tuple[Detection, ...]]] = {}
        self.samples: dict[tuple[int, str], _Sample] = {}
        self.skipped: dict[str, int] = {}
        self.topic_frames: dict[str, int] = {}
        self.ground_truth: dict[tuple[int, str, int], tuple[Detection, ...]] = {}
        # every backend's detections per frame, for the agreement between backends
        self.detections: dict[tuple[str, str], dict[tuple[int, int], tuple[Detection, ...]]] = {}
        self.resources: dict[str, dict[str, Any]] = {}
        self.agreements: list[Agreement] = []
        # taken before the replay, so that load average and the like describe the machine, not us
        self.environment = environment()
        self.done = 0
        self.total = 0
        self.frames_csv: FramesCsvWriter | _Discard
        self.detections_out: Any
        self.warnings: list[str] = []
        self.warmups: dict[str, int] = {}
        self.tags = TagRun()  # the tag task: truth, outputs and scores of tag backends

    def set_warmups(self) -> None:
        """Warm-up frames per topic, from ``topic_frames``: the default, or --warmup clamped
        so that at least one frame of each topic is measured (with a warning)."""
        wanted = self.config.warmup
        for topic, frames in self.topic_frames.items():
            if wanted is None:
                self.warmups[topic] = default_warmup(frames)
            elif frames >= 1 and wanted > frames - 1:
                self.warmups[topic] = frames - 1
                self.warnings.append(
                    f'--warmup {wanted} leaves no frame of {topic} to measure ({frames} '
                    f'frame(s) per backend): {frames - 1} warm-up frame(s) used'
                )
            else:
                self.warmups[topic] = wanted

    def warmup_for(self, topic: str) -> int:
        found = self.warmups.get(topic)
        if found is not None:
            return found
        if self.config.warmup is not None:
            return self.config.warmup
        return default_warmup(self.topic_frames.get(topic, 0))

    def skip(self, reason: str) -> None:
        short = reason.split(':', 1)[0] if len(reason) > 80 else reason
        self.skipped[short] = self.skipped.get(short, 0) + 1

    def check_stop(self) -> None:
        """``_Stopped`` once the cancellation token is set."""
        if self.stop is not None and self.stop.is_set():
            raise _Stopped

    def advance(self, frames: int) -> None:
        self.done += frames
        if self.progress is not None:
            self.progress(self.done, self.total)


def _expected_frames(topic: CameraTopic, config: RunConfig) -> int:
    n = topic.count
    if config.max_frames is not None:
        n = min(n, config.max_frames)
    return n


def run_benchmark(
    config: RunConfig,
    *,
    clock: Clock | None = None,
    progress: Callable[[int, int], None] | None = None,
    backend_factory: Callable[[str, BackendOptions], Backend] | None = None,
    stop: threading.Event | None = None,
    render: Renderer | None = None,
    hasher: Callable[[Sequence[Path]], InputHash] | None = None,
    notice: Callable[[str], None] | None = None,
) -> RunOutcome:
    """Replay every input through every backend and write the run folder.

    Order of work: the options and ``config.out_dir`` are checked (nothing read or created
    yet); the folder is locked (``RunFolder``); the inputs are opened and probed; every
    backend is opened (models loaded); then the inputs are replayed. Each input's sha256 is
    computed beside the rest from the moment it is opened (``replaybench.replay.hashing``;
    ``hasher`` makes the ``InputHash``, ``config.hash_inputs`` False skips it) and recorded when
    the passes have ended; ``notice`` gets the lines a person should see while it lasts (the
    hashing of an input over 1 GB, a wait for it at the end). The run is
    written into a temporary folder beside ``out_dir`` and swapped in when it has ended, with
    run.json as its last file: whatever fails leaves ``out_dir`` as it was and nothing else.

    Raises ``ReplaybenchError`` subclasses: bad inputs and options, and a run that measured no
    frame (exit code 2); ``BackendFailedError`` when every backend raised in ``detect`` and
    ``OutputError`` when an output cannot be written (1). A backend that raises while others
    finish gives status ``partial``. Setting ``stop`` (a cancellation token; the command line
    sets it on Ctrl-C or SIGTERM, ``replaybench.app.signals``) ends the replay at the next
    frame: every output is finalised with the frames done so far and the run returns with
    status ``interrupted``; so does a ``KeyboardInterrupt`` raised while frames replay. No
    signal handler is installed. ``render`` draws the samples and report.html
    (``config.report``); without it the folder holds neither, and run.json says so.
    ``config.threads`` limits OpenCV's and the native thread pools'
    threads for the run (``thread_limits``); they are restored when it returns.
    """
    if not config.backends:
        msg = 'no backend given: add --backend NAME (see `replaybench backends`)'
        raise UsageError(msg)
    if len(set(config.backends)) != len(config.backends):
        msg = 'each --backend may be given once'
        raise UsageError(msg)
    if config.detections_format not in {'mcap', 'rosbag2'}:
        msg = f'unknown --format {config.detections_format!r}: use mcap or rosbag2'
        raise UsageError(msg)
    for bag in config.inputs:
        if not Path(bag).exists():
            msg = f'{bag}: no such file or directory'
            raise SourceError(msg)
    factory = backend_factory or _make_backend
    if backend_factory is None:
        for name in config.backends:
            status = get_backend(name).available()
            if not status.ok:
                msg = f'backend {name!r} is not available here: {status.reason}'
                raise BackendUnavailableError(msg)
    if config.out_dir is not None:
        check_out_dir(config.out_dir, force=config.force)

    external = _load_external(config)
    started = dt.datetime.now(dt.UTC)
    t_start = time.perf_counter()
    # in memory (no out_dir): no folder, no file
    folder = RunFolder(config.out_dir, force=config.force) if config.out_dir is not None else None
    inputs: list[_Input] = []
    opened: list[_OpenBackend] = []
    limits = contextlib.ExitStack()
    limits.enter_context(thread_limits(config.threads))
    try:
        with folder if folder is not None else contextlib.nullcontext():
            made = _make_backends(config, factory)
            recorded = any(backend_traits(b).uses_recorded_detections for _, b in made)
            for index, path in enumerate(config.inputs):
                inp = _open_input(index, Path(path), config, external, recorded_detections=recorded)
                # hashed beside the model loading and the replay; joined when the passes end
                inputs.append(inp._replace(sha256=_start_hash(inp, config, hasher, notice)))
            opened = _open_backends(made, inputs, notice)
            input_meta = [_input_meta(inp) for inp in inputs]
            outcome = _execute(
                config,
                clock or MonotonicClock(),
                progress,
                stop,
                render,
                opened,
                inputs,
                input_meta,
                started,
                t_start,
                folder.path if folder is not None else None,
                notice=notice,
            )
            if folder is not None:
                folder.commit()
    except OSError as err:
        if folder is None:
            raise
        raise folder.output_error(err) from err
    finally:
        for inp in inputs:
            if inp.sha256 is not None:
                inp.sha256.cancel()  # a failed run does not wait for its hash
        for entry in opened:
            entry.close()  # those a failure left open
        for inp in inputs:
            inp.source.close()
        limits.close()
    return outcome._replace(run_dir=config.out_dir)


def _load_external(config: RunConfig) -> ExternalGroundTruth | None:
    """The --ground-truth-file, read and checked against the other options."""
    if config.ground_truth_file is None:
        return None
    from replaybench.results.groundtruth import load_ground_truth_file

    if config.ground_truth_explicit:
        msg = 'give --ground-truth (a topic) or --ground-truth-file, not both'
        raise UsageError(msg)
    if config.ground_truth_match == 'seq' and len(config.inputs) > 1:
        msg = '--ground-truth-match seq needs a single BAG: seq numbers restart in every bag'
        raise UsageError(msg)
    return load_ground_truth_file(
        config.ground_truth_file,
        match=cast('MatchMode', config.ground_truth_match),
        topic=config.ground_truth_image_topic,
        seq_offset=config.ground_truth_seq_offset,
    )


def _replayed(inp: _Input, config: RunConfig) -> Iterator[RawMessage]:
    """The image messages a pass replays: the window, at most --max-frames per topic."""
    names = [t.name for t in inp.topics]
    messages = inp.source.messages(topics=names, start_ns=inp.start_ns, end_ns=inp.end_ns)
    if config.max_frames is None:
        return messages
    return _at_most(messages, names, config.max_frames)


def _at_most(
    messages: Iterator[RawMessage], names: Sequence[str], limit: int
) -> Iterator[RawMessage]:
    """The first ``limit`` messages of each topic in ``names``."""
    counts: dict[str, int] = {}
    for raw in messages:
        n = counts.get(raw.topic, 0)
        if n >= limit:
            if all(counts.get(t, 0) >= limit for t in names):
                return
            continue
        counts[raw.topic] = n + 1
        yield raw


def _copy_images(inputs: list[_Input], config: RunConfig, writer: Any) -> dict[int, str]:
    """--copy-images: the replayed image messages into detections.mcap, once each.

    Returns a warning per input whose messages could not all be copied.
    """
    problems: dict[int, str] = {}
    for inp in inputs:
        failed, first = 0, ''
        for raw in _replayed(inp, config):
            try:
                writer.add_raw(raw)
            except DecodeError as err:
                failed, first = failed + 1, first or str(err)
        if failed:
            problems[inp.number] = f'{failed} image message(s) not copied: {first}'
    return problems


class _OpenBackend:
    """A backend made and opened before the replay; closed once, after its pass."""

    def __init__(self, name: str, backend: Backend) -> None:
        self.name = name
        self.backend = backend
        self.closed = False

    def close(self) -> str | None:
        """Close it (the first call only); what ``close()`` raised, as one line, or None."""
        if self.closed:
            return None
        self.closed = True
        try:
            self.backend.close()
        except Exception as err:  # noqa: BLE001  a plugin's close() must not lose the run
            return f'{type(err).__name__}: {err}'.splitlines()[0]
        return None


def _make_backends(
    config: RunConfig, factory: Callable[[str, BackendOptions], Backend]
) -> list[tuple[str, Backend]]:
    """Every backend made (not opened yet), with its traits checked (``backend_traits``)."""
    made: list[tuple[str, Backend]] = []
    for name in config.backends:
        try:
            backend = factory(name, config.options)
            backend_traits(backend)
        except ReplaybenchError:
            raise
        except Exception as err:  # a plugin's own error: one line
            first = f'{type(err).__name__}: {err}'.splitlines()[0]
            msg = f'backend {name!r} could not be opened: {first}'
            raise BackendError(msg) from err
        made.append((name, backend))
    return made


#: A backend still opening after this many seconds is announced through ``notice``.
SLOW_OPEN_S = 2.0


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


def _open_backends(
    made: list[tuple[str, Backend]],
    inputs: list[_Input],
    notice: Callable[[str], None] | None = None,
) -> list[_OpenBackend]:
    """Every backend prepared and opened (models loaded) before anything is measured; one
    still opening after ``SLOW_OPEN_S`` (a model conversion, an engine build) is announced
    through ``notice``. On failure those already opened are closed again."""
    opened: list[_OpenBackend] = []
    try:
        for name, backend in made:
            try:
                if backend_traits(backend).uses_recorded_detections:
                    prepare = getattr(backend, 'prepare', None)
                    if not callable(prepare):
                        msg = f'backend {name!r} uses recorded detections but has no prepare()'
                        raise BackendError(msg)
                    prepare(
                        RecordedDetections(
                            ', '.join(sorted({i.recorded_topic or '' for i in inputs})),
                            {
                                (inp.number, *key): dets
                                for inp in inputs
                                for key, dets in inp.recorded.items()
                            },
                        )
                    )
                slow = (
                    f'replaybench: opening backend {name} (loading its model; a conversion or '
                    'an engine build can take minutes)'
                )
                with _announced_if_slow(notice, slow):
                    backend.open()
            except ReplaybenchError:
                raise
            except Exception as err:  # a plugin's own error: one line
                first = f'{type(err).__name__}: {err}'.splitlines()[0]
                msg = f'backend {name!r} could not be opened: {first}'
                raise BackendError(msg) from err
            opened.append(_OpenBackend(name, backend))
    except BaseException:
        for entry in opened:
            entry.close()
        raise
    return opened


def _execute(
    config: RunConfig,
    clock: Clock,
    progress: Callable[[int, int], None] | None,
    stop: threading.Event | None,
    render: Renderer | None,
    opened: list[_OpenBackend],
    inputs: list[_Input],
    input_meta: list[dict[str, Any]],
    started: dt.datetime,
    t_start: float,
    out: Path | None,
    *,
    notice: Callable[[str], None] | None = None,
) -> RunOutcome:
    """Replay into the (temporary) folder ``out``; run.json is its last file. ``out`` None:
    in memory, nothing is written.

    Raises ``BackendFailedError`` when every backend raised, and a ``ReplaybenchError`` saying
    why when no frame was measured (``_nothing_measured``).
    """
    from replaybench.sinks.mcap_writer import DetectionsWriter

    run = _Run(config, clock, progress, stop)
    for inp in inputs:
        run.tags.read_truth(inp.number, inp.source)
        for (frame_id, stamp), dets in inp.ground_truth.items():
            run.ground_truth[(inp.number, frame_id, stamp)] = dets
        for topic in inp.topics:
            run.topic_frames[topic.name] = run.topic_frames.get(topic.name, 0) + _expected_frames(
                topic, config
            )
    run.set_warmups()
    run.total = sum(run.topic_frames.values()) * len(config.backends)
    backend_meta: list[dict[str, Any]] = []
    copy_problems: dict[int, str] = {}
    status = 'complete'
    try:
        with (
            FramesCsvWriter(out / 'frames.csv') if out is not None else _Discard() as frames_csv,
            DetectionsWriter(
                out / 'detections.mcap',
                annotations=config.annotations,
                backends=[name.replace('-', '_') for name in config.backends],
            )
            if out is not None
            else _Discard() as detections_out,
        ):
            run.frames_csv = frames_csv
            run.detections_out = detections_out
            _copy_camera_infos(inputs, detections_out)
            passes_began = time.perf_counter()
            try:
                for entry in opened:
                    label = entry.name.replace('-', '_')
                    with ResourceSampler(gpu_index=_gpu_index(entry.backend, config)) as sampler:
                        _run_backend(run, entry, label, inputs, sampler, backend_meta)
                if config.copy_images:
                    copy_problems = _copy_images(inputs, config, detections_out)
            except (KeyboardInterrupt, _Stopped):
                status = 'interrupted'
    except OSError as err:
        if out is None:
            raise
        # frames.csv names its own errors: one that names no file is detections.mcap's
        raise with_filename(err, out / 'detections.mcap') from None
    if config.detections_format == 'rosbag2' and out is not None:
        from replaybench.sinks.rosbag2 import write_rosbag2_metadata

        write_rosbag2_metadata(out / 'detections.mcap')
    for inp, meta in zip(inputs, input_meta, strict=True):
        meta['truncated'] = inp.source.truncated
        meta['warnings'] = [*inp.source.warnings, *inp.notes]
        _record_hash(
            inp,
            meta,
            config,
            passes_began=passes_began,
            interrupted=status == 'interrupted',
            notice=notice,
        )
        if inp.number in copy_problems:
            meta['warnings'].append(copy_problems[inp.number])
        if inp.external is not None:
            matched = sum(1 for key in run.ground_truth if key[0] == inp.number)
            meta['ground_truth_frames'] = matched
            meta['warnings'] += list(inp.external.warnings)
            if not matched and run.done:
                meta['warnings'].append(
                    f'{inp.external.path} annotates none of the replayed frames '
                    f'(matched by {inp.external.match}); see docs/ground-truth.md'
                )

    failed = [meta for meta in backend_meta if meta['status'] == 'failed']
    if status == 'complete' and failed:
        if len(failed) == len(config.backends):
            msg = f'{_failures(failed)}; no other backend to finish the run, nothing was written'
            raise BackendFailedError(msg)
        status = 'partial'
    # frames pushed out of their queue are a measurement (of drops); nothing else is
    measured = any((r.status == 'ok' and not r.warmup) or r.dropped for r in run.records)
    if status != 'interrupted' and not measured:
        raise _nothing_measured(run, inputs, config)

    summaries = _summaries(run)
    run.warnings.extend(run.tags.warnings())
    if len(config.backends) > 1:
        run.agreements = agreement_table(run.detections, iou=AGREEMENT_IOU)
    if out is not None:
        write_summary_csv(out / 'summary.csv', summaries)
    drawn = render if out is not None else None
    sample_paths = drawn.samples(out, _sample_images(run, inputs)) if drawn and out else []
    reported = config.report and drawn is not None
    record = _run_record(
        config,
        run,
        status,
        input_meta,
        backend_meta,
        summaries,
        started,
        t_start,
        sample_paths,
        report=reported,
    )
    if out is None:
        return RunOutcome(None, status, summaries, record, tuple(run.records))
    if render is not None and reported:
        render.report(out, record)
    # last: a run.json never points at a file that is not there yet
    write_run_result(out / 'run.json', record)
    return RunOutcome(out, status, summaries, record, tuple(run.records))


def _failures(failed: Sequence[dict[str, Any]]) -> str:
    """One line for the backends that raised: where and what."""
    parts = []
    for meta in failed:
        where = meta['error']
        parts.append(
            f'backend {meta["name"]!r} raised on input {where["input"]} {where["topic"]} '
            f'seq {where["seq"]}: {where["message"]}'
        )
    return '; '.join(parts)


def _nothing_measured(run: _Run, inputs: Sequence[_Input], config: RunConfig) -> ReplaybenchError:
    """Why a run measured no frame, as the error that refuses it (exit 2)."""
    head = 'no frame was measured'
    if not run.records:
        if config.start_s is None and config.duration_s is None:
            return UsageError(f'{head}: the selected topics hold no image message')
        window = ' '.join(
            f'--{name} {value:g} s'
            for name, value in (('start', config.start_s), ('duration', config.duration_s))
            if value is not None
        )
        spans = []
        for inp in inputs:
            first = min((t.first_ns for t in inp.source.topics()), default=0)
            lo = min((t.first_ns for t in inp.topics), default=first) - first
            hi = max((t.last_ns for t in inp.topics), default=first) - first
            spans.append(f'{inp.path.name}: images from {lo / _NS:.3f} s to {hi / _NS:.3f} s')
        return UsageError(
            f'{head}: the time window {window} holds no image message of the selected topics '
            f'({"; ".join(spans)})'
        )
    if not any(r.status == 'ok' for r in run.records):
        reasons = '; '.join(f'{k} ({v})' for k, v in run.skipped.items())
        return DecodeError(
            f'{head}: not one frame of the selected topics could be decoded: {reasons}'
        )
    processed = sum(1 for r in run.records if r.status == 'ok')
    return UsageError(
        f'{head}: every processed frame ({processed} in all) was a warm-up frame: lower --warmup'
    )


def _gpu_index(backend: Backend, config: RunConfig) -> int | None:
    """The GPU whose utilisation is sampled: --device for the GPU backends, none otherwise."""
    return config.options.device if backend_traits(backend).device == 'cuda' else None


def _run_backend(
    run: _Run,
    entry: _OpenBackend,
    label: str,
    inputs: list[_Input],
    sampler: ResourceSampler,
    backend_meta: list[dict[str, Any]],
) -> None:
    """One opened backend over every input, sampled for resource use, then closed; its meta
    recorded even if cut short. A ``detect`` that raises stops the backend: the frames before
    it are kept and the error recorded (``status`` 'failed', ``error``)."""
    config = run.config
    backend = entry.backend
    passes: list[_Pass] = []
    error: dict[str, Any] | None = None
    try:
        for inp in inputs:
            p = _Pass(run, label, backend, inp)
            passes.append(p)
            try:
                run.check_stop()
                p.warm_short_topics()
                if config.rate.timed:
                    p.run_timed(config.rate)
                else:
                    p.run_max()
            finally:
                p.finalize()
    except _DetectError as failure:
        error = failure.where
    finally:
        # after the passes: what the backend actually used and counted
        sampler.stop()
        summary = sampler.summary()
        resources = {'summary': summary, 'series': sampler.series()}
        run.resources[label] = summary
        try:
            info = backend.info()
        except Exception as err:  # noqa: BLE001  a plugin's info() must not lose the run
            info = {'error': f'{type(err).__name__}: {err}'.splitlines()[0]}
        closing = entry.close()
        if closing is not None:
            run.warnings.append(f'backend {entry.name!r}: close() raised {closing}')
        backend_meta.append(
            {
                'name': entry.name,
                'label': label,
                'status': 'ok' if error is None else 'failed',
                'error': error,
                'info': info,
                'resources': resources,
                'read_ahead': [
                    {'input': p.inp.number, **p.read_ahead}
                    for p in passes
                    if p.read_ahead is not None
                ],
                # records, frames.csv rows, detections messages: made after each pass
                'record_s': sum(p.record_s for p in passes),
            }
        )


def _make_backend(name: str, options: BackendOptions) -> Backend:
    cls = get_backend(name)
    backend: Backend = cls(options)  # type: ignore[call-arg]
    return backend


def _copy_camera_infos(inputs: list[_Input], writer: Any) -> None:
    seen: set[tuple[str, int]] = set()
    for inp in inputs:
        for info in inp.camera_infos.all():
            key = (info.topic, info.log_time_ns)
            if key in seen:
                continue
            seen.add(key)
            writer.add_camera_info(info.topic, info.log_time_ns, info)


def _input_meta(inp: _Input) -> dict[str, Any]:
    files = list(inp.source.files)
    return {
        'index': inp.number,
        'path': str(inp.path),
        'format': inp.source.format,
        'size_bytes': sum(f.stat().st_size for f in files),
        'sha256': None,  # when the passes have ended (_record_hash)
        'truncated': inp.source.truncated,
        'warnings': list(inp.source.warnings),
        'ground_truth_frames': len(inp.ground_truth),
        'topics': [
            {
                'name': t.name,
                'msgtype': t.msgtype,
                'encoding': t.encoding,
                'width': t.width,
                'height': t.height,
                'count': t.count,
                'is_depth': t.is_depth,
                'camera_info_topic': t.camera_info_topic,
            }
            for t in inp.topics
        ],
    }


def _summaries(run: _Run) -> list[Summary]:
    from dataclasses import replace

    from replaybench.results.accuracy import evaluate

    summaries = summarize(run.records)
    out: list[Summary] = []
    for s in summaries:
        key = (s.backend, s.topic)
        scored = run.scored.get(key)
        if not scored:
            out.append(s)
            continue
        frames_gt = {k: run.ground_truth[k] for k in scored}
        result = evaluate(frames_gt, scored)
        accuracy = {
            'frames': len(frames_gt),
            'precision50': result.precision50,
            'recall50': result.recall50,
            'map50': result.map50 if result.map50 >= 0 else None,
            'map50_95': result.map50_95 if result.map50_95 >= 0 else None,
            'ap50': result.ap50,
            'ap50_95': result.ap50_95,
            'n_gt': result.n_gt,
            'n_det': result.n_det,
        }
        out.append(replace(s, accuracy=accuracy))
    out = [replace(s, resources=run.resources.get(s.backend)) for s in out]
    out = run.tags.summaries(out)
    return with_intervals(out, run.records)


def _sample_images(run: _Run, inputs: Sequence[_Input]) -> Iterator[SampleImage]:
    """Each sample frame, read and decoded again, with every backend's detections."""
    for (index, topic), sample in sorted(run.samples.items()):
        image = _sample_image(inputs[index].source, topic, sample)
        if image is not None:
            yield SampleImage(index, topic, image, sample.detections, sample.title)


def _sample_image(source: Source, topic: str, sample: _Sample) -> Any:
    """The sample's frame as BGR, or None if it cannot be read again."""
    log_time = sample.log_time_ns
    for raw in source.messages(topics=[topic], start_ns=log_time, end_ns=log_time + 1):
        if raw.seq == sample.seq:
            try:
                frame = decode_image(raw)
            except DecodeError:
                return None
            return to_bgr8(frame.image, frame.encoding)
    return None


def _run_record(
    config: RunConfig,
    run: _Run,
    status: str,
    input_meta: list[dict[str, Any]],
    backend_meta: list[dict[str, Any]],
    summaries: list[Summary],
    started: dt.datetime,
    t_start: float,
    samples: list[str] | None = None,
    *,
    report: bool = False,
) -> RunResult:
    """What run.json holds (written by the caller, last)."""
    rows = []
    for s in summaries:
        row = summary_json(s)
        rows.append(from_document(SummaryRow, row))
    return RunResult(
        schema_version=RUN_SCHEMA_VERSION,
        tool=Tool(name='replaybench', version=__version__),
        status=status,
        command=tuple(config.command),
        started_at=started.isoformat(),
        finished_at=dt.datetime.now(dt.UTC).isoformat(),
        wall_s=time.perf_counter() - t_start,
        settings=RunSettings(
            rate=str(config.rate),
            queue_depth=config.queue_depth,
            warmup=config.warmup,
            warmup_per_topic={t: run.warmup_for(t) for t in run.topic_frames},
            threads=config.threads,
            max_frames=config.max_frames,
            start_s=config.start_s,
            duration_s=config.duration_s,
            topics=tuple(config.topics) if config.topics else None,
            ground_truth_topic=config.ground_truth_topic
            if config.ground_truth_file is None
            and any(m['ground_truth_frames'] for m in input_meta)
            else None,
            ground_truth_file=str(config.ground_truth_file)
            if config.ground_truth_file is not None
            else None,
            ground_truth_match=config.ground_truth_match
            if config.ground_truth_file is not None
            else None,
            annotations=config.annotations,
            copy_images=config.copy_images,
            detections_format=config.detections_format,
            agreement_iou=AGREEMENT_IOU,
        ),
        inputs=tuple(from_document(InputInfo, meta) for meta in input_meta),
        environment=from_document(Environment, run.environment),
        backends=tuple(from_document(BackendRun, meta) for meta in backend_meta),
        summary_rows=tuple(rows),
        agreement=tuple(from_document(AgreementRow, a._asdict()) for a in run.agreements),
        counts=RunCounts(
            frames=len(run.records),
            processed=sum(1 for r in run.records if r.status == 'ok'),
            dropped=sum(1 for r in run.records if r.status == 'dropped'),
            skipped=sum(1 for r in run.records if r.status == 'skipped'),
        ),
        skipped=dict(run.skipped),
        warnings=tuple(run.warnings),
        outputs=RunOutputs(
            detections_mcap='detections.mcap',
            frames_csv='frames.csv',
            summary_csv='summary.csv',
            report='report.html' if report else None,
            samples=tuple(samples or ()),
        )
        if config.out_dir is not None
        else None,
    )
