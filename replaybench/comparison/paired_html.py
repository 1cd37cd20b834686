"""comparison.html's section *What the precision costs*: per candidate row paired frame by frame
with its baseline row (``comparison.paired``), the accuracy change with its paired interval,
the agreement of the two backends' outputs, the latency ratio, and the least agreeing frames as
embedded thumbnails."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.report.markup import escaped

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from replaybench.comparison.core import Comparison
    from replaybench.comparison.paired import FrameAgreement, Paired
    from replaybench.comparison.runs import RunInfo

__all__ = ['paired_html', 'thumbnails']

#: A paired metric's name on the page.
_PAIRED_NAMES = {'map50': 'mAP@0.5', 'miou': 'mIoU'}


def _agreement_text(paired: Paired) -> str:
    if paired.matched_mean is None or paired.iou_mean is None:
        return ''
    if paired.metric == 'miou':
        return (
            f'masks agree: pixels {paired.matched_mean:.4f} (lowest frame '
            f'{paired.matched_min:.4f}), mIoU of the two {paired.iou_mean:.3f}; '
            f'{paired.agreeing_frames} frames alike'
        )
    return (
        f'boxes agree: matched {paired.matched_mean:.3f} (lowest frame '
        f'{paired.matched_min:.3f}), IoU {paired.iou_mean:.3f}; '
        f'{paired.agreeing_frames} frames fully matched'
    )


def _caption(paired: Paired, frame: FrameAgreement) -> str:
    if paired.metric == 'miou':
        return f'pixels alike {frame.matched:.4f} · mIoU of the two {frame.iou:.3f}'
    return (
        f'matched {frame.matched:.2f} · IoU {frame.iou:.2f} · boxes '
        f'{frame.n_baseline} / {frame.n_candidate}'
    )


def paired_html(comparison: Comparison) -> str:
    """What the precision costs: per paired row, the accuracy change with its paired interval,
    the agreement of the two backends' outputs, the latency ratio, and the frames where the two
    agree least as thumbnails (drawn from the bag, embedded)."""
    rows = [r for r in comparison.rows if r.paired is not None]
    if not rows:
        return ''
    intro = (
        '<h2 id="paired">What the precision costs</h2><p class="meta">Each candidate row '
        'against its baseline row on the frames both output: the accuracy change (mAP@0.5 for '
        'boxes, mIoU for label masks) with a bootstrap interval paired by frame (the same '
        'resampled frames scored for both), the agreement of the two backends per frame '
        '(boxes — matched: share of the boxes of both that found a box of the same label at '
        'IoU ≥ 0.5, IoU: mean best-match IoU of every box; masks — the share of pixels both '
        'label alike, and the mIoU of one mask against the other), the median latency ratio, '
        'and the frames where the two agree least.</p>'
    )
    parts = [intro]
    for row in rows:
        paired = row.paired
        assert paired is not None
        level = round(paired.confidence * 100)
        name = _PAIRED_NAMES.get(paired.metric, paired.metric)
        if paired.ci is not None and paired.change is not None:
            lo, hi = paired.ci
            change = (
                f'{name} {paired.baseline:.4f} → {paired.candidate:.4f}: Δ {paired.change:+.4f}, '
                f'{level}% CI [{lo:+.4f}, {hi:+.4f}] ({paired.resamples} paired resamples of '
                f'{paired.frames} frames, seed {paired.seed})'
            )
        else:
            change = f'no paired interval: {paired.note}'
        median = row.metrics['median_ms']
        latency = f'median latency ×{median.ratio:.3f}' if median.ratio is not None else ''
        if median.ratio_ci is not None:
            latency += f' [{median.ratio_ci[0]:.3f}, {median.ratio_ci[1]:.3f}]'
        agree = _agreement_text(paired)
        items = ''.join(f'<li>{escaped(t)}</li>' for t in (change, agree, latency) if t)
        names = (str(row.baseline_backend), row.backend)
        shots, missing = thumbnails(paired, comparison.runs[row.run], row.topic, names)
        figures = ''.join(
            f'<figure><img src="{uri}" alt="{escaped(f"{row.topic} {f.stamp_ns}")}">'
            f'<figcaption>{escaped(_caption(paired, f))}</figcaption></figure>'
            for f, uri in shots
        )
        if not paired.worst and paired.matched_mean is not None:
            figures = '<p class="meta">The two agree on every frame.</p>'
        if missing:
            figures += f'<p class="meta">{escaped(missing)}</p>'
        parts.append(
            f'<h3>{escaped(row.name)} vs {escaped(names[0])}</h3><ul>{items}</ul>'
            f'<div class="thumbs">{figures}</div>'
        )
    return ''.join(parts)


def _thumbnail(
    paired: Paired,
    at: int,
    image: npt.NDArray[np.uint8],
    topic: str,
    seq: int,
    names: tuple[str, str],
) -> npt.NDArray[np.uint8]:
    """One least-agreeing frame drawn: the image with both backends' boxes, or (masks) the
    image beside the two masks in the segmentation palette."""
    import numpy as np

    from replaybench.report.samples import sample_canvas

    agree = paired.worst[at]
    if paired.metric != 'miou':
        base, cand = paired.worst_boxes[at]
        title = f'{topic} #{seq}: matched {agree.matched:.2f}, IoU {agree.iou:.2f}'
        drawn: npt.NDArray[np.uint8] = sample_canvas(image, {names[0]: base, names[1]: cand}, title)
        return drawn
    from replaybench.segmentation.palette import colourise

    masks = [colourise(m)[:, :, ::-1] for m in paired.worst_masks[at]]  # palette RGB -> BGR
    if any(m.shape != image.shape for m in masks):
        masks = []
    strip = np.hstack([image, *masks])
    title = f'{topic} #{seq}: image | {names[0]} | {names[1]}: pixels alike {agree.matched:.4f}'
    return np.asarray(sample_canvas(strip, {}, title), dtype=np.uint8)


def thumbnails(
    paired: Paired, run: RunInfo, topic: str, names: tuple[str, str]
) -> tuple[list[tuple[FrameAgreement, str]], str]:
    """The ``worst`` frames of ``paired`` drawn from ``run``'s bag with both backends' boxes
    (``names``: baseline, candidate), as JPEG ``data:`` URIs in ``worst`` order, and a line
    saying which could not be drawn and why ('' when all were)."""
    if not paired.worst or not (
        paired.worst_masks if paired.metric == 'miou' else paired.worst_boxes
    ):
        return [], ''
    if len(run.input_paths) != 1:
        return [], f'not drawn: the run has {len(run.input_paths)} inputs'
    import base64

    import cv2

    from replaybench.comparison.paired import input_path
    from replaybench.decode.image import decode_image, image_stamp, to_bgr8
    from replaybench.errors import DecodeError, ReplaybenchError
    from replaybench.report.samples import JPEG_QUALITY
    from replaybench.sources import open_source

    bag = input_path(run, run.input_paths[0])
    if bag is None:
        return [], f'not drawn: input {run.input_paths[0]} not found'
    wanted = {(f.frame_id, f.stamp_ns): i for i, f in enumerate(paired.worst)}
    stamps = {f.stamp_ns for f in paired.worst}
    drawn: dict[int, str] = {}
    try:
        with open_source(bag) as source:
            for raw in source.messages(topics=[topic]):
                try:
                    # the stamp first: only the frames drawn are decoded
                    if image_stamp(raw) not in stamps:
                        continue
                    frame = decode_image(raw)
                except DecodeError:
                    continue
                at = wanted.get((frame.frame_id, frame.stamp_ns))
                if at is None:
                    continue
                canvas = _thumbnail(
                    paired, at, to_bgr8(frame.image, frame.encoding), topic, frame.seq, names
                )
                ok, encoded = cv2.imencode('.jpg', canvas, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
                if ok:
                    text = base64.b64encode(encoded.tobytes()).decode('ascii')
                    drawn[at] = f'data:image/jpeg;base64,{text}'
                if len(drawn) == len(wanted):
                    break
    except ReplaybenchError as err:
        note = f'{len(wanted) - len(drawn)} of {len(wanted)} frames not drawn: {err}'
        return [(paired.worst[i], uri) for i, uri in sorted(drawn.items())], note
    missing = len(wanted) - len(drawn)
    note = f'{missing} of {len(wanted)} frames not found in {bag}' if missing else ''
    return [(paired.worst[i], uri) for i, uri in sorted(drawn.items())], note
