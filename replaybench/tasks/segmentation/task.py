"""The segmentation task: label masks against ground-truth masks."""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

from replaybench.tasks.base import LazyMapping, MetricSpec, TaskViews

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.decode.recorded import OutputReader

__all__ = ['TASK', 'SegmentationTask']


class SegmentationTask:
    """Masks (``replaybench.results.segmentation``): mean IoU over classes, pixel accuracy."""

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
    )
    views: ClassVar[TaskViews] = TaskViews(summary_field='segmentation', terminal_metrics=('miou',))

    #: a processed frame's mask written and scored, its boxes not scored
    #: (``replaybench.replay.segmentation.Segmentation``), loaded when a backend of the task's
    #: frames are first recorded
    recording: ClassVar[str] = 'replaybench.replay.segmentation:recording'

    #: ``replaybench.tasks.segmentation.recorded``, imported when the ``recorded`` backend reads it
    recorded_readers: ClassVar[Mapping[str, OutputReader]] = LazyMapping(
        'replaybench.tasks.segmentation.recorded:READERS'
    )


TASK = SegmentationTask()
