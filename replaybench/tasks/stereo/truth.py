"""The stereo task's ground truth: the left image's disparity per pair, from a topic.

``/ground_truth/disparity`` holds a ``32FC1`` ``sensor_msgs/Image`` of the left image's
disparity in pixels (the stereo fixture's) or a ``stereo_msgs/DisparityImage``; 0, NaN and
inf are unknown (``replaybench.stereo.metrics.known_truth``). A message is matched to a pair
by the left image's frame_id and header stamp. The topic is indexed when its first pair is
scored (after the pass) and each truth read again when its pair is scored.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from replaybench.errors import DecodeError

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.sources import Source
    from replaybench.types import RawMessage

__all__ = ['DisparityTopic', 'read_truth_message']


def read_truth_message(raw: RawMessage) -> tuple[str, int, npt.NDArray[np.float32]]:
    """(frame_id, stamp_ns, disparity) of a truth message; ``DecodeError`` for one that is
    no 32FC1 Image or DisparityImage."""
    from replaybench.stereo.msgs import DISPARITY_IMAGE, parse_disparity_image

    if raw.msgtype == DISPARITY_IMAGE:
        found = parse_disparity_image(raw.data, ros1=raw.serialization == 'ros1')
        with np.errstate(invalid='ignore'):
            values = np.where(found.disparity >= found.min_disparity, found.disparity, np.nan)
        return found.frame_id, found.stamp_ns, values.astype(np.float32)
    from replaybench.decode import decode_image

    frame = decode_image(raw)
    image = np.asarray(frame.image)
    if image.ndim != 2 or image.dtype != np.float32:
        msg = f'{raw.topic}: truth disparity of encoding {frame.source_encoding}, not 32FC1'
        raise DecodeError(msg)
    return frame.frame_id, frame.stamp_ns, image


class DisparityTopic:
    """An input's truth topic: each message's place by (frame_id, stamp), read on first use."""

    def __init__(self, source: Source, topic: str, notes: list[str]) -> None:
        self.source = source
        self.topic = topic
        self.notes = notes
        self._index: dict[tuple[str, int], tuple[int, int]] | None = None

    def _indexed(self) -> dict[tuple[str, int], tuple[int, int]]:
        if self._index is None:
            index: dict[tuple[str, int], tuple[int, int]] = {}
            bad, first = 0, ''
            for raw in self.source.messages(topics=[self.topic]):
                try:
                    frame_id, stamp, _ = read_truth_message(raw)
                except DecodeError as err:
                    bad += 1
                    first = first or str(err)
                    continue
                index[(frame_id, stamp)] = (raw.log_time_ns, raw.seq)
            if bad:
                self.notes.append(f'{self.topic}: {bad} message(s) could not be read: {first}')
            self._index = index
        return self._index

    def lookup(self, frame_id: str, stamp_ns: int) -> npt.NDArray[np.float32] | None:
        """The truth of the left image (frame_id, stamp), or None."""
        found = self._indexed().get((frame_id, stamp_ns))
        if found is None:
            return None
        log_time, seq = found
        for raw in self.source.messages(
            topics=[self.topic], start_ns=log_time, end_ns=log_time + 1
        ):
            if raw.seq == seq:
                return read_truth_message(raw)[2]
        return None
