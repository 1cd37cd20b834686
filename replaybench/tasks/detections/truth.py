"""Box ground truth: a Detection2DArray topic of the input (``--ground-truth``, default
``/ground_truth/detections`` when present), or a COCO JSON / CVAT XML file beside the bags
(``--ground-truth-file``, parsed by ``replaybench.results.groundtruth``), which replaces the
topic. The topic is read whole when the input opens; the file once, before any input opens.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple, Protocol, cast

from replaybench.decode.detections import decode_detections
from replaybench.errors import DecodeError, UsageError

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from replaybench.results.groundtruth import ExternalGroundTruth, MatchMode
    from replaybench.sources import Source
    from replaybench.tasks.base import TruthInput
    from replaybench.types import Detection

__all__ = ['BoxTruth', 'DetectionTable', 'load_file', 'open_box_truth', 'read_detections']

#: Detections by (frame_id, stamp_ns), as a Detection2DArray topic holds them
DetectionTable = dict[tuple[str, int], tuple['Detection', ...]]


class TopicOptions(Protocol):
    """What ``open_box_truth`` reads of the run's ``InputOptions``."""

    @property
    def ground_truth_topic(self) -> str | None: ...
    @property
    def ground_truth_explicit(self) -> bool: ...


class FileOptions(TopicOptions, Protocol):
    """What ``load_file`` reads of the ``RunConfig``."""

    @property
    def inputs(self) -> Sequence[Path]: ...
    @property
    def ground_truth_file(self) -> Path | None: ...
    @property
    def ground_truth_match(self) -> str: ...
    @property
    def ground_truth_image_topic(self) -> str | None: ...
    @property
    def ground_truth_seq_offset(self) -> int: ...


class BoxTruth(NamedTuple):
    """An input's box ground truth: its topic's boxes by (frame_id, stamp), or the run's
    ground-truth file (``external``, matched to frames as they are scored)."""

    frames: DetectionTable
    external: ExternalGroundTruth | None = None


def load_file(config: FileOptions) -> ExternalGroundTruth | None:
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
    found = load_ground_truth_file(
        config.ground_truth_file,
        match=cast('MatchMode', config.ground_truth_match),
        topic=config.ground_truth_image_topic,
        seq_offset=config.ground_truth_seq_offset,
    )
    if found.format == 'mot' and len(config.inputs) > 1:
        msg = f"{found.path}: a MOT file counts one topic's images from 1: give a single BAG"
        raise UsageError(msg)
    return found


def open_box_truth(
    inp: TruthInput,
    options: TopicOptions,
    external: ExternalGroundTruth | None,
    notes: list[str],
) -> BoxTruth | None:
    """The input's box truth: the file's (checked against the replayed topics), else its
    topic's; None without either. ``UsageError`` for a --ground-truth topic the input lacks."""
    path = inp.path
    if external is not None:
        _check_external_topics(path, external, inp.replayed)
    gt_topic = options.ground_truth_topic
    gt_present = any(t.name == gt_topic for t in inp.source.topics())
    if gt_topic and not gt_present and options.ground_truth_explicit:
        msg = f'{path}: ground-truth topic {gt_topic} is not in this file'
        raise UsageError(msg)
    if external is not None:
        return BoxTruth({}, external)
    if gt_topic and gt_present:
        return BoxTruth(read_detections(inp.source, gt_topic, notes))
    return None


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


def read_detections(source: Source, topic: str, notes: list[str] | None = None) -> DetectionTable:
    """Detection2DArray messages of a topic keyed by (frame_id, stamp); bad messages skipped.

    Detections with a NaN or infinite box or score are left out; ``notes`` gets a line
    saying how many.
    """
    table: DetectionTable = {}
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
