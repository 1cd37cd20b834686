"""Disparity in outputs.mcap: per pair of a stereo backend, a ``stereo_msgs/msg/DisparityImage``
on ``/replaybench/<backend><left image topic>/disparity`` with the left image's header (32FC1,
no estimate written as ``min_disparity - 1``; ``replaybench.stereo.msgs``); with ``--depth``
also a ``sensor_msgs/msg/Image`` on ``.../depth``: 32FC1 depth in metres (the baseline's unit,
``Disparity.depth``), NaN without an estimate (REP 118), where the output has a focal length
and a baseline."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.stereo.msgs import DISPARITY_IMAGE, serialize_disparity_image

if TYPE_CHECKING:
    from replaybench.sinks.writer import OutputWriter
    from replaybench.stereo.output import Disparity

__all__ = ['depth_channel', 'disparity_channel', 'write_disparity']


def disparity_channel(backend: str, image_topic: str) -> str:
    """>>> disparity_channel('sgbm', '/stereo/left/image_rect')
    '/replaybench/sgbm/stereo/left/image_rect/disparity'
    """
    topic = image_topic if image_topic.startswith('/') else f'/{image_topic}'
    return f'/replaybench/{backend.replace("-", "_")}{topic}/disparity'


def depth_channel(backend: str, image_topic: str) -> str:
    """>>> depth_channel('sgbm', '/stereo/left/image_rect')
    '/replaybench/sgbm/stereo/left/image_rect/depth'
    """
    return disparity_channel(backend, image_topic).removesuffix('/disparity') + '/depth'


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
    if writer.depth and disparity.f > 0 and disparity.t > 0:
        from replaybench.msgs import IMAGE, serialize_image

        depth = serialize_image(stamp_ns, frame_id, disparity.depth(), '32FC1')
        writer.add_message(depth_channel(backend, image_topic), IMAGE, log_time_ns, depth)
