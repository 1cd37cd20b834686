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
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, Protocol, TypeVar

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy as np
    import numpy.typing as npt

    from replaybench.comparison.metric import MetricComparison
    from replaybench.comparison.runs import RunInfo
    from replaybench.types import Detection

__all__ = [
    'PAIRED_METRICS',
    'PAIRED_RESAMPLES',
    'WORST_FRAMES',
    'FrameAgreement',
    'Paired',
    'Pairing',
    'box_agreement',
    'input_path',
    'paired_boxes',
    'paired_masks',
    'paired_rows',
    'with_paired',
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
    #: the baseline's and the candidate's label masks on each ``worst`` frame (mask rows)
    worst_masks: tuple[tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]], ...] = field(
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


def paired_masks(
    baseline: Mapping[BoxKey, npt.NDArray[np.uint8]],
    candidate: Mapping[BoxKey, npt.NDArray[np.uint8]],
    truth: Mapping[BoxKey, npt.NDArray[np.uint8]],
    *,
    resamples: int = PAIRED_RESAMPLES,
    confidence: float = 0.95,
    seed: int = 0,
) -> Paired:
    """The paired mIoU change and its bootstrap interval, and the agreement of two backends'
    label masks (the module text): each frame's confusion matrix against its truth
    (``tasks.segmentation.scoring.confusion``), summed over the drawn frames and scored by
    ``scoring.scores`` as the run scores the sum over its frames. Per frame, ``matched`` is
    the share of pixels both label alike and ``iou`` the mIoU of the candidate's mask against
    the baseline's."""
    import numpy as np

    from replaybench.tasks.segmentation.scoring import confusion, scores

    both = sorted(k for k in baseline if k in candidate)
    frames = []
    for k in both:
        a, b = baseline[k], candidate[k]
        same = a.shape == b.shape
        alike = float(np.count_nonzero(a == b)) / a.size if same and a.size else 0.0
        between = scores(confusion(b, a, ignore=None)).miou if same else None
        frames.append(
            FrameAgreement(
                k[0],
                k[1],
                alike,
                1.0 if between is None and same else between or 0.0,
                int(np.unique(a).size),
                int(np.unique(b).size),
            )
        )
    ranked = sorted(frames, key=lambda f: (f.matched, f.iou))
    worst = tuple(f for f in ranked if f.matched < 1.0)[:WORST_FRAMES]
    agreement = {
        'matched_mean': float(np.mean([f.matched for f in frames])) if frames else None,
        'iou_mean': float(np.mean([f.iou for f in frames])) if frames else None,
        'matched_min': min(f.matched for f in frames) if frames else None,
        'agreeing_frames': sum(f.matched == 1.0 for f in frames),
        'worst': worst,
        'worst_masks': tuple(
            (baseline[f.frame_id, f.stamp_ns], candidate[f.frame_id, f.stamp_ns]) for f in worst
        ),
    }
    keys = [
        k for k in both if k in truth and truth[k].shape == baseline[k].shape == candidate[k].shape
    ]
    if not keys:
        note = 'no frame both backends labelled has a ground-truth mask of its size'
        return Paired('miou', 0, confidence=confidence, seed=seed, note=note, **agreement)  # type: ignore[arg-type]
    # the class ids that occur: the matrices are kept over those alone (the IoUs are the same)
    ids = np.unique(
        np.concatenate([np.unique(m[k]) for m in (baseline, candidate, truth) for k in keys])
    )
    compact = [
        np.stack([confusion(dets[k], truth[k])[np.ix_(ids, ids)] for k in keys])
        for dets in (baseline, candidate)
    ]
    n, size = len(keys), len(ids)

    def miou(matrix: npt.NDArray[np.int64]) -> float | None:
        return scores(matrix.reshape(size, size)).miou

    base_value = miou(compact[0].sum(axis=0))
    cand_value = miou(compact[1].sum(axis=0))
    draws = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    weights = np.stack([np.bincount(d, minlength=n) for d in draws]).astype(np.int64)
    sums = [weights @ c.reshape(n, size * size) for c in compact]
    changes = []
    for base_sum, cand_sum in zip(sums[0], sums[1], strict=True):
        base_draw, cand_draw = miou(base_sum), miou(cand_sum)
        if base_draw is not None and cand_draw is not None:
            changes.append(cand_draw - base_draw)
    ci = None
    if changes and base_value is not None and cand_value is not None:
        lo, hi = np.quantile(np.asarray(changes), [(1 - confidence) / 2, (1 + confidence) / 2])
        ci = (float(lo), float(hi))
    return Paired(
        'miou',
        n,
        base_value,
        cand_value,
        cand_value - base_value if base_value is not None and cand_value is not None else None,
        ci,
        resamples,
        resamples - len(changes),
        confidence,
        seed,
        note='' if ci is not None else 'every pixel of the paired frames is ignored',
        **agreement,  # type: ignore[arg-type]
    )


class _Folder(NamedTuple):
    """What a run folder gives the pairing: each (backend, topic)'s boxes or masks, and the
    truth of each (by metric)."""

    outputs: dict[tuple[str, str], dict[BoxKey, Any]]
    truth: dict[str, dict[BoxKey, Any]]
    note: str


def input_path(run: RunInfo, path: str) -> Path | None:
    """An input of ``run`` as run.json names it: as given (absolute, or from the current
    folder), else beside the run folder; None when neither exists."""
    given = Path(path)
    for found in (given, run.dir / given, run.dir.parent / given):
        if found.exists():
            return found
    return None


def _mask_truth_topic(run: RunInfo) -> str | None:
    """The ground-truth mask topic of ``run``: its ``--ground-truth-masks`` (run.json
    ``command``) when that names a topic, else the default; None for a folder of PNGs."""
    from replaybench.tasks.segmentation.scoring import GROUND_TRUTH_MASK_TOPIC

    command = list(run.data.run.command)
    for i, word in enumerate(command):
        given = None
        if word == '--ground-truth-masks' and i + 1 < len(command):
            given = command[i + 1]
        elif word.startswith('--ground-truth-masks='):
            given = word.split('=', 1)[1]
        if given is not None:
            return given if given.startswith('/') and not Path(given).is_dir() else None
    return GROUND_TRUTH_MASK_TOPIC


def _masks(source: Any, topic: str) -> dict[BoxKey, npt.NDArray[np.uint8]]:
    """The mono8 label masks of a topic keyed by (frame_id, stamp)."""
    import numpy as np

    from replaybench.decode import decode_image
    from replaybench.errors import DecodeError

    found: dict[BoxKey, npt.NDArray[np.uint8]] = {}
    for raw in source.messages(topics=[topic]):
        try:
            frame = decode_image(raw)
        except DecodeError:
            continue
        if frame.encoding == 'mono8':
            image = np.ascontiguousarray(frame.image).reshape(frame.image.shape[:2])
            found[(frame.frame_id, frame.stamp_ns)] = image.astype(np.uint8, copy=False)
    return found


def _read_folder(run: RunInfo, wanted: Sequence[tuple[str, str, str]]) -> _Folder:
    from replaybench.errors import ReplaybenchError
    from replaybench.sinks.mcap_writer import detections_channel
    from replaybench.sources import open_source
    from replaybench.tasks.detections.truth import read_detections
    from replaybench.tasks.segmentation.sink import labels_channel

    settings = run.data.run.settings
    outputs = run.data.run.outputs
    name = outputs.outputs_mcap if outputs is not None else None
    if not name:
        return _Folder({}, {}, f'{run.label}: no outputs.mcap (outputs are not kept)')
    mcap = run.dir / name
    if not mcap.is_file():
        return _Folder({}, {}, f'{run.label}: {name} is missing from {run.dir}')
    if len(run.input_paths) != 1:
        return _Folder({}, {}, f'{run.label}: {len(run.input_paths)} inputs (one is paired)')
    metrics = {metric for _, _, metric in wanted}
    gt_topic = settings.ground_truth_topic
    mask_topic = _mask_truth_topic(run)
    if 'map50' in metrics and not gt_topic:
        return _Folder({}, {}, f'{run.label}: no ground-truth topic (a file is not paired)')
    if 'miou' in metrics and mask_topic is None:
        return _Folder({}, {}, f'{run.label}: ground-truth masks from a folder are not paired')
    bag = input_path(run, run.input_paths[0])
    if bag is None:
        return _Folder({}, {}, f'{run.label}: input {run.input_paths[0]} not found')
    size = run.data.run.inputs[0].size_bytes
    if size is not None and bag.is_file() and bag.stat().st_size != size:
        return _Folder({}, {}, f'{run.label}: input {bag} is not the one replayed (size)')
    try:
        found: dict[tuple[str, str], dict[BoxKey, Any]] = {}
        with open_source(mcap) as source:
            for backend, topic, metric in wanted:
                if metric == 'miou':
                    found[backend, topic] = _masks(source, labels_channel(backend, topic))
                else:
                    channel = detections_channel(backend, topic)
                    found[backend, topic] = dict(read_detections(source, channel))
        truth: dict[str, dict[BoxKey, Any]] = {}
        with open_source(bag) as source:
            if 'map50' in metrics and gt_topic:
                truth['map50'] = dict(read_detections(source, gt_topic))
            if 'miou' in metrics and mask_topic is not None:
                truth['miou'] = dict(_masks(source, mask_topic))
    except ReplaybenchError as err:
        return _Folder({}, {}, f'{run.label}: {err}')
    return _Folder(found, truth, '')


#: What a pairing compares: (baseline run, baseline backend, candidate run, candidate backend,
#: topic, metric: ``map50`` for boxes or ``miou`` for label masks).
Pairing = tuple['RunInfo', str, 'RunInfo', str, str, str]


def paired_rows(
    pairs: Sequence[Pairing],
    *,
    resamples: int = PAIRED_RESAMPLES,
    confidence: float = 0.95,
    seed: int = 0,
) -> list[Paired]:
    """``paired_boxes`` or ``paired_masks`` for each pairing, each run folder read once; a
    ``Paired`` with a ``note`` where it cannot be made."""
    wanted: dict[int, list[tuple[str, str, str]]] = {}
    runs: dict[int, RunInfo] = {}
    for base_run, base_backend, cand_run, cand_backend, topic, metric in pairs:
        runs[base_run.index], runs[cand_run.index] = base_run, cand_run
        wanted.setdefault(base_run.index, []).append((base_backend, topic, metric))
        wanted.setdefault(cand_run.index, []).append((cand_backend, topic, metric))
    folders = {i: _read_folder(runs[i], list(dict.fromkeys(w))) for i, w in wanted.items()}
    out = []
    for base_run, base_backend, cand_run, cand_backend, topic, metric in pairs:
        base, cand = folders[base_run.index], folders[cand_run.index]
        note = base.note or cand.note
        truth = base.truth.get(metric)
        if note or truth is None:
            out.append(Paired(metric, 0, confidence=confidence, seed=seed, note=note))
            continue
        b, c = base.outputs[base_backend, topic], cand.outputs[cand_backend, topic]
        if not b or not c:
            empty = base_backend if not b else cand_backend
            what = 'masks' if metric == 'miou' else 'boxes'
            note = f'no {what} of {empty} on {topic} in outputs.mcap'
            out.append(Paired(metric, 0, confidence=confidence, seed=seed, note=note))
            continue
        pair = paired_masks if metric == 'miou' else paired_boxes
        out.append(pair(b, c, truth, resamples=resamples, confidence=confidence, seed=seed))
    return out


#: The accuracy metric a row is paired on, by what its backend outputs: boxes, label masks.
PAIRED_METRICS: tuple[str, ...] = ('map50', 'miou')


class _Row(Protocol):
    """What ``with_paired`` reads of a compare row (``comparison.core.Row``)."""

    __dataclass_fields__: ClassVar[dict[str, Any]]

    @property
    def run(self) -> int: ...
    @property
    def backend(self) -> str: ...
    @property
    def topic(self) -> str: ...
    @property
    def role(self) -> str: ...
    @property
    def baseline_backend(self) -> str | None: ...
    @property
    def inputs_match(self) -> bool | None: ...
    @property
    def metrics(self) -> dict[str, MetricComparison]: ...
    @property
    def flags(self) -> tuple[str, ...]: ...


_R = TypeVar('_R', bound=_Row)


def _paired_metric(row: _Row) -> str | None:
    """The metric a candidate row is paired on over its baseline row's frames (``map50`` for
    boxes, ``miou`` for label masks: both rows have it), when the two are of one run or of
    runs of the same inputs; None for any other row."""
    from replaybench.results.model.summary import RIG_TOPIC

    if row.role != 'candidate' or row.topic == RIG_TOPIC or row.inputs_match is not True:
        return None
    for metric in PAIRED_METRICS:
        acc = row.metrics.get(metric)
        if acc is not None and acc.value is not None and acc.baseline is not None:
            return metric
    return None


def with_paired(
    rows: list[_R],
    runs: Sequence[RunInfo],
    baseline: int,
    *,
    seed: int,
    confidence: float,
    resamples: int | None,
) -> list[_R]:
    """``rows`` with each pairable row's ``paired`` and the ``diff_ci`` of its metric."""
    from dataclasses import replace

    chosen = [(i, metric) for i, row in enumerate(rows) if (metric := _paired_metric(row))]
    if not chosen:
        return rows
    found = paired_rows(
        [
            (
                runs[baseline],
                str(rows[i].baseline_backend),
                runs[rows[i].run],
                rows[i].backend,
                rows[i].topic,
                metric,
            )
            for i, metric in chosen
        ],
        resamples=PAIRED_RESAMPLES if resamples is None else resamples,
        confidence=confidence,
        seed=seed,
    )
    out = list(rows)
    for (i, metric), paired in zip(chosen, found, strict=True):
        row = rows[i]
        acc = row.metrics[metric]
        flags = list(row.flags)
        metrics = dict(row.metrics)
        if paired.note:
            flags.append(f'paired accuracy interval not made: {paired.note}')
        if paired.ci is not None:
            metrics[metric] = replace(acc, diff_ci=paired.ci, method='paired-bootstrap')
        if (
            paired.change is not None
            and acc.diff is not None
            and abs(paired.change - acc.diff) > 1e-9
        ):
            flags.append(
                f'paired over {paired.frames} frames both backends output: {metric} change '
                f'{paired.change:+.4f}, not the {acc.diff:+.4f} of the frames each scored'
            )
        out[i] = replace(row, metrics=metrics, flags=tuple(flags), paired=paired)
    return out
