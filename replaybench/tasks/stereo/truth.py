"""The stereo task's ground truth: the left image's disparity per pair.

- A topic (``--ground-truth-disparity TOPIC``, default ``/ground_truth/disparity``): a
  ``32FC1`` ``sensor_msgs/Image`` of the left image's disparity in pixels (the stereo
  fixture's) or a ``stereo_msgs/DisparityImage``, matched to a pair by the left image's
  frame_id and header stamp (``DisparityTopic``).
- A folder (``--ground-truth-disparity DIR``): Middlebury ``.pfm`` or KITTI 16-bit ``.png``
  files named ``<stamp_ns>.pfm`` / ``.png`` by the left image's header stamp in nanoseconds
  (``DisparityFolder``), serving every input.
- A depth topic (``--ground-truth-depth TOPIC``): a depth Image of the left rectified image,
  ``32FC1`` in metres or ``16UC1`` in millimetres (REP 118), matched as a disparity topic is
  and converted to disparity with the focal length and baseline of the output it scores
  (``DepthTopic``, ``depth_to_disparity``).

0, NaN and inf are unknown (``replaybench.stereo.metrics.known_truth``). A topic is indexed
when its first pair is scored (after the pass) and each truth read again when its pair is
scored.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from replaybench.errors import DecodeError, UsageError

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from replaybench.sources import Source
    from replaybench.types import RawMessage

__all__ = [
    'DepthTopic',
    'DisparityFolder',
    'DisparityTopic',
    'depth_to_disparity',
    'read_depth_message',
    'read_truth_message',
]


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


def read_depth_message(raw: RawMessage) -> tuple[str, int, npt.NDArray[np.float32]]:
    """(frame_id, stamp_ns, depth in metres) of a depth Image: ``32FC1`` metres or ``16UC1``
    millimetres (0 unknown); ``DecodeError`` for another encoding."""
    from replaybench.decode import decode_image

    frame = decode_image(raw)
    image = np.asarray(frame.image)
    if image.ndim == 2 and image.dtype == np.float32:
        return frame.frame_id, frame.stamp_ns, image
    if image.ndim == 2 and image.dtype == np.uint16:
        metres = np.where(image > 0, image.astype(np.float32) / 1000.0, np.nan)
        return frame.frame_id, frame.stamp_ns, metres.astype(np.float32)
    msg = f'{raw.topic}: truth depth of encoding {frame.source_encoding}, not 32FC1 or 16UC1'
    raise DecodeError(msg)


def depth_to_disparity(
    depth: npt.NDArray[np.float32], f: float, baseline: float, cx_offset: float = 0.0
) -> npt.NDArray[np.float32]:
    """Disparity in pixels of depth ``depth`` (the baseline's unit): ``f * B / z + cx_offset``,
    the inverse of ``Disparity.depth``; NaN where the depth is unknown (0, NaN, inf) or <= 0."""
    z = np.asarray(depth, dtype=np.float64)
    with np.errstate(divide='ignore', invalid='ignore'):
        d = np.where(np.isfinite(z) & (z > 0), f * baseline / z + cx_offset, np.nan)
    return d.astype(np.float32)


class DisparityTopic:
    """An input's truth topic: each message's place by (frame_id, stamp), read on first use;
    ``depth``: the messages are depth images (``read_depth_message``), not disparities."""

    def __init__(
        self, source: Source, topic: str, notes: list[str], *, depth: bool = False
    ) -> None:
        self.source = source
        self.topic = topic
        self.notes = notes
        self.depth = depth
        self._read = read_depth_message if depth else read_truth_message
        self._index: dict[tuple[str, int], tuple[int, int]] | None = None

    def _indexed(self) -> dict[tuple[str, int], tuple[int, int]]:
        if self._index is None:
            index: dict[tuple[str, int], tuple[int, int]] = {}
            bad, first = 0, ''
            for raw in self.source.messages(topics=[self.topic]):
                try:
                    frame_id, stamp, _ = self._read(raw)
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
                return self._read(raw)[2]
        return None


class DepthTopic(DisparityTopic):
    """A depth Image topic of the left rectified image (``--ground-truth-depth``)."""

    def __init__(self, source: Source, topic: str, notes: list[str]) -> None:
        super().__init__(source, topic, notes, depth=True)


class DisparityFolder:
    """Truth disparities as ``<stamp_ns>.pfm`` / ``<stamp_ns>.png`` files (Middlebury, KITTI;
    ``replaybench.stereo.files``), by the left image's stamp; ``UsageError`` for a folder
    without any, or with a stamp named by both a .pfm and a .png file."""

    depth = False

    def __init__(self, path: Path) -> None:
        self.path = path
        files: dict[int, Path] = {}
        for p in sorted(path.iterdir()):
            if p.suffix.lower() not in {'.pfm', '.png'} or not p.stem.isdigit():
                continue
            stamp = int(p.stem)
            if stamp in files:
                msg = f'{path}: two truth files for stamp {stamp}: {files[stamp].name}, {p.name}'
                raise UsageError(msg)
            files[stamp] = p
        if not files:
            msg = f'{path}: no ground-truth disparity (<stamp_ns>.pfm or .png) in this folder'
            raise UsageError(msg)
        self.files = files

    def lookup(self, frame_id: str, stamp_ns: int) -> npt.NDArray[np.float32] | None:
        """The disparity file of the left image's stamp, read (a bad file: ``StereoError``)."""
        from replaybench.stereo.files import read_disparity_file

        del frame_id  # one folder serves every input
        path = self.files.get(stamp_ns)
        return None if path is None else read_disparity_file(path)
