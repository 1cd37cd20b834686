"""Tag outputs in outputs.mcap: Isaac's AprilTagDetectionArray, TF, and image annotations.

Per processed frame of a tag backend (``TagResult``), beside its Detection2DArray:

* ``/replaybench/<backend><image topic>/tags``: ``isaac_ros_apriltag_interfaces/msg/
  AprilTagDetectionArray`` (the image's header; corners in the canonical order, pixel centres
  at integers; each pose in the camera's frame);
* ``/replaybench/<backend>/tf``: ``tf2_msgs/msg/TFMessage``, camera frame -> one child frame
  per tag with a pose, named as Isaac names them (``tag36h11:14``); one topic per backend, so
  that two backends' trees do not mix;
* with ``--annotations``, ``/replaybench/<backend><image topic>/tag_annotations``:
  ``foxglove_msgs/msg/ImageAnnotations``, each tag's corner polygon (a ``LINE_LOOP``) and its
  id, in Foxglove's pixel convention (origin at the top-left corner of the top-left pixel).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.fiducials.msgs import (
    APRILTAG_DETECTION_ARRAY,
    TF_MESSAGE,
    serialize_tag_array,
    serialize_tf,
)
from replaybench.msgs import IMAGE_ANNOTATIONS, typestore
from replaybench.sinks.annotations import FONT_SIZE, LINE_LOOP, THICKNESS, rgba

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.fiducials.types import TagDetection, TagResult
    from replaybench.sinks.writer import OutputWriter

__all__ = [
    'serialize_tag_annotations',
    'tag_annotations_channel',
    'tags_channel',
    'tf_channel',
    'write_tags',
]


def _base(backend: str, image_topic: str) -> str:
    topic = image_topic if image_topic.startswith('/') else f'/{image_topic}'
    return f'/replaybench/{backend.replace("-", "_")}{topic}'


def tags_channel(backend: str, image_topic: str) -> str:
    """>>> tags_channel('apriltag', '/camera/image_raw')
    '/replaybench/apriltag/camera/image_raw/tags'
    """
    return f'{_base(backend, image_topic)}/tags'


def tag_annotations_channel(backend: str, image_topic: str) -> str:
    """>>> tag_annotations_channel('aruco', '/camera/image_raw')
    '/replaybench/aruco/camera/image_raw/tag_annotations'
    """
    return f'{_base(backend, image_topic)}/tag_annotations'


def tf_channel(backend: str) -> str:
    """>>> tf_channel('apriltag')
    '/replaybench/apriltag/tf'
    """
    return f'/replaybench/{backend.replace("-", "_")}/tf'


def serialize_tag_annotations(stamp_ns: int, tags: Sequence[TagDetection], colour: str) -> bytes:
    """The ImageAnnotations of one frame's tags: corner polygon and ``family:id`` per tag."""
    store = typestore()
    t = store.types
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)

    def stamp() -> Any:
        return t['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)

    def col(rgba_: tuple[float, float, float, float]) -> Any:
        r, g, b, a = rgba_
        return t['foxglove_msgs/msg/Color'](r=r, g=g, b=b, a=a)

    point = t['foxglove_msgs/msg/Point2']
    outline = rgba(colour)
    points, texts = [], []
    for tag in tags:
        corners = [point(x=x + 0.5, y=y + 0.5) for x, y in tag.corners]
        points.append(
            t['foxglove_msgs/msg/PointsAnnotation'](
                timestamp=stamp(),
                type=LINE_LOOP,
                points=corners,
                outline_color=col(outline),
                outline_colors=[],
                fill_color=col((*outline[:3], 0.0)),
                thickness=THICKNESS,
                metadata=[],
            )
        )
        texts.append(
            t['foxglove_msgs/msg/TextAnnotation'](
                timestamp=stamp(),
                position=point(x=tag.center[0] + 0.5, y=tag.center[1] + 0.5),
                text=tag.label,
                font_size=FONT_SIZE,
                text_color=col((1.0, 1.0, 1.0, 1.0)),
                background_color=col(rgba(colour, 0.8)),
                metadata=[],
            )
        )
    message = t[IMAGE_ANNOTATIONS](
        timestamp=stamp(), circles=[], points=points, texts=texts, metadata=[]
    )
    return bytes(store.serialize_cdr(message, IMAGE_ANNOTATIONS))


def write_tags(
    writer: OutputWriter,
    backend: str,
    image_topic: str,
    log_time_ns: int,
    stamp_ns: int,
    frame_id: str,
    result: TagResult,
) -> None:
    """One frame's tag outputs into ``writer`` (none made for a writer that keeps nothing)."""
    if not writer.keeps:
        return
    camera_frame = result.camera_frame or frame_id
    writer.add_message(
        tags_channel(backend, image_topic),
        APRILTAG_DETECTION_ARRAY,
        log_time_ns,
        serialize_tag_array(stamp_ns, frame_id, result.tags, camera_frame),
    )
    if any(tag.pose is not None for tag in result.tags):
        writer.add_message(
            tf_channel(backend),
            TF_MESSAGE,
            log_time_ns,
            serialize_tf(stamp_ns, camera_frame, result.tags),
        )
    if writer.annotations:
        writer.add_message(
            tag_annotations_channel(backend, image_topic),
            IMAGE_ANNOTATIONS,
            log_time_ns,
            serialize_tag_annotations(stamp_ns, result.tags, writer.colour(backend)),
            annotation=True,
        )
