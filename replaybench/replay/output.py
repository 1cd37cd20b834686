"""The run folder's files as the engine writes them: outputs.mcap (with the camera infos
and, on request, the replayed images), frames.csv, summary.csv, run.json, and the sample
frames read again for the renderer. In memory (no folder) the writers are ``Discard``.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

from replaybench.decode import decode_image, to_bgr8
from replaybench.errors import DecodeError
from replaybench.replay.inputs import replayed
from replaybench.results.records import FramesCsvWriter
from replaybench.results.runfolder import OUTPUTS_MCAP, with_filename

if TYPE_CHECKING:
    import threading
    from collections.abc import Iterable, Iterator, Mapping, Sequence
    from pathlib import Path

    from replaybench.replay.config import OutputOptions
    from replaybench.replay.inputs import OpenedInput
    from replaybench.replay.recording import DetectionsSink, FrameSink, Sample
    from replaybench.results.model import RunResult
    from replaybench.results.stats import Summary
    from replaybench.sources import Source
    from replaybench.types import Detection

__all__ = [
    'Discard',
    'Renderer',
    'SampleImage',
    'camera_info_channels',
    'copy_camera_infos',
    'copy_images',
    'finish_files',
    'sample_images',
    'writers',
]


class SampleImage(NamedTuple):
    """The sample frame of one topic, read again after the passes, with every backend's
    detections on it (by backend label, in run order)."""

    input: int
    topic: str
    image: Any  # BGR8 ndarray
    detections: Mapping[str, tuple[Detection, ...]]
    title: str
    #: what each backend's task draws beside the boxes (a segmentation backend's label mask),
    #: by backend label: (the task's name, what it drew); its picture is the task's
    #: ``TaskViews.sample_picture``
    drawn: Mapping[str, tuple[str, Any]] | None = None


class Renderer(Protocol):
    """What the application draws into the run folder besides the engine's files: the sample
    pictures and report.html (``replaybench.app.run.ReportRenderer``). The engine calls it in
    the temporary folder, before run.json is written."""

    def samples(self, out: Path, samples: Iterable[SampleImage]) -> list[str]:
        """Draw each sample into ``out``; the files written, relative to ``out``."""
        ...

    def report(self, out: Path, run: RunResult) -> None:
        """Write report.html into ``out`` from ``run`` (run.json to be), whose
        ``frame_records`` are frames.csv's rows."""
        ...


class Discard:
    """The frames.csv and outputs.mcap writers of a run made in memory: nothing is kept.

    It is an ``OutputWriter`` (``replaybench.sinks.writer``) that keeps nothing, so the tasks'
    sinks call it as they call outputs.mcap's writer.
    """

    #: what it is given is dropped (``OutputWriter.keeps``), and it writes no annotations
    keeps: bool = False
    annotations: bool = False
    depth: bool = False

    def __enter__(self) -> Discard:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def write(self, *args: object) -> None:
        """A frames.csv row: dropped."""

    def add(self, *args: object) -> None:
        """A detections message: dropped."""

    def add_camera_info(self, *args: object) -> None:
        """A camera info message: dropped."""

    def add_camera_info_channel(self, *args: object) -> None:
        """A camera info channel: dropped."""

    def add_raw(self, *args: object) -> None:
        """A copied image message: dropped."""

    def add_message(self, *args: object, **kwargs: object) -> None:
        """A task's result message: dropped."""

    def add_metadata(self, *args: object) -> None:
        """A metadata record: dropped."""

    def colour(self, backend: str) -> str:
        """No colour: nothing is drawn."""
        del backend
        return ''


@contextlib.contextmanager
def writers(options: OutputOptions) -> Iterator[tuple[FrameSink, DetectionsSink]]:
    """frames.csv's and outputs.mcap's writers, open for the passes (``Discard`` in
    memory). An ``OSError`` that names no file is outputs.mcap's (frames.csv names its
    own)."""
    out = options.out
    if out is None:
        yield Discard(), Discard()
        return
    from replaybench.sinks.mcap_writer import DetectionsWriter

    try:
        with (
            FramesCsvWriter(out / 'frames.csv', task_columns=options.task_columns) as frames_csv,
            DetectionsWriter(
                out / OUTPUTS_MCAP,
                annotations=options.annotations,
                depth=options.depth,
                backends=list(options.backend_labels),
            ) as detections_out,
        ):
            yield frames_csv, detections_out
    except OSError as err:
        raise with_filename(err, out / OUTPUTS_MCAP) from None


def camera_info_channels(inputs: Sequence[OpenedInput], writer: DetectionsSink) -> None:
    """outputs.mcap's channels of the camera infos, made before the passes in the order
    ``copy_camera_infos`` would make them (the first decodable message of each topic), so that
    the messages can be copied after the passes without changing a byte of the file."""
    for inp in inputs:
        for topic in inp.camera_infos.first_topics():
            writer.add_camera_info_channel(topic)


def copy_camera_infos(
    inputs: Sequence[OpenedInput], writer: DetectionsSink, stop: threading.Event | None = None
) -> bool:
    """Every input's camera infos into outputs.mcap, once each (by topic and log time);
    False when ``stop`` was set (looked at before each input and each message written), or a
    ``KeyboardInterrupt`` came, before all were copied: those copied stay, and the file is
    finished as after an interrupt in the passes."""
    seen: set[tuple[str, int]] = set()
    try:
        for inp in inputs:
            if stop is not None and stop.is_set():
                return False
            for info in inp.camera_infos.all():
                key = (info.topic, info.log_time_ns)
                if key in seen:
                    continue
                if stop is not None and stop.is_set():
                    return False
                seen.add(key)
                writer.add_camera_info(info.topic, info.log_time_ns, info)
    except KeyboardInterrupt:
        return False
    return True


def copy_images(inputs: Sequence[OpenedInput], writer: DetectionsSink) -> dict[int, str]:
    """--copy-images: the replayed image messages into outputs.mcap, once each.

    Returns a warning per input whose messages could not all be copied.
    """
    problems: dict[int, str] = {}
    for inp in inputs:
        failed, first = 0, ''
        for raw in replayed(inp):
            try:
                writer.add_raw(raw)
            except DecodeError as err:
                failed, first = failed + 1, first or str(err)
        if failed:
            problems[inp.number] = f'{failed} image message(s) not copied: {first}'
    return problems


def sample_images(
    samples: Mapping[tuple[int, str], Sample], inputs: Sequence[OpenedInput]
) -> Iterator[SampleImage]:
    """Each sample frame, read and decoded again, with every backend's detections."""
    for (index, topic), sample in sorted(samples.items()):
        image = _sample_image(inputs[index].source, topic, sample)
        if image is not None:
            yield SampleImage(
                index, topic, image, sample.detections, sample.title, sample.drawn or None
            )


def _sample_image(source: Source, topic: str, sample: Sample) -> Any:
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


def write_detections_metadata(options: OutputOptions) -> None:
    """--format rosbag2: metadata.yaml beside outputs.mcap, which makes the folder a bag."""
    if options.detections_format == 'rosbag2' and options.out is not None:
        from replaybench.sinks.rosbag2 import write_rosbag2_metadata

        write_rosbag2_metadata(options.out / OUTPUTS_MCAP)


def write_summary(options: OutputOptions, summaries: Sequence[Summary]) -> None:
    """summary.csv."""
    from replaybench.results.summarycsv import write_summary_csv  # with the record, after passes

    if options.out is not None:
        write_summary_csv(options.out / 'summary.csv', summaries)


def draw_samples(
    options: OutputOptions, render: Renderer | None, samples: Iterable[SampleImage]
) -> list[str]:
    """The sample pictures the renderer draws into the folder; their paths in it."""
    if options.out is None or render is None:
        return []
    return render.samples(options.out, samples)


def finish_files(options: OutputOptions, render: Renderer | None, record: RunResult) -> None:
    """report.html (drawn by ``render`` when the report is asked for), then run.json: last, so
    that a run.json never points at a file that is not there yet."""
    from replaybench.results.io import write_run_result  # with the record, after passes

    out = options.out
    if out is None:
        return
    if render is not None and record.outputs is not None and record.outputs.report is not None:
        render.report(out, record)
    write_run_result(out / 'run.json', record)
