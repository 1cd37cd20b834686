"""The inputs of a run, opened: their topics, time window, camera infos, each task's ground
truth, the recorded outputs a backend replays, the sample frame of each topic and their sha256.

``open_input`` opens and probes one BAG argument into an ``OpenedInput``; ``replayed`` is the
stream of image messages each pass reads from it; ``decoder`` turns one into the ``Frame`` a
backend gets. The sha256 is taken while nothing is timed: a small input's when it opens, a
larger one's after the passes (``deferred_hash``), settled with a check that the input did not
change meanwhile (``settle_hash``).

Ground truth belongs to the tasks (``replaybench.tasks.TaskTruth``): ``load_truths`` asks every
registered task for what the run reads once, and ``open_input`` keeps each task's truth topics
out of the cameras and the recorded topic and holds what each task's ``open_truth`` read of the
input, by task name (``OpenedInput.truth``). No task is named here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

from replaybench.decode import decode_image, message_kind
from replaybench.decode.camera_info import CameraInfoIndex
from replaybench.decode.probe import CameraTopic, probe_topics, unreadable_image_topics
from replaybench.errors import SourceError, UsageError
from replaybench.replay.hashing import ANNOUNCE_MIN_BYTES, InputHash, describe_size
from replaybench.replay.recorded import read_recorded, without_recorded
from replaybench.sources import Source, open_source
from replaybench.tasks import TruthInput

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Mapping, Sequence
    from pathlib import Path

    from replaybench.decode.recorded import OutputReader, RecordedOutput
    from replaybench.replay.config import InputOptions, RunConfig
    from replaybench.tasks import TaskTruth
    from replaybench.types import Frame, RawMessage, SkippedTopic

__all__ = [
    'HashOutcome',
    'OpenedInput',
    'RunTruth',
    'decoder',
    'deferred_hash',
    'expected_frames',
    'load_truths',
    'open_input',
    'replayed',
    'settle_hash',
]

_NS = 1_000_000_000


class OpenedInput(NamedTuple):
    """One BAG argument, opened and probed; its source is closed when the run ends."""

    number: int
    path: Path
    source: Source
    topics: list[CameraTopic]
    camera_infos: CameraInfoIndex
    start_ns: int | None
    end_ns: int | None
    sample_index: dict[str, int]  # per topic: index among the replayed frames of the sample frame
    recorded: dict[tuple[str, int], RecordedOutput]  # for the `recorded` backend
    recorded_topic: str | None
    #: each task's ground truth of the input by task name (``TaskTruth.open_truth``); a task
    #: without truth here is absent
    truth: Mapping[str, object]
    notes: tuple[str, ...] = ()  # warnings found while opening (detections left out)
    sha256: InputHash | None = None  # made when the input opened (``deferred_hash``)
    max_frames: int | None = None  # at most this many frames of each topic are replayed
    size_bytes: int = 0  # of its files, when it was opened
    files_state: tuple[tuple[int, int], ...] = ()  # (size, mtime_ns) per file when hashed
    recorded_reader: OutputReader | None = None  # how the recorded topic's type is read


class RunTruth(NamedTuple):
    """The registered tasks that read ground truth, each with what the run read of its truth
    once (``TaskTruth.load_truth``), in the registry's order."""

    readers: tuple[tuple[str, TaskTruth, object | None], ...] = ()

    def topics(self, options: InputOptions) -> frozenset[str]:
        """Every task's truth topics: no camera, never the recorded topic."""
        return frozenset(t for _, reader, _ in self.readers for t in reader.truth_topics(options))


def load_truths(config: RunConfig) -> RunTruth:
    """Every task's ground-truth reader, and what each reads once for the run (the
    --ground-truth-file, a folder of masks), read and checked against the other options."""
    from replaybench.tasks import truth_readers

    return RunTruth(
        tuple((name, reader, reader.load_truth(config)) for name, reader in truth_readers())
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


def _chosen(
    path: Path,
    topics: list[CameraTopic],
    choose: Callable[[Sequence[str]], tuple[Sequence[str], str | None]],
    notes: list[str],
) -> list[CameraTopic]:
    """The camera topics a backend's ``frame_set_topics`` chooses of ``topics`` (a stereo
    pair by name, left first), its note among the input's warnings."""
    by_name = {t.name: t for t in topics}
    chosen, note = choose(list(by_name))
    if note is not None:
        notes.append(f'{path.name}: {note}')
    return [by_name[name] for name in chosen]


def open_input(
    index: int,
    path: Path,
    options: InputOptions,
    truths: RunTruth,
    *,
    recorded_detections: bool = False,
) -> OpenedInput:
    """Open and probe one input; ``truths``: the tasks' ground-truth readers (``load_truths``),
    each of which opens its truth of the input; ``recorded_detections``: a backend replays a
    recorded output topic (``Backend.uses_recorded_detections``), which is read here by its
    message type (``replaybench.replay.recorded.read_recorded``)."""
    source = open_source(path)
    try:
        skipped = source.skipped_topics()
        if not any(t.count for t in source.topics()) and not any(t.count for t in skipped):
            damaged = ' before the damage' if source.truncated else ' in this file'
            msg = f'{path}: no messages{damaged}'
            raise SourceError(msg)
        images = probe_topics(source)
        truth_topics = truths.topics(options)
        found = [t for t in images if t.name not in truth_topics]  # the truth is no camera
        topics = _select_topics(path, found, options.topics, unreadable_image_topics(source))
        notes: list[str] = []
        if options.choose_topics is not None and not options.topics:
            topics = _chosen(path, topics, options.choose_topics, notes)
        truth = _open_truths(
            truths,
            options,
            notes,
            TruthInput(
                index, path, source, tuple(t.name for t in images), tuple(t.name for t in topics)
            ),
        )
        all_topics = source.topics()
        first = min((t.first_ns for t in all_topics), default=0)
        start_ns = first + round(options.start_s * _NS) if options.start_s else None
        end_ns = None
        if options.duration_s is not None:
            end_ns = (start_ns if start_ns is not None else first) + round(options.duration_s * _NS)
        info_topics = [t.name for t in all_topics if message_kind(t.msgtype) == 'camera_info']
        # read when first used: by the first pass of a backend that reads camera infos, or
        # after the passes for outputs.mcap (``decoder``, ``output.copy_camera_infos``)
        camera_infos = CameraInfoIndex.deferred(source, info_topics)
        recorded: dict[tuple[str, int], RecordedOutput] = {}
        recorded_topic = recorded_reader = None
        if recorded_detections:
            # no task's ground truth is the recorded output
            recorded_topic, recorded_reader, recorded = read_recorded(
                path, source, all_topics, options.recorded_topic, truth_topics, notes
            )
            topics = without_recorded(path, topics, recorded_topic)
        # the frame drawn in samples/: the middle one of the replayed frames (the first one when
        # --start/--duration cut a window whose size is unknown before reading)
        sample_index = {
            t.name: 0 if options.windowed else min(t.count, options.max_frames or t.count) // 2
            for t in topics
        }
        return OpenedInput(
            number=index,
            path=path,
            source=source,
            topics=topics,
            camera_infos=camera_infos,
            start_ns=start_ns,
            end_ns=end_ns,
            sample_index=sample_index,
            recorded=recorded,
            recorded_topic=recorded_topic,
            truth=truth,
            notes=tuple(notes),
            max_frames=options.max_frames,
            size_bytes=sum(f.stat().st_size for f in source.files),
            recorded_reader=recorded_reader,
        )
    except BaseException:
        source.close()
        raise


def _open_truths(
    truths: RunTruth, options: InputOptions, notes: list[str], inp: TruthInput
) -> dict[str, object]:
    """What each task's ``open_truth`` read of the input, by task name (none: left out)."""
    opened: dict[str, object] = {}
    for name, reader, loaded in truths.readers:
        found = reader.open_truth(inp, options, loaded, notes)
        if found is not None:
            opened[name] = found
    return opened


def expected_frames(topic: CameraTopic, max_frames: int | None) -> int:
    """Frames of ``topic`` a pass replays (its count, at most ``max_frames``)."""
    n = topic.count
    if max_frames is not None:
        n = min(n, max_frames)
    return n


def replayed(inp: OpenedInput) -> Iterator[RawMessage]:
    """The image messages a pass replays: the window, at most --max-frames per topic."""
    names = [t.name for t in inp.topics]
    messages = inp.source.messages(topics=names, start_ns=inp.start_ns, end_ns=inp.end_ns)
    if inp.max_frames is None:
        return messages
    return _at_most(messages, names, inp.max_frames)


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


def decoder(inp: OpenedInput, *, camera_info: bool = True) -> Callable[[RawMessage], Frame]:
    """RawMessage -> the Frame a backend gets: ``decode_image``, plus camera info and the
    input's index where there are any to add. ``camera_info`` False (a backend that never
    reads it, ``BackendTraits.reads_camera_info``): frames without one, and the input's
    CameraInfo messages are not read for them."""
    number = inp.number
    if not camera_info:
        if number == 0:
            return decode_image

        def numbered(raw: RawMessage) -> Frame:
            return decode_image(raw)._replace(input_index=number)

        return numbered
    lookup = inp.camera_infos.lookup
    if number == 0 and all(inp.camera_infos.topic_for(t.name) is None for t in inp.topics):
        return decode_image

    def decode(raw: RawMessage) -> Frame:
        frame = decode_image(raw)
        return frame._replace(camera_info=lookup(frame.topic, frame.stamp_ns), input_index=number)

    return decode


# -- the sha256 --------------------------------------------------------------------------------


def deferred_hash(
    inp: OpenedInput,
    options: InputOptions,
    hasher: Callable[[Sequence[Path]], InputHash] | None,
) -> OpenedInput:
    """The input with its ``InputHash``, computed after the passes (``settle_hash``): nothing
    reads and digests beside the measured frames, nor before the first one (an input of at most
    ``INLINE_MAX_BYTES`` is hashed there at once, a larger one in a thread the run waits for).
    Its files' size and mtime are noted now and checked then. Unchanged when not computed here
    (--no-hash, or known already)."""
    if not options.hash_inputs or options.input_sha256 is not None:
        return inp
    found = (hasher or InputHash)(list(inp.source.files))
    return inp._replace(sha256=found, files_state=_files_state(inp))


def _files_state(inp: OpenedInput) -> tuple[tuple[int, int], ...]:
    """(size, mtime_ns) of each file of the input, to tell that it did not change."""
    out = []
    for path in inp.source.files:
        st = path.stat()
        out.append((st.st_size, st.st_mtime_ns))
    return tuple(out)


def _hash_after_passes(
    inp: OpenedInput, found: InputHash, notice: Callable[[str], None] | None
) -> bool:
    """Start the hashing of an input left for after the passes (``deferred_hash``); True when
    it was (the caller waits for it), False when it had started before them."""
    if found.started_s is not None:
        return False
    if notice is not None and found.size_bytes > ANNOUNCE_MIN_BYTES:
        size = describe_size(found.size_bytes)
        notice(f'replaybench: hashing {inp.path.name} ({size}, sha256) after the passes')
    found.start()
    return True


def _changed(inp: OpenedInput) -> str | None:
    """Why the input's files are not as they were when it opened (size or mtime), or None."""
    try:
        now = _files_state(inp)
    except OSError as err:
        return f'cannot stat it: {err.strerror or err}'
    return None if now == inp.files_state else 'its size or modification time changed'


class HashOutcome(NamedTuple):
    """An input's sha256 as run.json records it, and what to warn about it."""

    sha256: str | None
    warnings: tuple[str, ...] = ()


def settle_hash(
    inp: OpenedInput,
    options: InputOptions,
    *,
    passes_began: float,
    interrupted: bool,
    notice: Callable[[str], None] | None,
) -> HashOutcome:
    """The input's sha256 once the passes have ended (a larger input's is computed now,
    ``deferred_hash``); a hash that ran while frames were measured, was cut short or failed is
    a warning of the input, and one of an input whose size or mtime changed since it was opened
    is not recorded (null, with a warning)."""
    if not options.hash_inputs:
        return HashOutcome(
            None,
            (
                (
                    'not hashed (--no-hash): sha256 is null, so compare cannot check that other '
                    'runs replayed the same input'
                ),
            ),
        )
    if options.input_sha256 is not None:
        return HashOutcome(options.input_sha256[inp.number])
    found = inp.sha256
    if found is None:  # pragma: no cover - started for every input that is hashed
        return HashOutcome(None)
    if interrupted and found.background and not found.done:  # a small one is hashed at once
        found.cancel()
        return HashOutcome(None, ('sha256 not computed: the run was interrupted before it ended',))
    deferred = _hash_after_passes(inp, found, notice)
    if not found.done and notice is not None and not deferred:
        notice(f'replaybench: waiting for the sha256 of {inp.path.name}')
    sha256 = found.wait()
    warnings: list[str] = []
    if found.error is not None:
        warnings.append(f'sha256 not computed: {found.error}')
    why = _changed(inp) if inp.files_state and sha256 is not None else None
    if why is not None:
        sha256 = None
        warnings.append(
            f'sha256 not recorded: the input changed during the run ({why}), so its digest '
            'would not describe the frames replayed'
        )
    overlap = found.overlap_s(passes_began)
    if found.background and overlap > 0 and not deferred:
        warnings.append(
            f'its sha256 was computed during the first {overlap:.1f} s of the measured passes, '
            'sharing the CPU and the disk with them (--no-hash leaves it out)'
        )
    return HashOutcome(sha256, tuple(warnings))
