"""The tags task's part of recording a run: each tag backend's tags written into outputs.mcap
(``replaybench.tasks.tags.sink``) and scored per frame against the input's tag ground truth (read
when it opens, ``replaybench.tasks.tags.truth``; scored by ``replaybench.tasks.tags.scoring``).

``TagScores`` is the tags task's ``TaskRecording`` (``recording``, named by
``replaybench.tasks.tags.task``), made by the ``Recorder`` (``replaybench.replay.recording``)
when the frames of a backend that declares the task (``Backend.task``) are first recorded, after
the first frame: ``Recorder.task_outputs`` calls ``frame`` for each processed frame, after the
pass, outside any timed region, and it reads the frame's truth from the input's truth of the
task (``OpenedInput.truth``). It gives each (backend, topic) its ``TagAccuracy`` (``summary``,
read by ``replaybench.replay.record.summaries``). The backends of other tasks never reach it
(their tag columns stay empty); the scorer and the sink are imported at the first tag result.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, cast

from replaybench.errors import BackendError
from replaybench.tasks.base import TaskRecordingBase

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.fiducials.types import TagDetection, TagResult
    from replaybench.results.model import TagAccuracy
    from replaybench.sinks.writer import OutputWriter
    from replaybench.tasks.tags.scoring import FrameTagScore
    from replaybench.tasks.tags.truth import TagTable
    from replaybench.types import BackendResult

__all__ = ['TagScores', 'TaggedInput', 'recording']


class TaggedInput(Protocol):
    """What the tags' recording reads of an input (``replaybench.replay.inputs.OpenedInput``):
    each task's ground truth by task name, the tags' a ``TagTable``
    (``replaybench.tasks.tags.truth``)."""

    @property
    def truth(self) -> Mapping[str, object]: ...
    @property
    def number(self) -> int: ...


class TagScores(TaskRecordingBase):
    """The tag task's state over one run: each (backend label, topic)'s frame scores."""

    #: a tag backend's boxes (the tags' bounding boxes) are scored against box ground truth
    scores_boxes = True
    #: its messages follow the frame's detections message in outputs.mcap
    writes_first = False

    def __init__(self) -> None:
        # (backend label, topic) -> scores of its frames with truth, in replay order
        self.scores: dict[tuple[str, str], list[FrameTagScore]] = {}
        # (backend label, topic) -> (input, seq) -> the tags found: the outputs the streaming
        # scores show (``replaybench.tasks.tags.streaming``)
        self.found: dict[tuple[str, str], dict[tuple[int, int], tuple[TagDetection, ...]]] = {}
        self.notes: dict[tuple[str, str], str] = {}

    def frame(
        self,
        writer: OutputWriter,
        label: str,
        inp: TaggedInput,
        key: tuple[str, int, int, int, str],
        result: BackendResult,
    ) -> Mapping[str, Any]:
        """One processed frame of a tag backend: its tags written and, against the frame's
        tag ground truth (where it has some), scored; its frames.csv tag columns.
        ``BackendError`` for a result that is no ``TagResult`` (a backend that declares the
        task and returns no tags)."""
        from replaybench.tasks.tags.scoring import score_frame
        from replaybench.tasks.tags.sink import write_tags

        topic, _, log_time_ns, stamp_ns, frame_id = key
        tagged = cast('TagResult', result)
        try:
            tags, note = tagged.tags, tagged.note
        except AttributeError:
            msg = f'backend {label!r} declares task tags but returned no tags (a TagResult)'
            raise BackendError(msg) from None
        if note and (label, topic) not in self.notes:
            self.notes[(label, topic)] = f'{label}: {note}'
        write_tags(writer, label, topic, log_time_ns, stamp_ns, frame_id, tagged)
        self.found.setdefault((label, topic), {})[inp.number, key[1]] = tuple(tags)
        table = cast('TagTable | None', inp.truth.get('tags'))
        truth = None if table is None else table.get((frame_id, stamp_ns))
        if truth is None:
            return {'tags': len(tags)}
        score = score_frame(tags, truth)
        self.scores.setdefault((label, topic), []).append(score)
        return score.columns()

    def accuracy(self, backend: str, topic: str) -> TagAccuracy | None:
        """The tag accuracy of a (backend label, topic), None where no frame was scored."""
        from replaybench.tasks.tags.scoring import tag_accuracy

        scores = self.scores.get((backend, topic))
        return tag_accuracy(scores) if scores else None

    def summary(self, backend: str, topic: str) -> Mapping[str, Any] | None:
        """The row's tag fields: ``tag_accuracy`` and its figures as the ``tag_*`` columns;
        None where no frame of it was scored."""
        tags = self.accuracy(backend, topic)
        if tags is None:
            return None
        return {
            'tag_accuracy': tags,
            'tag_recall': tags.recall,
            'tag_wrong_ids': tags.wrong_ids,
            'tag_phantoms': tags.phantoms,
            'tag_corner_rmse_px': tags.corner_rmse_px,
            'tag_trans_err_m': tags.trans_err_m,
            'tag_trans_err_pct': tags.trans_err_pct,
            'tag_rot_err_deg': tags.rot_err_deg,
        }

    def warnings(self) -> list[str]:
        """One line per (backend label, topic) whose tags got no pose."""
        return list(self.notes.values())


def recording(recorder: object) -> TagScores:
    """The tags task's ``TaskRecording`` for the run of ``recorder``
    (``replaybench.replay.recording.Recorder``): a new ``TagScores``."""
    del recorder  # the tags' scores need nothing of the run
    return TagScores()
