"""The detections task: boxes against Detection2DArray ground truth, at IoU 0.5."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar, cast

from replaybench.tasks.base import LazyMapping, MetricSpec, TaskViews

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.decode.recorded import OutputReader
    from replaybench.results.groundtruth import ExternalGroundTruth
    from replaybench.tasks.base import TruthInput

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
        # streaming scores (replaybench.replay.streaming): each frame's truth against the
        # output in use at its release; timed rates and recorded outputs only
        MetricSpec('streaming_map50', 'streaming mAP@0.5', 'stream mAP@0.5', 'higher', sweep=True),
        MetricSpec('streaming_map50_95', 'streaming mAP@0.5:0.95', 'stream mAP', 'higher'),
        MetricSpec('streaming_recall', 'streaming recall@0.5', 'stream R@0.5', 'higher'),
        MetricSpec('streaming_precision', 'streaming precision@0.5', 'stream P@0.5', 'higher'),
    )
    #: the streaming metrics (names of ``metrics``), each with the offline figure it is the
    #: streaming form of (a metric or ``SummaryRow`` field), and how picks are scored to them
    #: (``replaybench.replay.streaming``)
    streaming_metrics: ClassVar[Mapping[str, str]] = {
        'streaming_map50': 'map50',
        'streaming_map50_95': 'map50_95',
        'streaming_recall': 'recall50',
        'streaming_precision': 'precision50',
    }
    streaming: ClassVar[str] = 'replaybench.tasks.detections.streaming:score'
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

    # the ground truth (``replaybench.tasks.detections.truth``, imported where there is some)

    def truth_topics(self, options: Any) -> frozenset[str]:
        """The Detection2DArray topic of box truth (``--ground-truth``), present or not."""
        topic: str | None = options.ground_truth_topic
        return frozenset((topic,)) if topic else frozenset()

    def load_truth(self, config: Any) -> object | None:
        """The ``--ground-truth-file`` (an ``ExternalGroundTruth``), read once; None without."""
        if config.ground_truth_file is None:
            return None
        from replaybench.tasks.detections.truth import load_file

        return load_file(config)

    def open_truth(
        self, inp: TruthInput, options: Any, loaded: object | None, notes: list[str]
    ) -> object | None:
        """The input's ``BoxTruth``: the file's, else its topic's read whole; None without."""
        topic = options.ground_truth_topic
        present = bool(topic) and any(t.name == topic for t in inp.source.topics())
        if loaded is None and not present and not options.ground_truth_explicit:
            return None  # nothing to read: the truth module is not imported
        from replaybench.tasks.detections.truth import open_box_truth

        return open_box_truth(inp, options, cast('ExternalGroundTruth | None', loaded), notes)


TASK = DetectionsTask()
