"""Stereo pairs of image topics, by ``stereo_image_proc``'s naming or ``--stereo LEFT,RIGHT``.

``stereo_image_proc`` subscribes ``left/image_rect`` and ``right/image_rect`` (rectified; the
``_color`` variants are image_proc's colour outputs) or, for the whole pipeline,
``left/image_raw`` and ``right/image_raw``, each beside its ``camera_info`` in the same
namespace. ``find_pairs`` pairs the topics of a bag the same way: ``NS/left/NAME`` with
``NS/right/NAME`` for NAME one of ``STEREO_IMAGE_NAMES``, preferring, in one namespace, the
rectified images (``image_rect``, then ``image_rect_color``) over the raw ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from replaybench.errors import StereoError

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = [
    'STEREO_IMAGE_NAMES',
    'StereoTopics',
    'camera_info_topic',
    'find_pairs',
    'pair_by_name',
    'parse_stereo',
]

#: The image names of stereo_image_proc, best first: whether each is rectified.
STEREO_IMAGE_NAMES: dict[str, bool] = {
    'image_rect': True,
    'image_rect_color': True,
    'image_raw': False,
}


@dataclass(frozen=True, slots=True)
class StereoTopics:
    """A left and a right image topic; ``rectified``: True, False or None (not known from
    the names, for a ``--stereo`` pair not named as stereo_image_proc names them)."""

    left: str
    right: str
    rectified: bool | None

    @property
    def left_info(self) -> str:
        return camera_info_topic(self.left)

    @property
    def right_info(self) -> str:
        return camera_info_topic(self.right)


def camera_info_topic(image_topic: str) -> str:
    """The CameraInfo topic beside an image topic, as image_transport names it.

    >>> camera_info_topic('/stereo/left/image_rect')
    '/stereo/left/camera_info'
    >>> camera_info_topic('/stereo/left/image_raw/compressed')
    '/stereo/left/camera_info'
    """
    parts = image_topic.rstrip('/').split('/')
    if len(parts) > 2 and parts[-1] in {'compressed', 'compressedDepth', 'theora', 'zstd'}:
        parts = parts[:-1]
    return '/'.join([*parts[:-1], 'camera_info'])


def _split(topic: str) -> tuple[str, str, str] | None:
    """(namespace, side, image name) of ``NS/left/NAME`` or ``NS/right/NAME``."""
    parts = topic.split('/')
    if len(parts) < 2 or parts[-1] not in STEREO_IMAGE_NAMES or parts[-2] not in {'left', 'right'}:
        return None
    return '/'.join(parts[:-2]), parts[-2], parts[-1]


def find_pairs(topics: Iterable[str]) -> list[StereoTopics]:
    """The stereo pairs among ``topics``, one per namespace (its best-named images), in the
    order of the namespaces' first topic."""
    names = list(dict.fromkeys(topics))
    present = set(names)
    found: dict[str, StereoTopics] = {}
    for topic in names:
        split = _split(topic)
        if split is None:
            continue
        namespace, _, _ = split
        if namespace in found:
            continue
        for name, rectified in STEREO_IMAGE_NAMES.items():
            left, right = f'{namespace}/left/{name}', f'{namespace}/right/{name}'
            if left in present and right in present:
                found[namespace] = StereoTopics(left, right, rectified)
                break
    return list(found.values())


def pair_by_name(topics: Iterable[str]) -> tuple[tuple[str, ...], str | None]:
    """The stereo pair to replay of an input's camera ``topics`` by their names (left, right),
    the first of several with a note naming the others; ``topics`` as they are, without a
    note, where the names make no pair (a stereo backend's ``frame_set_topics``).

    >>> pair_by_name(['/front/image_raw', '/s/right/image_rect', '/s/left/image_rect'])
    (('/s/left/image_rect', '/s/right/image_rect'), None)
    """
    names = tuple(dict.fromkeys(topics))
    pairs = find_pairs(names)
    if not pairs:
        return names, None
    pair, note = pairs[0], None
    if len(pairs) > 1:
        others = '; '.join(f'{p.left},{p.right}' for p in pairs[1:])
        note = (
            f'{len(pairs)} stereo pairs by name; replayed {pair.left},{pair.right} (the '
            f'first), not {others}: --stereo LEFT,RIGHT chooses'
        )
    return (pair.left, pair.right), note


def parse_stereo(text: str, topics: Iterable[str] | None = None) -> StereoTopics:
    """``--stereo LEFT,RIGHT``: two image topics, checked against ``topics`` where given;
    ``StereoError`` (one line) for anything else.

    >>> parse_stereo('/cam/left/image_rect,/cam/right/image_rect')
    StereoTopics(left='/cam/left/image_rect', right='/cam/right/image_rect', rectified=True)
    """
    parts = [p.strip() for p in text.split(',')]
    if len(parts) != 2 or not all(parts):
        msg = f'invalid --stereo {text!r}: give two image topics, LEFT,RIGHT'
        raise StereoError(msg)
    left, right = parts
    if left == right:
        msg = f'invalid --stereo {text!r}: the left and right topics are the same'
        raise StereoError(msg)
    if topics is not None:
        known = set(topics)
        missing = [t for t in (left, right) if t not in known]
        if missing:
            msg = f'--stereo names {", ".join(missing)}, not an image topic of the input'
            raise StereoError(msg)
    split_left, split_right = _split(left), _split(right)
    rectified = None
    if split_left is not None and split_right is not None and split_left[2] == split_right[2]:
        rectified = STEREO_IMAGE_NAMES[split_left[2]]
    return StereoTopics(left, right, rectified)
