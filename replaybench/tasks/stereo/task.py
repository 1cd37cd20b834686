"""The stereo task: disparity against ground-truth disparity (``replaybench.stereo.metrics``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.errors import UsageError
from replaybench.tasks.base import LazyMapping, MetricSpec, TaskViews
from replaybench.tasks.stereo import DISPARITY_TRUTH_TOPIC

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.decode.recorded import OutputReader
    from replaybench.tasks.base import TruthInput

__all__ = ['FRAME_COLUMNS', 'TASK', 'StereoTask']


def _truth_topic(options: Any) -> str | None:
    """The truth topic asked for: the depth topic, the disparity topic, the default; None for
    a folder."""
    depth: str | None = getattr(options, 'ground_truth_depth', None)
    if depth is not None:
        return depth
    disparity: str | None = getattr(options, 'ground_truth_disparity', None)
    if disparity is None:
        return DISPARITY_TRUTH_TOPIC
    return None if Path(disparity).is_dir() else disparity


#: frames.csv's columns of a stereo backend's row: the pair's own figures (after the known ones)
FRAME_COLUMNS = ('epe', 'bad1', 'bad2', 'bad3', 'd1_all', 'density', 'abs_rel')


class StereoTask:
    """Disparity per stereo pair: EPE, bad-1/2/3, D1-all and density over the pixels with
    truth, pooled over a (backend, topic)'s pairs, and depth AbsRel where depth can be formed."""

    name: ClassVar[str] = 'stereo'
    metrics: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec(
            'epe', 'EPE (px)', 'EPE px', 'lower', fmt='.3f', sweep=True, terminal_label='EPE'
        ),
        MetricSpec('bad1', 'bad-1 (share > 1 px)', 'bad-1', 'lower'),
        MetricSpec(
            'bad2',
            'bad-2 (share > 2 px)',
            'bad-2',
            'lower',
            sweep=True,
            main=True,
            terminal_label='bad2',
        ),
        MetricSpec('bad3', 'bad-3 (share > 3 px)', 'bad-3', 'lower'),
        MetricSpec('d1_all', 'D1-all (share > 3 px and > 5 %)', 'D1-all', 'lower', sweep=True),
        MetricSpec(
            'density',
            'density (share of truth with an estimate)',
            'density',
            'higher',
            sweep=True,
            terminal_label='dens.',
        ),
        MetricSpec('abs_rel', 'depth AbsRel', 'AbsRel', 'lower'),
    )
    frame_columns: ClassVar[tuple[str, ...]] = FRAME_COLUMNS
    #: ``replaybench run``'s table: EPE, bad-2 and density after the memory column, where a
    #: row has them; the report shows bad-2 in its Summary and the others under More figures
    #: report.html shows each backend's disparity of the sample pair and its error
    views: ClassVar[TaskViews] = TaskViews(
        terminal_metrics=('epe', 'bad2', 'density'),
        sample_picture='replaybench.report.disparity:disparity_sample_picture',
        sample_caption='replaybench.report.disparity:disparity_caption',
    )

    #: each pair's disparity written and scored (``replaybench.tasks.stereo.recording``)
    recording: ClassVar[str] = 'replaybench.tasks.stereo.recording:recording'

    #: a recorded stereo_msgs/DisparityImage (an ESS or disparity node's output)
    recorded_readers: ClassVar[Mapping[str, OutputReader]] = LazyMapping(
        'replaybench.tasks.stereo.recorded:READERS'
    )

    # the ground truth (``replaybench.tasks.stereo.truth``, imported for an input with some)

    def truth_topics(self, options: Any) -> frozenset[str]:
        """The truth topic (``--ground-truth-depth``, ``--ground-truth-disparity``, default
        ``/ground_truth/disparity``): no camera; none for a folder."""
        topic = _truth_topic(options)
        return frozenset((topic,)) if topic is not None else frozenset()

    def load_truth(self, config: Any) -> object | None:
        """The folder of ``--ground-truth-disparity DIR`` (a ``DisparityFolder``), listed once;
        None for a topic. ``UsageError`` for both options, or a folder without truth."""
        disparity: str | None = getattr(config, 'ground_truth_disparity', None)
        if disparity is not None and getattr(config, 'ground_truth_depth', None) is not None:
            msg = 'give --ground-truth-disparity or --ground-truth-depth, not both'
            raise UsageError(msg)
        if disparity is None or not Path(disparity).is_dir():
            return None
        from replaybench.tasks.stereo.truth import DisparityFolder

        return DisparityFolder(Path(disparity))

    def open_truth(
        self, inp: TruthInput, options: Any, loaded: object | None, notes: list[str]
    ) -> object | None:
        """The run's folder, or the input's truth topic (indexed when its first pair is scored,
        after the pass); None without either. ``UsageError`` for a topic named by an option
        that the input lacks."""
        if loaded is not None:
            return loaded
        topic = _truth_topic(options)
        if topic is None:
            return None
        if not any(t.name == topic for t in inp.source.topics()):
            if topic != DISPARITY_TRUTH_TOPIC:
                msg = f'{inp.path}: ground-truth topic {topic} is not a topic of this file'
                raise UsageError(msg)
            return None
        from replaybench.tasks.stereo.truth import DepthTopic, DisparityTopic

        if getattr(options, 'ground_truth_depth', None) is not None:
            return DepthTopic(inp.source, topic, notes)
        return DisparityTopic(inp.source, topic, notes)


TASK = StereoTask()
