"""Mask ground truth: a ``mono8`` Image topic of class ids in the input (``--ground-truth-masks
TOPIC``, default ``/ground_truth/labels`` when present), matched by frame_id and header stamp,
or a folder of single-channel 8-bit PNG masks named ``<stamp_ns>.png``
(``--ground-truth-masks DIR``), which serves every input.

Nothing of the masks is read when an input opens: a topic's index is built when its first
mask is scored (after the pass that made it), and each mask is read again from the input, or
from its file, when a frame is scored against it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

from replaybench.errors import DecodeError, UsageError

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from replaybench.sources import Source

__all__ = ['MaskFolder', 'MaskTopic']


class MaskTopic:
    """The ground-truth masks of one input's topic, indexed by (frame_id, stamp) on the first
    lookup; each mask is read again from the input when asked for."""

    def __init__(self, source: Source, topic: str) -> None:
        self.source = source
        self.topic = topic
        self._index: dict[tuple[str, int], tuple[int, int]] | None = None
        self.class_names: tuple[str, ...] = ()

    @property
    def index(self) -> dict[tuple[str, int], tuple[int, int]]:
        """(frame_id, stamp) -> (log time, seq) of each mono8 mask of the topic."""
        if self._index is None:
            from replaybench.decode import decode_image

            index: dict[tuple[str, int], tuple[int, int]] = {}
            for raw in self.source.messages(topics=[self.topic]):
                try:
                    frame = decode_image(raw)
                except DecodeError:
                    continue
                if frame.encoding == 'mono8':
                    index[(frame.frame_id, frame.stamp_ns)] = (raw.log_time_ns, raw.seq)
            self._index = index
        return self._index

    def lookup(self, frame_id: str, stamp_ns: int) -> npt.NDArray[np.uint8] | None:
        from replaybench.decode import decode_image

        found = self.index.get((frame_id, stamp_ns))
        if found is None:
            return None
        log_time, seq = found
        for raw in self.source.messages(
            topics=[self.topic], start_ns=log_time, end_ns=log_time + 1
        ):
            if raw.seq == seq:
                image = decode_image(raw).image
                return np.ascontiguousarray(image.reshape(image.shape[0], image.shape[1]))
        return None


class MaskFolder:
    """Ground-truth masks as single-channel 8-bit PNG files named ``<stamp_ns>.png`` (the
    image's header stamp in nanoseconds); ``UsageError`` for a folder without any."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.files = {int(p.stem): p for p in path.glob('*.png') if p.stem.isdigit()}
        if not self.files:
            msg = f'{path}: no ground-truth masks (<stamp_ns>.png) in this folder'
            raise UsageError(msg)
        self.class_names: tuple[str, ...] = ()

    def lookup(self, frame_id: str, stamp_ns: int) -> npt.NDArray[np.uint8] | None:
        import cv2

        del frame_id  # one folder serves every replayed topic
        path = self.files.get(stamp_ns)
        if path is None:
            return None
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None or image.dtype != np.uint8 or image.ndim != 2:
            msg = f'{path}: not a single-channel 8-bit PNG mask'
            raise UsageError(msg)
        return cast('npt.NDArray[np.uint8]', image)
