"""The tags task: tag ids, corners and poses against tag ground truth."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.tasks.base import LazyMapping, MetricSpec, TaskViews
from replaybench.tasks.tags import TAG_GROUND_TRUTH_TOPIC

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    from replaybench.decode.recorded import OutputReader
    from replaybench.tasks.base import TruthInput

__all__ = ['TASK', 'TagsTask']


class TagsTask:
    """AprilTags (``replaybench.tasks.tags.scoring``): the summary.csv tag columns, in their
    order."""

    name: ClassVar[str] = 'tags'
    metrics: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec('tag_recall', 'tag recall', 'tag recall', 'higher', sweep=True, main=True),
        MetricSpec('tag_wrong_ids', 'wrong tag ids', 'wrong ids', 'lower'),
        MetricSpec('tag_phantoms', 'phantom tags', 'phantoms', 'lower'),
        MetricSpec('tag_corner_rmse_px', 'tag corner RMSE (px)', 'corner px', 'lower'),
        MetricSpec('tag_trans_err_m', 'tag translation error (m)', 'trans m', 'lower'),
        MetricSpec('tag_trans_err_pct', 'tag translation error (% of range)', 'trans %', 'lower'),
        MetricSpec('tag_rot_err_deg', 'tag rotation error (deg)', 'rot deg', 'lower', sweep=True),
        # streaming scores (replaybench.replay.streaming): each frame's tag truth against the
        # tags in use at its release; timed rates and recorded outputs only
        MetricSpec('streaming_tag_recall', 'streaming tag recall', 'stream tag recall', 'higher'),
        MetricSpec(
            'streaming_tag_trans_err_m',
            'streaming tag translation error (m)',
            'stream trans m',
            'lower',
        ),
        MetricSpec(
            'streaming_tag_rot_err_deg',
            'streaming tag rotation error (deg)',
            'stream rot deg',
            'lower',
        ),
    )
    #: the streaming metrics, each with the offline figure it is the streaming form of, and
    #: how picks are scored to them (``replaybench.replay.streaming``)
    streaming_metrics: ClassVar[Mapping[str, str]] = {
        'streaming_tag_recall': 'tag_recall',
        'streaming_tag_trans_err_m': 'tag_trans_err_m',
        'streaming_tag_rot_err_deg': 'tag_rot_err_deg',
    }
    streaming: ClassVar[str] = 'replaybench.tasks.tags.streaming:score'
    #: the report's section lives in the report layer (report/tags.py), the terminal's lines
    #: beside the tag scoring (tasks/tags/scoring.py); both imported where shown
    views: ClassVar[TaskViews] = TaskViews(
        summary_field='tag_accuracy',
        section_panel='replaybench.report.tags:tag_accuracy_html',
        terminal_lines='replaybench.tasks.tags.scoring:tag_lines',
    )

    #: a processed frame's tags written and scored (``replaybench.tasks.tags.recording``,
    #: ``TagScores``), loaded when the frames of a backend of the task are first recorded
    recording: ClassVar[str] = 'replaybench.tasks.tags.recording:recording'

    #: ``replaybench.tasks.tags.recorded``, imported when the ``recorded`` backend reads it
    recorded_readers: ClassVar[Mapping[str, OutputReader]] = LazyMapping(
        'replaybench.tasks.tags.recorded:READERS'
    )

    def backend_options(self, options: Any, inputs: Sequence[Path]) -> Any:
        """``options`` with the tag sizes the inputs record (``BAG_SIZE_KEYS``; the tag
        backends use them when the options give none, docs/fiducials.md)."""
        from dataclasses import replace

        from replaybench.fiducials.bagsizes import bag_size_keys

        keys = bag_size_keys(inputs)
        return replace(options, tag_options={**options.tag_options, **keys})

    # the ground truth (``replaybench.tasks.tags.truth``, imported for an input that has some)

    def truth_topics(self, options: Any) -> frozenset[str]:
        """``/ground_truth/tags``."""
        del options  # one topic, whatever the options
        return frozenset((TAG_GROUND_TRUTH_TOPIC,))

    def load_truth(self, config: Any) -> object | None:
        """Nothing: tag truth is read from each input."""
        del config
        return None

    def open_truth(
        self, inp: TruthInput, options: Any, loaded: object | None, notes: list[str]
    ) -> object | None:
        """The input's tags by (frame_id, stamp) (a ``TagTable``), read whole; None without
        the topic."""
        del options, loaded
        if not any(t.name == TAG_GROUND_TRUTH_TOPIC for t in inp.source.topics()):
            return None
        from replaybench.tasks.tags.truth import read_tag_truth

        return read_tag_truth(inp.source, notes)


TASK = TagsTask()
