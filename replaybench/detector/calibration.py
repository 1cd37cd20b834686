"""The frames a model is calibrated on: spread evenly over a bag, never one held out.

``replaybench quantize`` (ONNX Runtime's calibration) and ``tensorrt --precision int8`` (a
TensorRT calibration cache) take the same frames for the same bag, ``frames`` and
``holdout``: ``frames`` image messages of the selected topics (default: every non-depth image
topic but the ground truth's, ``/ground_truth/...``), in replay order, at evenly spaced
positions, leaving out every message whose log time falls in a held-out window (seconds from
the bag's first message).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from replaybench.errors import ReplaybenchError

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from replaybench.types import Frame

__all__ = ['Calibration', 'QuantizeError', 'calibration_frames', 'calibration_pairs']


#: Image topics under this prefix are ground truth (label masks), no camera.
TRUTH_PREFIX = '/ground_truth/'


class QuantizeError(ReplaybenchError):
    """A model, a bag or an ``--out`` that calibration cannot use (exit 2)."""


@dataclass(frozen=True, slots=True)
class Calibration:
    """The frames picked for calibration and where they came from."""

    frames: tuple[Frame, ...]
    topics: tuple[str, ...]
    available: int


def _pick(count: int, wanted: int) -> list[int]:
    """``wanted`` indices spread evenly over ``range(count)`` (all of them when fewer)."""
    if wanted >= count:
        return list(range(count))
    if wanted == 1:
        return [count // 2]
    return sorted({round(i * (count - 1) / (wanted - 1)) for i in range(wanted)})


def calibration_frames(
    bag: Path,
    frames: int,
    *,
    topics: Sequence[str] = (),
    holdout: Sequence[tuple[float, float | None]] = (),
) -> Calibration:
    """``frames`` decoded frames spread evenly over ``bag``'s image topics (default: every
    non-depth image topic), none of them in a held-out window."""
    from replaybench.decode import decode_image, probe_topics
    from replaybench.sources import open_source

    with open_source(bag) as source:
        cameras = probe_topics(source)
        if topics:
            known = {c.name for c in cameras}
            missing = [t for t in topics if t not in known]
            if missing:
                names = ', '.join(sorted(known)) or 'none'
                msg = f'{bag}: no image topic {missing[0]!r} (image topics: {names})'
                raise QuantizeError(msg)
            chosen = list(topics)
        else:
            chosen = [
                c.name
                for c in cameras
                if not c.is_depth and not c.error and not c.name.startswith(TRUTH_PREFIX)
            ]
        if not chosen:
            msg = f'{bag}: no colour or mono image topic to calibrate on'
            raise QuantizeError(msg)
        first = min((t.first_ns for t in source.topics()), default=0)
        windows = [
            (first + int(s * 1e9), None if e is None else first + int(e * 1e9)) for s, e in holdout
        ]

        def held(log_ns: int) -> bool:
            return any(log_ns >= s and (e is None or log_ns < e) for s, e in windows)

        # two passes: log times first, then only the picked messages decoded (a long bag's
        # messages are never all held at once)
        times = [m.log_time_ns for m in source.messages(topics=chosen)]
        eligible = [i for i, t in enumerate(times) if not held(t)]
        wanted = {eligible[j] for j in _pick(len(eligible), frames)}
        picked = []
        for i, raw in enumerate(source.messages(topics=chosen)):
            if i in wanted:
                frame = decode_image(raw)  # its image may be a view into the open file
                picked.append(frame._replace(image=np.array(frame.image)))
    if not picked:
        msg = f'{bag}: no frame left to calibrate on outside the --holdout windows'
        raise QuantizeError(msg)
    return Calibration(tuple(picked), tuple(chosen), len(eligible))


def calibration_pairs(
    bag: Path,
    frames: int,
    topics: Sequence[str],
    *,
    holdout: Sequence[tuple[float, float | None]] = (),
) -> Calibration:
    """``frames`` stereo pairs (left, right: ``topics`` in that order, paired by equal header
    stamps, each frame with its CameraInfo), spread evenly over the pairs outside the held-out
    windows; ``Calibration.frames`` holds them flat, left then right."""
    from replaybench.decode import CameraInfoIndex, camera_info_topic_for, decode_image
    from replaybench.decode.image import image_stamp
    from replaybench.decode.kinds import message_kind
    from replaybench.sources import open_source

    if len(topics) != 2 or topics[0] == topics[1]:
        msg = f'{bag}: a stereo model calibrates on two topics: --topic LEFT --topic RIGHT'
        raise QuantizeError(msg)
    with open_source(bag) as source:
        names = [t.name for t in source.topics()]
        info_topics = [t.name for t in source.topics() if message_kind(t.msgtype) == 'camera_info']
        missing = [t for t in topics if t not in names]
        if missing:
            msg = f'{bag}: no image topic {missing[0]!r}'
            raise QuantizeError(msg)
        first = min((t.first_ns for t in source.topics()), default=0)
        windows = [
            (first + int(s * 1e9), None if e is None else first + int(e * 1e9)) for s, e in holdout
        ]
        stamps: dict[str, dict[int, int]] = {t: {} for t in topics}
        for i, raw in enumerate(source.messages(topics=topics)):
            held = any(
                raw.log_time_ns >= s and (e is None or raw.log_time_ns < e) for s, e in windows
            )
            if not held:
                stamps[raw.topic].setdefault(image_stamp(raw), i)
        common = sorted(set(stamps[topics[0]]) & set(stamps[topics[1]]))
        chosen = [common[j] for j in _pick(len(common), frames)]
        wanted = {stamps[t][stamp] for stamp in chosen for t in topics}
        image_topics = [t for t in names if t in topics]
        infos = CameraInfoIndex.from_source(
            source,
            [
                found
                for t in topics
                if (found := camera_info_topic_for(t, info_topics, image_topics)) is not None
            ],
        )
        decoded: dict[tuple[str, int], Frame] = {}
        for i, raw in enumerate(source.messages(topics=topics)):
            if i in wanted:
                frame = decode_image(raw)
                frame = frame._replace(
                    image=np.array(frame.image),
                    camera_info=infos.lookup(frame.topic, frame.stamp_ns),
                )
                decoded[(frame.topic, frame.stamp_ns)] = frame
    picked = tuple(decoded[(t, stamp)] for stamp in chosen for t in topics)
    if not picked:
        msg = f'{bag}: no stereo pair (equal stamps) to calibrate on outside the --holdout windows'
        raise QuantizeError(msg)
    return Calibration(picked, tuple(topics), len(common))
