"""Disparity in outputs.mcap: per pair of a stereo backend, a ``stereo_msgs/msg/DisparityImage``
on ``/replaybench/<backend><left image topic>/disparity`` with the left image's header (32FC1,
no estimate written as ``min_disparity - 1``; ``replaybench.stereo.msgs``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.stereo.msgs import DISPARITY_IMAGE, serialize_disparity_image

if TYPE_CHECKING:
    from replaybench.sinks.writer import OutputWriter
    from replaybench.stereo.output import Disparity

__all__ = ['disparity_channel', 'write_disparity']


def disparity_channel(backend: str, image_topic: str) -> str:
    """>>> disparity_channel('sgbm', '/stereo/left/image_rect')
    '/replaybench/sgbm/stereo/left/image_rect/disparity'
    """
    topic = image_topic if image_topic.startswith('/') else f'/{image_topic}'
    return f'/replaybench/{backend.replace("-", "_")}{topic}/disparity'


def write_disparity(
    writer: OutputWriter,
    backend: str,
    image_topic: str,
    log_time_ns: int,
    stamp_ns: int,
    frame_id: str,
    disparity: Disparity,
) -> None:
    """The pair's DisparityImage, where the writer keeps messages."""
    if not writer.keeps:
        return
    data = serialize_disparity_image(
        stamp_ns,
        frame_id,
        disparity.disparity,
        f=disparity.f,
        t=disparity.t,
        min_disparity=disparity.min_disparity,
        max_disparity=disparity.max_disparity,
        delta_d=disparity.delta_d,
        valid_window=disparity.valid_window,
    )
    writer.add_message(disparity_channel(backend, image_topic), DISPARITY_IMAGE, log_time_ns, data)
