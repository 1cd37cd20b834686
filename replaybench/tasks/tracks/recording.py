"""The tracks task's part of recording a run: each frame's tracks kept, and each (backend,
topic)'s sequence scored against the ids of the box truth after the passes.

A tracked backend (``replaybench.backends.tracked``) returns its tracks as detections with
the track's id (``Detection.id``): the engine writes them into outputs.mcap (their
Detection2DArray's ``Detection2D.id``) and scores their boxes as any backend's. Here each
processed frame's tracks are kept beside the frame's truth boxes (the detections task's truth:
``/ground_truth/detections``, each box's ``id`` its object); after the passes a row's frames
with truth, in replay order, are one sequence for ``replaybench.tracking.score_tracks`` (box
IoU, every class together), and its CLEAR matching the row's id-switch timeline
(``timeline_of``: the row's ``track_timeline``, report.html's Tracking section). Frames the
tracker never saw (dropped from the queue, cut by ``--max-frames``) are not in the
sequence. Truth without ids (a box without one, or a
ground-truth file) gives no tracking metrics and a warning saying why; the boxes are still
scored.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, cast

from replaybench.errors import BackendError
from replaybench.tasks.base import TaskRecordingBase

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.decode.recorded import OutputReader
    from replaybench.results.model import TrackTimeline
    from replaybench.sinks.writer import OutputWriter
    from replaybench.tasks.detections.truth import BoxTruth
    from replaybench.tracking import TrackFrame, TrackScores
    from replaybench.types import BackendResult, Detection

__all__ = [
    'METRIC_NAMES',
    'READERS',
    'TracksRecording',
    'figures_of',
    'recording',
    'score_sequence',
    'scored_with_timeline',
    'timeline_of',
    'without_distractors',
]

#: the tracking figures of a row (``figures_of``), in summary.csv's order
METRIC_NAMES = (
    'hota', 'deta', 'assa', 'loca', 'idf1', 'idp', 'idr', 'mota', 'motp',
    'id_switches', 'fragmentations', 'mt', 'ml',
)  # fmt: skip

#: the tracks task reads no recorded outputs of its own
READERS: Mapping[str, OutputReader] = {}


class _Input(Protocol):
    @property
    def truth(self) -> Mapping[str, object]: ...


def figures_of(scores: TrackScores) -> dict[str, float | None]:
    """The sequence's figures by metric name (summary.csv's columns); MT and ML as fractions
    of the truth's objects."""
    objects = scores.gt_ids
    return {
        'hota': scores.hota,
        'deta': scores.deta,
        'assa': scores.assa,
        'loca': scores.loca,
        'idf1': scores.idf1,
        'idp': scores.idp,
        'idr': scores.idr,
        'mota': scores.mota,
        'motp': scores.motp,
        'id_switches': float(scores.id_switches),
        'fragmentations': float(scores.fragmentations),
        'mt': scores.mostly_tracked / objects if objects else None,
        'ml': scores.mostly_lost / objects if objects else None,
    }


def _track_frames(
    frames: Sequence[tuple[Sequence[Detection], Sequence[Detection]]],
) -> tuple[list[TrackFrame], list[str], list[str]]:
    """The sequence as ``TrackFrame`` s (ids numbered in order of first appearance, similarity
    box IoU), with the truth's and the tracks' id texts by number."""
    import numpy as np

    from replaybench.tracking import TrackFrame, box_iou_xywh

    gt_numbers: dict[str, int] = {}
    tr_numbers: dict[str, int] = {}

    def xywh(dets: Sequence[Detection]) -> Any:
        return np.array(
            [(d.x0, d.y0, d.x1 - d.x0, d.y1 - d.y0) for d in dets], dtype=np.float64
        ).reshape(-1, 4)

    made = []
    for truth, tracks in frames:
        gt = np.array([gt_numbers.setdefault(d.id, len(gt_numbers)) for d in truth], np.int64)
        tr = np.array([tr_numbers.setdefault(d.id, len(tr_numbers)) for d in tracks], np.int64)
        made.append(TrackFrame(gt, tr, box_iou_xywh(xywh(truth), xywh(tracks))))
    return made, list(gt_numbers), list(tr_numbers)


def score_sequence(
    frames: Sequence[tuple[Sequence[Detection], Sequence[Detection]]],
) -> TrackScores:
    """The tracking figures of a sequence of (truth boxes, tracks) per frame, in order: ids
    as the boxes' ``id`` texts, similarity box IoU. ``ValueError`` for an id twice in a
    frame."""
    from replaybench.tracking import score_tracks

    return score_tracks(_track_frames(frames)[0])


def _id_order(text: str) -> tuple[int, int, str]:
    """Ids in order: numbers by value first, then other texts."""
    return (0, int(text), '') if text.isdigit() else (1, 0, text)


def timeline_of(
    frames: Sequence[tuple[Sequence[Detection], Sequence[Detection]]],
    seqs: Sequence[int] = (),
) -> TrackTimeline:
    """The id-switch timeline of a sequence scored as ``score_sequence`` scores it (its CLEAR
    matching: ``scored_with_timeline``). ``ValueError`` as ``score_sequence``."""
    return scored_with_timeline(frames, seqs)[1]


def scored_with_timeline(
    frames: Sequence[tuple[Sequence[Detection], Sequence[Detection]]],
    seqs: Sequence[int] = (),
) -> tuple[TrackScores, TrackTimeline]:
    """``score_sequence`` and the sequence's id-switch timeline in one pass
    (``replaybench.tracking.score_and_match``): each truth object's frames as spans matched to
    one track or missed, and the ID switches, of the CLEAR matching that counted the figures'
    ``id_switches``; ``seqs``: each frame's ``seq`` (frames.csv), kept in the timeline where
    given for every frame. ``ValueError`` as ``score_sequence``."""
    from replaybench.results.model import IdSwitchEvent, TrackLane, TrackSpan, TrackTimeline
    from replaybench.tracking import score_and_match

    made, gt_names, tr_names = _track_frames(frames)
    scores, matching = score_and_match(made)
    spans: dict[str, list[TrackSpan]] = {}
    for index, (frame, pairs) in enumerate(zip(made, matching.pairs, strict=True)):
        matched = {gt_names[g]: tr_names[t] for g, t in pairs}
        for number in frame.gt_ids.tolist():
            name = gt_names[number]
            track = matched.get(name)
            lane = spans.setdefault(name, [])
            if lane and lane[-1].last == index - 1 and lane[-1].track_id == track:
                lane[-1] = TrackSpan(lane[-1].first, index, track)
            else:
                lane.append(TrackSpan(index, index, track))
    timeline = TrackTimeline(
        frames=len(made),
        seqs=tuple(seqs) if len(seqs) == len(made) else (),
        lanes=tuple(TrackLane(name, tuple(spans[name])) for name in sorted(spans, key=_id_order)),
        switches=tuple(
            IdSwitchEvent(s.frame, gt_names[s.gt_id], tr_names[s.from_id], tr_names[s.to_id])
            for s in matching.switches
        ),
    )
    return scores, timeline


def without_distractors(
    scored: Sequence[Detection], others: Sequence[Detection], tracks: tuple[Detection, ...]
) -> tuple[Detection, ...]:
    """The tracks less those matched to a distractor's box (``MOT_DISTRACTORS``): the tracks
    and every truth box of the frame matched one to one (Hungarian on IoU, IoU >= 0.5), as
    TrackEval's MOT17 preprocessing does."""
    from replaybench.results.groundtruth import MOT_DISTRACTORS

    if not tracks or not any(d.label in MOT_DISTRACTORS for d in others):
        return tracks
    import numpy as np

    from replaybench.tracking import box_iou_xywh
    from replaybench.tracking.metrics import _assign

    def xywh(dets: Sequence[Detection]) -> Any:
        return np.array(
            [(d.x0, d.y0, d.x1 - d.x0, d.y1 - d.y0) for d in dets], dtype=np.float64
        ).reshape(-1, 4)

    truth = [*scored, *others]
    iou = box_iou_xywh(xywh(truth), xywh(tracks))
    eps = float(np.finfo('float').eps)
    iou[iou < 0.5 - eps] = 0
    rows, cols = _assign(-iou)
    drop = {
        int(c)
        for r, c in zip(rows, cols, strict=True)
        if iou[r, c] > eps and truth[r].label in MOT_DISTRACTORS
    }
    return tuple(d for i, d in enumerate(tracks) if i not in drop)


class TracksRecording(TaskRecordingBase):
    """Each (backend label, topic)'s frames: the truth and the tracks of those with truth,
    and the tracker's times."""

    def __init__(self) -> None:
        self.sequences: dict[
            tuple[str, str], list[tuple[tuple[Detection, ...], tuple[Detection, ...]]]
        ] = {}
        self.times: dict[tuple[str, str], list[float]] = {}
        #: the ``seq`` of each frame of ``sequences``, by row
        self.seqs: dict[tuple[str, str], list[int]] = {}
        #: why a row has no tracking metrics, by row
        self.refused: dict[tuple[str, str], str] = {}
        self._warnings: dict[str, None] = {}
        self._figures: dict[tuple[str, str], dict[str, Any]] | None = None

    def frame(
        self,
        writer: OutputWriter,
        label: str,
        inp: _Input,
        key: tuple[str, int, int, int, str],
        result: BackendResult,
    ) -> Mapping[str, Any]:
        """One frame: its tracks kept beside its truth; its ``track_ms``."""
        from replaybench.backends.tracked import TrackStage

        del writer
        topic, seq, _, stamp_ns, frame_id = key
        stage = result.output
        if stage is not None and not isinstance(stage, TrackStage):
            msg = f'backend {label!r} declares task tracks but returned {type(stage).__name__}'
            raise BackendError(msg)
        row = (label, topic)
        track_ms = None if stage is None else stage.track_ns / 1e6
        if track_ms is not None:
            self.times.setdefault(row, []).append(track_ms)
        truth = cast('BoxTruth | None', inp.truth.get('detections'))
        if truth is None:
            return {'track_ms': track_ms}
        tracks = result.detections
        external = truth.external
        if external is not None and external.format != 'mot':
            self.refused[row] = f'a {external.format} ground-truth file holds no object ids'
            return {'track_ms': track_ms}
        if external is not None:  # a MOTChallenge file: TrackEval's MOT17 preset
            boxes = external.lookup(topic, seq, stamp_ns)
            if boxes is not None:
                tracks = without_distractors(boxes, external.others_of(topic, seq), tracks)
        else:
            boxes = truth.frames.get((frame_id, stamp_ns))
        if boxes is None:
            return {'track_ms': track_ms}
        if any(not d.id for d in boxes):
            self.refused.setdefault(row, 'its ground-truth boxes carry no ids (Detection2D.id)')
        self.sequences.setdefault(row, []).append((boxes, tracks))
        self.seqs.setdefault(row, []).append(seq)
        return {'track_ms': track_ms}

    def _scored(self) -> dict[tuple[str, str], dict[str, Any]]:
        """Every row's figures, scored once (after the passes); why a row has none goes into
        the warnings."""
        if self._figures is not None:
            return self._figures
        figures: dict[tuple[str, str], dict[str, Any]] = {}
        for row in dict.fromkeys([*self.times, *self.sequences]):
            backend, topic = row
            found: dict[str, Any] = dict.fromkeys(METRIC_NAMES)
            frames = self.sequences.get(row)
            reason = self.refused.get(row)
            if reason is None and frames:
                try:
                    scores, timeline = scored_with_timeline(frames, self.seqs.get(row, ()))
                except ValueError as err:
                    reason = str(err)
                else:
                    found.update(figures_of(scores))
                    found['track_timeline'] = timeline
            if reason is not None:
                self._warnings[f'{backend} on {topic}: no tracking metrics: {reason}'] = None
            times = self.times.get(row)
            found['track_ms'] = sum(times) / len(times) if times else None
            figures[row] = found
        self._figures = figures
        return figures

    def summary(self, backend: str, topic: str) -> Mapping[str, Any] | None:
        """The row's tracking figures (None where refused or without truth), its id-switch
        timeline (``track_timeline``, where it has figures) and its mean tracker time; None for
        a row that is not the task's."""
        return self._scored().get((backend, topic))

    def warnings(self) -> list[str]:
        """Why rows have no tracking metrics."""
        self._scored()
        return list(self._warnings)


def recording(recorder: object) -> TracksRecording:
    """The tracks task's ``TaskRecording`` for a run."""
    del recorder
    return TracksRecording()
