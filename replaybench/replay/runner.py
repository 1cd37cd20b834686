"""Run a benchmark: inputs x backends -> run folder (detections.mcap, frames.csv, summary.csv,
run.json, samples/, report.html).

Backends run one after another over the same frames; each (backend, input) pass reads the bag
again, so every backend is measured on the same path from container to detections.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import math
import os
import shutil
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, cast

from replaybench import __version__
from replaybench.backends import get_backend
from replaybench.backends.base import BackendOptions
from replaybench.backends.recorded import RecordedBackend
from replaybench.decode import (
    DecodedImage,
    decode_detections,
    decode_image,
    message_kind,
    to_bgr8,
)
from replaybench.decode.camera_info import CameraInfoIndex
from replaybench.decode.probe import CameraTopic, probe_topics
from replaybench.errors import (
    BackendUnavailableError,
    DecodeError,
    SourceError,
    UsageError,
)
from replaybench.replay.clock import Clock, MonotonicClock
from replaybench.replay.prefetch import Prefetcher
from replaybench.replay.rate import Rate
from replaybench.replay.resources import ResourceSampler
from replaybench.replay.scheduler import replay_timed
from replaybench.results.agreement import Agreement, agreement_table
from replaybench.results.records import FrameRecord, FramesCsvWriter
from replaybench.results.runfile import (
    SCHEMA_VERSION,
    environment,
    write_json_atomic,
    write_summary_csv,
)
from replaybench.results.stats import Summary, summarize, summary_row
from replaybench.sources import Source, open_source
from replaybench.types import Detection, Frame, TopicInfo

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Sequence

    from replaybench.backends.base import Backend
    from replaybench.results.groundtruth import ExternalGroundTruth, MatchMode
    from replaybench.types import RawMessage

__all__ = [
    'DEFAULT_GROUND_TRUTH_TOPIC',
    'THREAD_VARS',
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
    out_dir: Path
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


class RunOutcome(NamedTuple):
    """What a finished (or interrupted) run left behind."""

    run_dir: Path
    status: str
    summaries: list[Summary]
    run: dict[str, Any]


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


class _Sample:
    """The frame drawn for a topic, with each backend's detections on it.

    The replay keeps a reference to the frame's image; ``settle`` converts it to a BGR copy
    after the pass, so that the conversion (milliseconds at 1080p) is not in the replay.
    """

    def __init__(self, image: Any, encoding: str, seq: int, title: str) -> None:
        self.image: Any = image
        self.encoding: str | None = encoding
        self.seq = seq
        self.title = title
        self.detections: dict[str, tuple[Detection, ...]] = {}

    def settle(self) -> None:
        """Replace the image by its BGR copy (once): it may be a view into the input."""
        if self.encoding is not None:
            self.image = to_bgr8(self.image, self.encoding).copy()
            self.encoding = None


def _sha256(paths: Sequence[Path]) -> str:
    digest = hashlib.sha256()
    for path in paths:
        with path.open('rb') as f:
            while chunk := f.read(1 << 20):
                digest.update(chunk)
    return digest.hexdigest()


def _prepare_out_dir(out: Path, force: bool) -> None:
    if out.exists() and not out.is_dir():
        msg = f'{out} exists and is not a directory'
        raise UsageError(msg)
    if out.is_dir() and any(out.iterdir()):
        if not force:
            msg = f'output folder {out} is not empty: choose another --out or pass --force'
            raise UsageError(msg)
        for name in ('detections.mcap', 'frames.csv', 'summary.csv', 'run.json', 'report.html'):
            (out / name).unlink(missing_ok=True)
        shutil.rmtree(out / 'samples', ignore_errors=True)
    out.mkdir(parents=True, exist_ok=True)


def _select_topics(
    path: Path, found: list[CameraTopic], wanted: Sequence[str] | None
) -> list[CameraTopic]:
    if not found:
        msg = f'{path}: no image messages (sensor_msgs Image / CompressedImage) in this file'
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
    index: int, path: Path, config: RunConfig, external: ExternalGroundTruth | None = None
) -> _Input:
    source = open_source(path)
    try:
        found = probe_topics(source)
        topics = _select_topics(path, found, config.topics)
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
        ground_truth: dict[tuple[str, int], tuple[Detection, ...]] = {}
        gt_topic = config.ground_truth_topic
        gt_present = any(t.name == gt_topic for t in all_topics)
        if gt_topic and not gt_present and config.ground_truth_explicit:
            msg = f'{path}: ground-truth topic {gt_topic} is not in this file'
            raise UsageError(msg)
        if gt_topic and gt_present and external is None:
            ground_truth = _read_detections(source, gt_topic)
        recorded: dict[tuple[str, int], tuple[Detection, ...]] = {}
        recorded_topic = None
        if 'recorded' in config.backends:
            recorded_topic = _recorded_topic(path, all_topics, config)
            recorded = _read_detections(source, recorded_topic)
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


def _read_detections(source: Source, topic: str) -> dict[tuple[str, int], tuple[Detection, ...]]:
    """Detection2DArray messages of a topic keyed by (frame_id, stamp); bad messages skipped."""
    table: dict[tuple[str, int], tuple[Detection, ...]] = {}
    for raw in source.messages(topics=[topic]):
        try:
            found = decode_detections(raw)
        except DecodeError:
            continue
        table[(found.frame_id, found.stamp_ns)] = found.detections
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


class _Pass:
    """One backend over one input: fetch, decode, detect, record, write."""

    def __init__(
        self,
        run: _Run,
        backend_name: str,
        label: str,
        backend: Backend,
        inp: _Input,
    ) -> None:
        self.run = run
        self.backend_name = backend_name
        self.label = label
        self.backend = backend
        self.inp = inp
        self.t0 = 0.0
        self.taken: dict[str, int] = {}
        self.measures_latency = bool(getattr(backend, 'measures_latency', True))
        # at max rate: whether frames were read ahead in a thread, and why (run.json)
        self.read_ahead: dict[str, Any] | None = None

    def messages(self) -> Iterator[RawMessage]:
        return _replayed(self.inp, self.run.config)

    def record(self, rec: FrameRecord) -> None:
        self.run.records.append(rec)
        self.run.frames_csv.write(rec)
        self.run.tick()

    def drop(self, raw: RawMessage, release: float) -> None:
        self.record(
            FrameRecord(
                input=self.inp.number,
                backend=self.label,
                topic=raw.topic,
                seq=raw.seq,
                log_time_ns=raw.log_time_ns,
                stamp_ns=None,
                status='dropped',
                note='pushed out of the queue',
                warmup=False,
                dropped=True,
                release_s=release - self.t0,
            )
        )

    def process(self, raw: RawMessage, release: float, start: float, read_s: float) -> float:
        """Decode and detect one frame now (timed modes, and max rate without read-ahead).

        Returns the frame's read + decode time.
        """
        clock = self.run.clock
        t_decode = clock.now()
        decoded = _decode(raw)
        read_decode_s = read_s + clock.now() - t_decode
        self.complete(raw, decoded, release, start, start - release, read_decode_s)
        return read_decode_s

    def complete(
        self,
        raw: RawMessage,
        decoded: DecodedImage | DecodeError,
        release: float,
        start: float,
        queue_wait_s: float,
        read_decode_s: float,
    ) -> None:
        """Run the backend on a decoded frame (or record its decode failure) and write the row.

        ``latency = queue wait + read/decode + backend``: the backend part runs from here to the
        detections; read/decode was measured where it ran (here, or in the prefetch thread).
        """
        clock = self.run.clock
        run = self.run
        if isinstance(decoded, DecodeError):
            reason = str(decoded)
            run.skip(reason)
            self.record(
                FrameRecord(
                    input=self.inp.number,
                    backend=self.label,
                    topic=raw.topic,
                    seq=raw.seq,
                    log_time_ns=raw.log_time_ns,
                    stamp_ns=None,
                    status='skipped',
                    note=reason,
                    warmup=False,
                    dropped=False,
                    release_s=release - self.t0,
                    start_s=start - self.t0,
                    done_s=clock.now() - self.t0,
                    queue_wait_ms=queue_wait_s * 1e3,
                    read_decode_ms=read_decode_s * 1e3,
                )
            )
            return
        frame = self.make_frame(raw, decoded)
        t_detect = clock.now()
        result = self.backend.detect(frame)
        done = clock.now()
        key = (self.label, raw.topic)
        detections = result.detections
        run.detections.setdefault(key, {})[(self.inp.number, raw.seq)] = detections
        n_done = run.processed.get(key, 0)
        run.processed[key] = n_done + 1
        run.detections_out.add(
            self.label, raw.topic, raw.log_time_ns, decoded.stamp_ns, decoded.frame_id, detections
        )
        if self.inp.external is not None:
            truth = self.inp.external.lookup(raw.topic, raw.seq, decoded.stamp_ns)
            if truth is not None:
                frame_key = (self.inp.number, raw.topic, raw.seq)
                run.ground_truth[frame_key] = truth
                run.scored.setdefault(key, {})[frame_key] = detections
        else:
            gt_key = (decoded.frame_id, decoded.stamp_ns)
            if gt_key in self.inp.ground_truth:
                run.scored.setdefault(key, {})[(self.inp.number, *gt_key)] = detections
        self.sample(frame, detections)
        t0 = self.t0
        if not self.measures_latency:
            self.record(
                FrameRecord(
                    self.inp.number,
                    self.label,
                    raw.topic,
                    raw.seq,
                    raw.log_time_ns,
                    decoded.stamp_ns,
                    'ok',
                    'recorded detections: latency not measured',
                    False,
                    False,
                    release - t0,
                    start - t0,
                    done - t0,
                    queue_wait_s * 1e3,
                    read_decode_s * 1e3,
                    None,
                    None,
                    None,
                    None,
                    None,
                    None,
                    len(detections),
                )
            )
            return
        stages = result.stages
        self.record(
            FrameRecord(
                self.inp.number,
                self.label,
                raw.topic,
                raw.seq,
                raw.log_time_ns,
                decoded.stamp_ns,
                'ok',
                '',
                n_done < run.warmup_for(raw.topic),
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
                (queue_wait_s + read_decode_s + done - t_detect) * 1e3,
                len(detections),
            )
        )

    def sample(self, frame: Frame, detections: tuple[Detection, ...]) -> None:
        """Keep the sample frame of this topic (chosen by the first backend) and its boxes."""
        key = (self.inp.number, frame.topic)
        taken = self.taken.get(frame.topic, 0)
        self.taken[frame.topic] = taken + 1
        sample = self.run.samples.get(key)
        if sample is None and taken == self.inp.sample_index.get(frame.topic):
            sample = self.run.samples[key] = _Sample(
                frame.image, frame.encoding, frame.seq, f'{frame.topic} #{frame.seq}'
            )
        if sample is not None and sample.seq == frame.seq:
            sample.detections[self.label] = detections

    def make_frame(self, raw: RawMessage, decoded: DecodedImage) -> Frame:
        return Frame(
            topic=raw.topic,
            seq=raw.seq,
            log_time_ns=raw.log_time_ns,
            stamp_ns=decoded.stamp_ns,
            frame_id=decoded.frame_id,
            image=decoded.image,
            encoding=decoded.encoding,
            source_encoding=decoded.source_encoding,
            is_depth=decoded.is_depth,
            camera_info=self.inp.camera_infos.lookup(raw.topic, decoded.stamp_ns),
            input_index=self.inp.number,
        )

    def run_max(self) -> None:
        """Every frame as fast as possible.

        The first ``READ_AHEAD_PROBE`` frames are read inline and timed; when reading and
        decoding a frame takes at least ``READ_AHEAD_MIN_S`` (compressed images, compressed
        chunks, colour conversions), the rest are read and decoded ahead in a bounded thread
        (``Prefetcher``), overlapping with the backend. Below that there is nothing to overlap
        (a raw frame mapped from the file is a few microseconds of Python, holding the GIL)
        and handing frames between threads would cost more than reading them.
        """
        clock = self.run.clock
        self.t0 = clock.now()
        messages = self.messages()
        depth = self.run.config.prefetch
        if depth < 1:
            self.inline(messages, None)
            self.read_ahead = {'depth': 0, 'used': False, 'reason': 'prefetch=0'}
            return
        spent = self.inline(messages, READ_AHEAD_PROBE)
        if len(spent) < READ_AHEAD_PROBE:
            self.read_ahead = {'depth': depth, 'used': False, 'reason': 'input ended in the probe'}
            return
        # the mean, not the median: a compressed chunk holding several frames is paid by one
        typical = sum(spent[1:]) / (len(spent) - 1)
        used = typical >= READ_AHEAD_MIN_S
        self.read_ahead = {
            'depth': depth,
            'used': used,
            'probe_frames': len(spent) - 1,
            'probe_read_decode_ms': typical * 1e3,
            'threshold_ms': READ_AHEAD_MIN_S * 1e3,
        }
        if not used:
            self.inline(messages, None)
            return
        with Prefetcher(messages, clock, depth) as frames:
            for item in frames:
                self.complete(
                    item.raw, item.decoded, item.release, clock.now(), 0.0, item.read_decode_s
                )

    def inline(self, messages: Iterator[RawMessage], limit: int | None) -> list[float]:
        """Read, decode and detect up to ``limit`` frames (all with None) in this thread.

        Returns the read + decode time of each frame when ``limit`` is given (else empty).
        """
        clock = self.run.clock
        spent: list[float] = []
        count = 0
        while limit is None or count < limit:
            release = clock.now()
            raw = next(messages, None)
            if raw is None:
                break
            read_decode_s = self.process(raw, release, release, clock.now() - release)
            if limit is not None:
                spent.append(read_decode_s)
                count += 1
        return spent

    def run_timed(self, rate: Rate) -> None:
        clock = self.run.clock
        self.t0 = clock.now()

        def releases() -> Iterator[tuple[float, str, tuple[RawMessage, float]]]:
            first_log: int | None = None
            per_topic: dict[str, int] = {}
            last = 0.0
            for raw in self.messages():
                if rate.mode == 'fixed':
                    k = per_topic.get(raw.topic, 0)
                    per_topic[raw.topic] = k + 1
                    offset = max(last, k / rate.hz)
                else:
                    if first_log is None:
                        first_log = raw.log_time_ns
                    offset = max(last, (raw.log_time_ns - first_log) / _NS / rate.scale)
                last = offset
                yield offset, raw.topic, (raw, 0.0)

        def process(item: tuple[RawMessage, float], release: float, start: float) -> None:
            self.process(item[0], release, start, item[1])

        replay_timed(
            releases(),
            clock=clock,
            queue_depth=self.run.config.queue_depth,
            process=process,
            drop=lambda item, release: self.drop(item[0], release),
        )


def _decode(raw: RawMessage) -> DecodedImage | DecodeError:
    try:
        return decode_image(raw)
    except DecodeError as err:
        return err


def _ms(ns: int | None) -> float | None:
    return None if ns is None else ns / 1e6


class _Run:
    """State shared by the passes of one run."""

    def __init__(
        self,
        config: RunConfig,
        clock: Clock,
        progress: Callable[[int, int], None] | None,
    ) -> None:
        self.config = config
        self.clock = clock
        self.progress = progress
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
        self.frames_csv: FramesCsvWriter
        self.detections_out: Any

    def warmup_for(self, topic: str) -> int:
        if self.config.warmup is not None:
            return self.config.warmup
        return default_warmup(self.topic_frames.get(topic, 0))

    def skip(self, reason: str) -> None:
        short = reason.split(':', 1)[0] if len(reason) > 80 else reason
        self.skipped[short] = self.skipped.get(short, 0) + 1

    def tick(self) -> None:
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, self.total)


def _expected_frames(inp: _Input, topic: CameraTopic, config: RunConfig) -> int:
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
) -> RunOutcome:
    """Replay every input through every backend and write the run folder.

    Raises ``ReplaybenchError`` subclasses for bad inputs and options before anything is written.
    A ``KeyboardInterrupt`` (Ctrl-C, or SIGTERM while this runs) finalises every output with the
    frames done so far and returns with status ``interrupted``.
    """
    if not config.backends:
        msg = 'no backend given: add --backend NAME (see `replaybench backends`)'
        raise UsageError(msg)
    if len(set(config.backends)) != len(config.backends):
        msg = 'each --backend may be given once'
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
    if config.threads is not None:
        _set_threads(config.threads)

    external = _load_external(config)
    started = dt.datetime.now(dt.UTC)
    t_start = time.perf_counter()
    inputs: list[_Input] = []
    try:
        for index, path in enumerate(config.inputs):
            inputs.append(_open_input(index, Path(path), config, external))
        input_meta = [_input_meta(inp) for inp in inputs]
        _prepare_out_dir(config.out_dir, config.force)
        return _execute(
            config,
            clock or MonotonicClock(),
            progress,
            factory,
            inputs,
            input_meta,
            started,
            t_start,
        )
    finally:
        for inp in inputs:
            inp.source.close()


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
    limit = config.max_frames
    counts: dict[str, int] = {}
    names = [t.name for t in inp.topics]
    for raw in inp.source.messages(topics=names, start_ns=inp.start_ns, end_ns=inp.end_ns):
        n = counts.get(raw.topic, 0)
        if limit is not None and n >= limit:
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


def _execute(
    config: RunConfig,
    clock: Clock,
    progress: Callable[[int, int], None] | None,
    factory: Callable[[str, BackendOptions], Backend],
    inputs: list[_Input],
    input_meta: list[dict[str, Any]],
    started: dt.datetime,
    t_start: float,
) -> RunOutcome:
    from replaybench.sinks.mcap_writer import DetectionsWriter

    out = config.out_dir
    run = _Run(config, clock, progress)
    for inp in inputs:
        for (frame_id, stamp), dets in inp.ground_truth.items():
            run.ground_truth[(inp.number, frame_id, stamp)] = dets
        for topic in inp.topics:
            run.topic_frames[topic.name] = run.topic_frames.get(topic.name, 0) + _expected_frames(
                inp, topic, config
            )
    run.total = sum(run.topic_frames.values()) * len(config.backends)
    backend_meta: list[dict[str, Any]] = []
    copy_problems: dict[int, str] = {}
    status = 'complete'
    previous = signal.getsignal(signal.SIGTERM)
    with contextlib.suppress(ValueError):
        signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        with (
            FramesCsvWriter(out / 'frames.csv') as frames_csv,
            DetectionsWriter(
                out / 'detections.mcap',
                annotations=config.annotations,
                backends=[name.replace('-', '_') for name in config.backends],
            ) as detections_out,
        ):
            run.frames_csv = frames_csv
            run.detections_out = detections_out
            _copy_camera_infos(inputs, detections_out)
            try:
                for name in config.backends:
                    label = name.replace('-', '_')
                    with ResourceSampler(gpu_index=_gpu_index(name, config)) as sampler:
                        _run_backend(run, name, label, factory, inputs, sampler, backend_meta)
                if config.copy_images:
                    copy_problems = _copy_images(inputs, config, detections_out)
            except KeyboardInterrupt:
                status = 'interrupted'
    finally:
        with contextlib.suppress(ValueError):
            signal.signal(signal.SIGTERM, previous)
    for inp, meta in zip(inputs, input_meta, strict=True):
        meta['truncated'] = inp.source.truncated
        meta['warnings'] = list(inp.source.warnings)
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

    if run.done and not any(r.status == 'ok' for r in run.records) and status == 'complete':
        reasons = '; '.join(f'{k} ({v})' for k, v in run.skipped.items())
        msg = f'not one frame of the selected topics could be decoded: {reasons}'
        _write_run_json(config, run, 'failed', input_meta, backend_meta, [], started, t_start)
        raise DecodeError(msg)

    summaries = _summaries(run)
    if len(config.backends) > 1:
        run.agreements = agreement_table(run.detections)
    write_summary_csv(out / 'summary.csv', summaries)
    sample_paths = _write_samples(out, run)
    record = _write_run_json(
        config, run, status, input_meta, backend_meta, summaries, started, t_start, sample_paths
    )
    if config.report:
        from replaybench.report import render_report

        render_report(out)
    return RunOutcome(out, status, summaries, record)


def _gpu_index(name: str, config: RunConfig) -> int | None:
    """The GPU whose utilisation is sampled: --device for the GPU backends, none otherwise."""
    return config.options.device if name in _GPU_BACKENDS else None


_GPU_BACKENDS = frozenset({'cuda', 'tensorrt', 'hsv-cuda'})


def _run_backend(
    run: _Run,
    name: str,
    label: str,
    factory: Callable[[str, BackendOptions], Backend],
    inputs: list[_Input],
    sampler: ResourceSampler,
    backend_meta: list[dict[str, Any]],
) -> None:
    """One backend over every input, sampled for resource use; meta recorded even if cut short."""
    config = run.config
    backend = factory(name, config.options)
    if isinstance(backend, RecordedBackend):
        backend.bind(
            ', '.join(sorted({i.recorded_topic or '' for i in inputs})),
            {(inp.number, *key): dets for inp in inputs for key, dets in inp.recorded.items()},
        )
    backend.open()
    passes: list[_Pass] = []
    try:
        for inp in inputs:
            p = _Pass(run, name, label, backend, inp)
            passes.append(p)
            try:
                if config.rate.timed:
                    p.run_timed(config.rate)
                else:
                    p.run_max()
            finally:
                # before the input can be closed: a sample may be a view into it
                for sample in run.samples.values():
                    sample.settle()
    finally:
        # after the passes: what the backend actually used and counted
        sampler.stop()
        summary = sampler.summary()
        resources = {'summary': summary, 'series': sampler.series()}
        run.resources[label] = summary
        backend_meta.append(
            {
                'name': name,
                'label': label,
                'info': backend.info(),
                'resources': resources,
                'read_ahead': [
                    {'input': p.inp.number, **p.read_ahead}
                    for p in passes
                    if p.read_ahead is not None
                ],
            }
        )
        backend.close()


def _raise_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _make_backend(name: str, options: BackendOptions) -> Backend:
    cls = get_backend(name)
    backend: Backend = cls(options)  # type: ignore[call-arg]
    return backend


#: Environment variables ``--threads`` sets, besides OpenCV's thread count.
THREAD_VARS = ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')


def _set_threads(threads: int) -> None:
    import cv2

    cv2.setNumThreads(threads)
    for var in THREAD_VARS:
        os.environ[var] = str(threads)


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
        'sha256': _sha256(files),
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
    return [replace(s, resources=run.resources.get(s.backend)) for s in out]


def _write_samples(out: Path, run: _Run) -> list[str]:
    from replaybench.report import sample_relpath, write_sample

    paths: list[str] = []
    folder = out / 'samples'
    folder.mkdir(exist_ok=True)
    for (index, topic), sample in sorted(run.samples.items()):
        rel = sample_relpath(index, topic)
        sample.settle()
        write_sample(out / rel, sample.image, sample.detections, sample.title)
        paths.append(rel)
    return paths


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


def _write_run_json(
    config: RunConfig,
    run: _Run,
    status: str,
    input_meta: list[dict[str, Any]],
    backend_meta: list[dict[str, Any]],
    summaries: list[Summary],
    started: dt.datetime,
    t_start: float,
    samples: list[str] | None = None,
) -> dict[str, Any]:
    rows = []
    for s in summaries:
        row = summary_row(s)
        row['accuracy'] = s.accuracy
        rows.append(row)
    counts = {
        'frames': len(run.records),
        'processed': sum(1 for r in run.records if r.status == 'ok'),
        'dropped': sum(1 for r in run.records if r.status == 'dropped'),
        'skipped': sum(1 for r in run.records if r.status == 'skipped'),
    }
    record: dict[str, Any] = {
        'schema_version': SCHEMA_VERSION,
        'tool': {'name': 'replaybench', 'version': __version__},
        'status': status,
        'command': list(config.command) or sys.argv,
        'started_at': started.isoformat(),
        'finished_at': dt.datetime.now(dt.UTC).isoformat(),
        'wall_s': time.perf_counter() - t_start,
        'settings': {
            'rate': str(config.rate),
            'queue_depth': config.queue_depth,
            'warmup': config.warmup,
            'warmup_per_topic': {t: run.warmup_for(t) for t in run.topic_frames},
            'threads': config.threads,
            'max_frames': config.max_frames,
            'start_s': config.start_s,
            'duration_s': config.duration_s,
            'topics': list(config.topics) if config.topics else None,
            'ground_truth_topic': config.ground_truth_topic
            if config.ground_truth_file is None
            and any(m['ground_truth_frames'] for m in input_meta)
            else None,
            'ground_truth_file': str(config.ground_truth_file)
            if config.ground_truth_file is not None
            else None,
            'ground_truth_match': config.ground_truth_match
            if config.ground_truth_file is not None
            else None,
            'annotations': config.annotations,
            'copy_images': config.copy_images,
        },
        'inputs': input_meta,
        'environment': run.environment,
        'backends': backend_meta,
        'summary': rows,
        'agreement': [a._asdict() for a in run.agreements],
        'counts': counts,
        'skipped': dict(run.skipped),
        'outputs': {
            'detections_mcap': 'detections.mcap',
            'frames_csv': 'frames.csv',
            'summary_csv': 'summary.csv',
            'report': 'report.html' if config.report else None,
            'samples': samples or [],
        },
    }
    record = _clean(record)
    write_json_atomic(config.out_dir / 'run.json', record)
    return record
