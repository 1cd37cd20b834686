"""Label masks into outputs.mcap: ``sensor_msgs/msg/Image`` per frame, for Foxglove and ROS.

For each frame a segmentation backend labels, ``labels_channel(backend, image_topic)`` gets a
``mono8`` Image of the class ids (0..255, the frame's size) with the source frame's header
(stamp and frame_id); with annotations, ``labels_colour_channel`` also gets an ``rgb8`` Image
of the same mask through ``replaybench.segmentation.palette`` (Foxglove overlays it on the
camera image). The class names of each backend go into an MCAP metadata record
``replaybench.segmentation`` (``<backend>``: a JSON list of names by id). Serialising
happens when the engine records a frame, after the timed pass, never between timed frames.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

from replaybench.msgs import IMAGE, serialize_image

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy as np
    import numpy.typing as npt

    from replaybench.sinks.writer import OutputWriter

__all__ = [
    'METADATA_NAME',
    'add_mask',
    'labels_channel',
    'labels_colour_channel',
    'write_class_names',
]

#: Name of the MCAP metadata record holding the class names of each backend.
METADATA_NAME = 'replaybench.segmentation'


def _base(backend: str, image_topic: str) -> str:
    topic = image_topic if image_topic.startswith('/') else f'/{image_topic}'
    return f'/replaybench/{backend.replace("-", "_")}{topic}'


def labels_channel(backend: str, image_topic: str) -> str:
    """The mono8 class-id topic of a backend on an image topic.

    >>> labels_channel('hsv-seg', '/camera/image_raw')
    '/replaybench/hsv_seg/camera/image_raw/labels'
    """
    return f'{_base(backend, image_topic)}/labels'


def labels_colour_channel(backend: str, image_topic: str) -> str:
    """The rgb8 colour-mapped mask topic (with annotations).

    >>> labels_colour_channel('hsv-seg', '/camera/image_raw')
    '/replaybench/hsv_seg/camera/image_raw/labels_rgb'
    """
    return f'{_base(backend, image_topic)}/labels_rgb'


def add_mask(
    writer: OutputWriter,
    backend: str,
    image_topic: str,
    log_time_ns: int,
    stamp_ns: int,
    frame_id: str,
    labels: npt.NDArray[np.uint8],
) -> None:
    """Stage one frame's mask (and its rgb8 picture when the writer writes annotations);
    none made for a writer that keeps nothing."""
    if not writer.keeps:
        return
    data = serialize_image(stamp_ns, frame_id, labels, 'mono8')
    writer.add_message(labels_channel(backend, image_topic), IMAGE, log_time_ns, data)
    if writer.annotations:
        from replaybench.segmentation.palette import colourise

        picture = serialize_image(stamp_ns, frame_id, colourise(labels), 'rgb8')
        writer.add_message(
            labels_colour_channel(backend, image_topic),
            IMAGE,
            log_time_ns,
            picture,
            annotation=True,
        )


def write_class_names(writer: OutputWriter, names: Mapping[str, Sequence[str]]) -> None:
    """The ``replaybench.segmentation`` metadata record: backend -> JSON list of class names."""
    if names:
        record = {backend: json.dumps(list(n)) for backend, n in sorted(names.items())}
        writer.add_metadata(METADATA_NAME, record)
