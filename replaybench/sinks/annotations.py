"""Foxglove image annotations of detections, for the Foxglove Image panel.

Each detection becomes a ``LINE_LOOP`` of its four box corners in the backend's colour and a
``label score`` text at the box's top-left corner, in one ``foxglove_msgs/msg/ImageAnnotations``
(ROS 2 CDR, the foxglove_msgs 3.4 layout: ``replaybench.msgs.FOXGLOVE_MSGS_ROS2``) per frame.
Coordinates are source-image pixels with the origin at the top-left corner of the top-left
pixel, as in ``Detection``; every timestamp (the message's and each annotation's) is the image's
header stamp, which is what the Image panel matches annotations to images by.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.colours import colour
from replaybench.msgs import IMAGE_ANNOTATIONS, typestore

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.types import Detection

__all__ = [
    'FONT_SIZE',
    'LINE_LOOP',
    'THICKNESS',
    'annotation_text',
    'annotations_channel',
    'backend_colour',
    'rgba',
    'serialize_image_annotations',
]

#: ``foxglove_msgs/msg/PointsAnnotation.LINE_LOOP``: a closed polygon.
LINE_LOOP = 2
#: Box outline thickness in pixels.
THICKNESS = 2.0
#: Label font size in pixels.
FONT_SIZE = 12.0
_TEXT_COLOUR = (1.0, 1.0, 1.0, 1.0)
_LABEL_ALPHA = 0.8


def annotations_channel(backend: str, image_topic: str) -> str:
    """Return the annotations topic of a backend on an image topic.

    >>> annotations_channel('yolo-nano', '/camera/image_raw')
    '/replaybench/yolo_nano/camera/image_raw/annotations'
    """
    topic = image_topic if image_topic.startswith('/') else f'/{image_topic}'
    # a tracked backend's + (hsv+sort) as _: ROS names hold letters, digits, _ and /
    name = backend.replace('-', '_').replace('+', '_')
    return f'/replaybench/{name}{topic}/annotations'


def backend_colour(index: int) -> str:
    """The colour (``#rrggbb``) of the ``index``-th backend: the report's palette colour."""
    return colour(index)


def rgba(hex_colour: str, alpha: float = 1.0) -> tuple[float, float, float, float]:
    """``#rrggbb`` as (r, g, b, a) floats in [0, 1]."""
    value = hex_colour.lstrip('#')
    if len(value) != 6:
        msg = f'not a #rrggbb colour: {hex_colour!r}'
        raise ValueError(msg)
    r, g, b = (int(value[i : i + 2], 16) / 255 for i in (0, 2, 4))
    return (r, g, b, float(alpha))


def annotation_text(det: Detection) -> str:
    """The text drawn next to a box: ``label score`` (score with two decimals), after the
    track's id where the box has one: ``#7 red 0.93``."""
    if det.id:
        return f'#{det.id} {det.label} {det.score:.2f}'
    return f'{det.label} {det.score:.2f}'


def serialize_image_annotations(
    stamp_ns: int,
    detections: Sequence[Detection],
    colour: str,
    *,
    thickness: float = THICKNESS,
    font_size: float = FONT_SIZE,
) -> bytes:
    """Serialise the ``foxglove_msgs/msg/ImageAnnotations`` (ROS 2 CDR) of one frame.

    Per detection: one ``PointsAnnotation`` (``LINE_LOOP`` through (x0, y0), (x1, y0),
    (x1, y1), (x0, y1), outline ``colour``, transparent fill) and one ``TextAnnotation``
    (``label score``, white on ``colour``) whose bottom-left corner sits on the box's top-left
    corner, or just inside the box when there is no room above it. No circles. An empty
    ``detections`` gives an empty message, which clears the previous frame's boxes. The
    message's own ``timestamp`` is the stamp too; every ``metadata`` is empty.
    """
    store = typestore()
    types = store.types
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    time_cls = types['builtin_interfaces/msg/Time']
    point_cls = types['foxglove_msgs/msg/Point2']
    colour_cls = types['foxglove_msgs/msg/Color']
    points_cls = types['foxglove_msgs/msg/PointsAnnotation']
    text_cls = types['foxglove_msgs/msg/TextAnnotation']

    def stamp() -> Any:
        return time_cls(sec=sec, nanosec=nanosec)

    def col(r: float, g: float, b: float, a: float) -> Any:
        return colour_cls(r=r, g=g, b=b, a=a)

    outline = rgba(colour)
    background = rgba(colour, _LABEL_ALPHA)
    points: list[Any] = []
    texts: list[Any] = []
    for det in detections:
        x0, y0, x1, y1 = float(det.x0), float(det.y0), float(det.x1), float(det.y1)
        corners = [point_cls(x=x, y=y) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))]
        points.append(
            points_cls(
                timestamp=stamp(),
                type=LINE_LOOP,
                points=corners,
                outline_color=col(*outline),
                outline_colors=[],
                fill_color=col(*outline[:3], 0.0),
                thickness=float(thickness),
                metadata=[],
            )
        )
        text_y = y0 if y0 >= font_size else y0 + font_size
        texts.append(
            text_cls(
                timestamp=stamp(),
                position=point_cls(x=x0, y=text_y),
                text=annotation_text(det),
                font_size=float(font_size),
                text_color=col(*_TEXT_COLOUR),
                background_color=col(*background),
                metadata=[],
            )
        )
    message = types[IMAGE_ANNOTATIONS](
        timestamp=stamp(), circles=[], points=points, texts=texts, metadata=[]
    )
    return bytes(store.serialize_cdr(message, IMAGE_ANNOTATIONS))
