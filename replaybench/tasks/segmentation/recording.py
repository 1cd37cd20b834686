"""The segmentation task's part of recording a run: its label masks written, scored and
compared between backends.

A backend that declares the segmentation task (``Backend.task``) returns
``BackendResult.mask``. ``Segmentation`` is the task's ``TaskRecording`` (``recording``, named by
``replaybench.tasks.segmentation.task``), made by the ``Recorder``
(``replaybench.replay.recording``) when the frames of such a backend are first recorded, after
the first frame. When the engine records one of its frames (after the timed pass,
``Recorder.task_outputs``), ``Segmentation.add``

* stages the mask in outputs.mcap (``replaybench.tasks.segmentation.sink``);
* scores it against the frame's ground-truth mask, when there is one: the input's truth of the
  segmentation task (``replaybench.tasks.segmentation.truth``: its mask topic, matched by
  frame_id and header stamp, or a folder of PNG masks named ``<stamp_ns>.png``), which the
  ``Segmentation.frame`` reads from ``OpenedInput.truth``; the frame's own mIoU and pixel accuracy
  go into its frames.csv row, its confusion matrix into the (backend, topic) sum that gives
  the summary (``replaybench.tasks.segmentation.scoring``);
* keeps the mask, PNG-compressed, when the run has several backends, for the agreement of its
  segmentation backends (the mIoU of each later backend against the earlier one, frame by
  frame).

A frame without a mask (a recorded mask topic without the frame's message) is not scored; the
boxes of the task's frames are never scored against box ground truth.

Masks are held in the pass's log until the pass ends (one ``H x W`` byte array per frame).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple, Protocol, cast

import numpy as np

from replaybench.errors import UsageError
from replaybench.results.io import to_json
from replaybench.tasks.base import TaskRecordingBase
from replaybench.tasks.segmentation.scoring import class_name, confusion, scores

if TYPE_CHECKING:
    from collections.abc import Mapping

    import numpy.typing as npt

    from replaybench.sinks.writer import OutputWriter
    from replaybench.types import BackendResult, LabelMask

__all__ = ['NO_MASK', 'FrameScore', 'MaskTruth', 'MaskedInput', 'Segmentation', 'recording']


def _number(value: Any) -> float | None:
    """A value as run.json holds it: a finite float (numpy's too), or None."""
    plain = to_json(value)
    return float(plain) if plain is not None else None


class MaskTruth(Protocol):
    """An input's ground-truth masks (``replaybench.tasks.segmentation.truth``)."""

    def lookup(self, frame_id: str, stamp_ns: int) -> npt.NDArray[np.uint8] | None: ...


def _unpng(data: bytes) -> npt.NDArray[np.uint8]:
    import cv2

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    return cast('npt.NDArray[np.uint8]', image)


class FrameScore(NamedTuple):
    """One frame's mIoU and pixel accuracy against its ground truth (None: no truth)."""

    miou: float | None = None
    pixel_accuracy: float | None = None


_NO_SCORE = FrameScore()
#: The score of a frame without a mask (a detector's).
NO_MASK = _NO_SCORE
_NO_COLUMNS: Mapping[str, Any] = {}


class MaskedInput(Protocol):
    """What the masks' recording reads of an input (``replaybench.replay.inputs.OpenedInput``):
    its number and each task's ground truth by task name, the segmentation task's a
    ``MaskTruth`` (``replaybench.tasks.segmentation.truth``)."""

    @property
    def number(self) -> int: ...

    @property
    def truth(self) -> Mapping[str, object]: ...


class Segmentation(TaskRecordingBase):
    """The run's masks: confusion sums, class names, kept masks."""

    #: the task's frames are scored against masks, not their boxes against box ground truth
    scores_boxes = False
    #: a mask's messages go before the frame's detections message in outputs.mcap
    writes_first = True

    def __init__(
        self, backends: int, streams: Mapping[tuple[str, str], object] | None = None
    ) -> None:
        self.keep = backends > 1
        #: the (backend label, topic)s with streaming picks (``Recorder.picks``, filled before
        #: a pass's frames are recorded): their masks are kept for the streaming scores
        #: (``replaybench.tasks.segmentation.streaming``)
        self.streams: Mapping[tuple[str, str], object] = {} if streams is None else streams
        self.matrices: dict[tuple[str, str], npt.NDArray[np.int64]] = {}
        self.frames: dict[tuple[str, str], int] = {}
        self.class_names: dict[str, tuple[str, ...]] = {}
        self.kept: dict[tuple[str, str], dict[tuple[int, int], bytes]] = {}
        self.shapes: dict[tuple[str, str], dict[tuple[int, int], tuple[int, int]]] = {}

    def frame(
        self,
        writer: OutputWriter,
        label: str,
        inp: MaskedInput,
        key: tuple[str, int, int, int, str],
        result: BackendResult,
    ) -> Mapping[str, Any]:
        """One processed frame of a segmentation backend (``TaskRecording.frame``): its mask
        written, scored against the input's ground-truth masks and kept (``add``); its
        frames.csv mIoU and pixel accuracy (none for a frame without a mask)."""
        mask = result.mask
        if mask is None:
            return _NO_COLUMNS
        truth = cast('MaskTruth | None', inp.truth.get('segmentation'))
        score = self.add(writer, label, inp.number, truth, key, mask)
        return {'miou': score.miou, 'pixel_accuracy': score.pixel_accuracy}

    def sample(self, result: BackendResult) -> npt.NDArray[np.uint8] | None:
        """The frame's class ids, drawn on the sample picture (None without a mask)."""
        mask = result.mask
        return None if mask is None else mask.labels

    def add(
        self,
        writer: OutputWriter,
        backend: str,
        number: int,
        truth: MaskTruth | None,
        key: tuple[str, int, int, int, str],
        mask: LabelMask,
    ) -> FrameScore:
        """Write, score against ``truth`` (the input's masks; None: none) and keep one frame's
        mask; its ``FrameScore``."""
        topic, seq, log_time_ns, stamp_ns, frame_id = key
        labels = mask.labels
        self.class_names.setdefault(backend, tuple(mask.class_names))
        if writer.keeps:
            from replaybench.tasks.segmentation.sink import add_mask

            add_mask(writer, backend, topic, log_time_ns, stamp_ns, frame_id, labels)
        group = (backend, topic)
        if self.keep or group in self.streams:
            import cv2

            ok, png = cv2.imencode('.png', labels, [cv2.IMWRITE_PNG_COMPRESSION, 1])
            if ok:
                self.kept.setdefault(group, {})[(number, seq)] = png.tobytes()
        if truth is None:
            return _NO_SCORE
        expected = truth.lookup(frame_id, stamp_ns)
        if expected is None:
            return _NO_SCORE
        if expected.shape != labels.shape:
            msg = (
                f'ground-truth mask of {topic} #{seq} is {expected.shape[1]}x{expected.shape[0]}, '
                f'the frame {labels.shape[1]}x{labels.shape[0]}'
            )
            raise UsageError(msg)
        matrix = confusion(labels, expected)
        total = self.matrices.get(group)
        self.matrices[group] = matrix if total is None else total + matrix
        self.frames[group] = self.frames.get(group, 0) + 1
        result = scores(matrix)
        return FrameScore(result.miou, result.pixel_accuracy)

    def summary(self, backend: str, topic: str) -> Mapping[str, Any] | None:
        """The row's segmentation fields: ``segmentation`` (a ``SegmentationSummary``), its
        ``miou`` and ``pixel_accuracy``; None for a row of another task's backend."""
        from replaybench.results.model import SegmentationSummary

        found = self.scored(backend, topic)
        if found is None:
            return None
        masks = SegmentationSummary(
            frames=found['frames'],
            miou=_number(found['miou']),
            pixel_accuracy=_number(found['pixel_accuracy']),
            iou={name: float(value) for name, value in found['iou'].items()},
            class_names=tuple(found['class_names']),
        )
        return {'segmentation': masks, 'miou': masks.miou, 'pixel_accuracy': masks.pixel_accuracy}

    def run_fields(self) -> Mapping[str, Any]:
        """run.json's ``segmentation_agreement``: each pair of segmentation backends on a topic,
        the later one's masks against the earlier one's."""
        from replaybench.results.model import SegmentationAgreementRow

        return {
            'segmentation_agreement': tuple(
                SegmentationAgreementRow(
                    backend_a=row['backend_a'],
                    backend_b=row['backend_b'],
                    topic=row['topic'],
                    frames=row['frames'],
                    miou=_number(row['miou']),
                    pixel_agreement=_number(row['pixel_agreement']),
                )
                for row in self.agreements()
            )
        }

    def scored(self, backend: str, topic: str) -> dict[str, Any] | None:
        """The ``segmentation`` entry of a summary row as plain values; None for a detector."""
        names = self.class_names.get(backend)
        if names is None:
            return None
        group = (backend, topic)
        matrix = self.matrices.get(group)
        if matrix is None:
            return {
                'frames': 0,
                'miou': None,
                'pixel_accuracy': None,
                'iou': {},
                'class_names': list(names),
            }
        result = scores(matrix)
        return {
            'frames': self.frames[group],
            'miou': result.miou,
            'pixel_accuracy': result.pixel_accuracy,
            'iou': {class_name(c, names): v for c, v in sorted(result.iou.items())},
            'class_names': list(names),
        }

    def agreements(self) -> list[dict[str, Any]]:
        """Per topic and pair of segmentation backends (run order): the frames both labelled,
        the mIoU and pixel agreement of the second against the first (as ground truth)."""

        rows: list[dict[str, Any]] = []
        groups = list(self.kept)
        for i, (first, topic) in enumerate(groups):
            for second, other_topic in groups[i + 1 :]:
                if other_topic != topic:
                    continue
                a, b = self.kept[(first, topic)], self.kept[(second, topic)]
                both = sorted(set(a) & set(b))
                total = np.zeros((256, 256), dtype=np.int64)
                for frame in both:
                    truth = _unpng(a[frame])
                    other = _unpng(b[frame])
                    total += confusion(other, truth, ignore=None)
                result = scores(total)
                rows.append(
                    {
                        'backend_a': first,
                        'backend_b': second,
                        'topic': topic,
                        'frames': len(both),
                        'miou': result.miou,
                        'pixel_agreement': result.pixel_accuracy,
                    }
                )
        return rows

    def finish(self, writer: OutputWriter) -> None:
        """The class names of every segmentation backend into the MCAP metadata."""
        self.write_names(writer)

    def write_names(self, writer: OutputWriter) -> None:
        """The class names of every segmentation backend into the MCAP metadata (none made
        for a writer that keeps nothing)."""
        if writer.keeps:
            from replaybench.tasks.segmentation.sink import write_class_names

            write_class_names(writer, self.class_names)


class _Recorder(Protocol):
    @property
    def backends(self) -> int: ...
    @property
    def picks(self) -> Mapping[tuple[str, str], object]: ...


def recording(recorder: _Recorder) -> Segmentation:
    """The segmentation task's ``TaskRecording`` for the run of ``recorder``
    (``replaybench.replay.recording.Recorder``): a new ``Segmentation``, which keeps masks for
    the agreement when the run has several backends, and for the streaming scores of a
    (backend, topic) that has them."""
    return Segmentation(recorder.backends, recorder.picks)
