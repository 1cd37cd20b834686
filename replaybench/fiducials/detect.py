"""What the tag backends share: their options, grey conversion, and tags from raw corners.

A backend finds (family, id, corners in canonical order, score) per tag; ``TagAssembler``
keeps at most ``max_tags`` of them, solves each pose from the frame's CameraInfo, and builds the
``TagResult`` (one Detection2D-compatible box per tag besides the tags).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replaybench.errors import BackendError, DecodeError, UsageError
from replaybench.fiducials.bagsizes import BAG_SIZE_KEYS
from replaybench.fiducials.camera import camera_model
from replaybench.fiducials.pose import (
    DEFAULT_TAG_SIZE,
    TagSizes,
    parse_tag_sizes,
    solve_tag_pose,
)
from replaybench.fiducials.types import TagDetection, TagResult, tag_box

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    import numpy.typing as npt

    from replaybench.fiducials.camera import CameraModel
    from replaybench.fiducials.types import Corners
    from replaybench.types import CameraInfo, Detection, Frame, StageTimes

__all__ = [
    'DEFAULT_FAMILY',
    'DEFAULT_MAX_TAGS',
    'TAG_OPTION_KEYS',
    'RawTag',
    'TagAssembler',
    'TagOptions',
    'gray8',
    'tag_extra',
    'tag_options',
]

#: Isaac ROS apriltag's defaults: family tag36h11, at most 64 tags a frame.
DEFAULT_FAMILY = 'tag36h11'
DEFAULT_MAX_TAGS = 64

#: ``BackendOptions.extra`` keys (and ``--config`` TOML keys) of the tag backends.
TAG_OPTION_KEYS = ('family', 'tag_size', 'tag_sizes', 'decimation', 'max_tags', 'refine')


@dataclass(frozen=True, slots=True)
class TagOptions:
    """A tag backend's configuration (docs/fiducials.md)."""

    family: str = DEFAULT_FAMILY
    sizes: TagSizes = field(default_factory=TagSizes)
    decimation: float = 2.0
    max_tags: int = DEFAULT_MAX_TAGS
    threads: int = 1
    refine: str = 'apriltag'
    #: where ``sizes`` came from: the run's options, the bag's metadata or the default
    sizes_from: str = 'the default'

    def describe(self) -> dict[str, Any]:
        """The options as run.json records them."""
        return {
            'family': self.family,
            'tag_size_m': self.sizes.default,
            'tag_sizes_m': {str(k): v for k, v in sorted(self.sizes.per_id.items())},
            'decimation': self.decimation,
            'max_tags': self.max_tags,
            'threads': self.threads,
            'refine': self.refine,
            'tag_sizes_from': self.sizes_from,
        }


def _from_toml(path: Any, backend: str) -> dict[str, str]:
    import tomllib

    try:
        with Path(path).open('rb') as file:
            table = tomllib.load(file)
    except OSError as err:
        msg = f'{backend}: cannot read --config {path}: {err.strerror or err}'
        raise BackendError(msg) from err
    except tomllib.TOMLDecodeError as err:
        msg = f'{backend}: --config {path} is not valid TOML: {err}'
        raise BackendError(msg) from err
    out: dict[str, str] = {}
    for key, value in table.items():
        if key == 'tag_sizes' and isinstance(value, dict):
            out[key] = ','.join(f'{k}={v}' for k, v in value.items())
        else:
            out[key] = str(value)
    return out


def tag_options(
    backend: str,
    extra: Mapping[str, str],
    *,
    threads: int | None = None,
    config: Any = None,
    families: Iterable[str] = (),
    refinements: Iterable[str] = ('apriltag',),
    decimation: float = 2.0,
    decimation_refine: str | None = None,
) -> TagOptions:
    """TagOptions from a ``--config`` TOML file and ``extra`` (which wins), checked; a
    ``BackendError`` naming the backend and the key for a value that does not fit.
    ``decimation``: the library's own default (AprilTag 3: 2; OpenCV's ArUco: 1, none);
    ``decimation_refine``: the one refinement that decimation acts in, where the detector
    uses it in one only (ArUco: ``apriltag``), so that a decimation given with another is
    refused rather than silently ignored."""
    bag = {k: str(v) for k, v in extra.items() if k in BAG_SIZE_KEYS}
    given = _from_toml(config, backend) if config is not None else {}
    given.update({k: v for k, v in extra.items() if k not in BAG_SIZE_KEYS})
    unknown = sorted(set(given) - set(TAG_OPTION_KEYS))
    if unknown:
        msg = f'{backend}: unknown option {unknown[0]!r} (known: {", ".join(TAG_OPTION_KEYS)})'
        raise BackendError(msg)
    family = given.get('family', DEFAULT_FAMILY).strip()
    known = tuple(families)
    if known and family not in known:
        msg = f'{backend}: unknown tag family {family!r} (known: {", ".join(known)})'
        raise BackendError(msg)
    sizes, sizes_from = _sizes(backend, given, bag)
    default_decimation = decimation
    decimation = _number(backend, 'decimation', given.get('decimation', str(default_decimation)))
    if not decimation >= 1:
        msg = f'{backend}: decimation must be >= 1, got {given["decimation"]!r}'
        raise BackendError(msg)
    max_tags = _number(backend, 'max_tags', given.get('max_tags', str(DEFAULT_MAX_TAGS)))
    if max_tags != int(max_tags) or max_tags < 1:
        msg = f'{backend}: max_tags must be an integer >= 1, got {given["max_tags"]!r}'
        raise BackendError(msg)
    refine = given.get('refine', next(iter(refinements), 'apriltag')).strip().lower()
    allowed = tuple(refinements)
    if refine not in allowed:
        msg = (
            f'{backend}: refine (--tag-refine) must be one of {", ".join(allowed)}, got {refine!r}'
        )
        raise BackendError(msg)
    if (
        decimation_refine is not None
        and refine != decimation_refine
        and 'decimation' in given
        and decimation > 1
    ):
        msg = (
            f'{backend}: decimation (--tag-decimation) acts with refine {decimation_refine!r} '
            f'only, and refine is {refine!r}: add --tag-refine {decimation_refine} or drop it'
        )
        raise BackendError(msg)
    return TagOptions(
        family, sizes, decimation, int(max_tags), max(1, threads or 1), refine, sizes_from
    )


def _sizes(backend: str, given: Mapping[str, str], bag: Mapping[str, str]) -> tuple[TagSizes, str]:
    """The tag sizes and where they came from: the options (``tag_size`` / ``tag_sizes``
    given), else the bag's ``replaybench.tags`` metadata (``bag_*`` keys the run filled in),
    else the default; a ``BackendError`` for sizes that do not parse, or inputs that record
    different ones when the options give none."""
    try:
        if 'tag_size' in given or 'tag_sizes' in given:
            sizes = parse_tag_sizes(given.get('tag_size'), given.get('tag_sizes'))
            return sizes, 'the options (--tag-size / --tag-sizes)'
        if 'bag_sizes_conflict' in bag:
            msg = f'{bag["bag_sizes_conflict"]}: give --tag-size / --tag-sizes'
            raise BackendError(msg)
        if 'bag_tag_size' in bag or 'bag_tag_sizes' in bag:
            sizes = parse_tag_sizes(bag.get('bag_tag_size') or None, bag.get('bag_tag_sizes'))
            return sizes, f'the bag ({bag.get("bag_sizes_from", "its metadata")})'
    except UsageError as err:
        msg = f'{backend}: {err}'
        raise BackendError(msg) from None
    why = bag.get('bag_sizes_from')
    default = f'the default ({DEFAULT_TAG_SIZE:g} m)'
    return TagSizes(), f'{default}: {why}' if why else default


def tag_extra(
    *,
    family: str | None = None,
    tag_size: float | None = None,
    tag_sizes: str | None = None,
    decimation: float | None = None,
    max_tags: int | None = None,
    refine: str | None = None,
) -> dict[str, str]:
    """The ``BackendOptions.extra`` of the command line's tag options (those given)."""
    given = {
        'family': family,
        'tag_size': tag_size,
        'tag_sizes': tag_sizes,
        'decimation': decimation,
        'max_tags': max_tags,
        'refine': refine,
    }
    return {key: str(value) for key, value in given.items() if value is not None}


def _number(backend: str, key: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        msg = f'{backend}: {key} must be a number, got {text!r}'
        raise BackendError(msg)
    return value


def gray8(image: npt.NDArray[Any], encoding: str) -> npt.NDArray[np.uint8]:
    """A frame's image as a contiguous HxW uint8 grey image (what tag detectors read)."""
    import cv2

    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if encoding == 'mono8' and image.dtype == np.uint8:
        return np.ascontiguousarray(image)
    codes = {
        'rgb8': cv2.COLOR_RGB2GRAY,
        'bgr8': cv2.COLOR_BGR2GRAY,
        'rgba8': cv2.COLOR_RGBA2GRAY,
        'bgra8': cv2.COLOR_BGRA2GRAY,
    }
    if encoding in codes:
        return np.asarray(cv2.cvtColor(image, codes[encoding]), dtype=np.uint8)
    from replaybench.decode import to_bgr8

    bgr = to_bgr8(image, encoding)
    return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), dtype=np.uint8)


class RawTag(NamedTuple):
    """A tag as a detector finds it: id, corners (canonical order, source pixels), score."""

    tag_id: int
    corners: Corners
    score: float = 1.0


class TagAssembler:
    """Turns a frame's raw tags into its ``TagResult``: at most ``max_tags`` (highest score
    first, then id), poses from the frame's CameraInfo, boxes for Detection2DArray consumers.

    The camera model of each CameraInfo is made once (kept by the message's identity).
    """

    def __init__(self, options: TagOptions) -> None:
        self.options = options
        self._models: dict[int, tuple[CameraInfo, CameraModel | str]] = {}
        self.frames_without_pose = 0

    def _camera(self, info: CameraInfo | None, topic: str) -> CameraModel | str:
        if info is None:
            return f'{topic}: no CameraInfo for this image topic: tag corners and ids only, no pose'
        found = self._models.get(id(info))
        if found is not None and found[0] is info:
            return found[1]
        try:
            model: CameraModel | str = camera_model(info)
        except DecodeError as err:
            model = f'{topic}: {err}: tag corners and ids only, no pose'
        if len(self._models) > 256:
            self._models.clear()
        self._models[id(info)] = (info, model)
        return model

    def result(self, frame: Frame, raw: Iterable[RawTag], stages: StageTimes) -> TagResult:
        """The frame's TagResult; ``stages.postprocess_ns`` is filled in with the pose time."""
        import time

        t0 = time.perf_counter_ns()
        options = self.options
        found = sorted(raw, key=lambda t: (-t.score, t.tag_id, t.corners))[: options.max_tags]
        found.sort(key=lambda t: (t.tag_id, t.corners))
        camera = self._camera(frame.camera_info, frame.topic) if found else ''
        note = camera if isinstance(camera, str) else ''
        tags: list[TagDetection] = []
        boxes: list[Detection] = []
        for tag in found:
            pts = np.asarray(tag.corners, dtype=np.float64)
            size = options.sizes.size(tag.tag_id)
            pose = None if isinstance(camera, str) else solve_tag_pose(pts, size, camera)
            cx, cy = (float(v) for v in pts.mean(axis=0))
            detection = TagDetection(
                options.family, tag.tag_id, (cx, cy), tag.corners, pose, size, tag.score
            )
            tags.append(detection)
            boxes.append(tag_box(detection))
        if note:
            self.frames_without_pose += 1
        frame_id = '' if isinstance(camera, str) else camera.frame_id or frame.frame_id
        stages = stages._replace(postprocess_ns=time.perf_counter_ns() - t0)
        return TagResult(tuple(boxes), stages, tags=tuple(tags), camera_frame=frame_id, note=note)
