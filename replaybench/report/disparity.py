"""Disparity thumbnails: a stereo backend's disparity of the sample pair, colour-mapped, and
its error against truth beside it where the pair has truth.

Written beside the pair's sample (its left image) as
``samples/input<i>_<topic>.disparity_<backend>.png``: on the left the disparity through
TURBO (``replaybench.stereo.thumbnail.disparity_picture``, 0 to the output's
``max_disparity``), on the right the error in KITTI's colours (``error_picture``: green
within 1 px, yellow within 3 px, red beyond, magenta for truth without an estimate); report.html
shows it under the frame.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.report.samples import sample_relpath, write_sample
from replaybench.results.runfolder import with_filename

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ['disparity_caption', 'disparity_relpath', 'disparity_sample_picture']

_MARK = '.disparity_'
#: each half's width in pixels, at most
_HALF = 320


def disparity_relpath(input_index: int, topic: str, backend: str) -> str:
    """The run-folder relative path of ``backend``'s disparity thumbnail of a topic's sample."""
    frame = sample_relpath(input_index, topic)
    safe = ''.join(c if c.isascii() and (c.isalnum() or c in '_-') else '_' for c in backend)
    return f'{frame.rsplit(".", 1)[0]}{_MARK}{safe}.png'


def disparity_sample_picture(out: Path, sample: Any, backend: str, drawn: Any) -> str:
    """The stereo task's ``TaskViews.sample_picture``: ``drawn`` is (the pair's
    ``Disparity``, its truth or None) (``StereoRecording.sample``); the thumbnail written into
    ``out``, its relative path. An ``OSError`` names the file."""
    import numpy as np

    from replaybench.stereo.thumbnail import disparity_picture, error_picture

    output, truth = drawn
    halves = [
        disparity_picture(
            output.disparity,
            max_disparity=output.max_disparity if output.max_disparity > 0 else None,
            min_disparity=output.min_disparity,
            width=_HALF,
        )
    ]
    title = f'{sample.title} {backend} disparity'
    if truth is not None:
        error = error_picture(
            output.disparity, truth, min_disparity=output.min_disparity, width=_HALF
        )
        halves.append(error)
        title += ' | error'
    gap = np.full((halves[0].shape[0], 4, 3), 255, np.uint8)
    rgb = halves[0] if len(halves) == 1 else np.concatenate([halves[0], gap, halves[1]], axis=1)
    rel = disparity_relpath(sample.input, sample.topic, backend)
    try:
        write_sample(out / rel, np.ascontiguousarray(rgb[:, :, ::-1]), {}, title)
    except OSError as err:
        raise with_filename(err, out / rel) from None
    return rel


def disparity_caption(rel: str) -> tuple[str, str] | None:
    """The stereo task's ``TaskViews.sample_caption``: (the frame sample's path, ``<backend>
    disparity``) of a disparity thumbnail; None for other files."""
    if _MARK not in rel or not rel.endswith('.png'):
        return None
    stem, _, backend = rel[: -len('.png')].rpartition(_MARK)
    return f'{stem}.jpg', f'{backend} disparity'
