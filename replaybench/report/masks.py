"""Mask thumbnails: a segmentation backend's label mask of the sample frame, colour-mapped.

Written beside the frame's sample as ``samples/input<i>_<topic>.mask_<backend>.png`` (the
palette of ``replaybench.segmentation.palette``, as in outputs.mcap's ``labels_rgb``);
report.html shows each under its frame.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.report.samples import sample_relpath, write_sample
from replaybench.results.runfolder import with_filename

if TYPE_CHECKING:
    from pathlib import Path

    import numpy as np
    import numpy.typing as npt

__all__ = ['mask_caption', 'mask_of', 'mask_picture', 'mask_relpath', 'write_mask_sample']

_MARK = '.mask_'


def mask_relpath(input_index: int, topic: str, backend: str) -> str:
    """The run-folder relative path of ``backend``'s mask thumbnail of a topic's sample."""
    frame = sample_relpath(input_index, topic)
    safe = ''.join(c if c.isascii() and (c.isalnum() or c in '_-') else '_' for c in backend)
    return f'{frame.rsplit(".", 1)[0]}{_MARK}{safe}.png'


def mask_of(rel: str) -> tuple[str, str] | None:
    """(the frame sample's path, backend) of a mask thumbnail's path; None for other files."""
    if _MARK not in rel or not rel.endswith('.png'):
        return None
    stem, _, backend = rel[: -len('.png')].rpartition(_MARK)
    return f'{stem}.jpg', backend


def write_mask_sample(path: str | Path, labels: npt.NDArray[np.uint8], title: str) -> None:
    """A thumbnail of ``labels`` in the class palette, with a title bar (PNG)."""
    import numpy as np

    from replaybench.segmentation.palette import colourise

    bgr = np.ascontiguousarray(colourise(labels)[:, :, ::-1])
    write_sample(path, bgr, {}, title)


def mask_picture(out: Path, sample: Any, backend: str, labels: npt.NDArray[np.uint8]) -> str:
    """The segmentation task's ``TaskViews.sample_picture``: ``backend``'s mask thumbnail of
    ``sample`` (a ``replaybench.replay.output.SampleImage``) written into the run folder
    ``out``; its relative path. An ``OSError`` names the file."""
    rel = mask_relpath(sample.input, sample.topic, backend)
    try:
        write_mask_sample(out / rel, labels, f'{sample.title} {backend} mask')
    except OSError as err:
        raise with_filename(err, out / rel) from None
    return rel


def mask_caption(rel: str) -> tuple[str, str] | None:
    """The segmentation task's ``TaskViews.sample_caption``: (the frame sample's path,
    ``<backend> mask``) of a mask thumbnail; None for other files."""
    found = mask_of(rel)
    return None if found is None else (found[0], f'{found[1]} mask')
