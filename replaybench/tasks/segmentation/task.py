"""The segmentation task: label masks against ground-truth masks."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.errors import UsageError
from replaybench.tasks.base import LazyMapping, MetricSpec, TaskViews

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.decode.recorded import OutputReader
    from replaybench.tasks.base import TruthInput

__all__ = ['TASK', 'SegmentationTask', 'mask_truth_topic']


def mask_truth_topic(spec: str | None) -> str | None:
    """The ground-truth mask topic asked for: ``spec`` when it names a topic, the default when
    ``spec`` is None, None when ``spec`` is a folder of PNG masks."""
    if spec is None:
        from replaybench.tasks.segmentation.scoring import GROUND_TRUTH_MASK_TOPIC

        return GROUND_TRUTH_MASK_TOPIC
    return None if Path(spec).is_dir() else spec


class SegmentationTask:
    """Masks (``replaybench.tasks.segmentation.scoring``): mean IoU over classes, pixel accuracy."""

    name: ClassVar[str] = 'segmentation'
    metrics: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec(
            'miou',
            'mIoU',
            'mIoU',
            'higher',
            sweep=True,
            main=True,
            appended=False,
            terminal_label='mIoU',
        ),
        MetricSpec('pixel_accuracy', 'pixel accuracy', 'pixel acc.', 'higher', appended=False),
        # streaming scores (replaybench.replay.streaming): each frame's truth mask against the
        # mask in use at its release; timed rates and recorded outputs only
        MetricSpec('streaming_miou', 'streaming mIoU', 'stream mIoU', 'higher'),
        MetricSpec(
            'streaming_pixel_accuracy', 'streaming pixel accuracy', 'stream pixel acc.', 'higher'
        ),
    )
    #: the streaming metrics, each with the offline figure it is the streaming form of, and
    #: how picks are scored to them (``replaybench.replay.streaming``)
    streaming_metrics: ClassVar[Mapping[str, str]] = {
        'streaming_miou': 'miou',
        'streaming_pixel_accuracy': 'pixel_accuracy',
    }
    streaming: ClassVar[str] = 'replaybench.tasks.segmentation.streaming:score'
    #: the report's mask thumbnails live in the report layer (report/masks.py)
    views: ClassVar[TaskViews] = TaskViews(
        summary_field='segmentation',
        terminal_metrics=('miou',),
        sample_picture='replaybench.report.masks:mask_picture',
        sample_caption='replaybench.report.masks:mask_caption',
    )

    #: a processed frame's mask written and scored, its boxes not scored
    #: (``replaybench.tasks.segmentation.recording``, ``Segmentation``), loaded when the frames
    #: of a backend of the task are first recorded
    recording: ClassVar[str] = 'replaybench.tasks.segmentation.recording:recording'

    #: ``replaybench.tasks.segmentation.recorded``, imported when the ``recorded`` backend reads it
    recorded_readers: ClassVar[Mapping[str, OutputReader]] = LazyMapping(
        'replaybench.tasks.segmentation.recorded:READERS'
    )

    # the ground truth (``replaybench.tasks.segmentation.truth``; masks are read when scored)

    def truth_topics(self, options: Any) -> frozenset[str]:
        """The mask topic (``--ground-truth-masks``, default ``/ground_truth/labels``): an
        Image topic that is no camera; none for a folder of masks."""
        topic = mask_truth_topic(options.ground_truth_masks)
        return frozenset((topic,)) if topic is not None else frozenset()

    def load_truth(self, config: Any) -> object | None:
        """The folder of PNG masks (a ``MaskFolder``), listed once; None for a topic."""
        spec: str | None = config.ground_truth_masks
        if spec is None or mask_truth_topic(spec) is not None:
            return None
        from replaybench.tasks.segmentation.truth import MaskFolder

        return MaskFolder(Path(spec))

    def open_truth(
        self, inp: TruthInput, options: Any, loaded: object | None, notes: list[str]
    ) -> object | None:
        """The input's masks: the run's folder, or its mask topic (a ``MaskTopic``, indexed
        when its first mask is scored); None without either. ``UsageError`` for a
        ``--ground-truth-masks`` topic that is not an image topic of the input."""
        del notes
        if loaded is not None:
            return loaded
        spec: str | None = options.ground_truth_masks
        topic = mask_truth_topic(spec)
        if topic is None:
            return None
        if topic not in inp.images:
            if spec is not None:
                msg = (
                    f'{inp.path}: ground-truth mask topic {topic} is not an image topic of '
                    'this file'
                )
                raise UsageError(msg)
            return None
        from replaybench.tasks.segmentation.truth import MaskTopic

        return MaskTopic(inp.source, topic)


TASK = SegmentationTask()
