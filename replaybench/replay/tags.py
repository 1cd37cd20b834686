"""The tag task in the engine: each tag backend's tags written into outputs.mcap and scored per
frame against the input's tag ground truth (read when it opens, ``replaybench.tasks.tags.truth``).

``TagScores`` is kept by the ``Recorder`` (``Recorder.task_outputs`` calls ``frame`` after the
pass, outside any timed region) and gives each (backend, topic) its ``TagAccuracy``
(``replaybench.replay.record.summaries``). Backends that return no ``TagResult`` pass through
untouched (their tag columns stay empty): the scorer and the sink are imported at the first
tag result, so that a run without tags does not load them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.fiducials.types import TagResult

if TYPE_CHECKING:
    from replaybench.fiducials.types import TagDetection
    from replaybench.results.model import TagAccuracy
    from replaybench.results.tags import FrameTagScore
    from replaybench.types import BackendResult

__all__ = ['TagScores']


class TagScores:
    """The tag task's state over one run: each (backend label, topic)'s frame scores."""

    def __init__(self) -> None:
        # (backend label, topic) -> scores of its frames with truth, in replay order
        self.scores: dict[tuple[str, str], list[FrameTagScore]] = {}
        self.notes: dict[tuple[str, str], str] = {}

    def frame(
        self,
        label: str,
        topic: str,
        log_time_ns: int,
        stamp_ns: int,
        frame_id: str,
        result: BackendResult,
        truth: tuple[TagDetection, ...] | None,
        writer: object,
    ) -> dict[str, Any]:
        """One processed frame: its tags written and, against ``truth`` (None: the frame has
        none), scored; its frames.csv tag columns (none for a backend that finds no tags)."""
        if not isinstance(result, TagResult):
            return {}
        from replaybench.results.tags import score_frame
        from replaybench.sinks.tags import write_tags

        if result.note and (label, topic) not in self.notes:
            self.notes[(label, topic)] = f'{label}: {result.note}'
        write_tags(writer, label, topic, log_time_ns, stamp_ns, frame_id, result)
        if truth is None:
            return {'tags': len(result.tags)}
        score = score_frame(result.tags, truth)
        self.scores.setdefault((label, topic), []).append(score)
        return score.columns()

    def accuracy(self, backend: str, topic: str) -> TagAccuracy | None:
        """The tag accuracy of a (backend label, topic), None where no frame was scored."""
        from replaybench.results.tags import tag_accuracy

        scores = self.scores.get((backend, topic))
        return tag_accuracy(scores) if scores else None

    def warnings(self) -> list[str]:
        """One line per (backend label, topic) whose tags got no pose."""
        return list(self.notes.values())
