"""What one backend's outputs cost against another's on the same frames: the accuracy change
with an interval paired by frame, and how closely the two backends' outputs agree per frame.

Both rows' boxes are read back from their run folders' outputs.mcap (a backend's Detection2DArray
per processed frame) and the ground truth from the bags their run.json names, each keyed by
(frame_id, header stamp). The frames paired are those both backends output and the truth holds.

* **The change** is the candidate's mAP@0.5 minus the baseline's, both scored by
  ``replaybench.results.accuracy.evaluate`` (the run's own scoring) on the paired frames.
* **Its interval**: a bootstrap over frames, paired by frame. Each of ``resamples`` draws
  picks ``n`` of the ``n`` paired frames with replacement (``numpy.random.default_rng(seed)
  .integers(0, n, size=(resamples, n))``, the frames in (frame_id, stamp) order); the same
  frames are scored for both backends, each drawn frame a frame of its own, and the change
  recomputed. The interval is the percentile interval (numpy ``linear``) of the changes at
  ``confidence``; draws in which no frame holds ground truth (mAP undefined) are left out and
  counted. Frame pairing removes what both backends share (a hard frame is hard for both), so
  the interval is that of the *change*, narrower than two separate intervals would give.
* **Agreement per frame**: the baseline's and the candidate's boxes of the same label matched
  greedily by IoU (``replaybench.results.agreement``, IoU >= 0.5): ``matched`` = 2 x matched pairs
  / (boxes of both), and ``iou`` = the mean over every box of both of its best IoU with a box of
  the same label on the other side (0 without one). A frame where neither has a box agrees
  fully (1.0). The frames that agree least (by ``matched``, then ``iou``) are listed.

Heavy modules (the bag readers, the scoring) are imported when a comparison asks for them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy as np
    import numpy.typing as npt

    from replaybench.comparison.runs import RunInfo
    from replaybench.types import Detection

__all__ = [
    'PAIRED_RESAMPLES',
    'WORST_FRAMES',
    'FrameAgreement',
    'Paired',
    'box_agreement',
    'paired_boxes',
    'paired_rows',
    'thumbnails',
]

#: Bootstrap draws of the paired interval (each scores both backends once).
PAIRED_RESAMPLES = 1000
#: How many of the least agreeing frames a ``Paired`` lists (comparison.html draws them).
WORST_FRAMES = 6

#: A frame as outputs.mcap and the truth topic key it: (frame_id, header stamp in ns).
BoxKey = tuple[str, int]


class FrameAgreement(NamedTuple):
    """How one frame's boxes of the two backends agree."""

    frame_id: str
    stamp_ns: int
    matched: float
    iou: float
    n_baseline: int
    n_candidate: int


@dataclass(frozen=True, slots=True)
class Paired:
    """A candidate row against its baseline row over the frames both output.

    ``note`` says why nothing was computed ('' when it was); the figures are then None.
    """

    metric: str
    frames: int
    baseline: float | None = None
    candidate: float | None = None
    change: float | None = None
    ci: tuple[float, float] | None = None
    resamples: int = 0
    #: draws left out: no paired frame of the draw held ground truth
    undefined: int = 0
    confidence: float = 0.95
    seed: int = 0
    matched_mean: float | None = None
    iou_mean: float | None = None
    matched_min: float | None = None
    #: frames on which every box of either side found its match
    agreeing_frames: int = 0
    worst: tuple[FrameAgreement, ...] = ()
    note: str = ''
    #: the baseline's and the candidate's boxes on each ``worst`` frame (for the thumbnails)
    worst_boxes: tuple[tuple[tuple[Detection, ...], tuple[Detection, ...]], ...] = field(
        default=(), compare=False, repr=False
    )


def _best_iou(a: Sequence[Detection], b: Sequence[Detection]) -> list[float]:
    """For each box of ``a``: its best IoU with a box of ``b`` of the same label (0 if none)."""
    import numpy as np

    out = [0.0] * len(a)
    if not a or not b:
        return out
    box_a = np.array([[d.x0, d.y0, d.x1, d.y1] for d in a], dtype=np.float64)
    box_b = np.array([[d.x0, d.y0, d.x1, d.y1] for d in b], dtype=np.float64)
    iw = np.minimum(box_a[:, None, 2], box_b[None, :, 2]) - np.maximum(
        box_a[:, None, 0], box_b[None, :, 0]
    )
    ih = np.minimum(box_a[:, None, 3], box_b[None, :, 3]) - np.maximum(
        box_a[:, None, 1], box_b[None, :, 1]
    )
    inter = np.clip(iw, 0.0, None) * np.clip(ih, 0.0, None)
    area_a = np.clip(box_a[:, 2] - box_a[:, 0], 0, None) * np.clip(
        box_a[:, 3] - box_a[:, 1], 0, None
    )
    area_b = np.clip(box_b[:, 2] - box_b[:, 0], 0, None) * np.clip(
        box_b[:, 3] - box_b[:, 1], 0, None
    )
    union = area_a[:, None] + area_b[None, :] - inter
    iou = np.zeros_like(inter)
    np.divide(inter, union, out=iou, where=union > 0)
    same = np.array([[da.label == db.label for db in b] for da in a], dtype=bool)
    iou = np.where(same, iou, 0.0)
    return [float(v) for v in iou.max(axis=1)]


def box_agreement(
    baseline: Sequence[Detection], candidate: Sequence[Detection], key: BoxKey = ('', 0)
) -> FrameAgreement:
    """How one frame's boxes agree (the module text): matched share and mean best IoU."""
    from replaybench.results.agreement import agreement

    n_a, n_b = len(baseline), len(candidate)
    if n_a + n_b == 0:
        return FrameAgreement(key[0], key[1], 1.0, 1.0, 0, 0)
    found = agreement({(0, 0): baseline}, {(0, 0): candidate}, backend_a='', backend_b='', topic='')
    best = _best_iou(baseline, candidate) + _best_iou(candidate, baseline)
    return FrameAgreement(
        key[0], key[1], 2 * found.matched / (n_a + n_b), sum(best) / len(best), n_a, n_b
    )


def paired_boxes(
    baseline: Mapping[BoxKey, Sequence[Detection]],
    candidate: Mapping[BoxKey, Sequence[Detection]],
    truth: Mapping[BoxKey, Sequence[Detection]],
    *,
    resamples: int = PAIRED_RESAMPLES,
    confidence: float = 0.95,
    seed: int = 0,
) -> Paired:
    """The paired mAP@0.5 change, its bootstrap interval and the agreement (module text)."""
    import numpy as np

    from replaybench.results.accuracy import frame_scores, resampled_map50

    keys = sorted(k for k in truth if k in baseline and k in candidate)
    both = sorted(k for k in baseline if k in candidate)
    frames = [box_agreement(baseline[k], candidate[k], k) for k in both]
    matched = [f.matched for f in frames]
    ranked = sorted(frames, key=lambda f: (f.matched, f.iou))
    worst = tuple(f for f in ranked if f.matched < 1.0 or f.iou < 1.0)[:WORST_FRAMES]
    agreement = {
        'worst_boxes': tuple(
            (tuple(baseline[f.frame_id, f.stamp_ns]), tuple(candidate[f.frame_id, f.stamp_ns]))
            for f in worst
        ),
        'matched_mean': float(np.mean(matched)) if frames else None,
        'iou_mean': float(np.mean([f.iou for f in frames])) if frames else None,
        'matched_min': min(matched) if frames else None,
        'agreeing_frames': sum(m == 1.0 for m in matched),
        'worst': worst,
    }
    if not keys:
        return Paired(
            'map50',
            0,
            confidence=confidence,
            seed=seed,
            note='no frame both backends output has ground truth',
            **agreement,  # type: ignore[arg-type]
        )

    truth_ordered = {k: truth[k] for k in keys}
    scored = [
        frame_scores(truth_ordered, {k: dets[k] for k in keys}) for dets in (baseline, candidate)
    ]

    def map50(which: int, picks: npt.NDArray[np.int64]) -> float | None:
        found = resampled_map50(scored[which], picks)
        return found if found >= 0 else None

    n = len(keys)
    everything = np.arange(n, dtype=np.int64)
    base_value, cand_value = map50(0, everything), map50(1, everything)
    draws = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    changes = []
    for picks in draws:
        b, c = map50(0, picks), map50(1, picks)
        if b is not None and c is not None:
            changes.append(c - b)
    ci = None
    if changes and base_value is not None and cand_value is not None:
        lo, hi = np.quantile(np.asarray(changes), [(1 - confidence) / 2, (1 + confidence) / 2])
        ci = (float(lo), float(hi))
    note = '' if ci is not None else 'no ground-truth box on the paired frames: mAP undefined'
    return Paired(
        'map50',
        n,
        base_value,
        cand_value,
        cand_value - base_value if base_value is not None and cand_value is not None else None,
        ci,
        resamples,
        resamples - len(changes),
        confidence,
        seed,
        note=note,
        **agreement,  # type: ignore[arg-type]
    )


class _Folder(NamedTuple):
    """What a run folder gives the pairing: each (backend, topic)'s boxes, and the truth."""

    boxes: dict[tuple[str, str], dict[BoxKey, tuple[Detection, ...]]]
    truth: dict[BoxKey, tuple[Detection, ...]] | None
    note: str


def _input_path(run: RunInfo, path: str) -> Path | None:
    """An input of ``run`` as run.json names it: as given (absolute, or from the current
    folder), else beside the run folder; None when neither exists."""
    given = Path(path)
    for found in (given, run.dir / given, run.dir.parent / given):
        if found.exists():
            return found
    return None


def _read_folder(run: RunInfo, wanted: Sequence[tuple[str, str]]) -> _Folder:
    from replaybench.errors import ReplaybenchError
    from replaybench.sinks.mcap_writer import detections_channel
    from replaybench.sources import open_source
    from replaybench.tasks.detections.truth import read_detections

    settings = run.data.run.settings
    outputs = run.data.run.outputs
    name = outputs.outputs_mcap if outputs is not None else None
    if not name or (settings.detections_format or 'mcap') != 'mcap':
        return _Folder({}, None, f'{run.label}: no outputs.mcap (boxes are not kept)')
    mcap = run.dir / name
    if not mcap.is_file():
        return _Folder({}, None, f'{run.label}: {name} is missing from {run.dir}')
    gt_topic = settings.ground_truth_topic
    if not gt_topic:
        return _Folder({}, None, f'{run.label}: no ground-truth topic (a file is not paired)')
    if len(run.input_paths) != 1:
        return _Folder({}, None, f'{run.label}: {len(run.input_paths)} inputs (one is paired)')
    bag = _input_path(run, run.input_paths[0])
    if bag is None:
        return _Folder({}, None, f'{run.label}: input {run.input_paths[0]} not found')
    size = run.data.run.inputs[0].size_bytes
    if size is not None and bag.is_file() and bag.stat().st_size != size:
        return _Folder({}, None, f'{run.label}: input {bag} is not the one replayed (size)')
    try:
        with open_source(mcap) as source:
            boxes = {
                (backend, topic): read_detections(source, detections_channel(backend, topic))
                for backend, topic in wanted
            }
        with open_source(bag) as source:
            truth = read_detections(source, gt_topic)
    except ReplaybenchError as err:
        return _Folder({}, None, f'{run.label}: {err}')
    return _Folder(boxes, truth, '')


def paired_rows(
    pairs: Sequence[tuple[RunInfo, str, RunInfo, str, str]],
    *,
    resamples: int = PAIRED_RESAMPLES,
    confidence: float = 0.95,
    seed: int = 0,
) -> list[Paired]:
    """``paired_boxes`` for each (baseline run, baseline backend, candidate run, candidate
    backend, topic), each run folder read once; a ``Paired`` with a ``note`` where it cannot
    be made."""
    wanted: dict[int, list[tuple[str, str]]] = {}
    runs: dict[int, RunInfo] = {}
    for base_run, base_backend, cand_run, cand_backend, topic in pairs:
        runs[base_run.index], runs[cand_run.index] = base_run, cand_run
        wanted.setdefault(base_run.index, []).append((base_backend, topic))
        wanted.setdefault(cand_run.index, []).append((cand_backend, topic))
    folders = {i: _read_folder(runs[i], list(dict.fromkeys(w))) for i, w in wanted.items()}
    out = []
    for base_run, base_backend, cand_run, cand_backend, topic in pairs:
        base, cand = folders[base_run.index], folders[cand_run.index]
        note = base.note or cand.note
        if note or base.truth is None:
            out.append(Paired('map50', 0, confidence=confidence, seed=seed, note=note))
            continue
        b, c = base.boxes[base_backend, topic], cand.boxes[cand_backend, topic]
        if not b or not c:
            empty = base_backend if not b else cand_backend
            note = f'no boxes of {empty} on {topic} in outputs.mcap'
            out.append(Paired('map50', 0, confidence=confidence, seed=seed, note=note))
            continue
        out.append(
            paired_boxes(b, c, base.truth, resamples=resamples, confidence=confidence, seed=seed)
        )
    return out


def thumbnails(
    paired: Paired, run: RunInfo, topic: str, names: tuple[str, str]
) -> list[tuple[FrameAgreement, str]]:
    """The ``worst`` frames of ``paired`` drawn from ``run``'s bag with both backends' boxes
    (``names``: baseline, candidate), as JPEG ``data:`` URIs in ``worst`` order; frames whose
    image the bag does not give (another topic, a bag that is gone) are left out."""
    if not paired.worst or len(run.input_paths) != 1:
        return []
    import base64

    import cv2

    from replaybench.decode.image import decode_image, to_bgr8
    from replaybench.errors import ReplaybenchError
    from replaybench.report.samples import JPEG_QUALITY, sample_canvas
    from replaybench.sources import open_source

    bag = _input_path(run, run.input_paths[0])
    if bag is None:
        return []
    wanted = {(f.frame_id, f.stamp_ns): i for i, f in enumerate(paired.worst)}
    drawn: dict[int, str] = {}
    try:
        with open_source(bag) as source:
            for raw in source.messages(topics=[topic]):
                frame = decode_image(raw)
                at = wanted.get((frame.frame_id, frame.stamp_ns))
                if at is None:
                    continue
                agree = paired.worst[at]
                base, cand = paired.worst_boxes[at]
                title = f'{topic} #{frame.seq}: matched {agree.matched:.2f}, IoU {agree.iou:.2f}'
                canvas = sample_canvas(
                    to_bgr8(frame.image, frame.encoding), {names[0]: base, names[1]: cand}, title
                )
                ok, encoded = cv2.imencode('.jpg', canvas, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
                if ok:
                    text = base64.b64encode(encoded.tobytes()).decode('ascii')
                    drawn[at] = f'data:image/jpeg;base64,{text}'
                if len(drawn) == len(wanted):
                    break
    except ReplaybenchError:
        return [(paired.worst[i], uri) for i, uri in sorted(drawn.items())]
    return [(paired.worst[i], uri) for i, uri in sorted(drawn.items())]
