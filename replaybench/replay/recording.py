"""From a pass's log to records: frames.csv rows, detections messages, scores and samples.

``Recorder.take`` runs after each pass (also one cut short) and turns every ``LogEntry`` into
its ``FrameRecord`` (a frames.csv row) and, for a frame the backend processed, into what its
``BackendResult`` leads to (``Recorder.task_outputs``): the detections message in
outputs.mcap, the detections kept for scoring against ground truth and for the agreement
between backends, and the boxes drawn on the sample picture. Every task has boxes; what a
task does beside them (its messages, its scores, its frames.csv fields) is its
``TaskRecording``, loaded once per run from the task the backend declares (``Pass.task``,
``Backend.task``; the task's ``recording``, ``replaybench.tasks.task_recording``).

With ``--repeat N`` every pass has its own warm-up and its records carry its number
(``FrameRecord.repeat``); the later passes detect the same frames again, so only the first
pass's results lead to task outputs (outputs.mcap holds each frame once, and the scores,
the agreement and the sample describe the frames it wrote).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Protocol, cast

from replaybench.errors import TaskUnavailableError
from replaybench.replay.recorded import NOT_RECORDED, frame_recorded_times, recorded_note
from replaybench.replay.streaming import Pick, StreamFrame, pick_outputs
from replaybench.results.records import FrameRecord
from replaybench.tasks.base import TaskRecording
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.replay.inputs import OpenedInput
    from replaybench.replay.passes import LogEntry, Pass, Warmups
    from replaybench.results.groundtruth import ExternalGroundTruth
    from replaybench.tasks.detections.truth import BoxTruth, DetectionTable
    from replaybench.types import CameraInfo, Detection, RawMessage

__all__ = ['DetectionsSink', 'FrameSink', 'Recorder', 'Sample', 'TaskRecording']

#: (input, seq) -> detections of one (backend label, topic)
FrameDetections = dict[tuple[int, int], tuple['Detection', ...]]
#: a ground-truth frame: (input, frame_id, stamp_ns) for a topic, (input, topic, seq) for a file
TruthKey = tuple[int, str, int]
#: a processed frame: (topic, seq, log_time_ns, stamp_ns, frame_id)
FrameKey = tuple[str, int, int, int, str]

_NOT_TIMED = StageTimes()
_NO_COLUMNS: Mapping[str, Any] = {}
_RECORD_FIELDS = frozenset(FrameRecord._fields)


def _as_fields(columns: Mapping[str, Any]) -> dict[str, Any]:
    """A task's frame columns as ``FrameRecord`` fields: a built-in task's are fields, any
    other task's go into ``task_values`` (frames.csv's columns after the known ones)."""
    fields = {k: v for k, v in columns.items() if k in _RECORD_FIELDS}
    fields['task_values'] = {k: v for k, v in columns.items() if k not in _RECORD_FIELDS}
    return fields


def _boxes(inp: OpenedInput) -> tuple[DetectionTable, ExternalGroundTruth | None]:
    """The input's box truth (``replaybench.tasks.detections.truth.BoxTruth``): its topic's
    boxes by (frame_id, stamp), and the run's ground-truth file; empty where it has none."""
    found = cast('BoxTruth | None', inp.truth.get('detections'))
    return ({}, None) if found is None else (found.frames, found.external)


class FrameSink(Protocol):
    """Where frames.csv rows go (``FramesCsvWriter``, or nothing in memory)."""

    def write(self, record: FrameRecord, /) -> None: ...


class DetectionsSink(Protocol):
    """Where detections messages go (``replaybench.sinks.mcap_writer.DetectionsWriter``, or
    nothing in memory)."""

    def add(
        self,
        backend: str,
        topic: str,
        log_time_ns: int,
        stamp_ns: int,
        frame_id: str,
        detections: Sequence[Detection],
        /,
    ) -> Any: ...

    def add_camera_info(self, topic: str, log_time_ns: int, info: CameraInfo, /) -> Any: ...

    def add_camera_info_channel(self, topic: str, /) -> Any: ...

    def add_raw(self, raw: RawMessage, /) -> Any: ...

    # what the tasks' sinks call (``replaybench.sinks.writer.OutputWriter``)
    @property
    def keeps(self) -> bool: ...

    @property
    def annotations(self) -> bool: ...

    @property
    def depth(self) -> bool: ...

    def colour(self, backend: str, /) -> str: ...

    def add_message(
        self,
        topic: str,
        msgtype: str,
        log_time_ns: int,
        data: bytes | memoryview,
        /,
        *,
        annotation: bool = False,
    ) -> None: ...

    def add_metadata(self, name: str, data: dict[str, str], /) -> None: ...


class Sample:
    """The frame drawn for a topic (by its seq and log time), with each backend's detections.

    The replay keeps no image: the frame is read again after the passes
    (``replaybench.replay.output.sample_images``).
    """

    def __init__(self, seq: int, log_time_ns: int, title: str) -> None:
        self.seq = seq
        self.log_time_ns = log_time_ns
        self.title = title
        self.detections: dict[str, tuple[Detection, ...]] = {}
        #: what each backend's task draws of the frame beside its boxes (a segmentation
        #: backend's label mask), by backend label: (the task's name, what it drew)
        self.drawn: dict[str, tuple[str, Any]] = {}


def _ms(ns: int | None) -> float | None:
    return None if ns is None else ns / 1e6


class Recorder:
    """The records of a run, made pass by pass from the passes' logs."""

    def __init__(
        self,
        inputs: Sequence[OpenedInput],
        warmups: Warmups,
        frames_csv: FrameSink,
        detections_out: DetectionsSink,
        backends: int = 1,
    ) -> None:
        #: backends in the run (a task's recording may keep outputs to compare them)
        self.backends = backends
        #: the run's inputs, by number (their truth, read again for streaming scores)
        self.inputs = tuple(inputs)
        self.warmups = warmups
        self.frames_csv = frames_csv
        self.detections_out = detections_out
        self.records: list[FrameRecord] = []
        #: frames processed per (backend label, topic, pass): each pass warms up anew
        self.processed: dict[tuple[str, str, int], int] = {}
        self.skipped: dict[str, int] = {}
        #: ground truth of the frames scored: from the inputs' topics, and matched from a file
        self.ground_truth: dict[TruthKey, tuple[Detection, ...]] = {
            (inp.number, frame_id, stamp): dets
            for inp in inputs
            for (frame_id, stamp), dets in _boxes(inp)[0].items()
        }
        #: per (backend label, topic): the detections of each frame that has ground truth
        self.scored: dict[tuple[str, str], dict[TruthKey, tuple[Detection, ...]]] = {}
        #: every backend's detections per frame, for the agreement between backends
        self.detections: dict[tuple[str, str], FrameDetections] = {}
        self.samples: dict[tuple[int, str], Sample] = {}
        self._taken: dict[tuple[str, int, str], int] = {}
        #: each declared task's part of recording a frame (None: boxes only), by task name
        self._recordings: dict[str, TaskRecording | None] = {}
        #: the streaming picks of each (backend label, topic), over its first pass of every
        #: input (``replaybench.replay.streaming``), and the task of its results
        self.picks: dict[tuple[str, str], list[Pick]] = {}
        self.stream_tasks: dict[tuple[str, str], str] = {}
        #: the backend labels whose streaming scores were refused (``--rate max``)
        self.streaming_refused: set[str] = set()

    def task_recording(self, name: str) -> TaskRecording | None:
        """The ``TaskRecording`` of the registered task ``name``, made on the first call
        (None for a task that names none: its frames are recorded as boxes only)."""
        if name in self._recordings:
            return self._recordings[name]
        from replaybench.tasks import get_task, load_view, task_recording

        found = get_task(name)
        target = task_recording(found)
        made: TaskRecording | None = None
        if target is not None:
            made = load_view(found, target, 'recording')(self)
            if not isinstance(made, TaskRecording):
                msg = (
                    f'task {name!r}: {target} made {type(made).__name__}, which is no '
                    'TaskRecording (replaybench.tasks.base; TaskRecordingBase has the defaults)'
                )
                raise TaskUnavailableError(msg)
        self._recordings[name] = made
        return made

    def task_recordings(self) -> list[TaskRecording]:
        """The recordings made so far (one per task whose backends' frames were recorded), in
        the order they were made: what ``replaybench.replay.record`` asks for the summaries,
        the warnings and run.json's task fields after the passes."""
        return [made for made in self._recordings.values() if made is not None]

    def take(self, done: Pass) -> float:
        """Turn the pass's log into records and frames.csv rows, detections messages, scores
        and the sample; the log is emptied. Returns the seconds it took (wall clock)."""
        began = time.perf_counter()
        entries, done.log = done.log, []
        recording = self.task_recording(done.task)
        ages = self._stream(done, entries) if done.repeat == 0 else None
        for index, entry in enumerate(entries):
            age = None if ages is None else ages[index]
            if isinstance(entry.outcome, BackendResult):
                self._processed(done, entry, entry.outcome, recording, age)
            else:
                self._unprocessed(done, entry, entry.outcome, age)
        return time.perf_counter() - began

    def _stream(self, done: Pass, entries: Sequence[LogEntry]) -> list[float | None] | None:
        """The pass's streaming picks (``replaybench.replay.streaming``), kept by (backend
        label, topic) for the scores after the passes; the output age of each entry (ms, None
        before the first output). None at ``--rate max`` for a timed backend: refused."""
        timed = done.measures_latency
        if timed and not done.replay.options.rate.timed:
            self.streaming_refused.add(done.label)
            for entry in entries:
                self.stream_tasks[done.label, entry.key[0]] = done.task
            return None
        by_topic: dict[str, list[tuple[int, StreamFrame]]] = {}
        base = entries[0].key[2] if entries else 0
        for index, entry in enumerate(entries):
            topic, _, log_time_ns, stamp_ns, frame_id = entry.key
            available: float | None = None
            if timed:
                released = entry.release - done.t0
                if isinstance(entry.outcome, BackendResult):
                    available = entry.done - done.t0
            else:  # recorded outputs: on the recording's clock, from its log times
                released = (log_time_ns - base) / 1e9
                if isinstance(entry.outcome, BackendResult) and stamp_ns is not None:
                    out_ns = frame_recorded_times(
                        done.inp.recorded, frame_id, stamp_ns, log_time_ns
                    ).output_log_time_ns
                    available = None if out_ns is None else (out_ns - base) / 1e9
            by_topic.setdefault(topic, []).append(
                (index, StreamFrame(entry.key, released, available))
            )
        ages: list[float | None] = [None] * len(entries)
        for topic, frames in by_topic.items():
            picks = pick_outputs(done.inp.number, [f for _, f in frames])
            self.picks.setdefault((done.label, topic), []).extend(picks)
            self.stream_tasks[done.label, topic] = done.task
            for (index, _), pick in zip(frames, picks, strict=True):
                ages[index] = None if pick.age_s is None else pick.age_s * 1e3
        return ages

    def _record(self, record: FrameRecord) -> None:
        self.records.append(record)
        self.frames_csv.write(record)

    def _skip(self, reason: str) -> None:
        short = reason.split(':', 1)[0] if len(reason) > 80 else reason
        self.skipped[short] = self.skipped.get(short, 0) + 1

    def _unprocessed(
        self, done: Pass, entry: LogEntry, error: Exception | None, age_ms: float | None = None
    ) -> None:
        """A frame the backend never saw: pushed out of its queue (``error`` None) or skipped
        because it did not decode (its times up to the failed decode are kept)."""
        topic, seq, log_time_ns, _, _ = entry.key
        t0 = done.t0
        dropped = error is None
        note = 'pushed out of the queue' if error is None else str(error)
        if not dropped:
            self._skip(note)
        self._record(
            FrameRecord(
                input=done.inp.number,
                backend=done.label,
                topic=topic,
                seq=seq,
                log_time_ns=log_time_ns,
                stamp_ns=None,
                status='dropped' if dropped else 'skipped',
                note=note,
                warmup=False,
                dropped=dropped,
                release_s=entry.release - t0,
                start_s=None if dropped else entry.start - t0,
                done_s=None if dropped else entry.done - t0,
                queue_wait_ms=None if dropped else entry.queue_wait_s * 1e3,
                read_decode_ms=None if dropped else entry.read_decode_s * 1e3,
                repeat=done.repeat,
                pipeline=done.pipeline_of.get(topic, 0),
                output_age_ms=age_ms,
            )
        )

    def _processed(
        self,
        done: Pass,
        entry: LogEntry,
        result: BackendResult,
        recording: TaskRecording | None = None,
        age_ms: float | None = None,
    ) -> None:
        """``latency = queue wait + read/decode + backend``: the backend part runs from the
        detector's call to its detections; read/decode was measured where it ran. A backend
        that is not timed (``recorded``) gets its recorded output's times from the recording
        instead (``replaybench.replay.recorded``)."""
        topic, seq, log_time_ns, stamp_ns, frame_id = entry.key
        assert stamp_ns is not None  # a processed frame decoded
        counted = (done.label, topic, done.repeat)
        n_done = self.processed.get(counted, 0)
        self.processed[counted] = n_done + 1
        # later passes of --repeat detect the same frames again: outputs and scores come from
        # the first pass only
        task_columns = (
            self.task_outputs(done, entry, result, recording) if done.repeat == 0 else _NO_COLUMNS
        )
        if task_columns and not task_columns.keys() <= _RECORD_FIELDS:
            task_columns = _as_fields(task_columns)
        t0 = done.t0
        timed = done.measures_latency
        stages = result.stages if timed else _NOT_TIMED
        queue_wait_s, read_decode_s = entry.queue_wait_s, entry.read_decode_s
        latency_s = queue_wait_s + read_decode_s + entry.done - entry.t_detect
        recorded = (
            NOT_RECORDED
            if timed
            else frame_recorded_times(done.inp.recorded, frame_id, stamp_ns, log_time_ns)
        )
        self._record(
            FrameRecord(
                input=done.inp.number,
                backend=done.label,
                topic=topic,
                seq=seq,
                log_time_ns=log_time_ns,
                stamp_ns=stamp_ns,
                status='ok',
                note='' if timed else recorded_note(recorded, done.inp.recorded_reader),
                warmup=timed and n_done < done.warmup_frames(topic),
                dropped=False,
                release_s=entry.release - t0,
                start_s=entry.start - t0,
                done_s=entry.done - t0,
                queue_wait_ms=queue_wait_s * 1e3,
                read_decode_ms=read_decode_s * 1e3,
                preprocess_ms=_ms(stages.preprocess_ns),
                infer_ms=_ms(stages.infer_ns),
                postprocess_ms=_ms(stages.postprocess_ns),
                h2d_ms=_ms(stages.h2d_ns),
                d2h_ms=_ms(stages.d2h_ns),
                latency_ms=latency_s * 1e3 if timed else None,
                detections=len(result.detections),
                preprocess_device_ms=_ms(stages.preprocess_device_ns),
                infer_device_ms=_ms(stages.infer_device_ns),
                postprocess_device_ms=_ms(stages.postprocess_device_ns),
                h2d_device_ms=_ms(stages.h2d_device_ns),
                d2h_device_ms=_ms(stages.d2h_device_ns),
                repeat=done.repeat,
                output_log_time_ns=recorded.output_log_time_ns,
                capture_to_output_ms=recorded.capture_to_output_ms,
                pipeline_ms=recorded.pipeline_ms,
                pipeline=done.pipeline_of.get(topic, 0),
                output_age_ms=age_ms,
                **task_columns,
            )
        )

    def task_outputs(
        self,
        done: Pass,
        entry: LogEntry,
        result: BackendResult,
        recording: TaskRecording | None = None,
    ) -> Mapping[str, Any]:
        """What a processed frame's result leads to besides its record.

        Its boxes (every task's): their message in outputs.mcap (the sink), the detections kept
        for the agreement between backends and, where the frame has ground truth and the task
        scores boxes, for scoring (the metrics, ``replaybench.replay.record.summaries``), and
        the sample's boxes. The rest is the task's ``recording`` (None: boxes only): a label
        mask written, scored against its ground-truth mask and kept for the agreement
        (``replaybench.tasks.segmentation.recording``), its boxes not scored; tags written and
        scored against the frame's tag ground truth (``replaybench.tasks.tags.recording``).
        Returns the task's
        own ``FrameRecord`` fields (the frame's mIoU and pixel accuracy, its tag columns).
        """
        topic, seq, log_time_ns, stamp_ns, frame_id = entry.key
        assert stamp_ns is not None  # a processed frame decoded
        inp = done.inp
        number = inp.number
        label_key = (done.label, topic)
        detections = result.detections
        key = (topic, seq, log_time_ns, stamp_ns, frame_id)
        columns = _NO_COLUMNS
        if recording is not None and recording.writes_first:
            columns = recording.frame(self.detections_out, done.label, inp, key, result)
        self.detections.setdefault(label_key, {})[(number, seq)] = detections
        self.detections_out.add(done.label, topic, log_time_ns, stamp_ns, frame_id, detections)
        box_frames, external = _boxes(inp)
        if recording is not None and not recording.scores_boxes:
            pass  # the task scores its own output, not the boxes
        elif external is not None:
            truth = external.lookup(topic, seq, stamp_ns)
            if truth is not None:
                frame_key = (number, topic, seq)
                self.ground_truth[frame_key] = truth
                self.scored.setdefault(label_key, {})[frame_key] = detections
        elif (frame_id, stamp_ns) in box_frames:
            self.scored.setdefault(label_key, {})[(number, frame_id, stamp_ns)] = detections
        if recording is not None and not recording.writes_first:
            columns = recording.frame(self.detections_out, done.label, inp, key, result)
        self._sample(done, topic, seq, log_time_ns, result, recording)
        return columns

    def _sample(
        self,
        done: Pass,
        topic: str,
        seq: int,
        log_time_ns: int,
        result: BackendResult,
        recording: TaskRecording | None,
    ) -> None:
        """Choose the sample frame of this topic (the first backend does) and keep its boxes
        (and what the task draws beside them: a segmentation backend's mask)."""
        inp = done.inp
        key = (inp.number, topic)
        counter = (done.label, inp.number, topic)
        taken = self._taken.get(counter, 0)
        self._taken[counter] = taken + 1
        sample = self.samples.get(key)
        if sample is None and taken == inp.sample_index.get(topic):
            sample = self.samples[key] = Sample(seq, log_time_ns, f'{topic} #{seq}')
        if sample is not None and sample.seq == seq:
            sample.detections[done.label] = result.detections
            drawn = None if recording is None else recording.sample(result)
            if drawn is not None:
                sample.drawn[done.label] = (done.task, drawn)

    def ground_truth_frames(self, number: int) -> int:
        """Frames of input ``number`` matched to a ground-truth file."""
        return sum(1 for key in self.ground_truth if key[0] == number)

    def measured(self) -> bool:
        """Whether any frame was measured: a processed frame past its warm-up, or a frame
        pushed out of its queue (a measurement of drops)."""
        return any((r.status == 'ok' and not r.warmup) or r.dropped for r in self.records)
