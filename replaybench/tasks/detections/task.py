"""The detections task: boxes against Detection2DArray ground truth, at IoU 0.5."""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

from replaybench.tasks.base import LazyMapping, MetricSpec, TaskViews

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.decode.recorded import OutputReader

__all__ = ['TASK', 'DetectionsTask']


class DetectionsTask:
    """Boxes (``replaybench.results.accuracy``): precision, recall and mAP at IoU 0.5."""

    name: ClassVar[str] = 'detections'
    metrics: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec(
            'map50',
            'mAP@0.5',
            'mAP@0.5',
            'higher',
            sweep=True,
            main=True,
            appended=False,
            terminal_label='mAP@.5',
            tracked=True,
        ),
        MetricSpec(
            'recall50',
            'recall@0.5',
            'R@0.5',
            'higher',
            appended=False,
            terminal_label='R@.5',
            tracked=True,
        ),
        MetricSpec(
            'precision50',
            'precision@0.5',
            'P@0.5',
            'higher',
            appended=False,
            terminal_label='P@.5',
            tracked=True,
        ),
    )
    #: the report's parts live in the report layer (report/detections.py), imported there
    views: ClassVar[TaskViews] = TaskViews(
        summary_field='accuracy',
        summary_panel='replaybench.report.detections:accuracy_details_html',
        more_columns='replaybench.report.detections:more_columns',
        terminal_metrics=('precision50', 'recall50', 'map50'),
        terminal='always',
    )

    #: ``replaybench.tasks.detections.recorded``, imported when the ``recorded`` backend reads it
    recorded_readers: ClassVar[Mapping[str, OutputReader]] = LazyMapping(
        'replaybench.tasks.detections.recorded:READERS'
    )


TASK = DetectionsTask()
