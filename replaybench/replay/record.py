"""The run record: the summaries (statistics, accuracy, resource use, intervals) and run.json's
``RunResult``, built typed from what the passes recorded.

``summaries`` is where a task type's metrics join the statistics of each (backend, topic):
``accuracy`` scores every backend's boxes, and each task's recording gives its own part of the
row (``TaskRecording.summary``: the label masks' mIoU, the tags' figures, a task's metrics);
``input_info`` and ``run_result`` construct the model classes of ``replaybench.results.model``
directly, with values as run.json holds them (NaN and infinities None, tuples for arrays), so
that the result kept in memory equals the one read back from the folder.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import time
from typing import TYPE_CHECKING, Any, cast

from replaybench._version import __version__
from replaybench.errors import TaskUnavailableError
from replaybench.results.agreement import AGREEMENT_IOU
from replaybench.results.intervals import with_intervals
from replaybench.results.io import to_json
from replaybench.results.model import (
    RUN_SCHEMA_VERSION,
    Accuracy,
    AgreementRow,
    InputInfo,
    RunCounts,
    RunOutputs,
    RunResult,
    RunSettings,
    SummaryRow,
    Tool,
    TopicMeta,
)
from replaybench.results.recorded_latency import with_recorded_latency
from replaybench.results.rig import rig_report, with_rig_rows
from replaybench.results.runfolder import OUTPUTS_MCAP
from replaybench.results.stats import Summary, repeat_statistics, summarize

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.replay.config import RunConfig
    from replaybench.replay.inputs import HashOutcome, OpenedInput
    from replaybench.replay.recording import Recorder, TruthKey
    from replaybench.results.agreement import Agreement
    from replaybench.results.model import BackendRun, Environment
    from replaybench.results.model.run import Pipelines
    from replaybench.tasks.detections.truth import BoxTruth
    from replaybench.types import Detection

__all__ = ['accuracy', 'input_info', 'run_result', 'summaries']


def summaries(recorder: Recorder, resources: Mapping[str, Mapping[str, Any]]) -> list[Summary]:
    """The statistics of each (backend, topic) with its metrics: its accuracy against ground
    truth (``accuracy``), its task's figures (``TaskRecording.summary``), its
    backend's resource use (``resources``, by label, as ``ResourceSampler.summary()`` gives
    it), its intervals and warnings, and, for a backend replaying recorded outputs, their
    latency from the recording (``with_recorded_latency``); a run with a rig gets each
    backend's rig row after its camera rows (``with_rig_rows``)."""
    out: list[Summary] = []
    for s in summarize(recorder.records):
        scored = recorder.scored.get((s.backend, s.topic))
        found = accuracy(recorder, scored) if scored else None
        if found is not None:
            s = dataclasses.replace(
                s,
                accuracy=found,
                precision50=found.precision50,
                recall50=found.recall50,
                map50=found.map50,
                map50_95=found.map50_95,
            )
        used = resources.get(s.backend)
        if used is not None:
            s = dataclasses.replace(
                s,
                cpu_percent_mean=_number(used.get('cpu_percent_mean')),
                private_mb_peak=_number(used.get('private_mb_peak')),
                mapped_mb_peak=_number(used.get('mapped_mb_peak')),
                rss_mb_peak=_number(used.get('rss_mb_peak')),
                gpu_util_mean=_number(used.get('gpu_util_mean')),
                gpu_mem_mb_peak=_number(used.get('gpu_mem_mb_peak')),
                gpu_power_w_mean=_number(used.get('gpu_power_w_mean')),
            )
        s = _with_tasks(s, recorder)
        s = _with_streaming(s, recorder)
        out.append(s)
    rows = with_intervals(out, recorder.records, resources=resources)
    rows = with_recorded_latency(rows, recorder.records)
    # a run replaying several camera topics of an input: each backend's rig row after its
    # cameras' (replaybench.results.rig)
    return with_rig_rows(rows, recorder.records)


def accuracy(recorder: Recorder, scored: Mapping[TruthKey, tuple[Detection, ...]]) -> Accuracy:
    """COCO-style accuracy of the ``scored`` frames against their ground truth."""
    from replaybench.results.accuracy import evaluate

    frames_gt = {k: recorder.ground_truth[k] for k in scored}
    result = evaluate(frames_gt, scored)
    return Accuracy(
        frames=len(frames_gt),
        precision50=_number(result.precision50),
        recall50=_number(result.recall50),
        map50=_number(result.map50) if result.map50 >= 0 else None,
        map50_95=_number(result.map50_95) if result.map50_95 >= 0 else None,
        ap50={str(k): float(v) for k, v in result.ap50.items()},
        ap50_95={str(k): float(v) for k, v in result.ap50_95.items()},
        n_gt=int(result.n_gt),
        n_det=int(result.n_det),
    )


_ROW_FIELDS = frozenset(f.name for f in dataclasses.fields(SummaryRow))


def _with_tasks(row: Summary, recorder: Recorder) -> Summary:
    """``row`` with what each task's recording gives it (``TaskRecording.summary``): the
    fields a built-in task has on ``SummaryRow``, the metrics of any other task in
    ``task_metrics`` (numbers, or None)."""
    fields: dict[str, Any] = {}
    metrics: dict[str, float | None] = {}
    for recording in recorder.task_recordings():
        found = recording.summary(row.backend, row.topic)
        for name, value in (found or {}).items():
            if name in _ROW_FIELDS:
                fields[name] = value
            elif value is None or (isinstance(value, int | float) and not isinstance(value, bool)):
                metrics[name] = _number(value)
            else:
                msg = (
                    f'{type(recording).__name__}.summary gave {name}={value!r}: a metric of a '
                    'task without a SummaryRow field must be a number or None'
                )
                raise TaskUnavailableError(msg)
    if metrics:
        fields['task_metrics'] = metrics
    return dataclasses.replace(row, **fields) if fields else row


def _with_streaming(row: Summary, recorder: Recorder) -> Summary:
    """``row`` with its streaming metrics in ``task_metrics`` (``replaybench.replay.streaming``:
    None where refused at ``--rate max``), after the task's own."""
    from replaybench.replay.streaming import streaming_scores

    found = streaming_scores(recorder, row)
    if not found:
        return row
    metrics = {**(row.task_metrics or {}), **{k: _number(v) for k, v in found.items()}}
    return dataclasses.replace(row, task_metrics=metrics)


def _task_fields(recorder: Recorder) -> dict[str, Any]:
    """The ``RunResult`` fields the tasks' recordings fill (``TaskRecording.run_fields``)."""
    found: dict[str, Any] = {}
    for recording in recorder.task_recordings():
        found.update(recording.run_fields())
    return found


def _cores() -> int:
    """The cores this process may run on (run.json's ``rig.cores``)."""
    import os

    found = len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else os.cpu_count()
    return max(1, found or 1)


def _number(value: Any) -> float | None:
    """A value as run.json holds it: a finite float, or None."""
    plain = to_json(value)
    return float(plain) if plain is not None else None


def _agreement_row(agreement: Agreement) -> AgreementRow:
    row = to_json(agreement._asdict())
    return AgreementRow(
        **{**row, 'disagreeing_frames': tuple(tuple(f) for f in row['disagreeing_frames'])}
    )


def input_info(
    inp: OpenedInput,
    hashed: HashOutcome,
    *,
    copy_problem: str | None,
    matched_frames: int,
    replayed_any: bool,
) -> InputInfo:
    """One input as run.json describes it once the passes have ended. ``matched_frames``: the
    frames matched to a --ground-truth-file; ``replayed_any``: whether any frame was
    replayed."""
    warnings = [*inp.source.warnings, *inp.notes, *hashed.warnings]
    if copy_problem is not None:
        warnings.append(copy_problem)
    boxes = cast('BoxTruth | None', inp.truth.get('detections'))
    ground_truth_frames = 0 if boxes is None else len(boxes.frames)
    external = None if boxes is None else boxes.external
    if external is not None:
        ground_truth_frames = matched_frames
        warnings += list(external.warnings)
        if not matched_frames and replayed_any:
            warnings.append(
                f'{external.path} annotates none of the replayed frames '
                f'(matched by {external.match}); see docs/ground-truth.md'
            )
    return InputInfo(
        index=inp.number,
        path=str(inp.path),
        format=inp.source.format,
        size_bytes=inp.size_bytes,
        sha256=hashed.sha256,
        truncated=inp.source.truncated,
        warnings=tuple(warnings),
        ground_truth_frames=ground_truth_frames,
        topics=tuple(
            TopicMeta(
                name=t.name,
                msgtype=t.msgtype,
                encoding=t.encoding,
                width=t.width,
                height=t.height,
                count=t.count,
                is_depth=t.is_depth,
                camera_info_topic=t.camera_info_topic,
            )
            for t in inp.topics
        ),
    )


def run_result(
    config: RunConfig,
    recorder: Recorder,
    *,
    status: str,
    inputs: Sequence[InputInfo],
    backends: Sequence[BackendRun],
    summary: Sequence[Summary],
    agreements: Sequence[Agreement],
    environment: Environment,
    warmup_per_topic: Mapping[str, int],
    warnings: Sequence[str],
    started: dt.datetime,
    t_start: float,
    samples: Sequence[str] = (),
    report: bool = False,
    pipelines: Pipelines | None = None,
) -> RunResult:
    """What run.json holds (written by the caller, last), with frames.csv's rows as
    ``frame_records`` (as the file holds them)."""
    from replaybench.results.records import as_written

    records = recorder.records
    rig = rig_report(
        summary,
        records,
        mode=config.pipelines,
        cores=pipelines.cores if pipelines is not None else _cores(),
        threads=config.threads,
    )
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
            warmup_per_topic=dict(warmup_per_topic),
            threads=config.threads,
            max_frames=config.max_frames,
            start_s=config.start_s,
            duration_s=config.duration_s,
            topics=tuple(config.topics) if config.topics else None,
            ground_truth_topic=config.ground_truth_topic
            if config.ground_truth_file is None and any(i.ground_truth_frames for i in inputs)
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
            repeat=config.repeat,
            pipelines=pipelines,
            added_latency_ms=config.added_latency_ms or None,
        ),
        inputs=tuple(inputs),
        environment=environment,
        backends=tuple(backends),
        summary_rows=tuple(summary),
        agreement=tuple(_agreement_row(a) for a in agreements),
        counts=RunCounts(
            frames=len(records),
            processed=sum(1 for r in records if r.status == 'ok'),
            dropped=sum(1 for r in records if r.status == 'dropped'),
            skipped=sum(1 for r in records if r.status == 'skipped'),
        ),
        skipped=dict(recorder.skipped),
        warnings=tuple(warnings),
        repeats=repeat_statistics(records) if config.repeat > 1 else None,
        outputs=RunOutputs(
            outputs_mcap=OUTPUTS_MCAP,
            frames_csv='frames.csv',
            summary_csv='summary.csv',
            report='report.html' if report else None,
            samples=tuple(samples),
        )
        if config.out_dir is not None
        else None,
        frame_records=tuple(as_written(r) for r in records),
        rig=rig,
        **_task_fields(recorder),
    )
