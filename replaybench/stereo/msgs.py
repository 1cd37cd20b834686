"""``stereo_msgs/msg/DisparityImage``: written (ROS 2 CDR or ROS 1) and read back.

The fields as stereo_image_proc fills them: ``image`` a ``32FC1`` Image of the left camera's
disparity, with the left image's header; ``f`` the focal length (px) and ``t`` (ROS 1 ``T``)
the baseline; ``min_disparity``/``max_disparity`` the search range; ``delta_d`` the smallest
step (1/16 for OpenCV's matchers); ``valid_window`` the pixels that can hold a match. A
missing match is a value below ``min_disparity``: ``serialize_disparity_image`` writes NaN
pixels as ``min_disparity - 1``, the value stereo_image_proc's conversion gives OpenCV's
invalid pixels (before its principal-point offset). Types come from rosbags' ROS 2 Humble
and ROS 1 Noetic stores (``replaybench.msgs.typestore``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.errors import DecodeError
from replaybench.msgs import typestore

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    'DISPARITY_IMAGE',
    'DisparityMessage',
    'parse_disparity_image',
    'serialize_disparity_image',
]

DISPARITY_IMAGE = 'stereo_msgs/msg/DisparityImage'


@dataclass(frozen=True, slots=True)
class DisparityMessage:
    """A DisparityImage read back: ``disparity`` HxW float32 as the message holds it (values
    below ``min_disparity`` are no match); ``valid_window`` (x_offset, y_offset, height, width)."""

    stamp_ns: int
    frame_id: str
    disparity: npt.NDArray[np.float32]
    f: float
    t: float
    min_disparity: float
    max_disparity: float
    delta_d: float
    valid_window: tuple[int, int, int, int]


def serialize_disparity_image(
    stamp_ns: int,
    frame_id: str,
    disparity: npt.NDArray[np.floating[Any]],
    *,
    f: float,
    t: float,
    min_disparity: float,
    max_disparity: float,
    delta_d: float,
    valid_window: tuple[int, int, int, int] = (0, 0, 0, 0),
    ros1: bool = False,
) -> bytes:
    """Serialise a DisparityImage; NaN and inf pixels become ``min_disparity - 1``."""
    store = typestore(ros1)
    types = store.types
    values = np.asarray(disparity, dtype=np.float32)
    pixels = np.where(np.isfinite(values), values, np.float32(min_disparity - 1)).astype('<f4')
    height, width = int(pixels.shape[0]), int(pixels.shape[1])
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    time = types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)
    header = types['std_msgs/msg/Header'](
        **({'seq': 0} if ros1 else {}), stamp=time, frame_id=frame_id
    )
    image = types['sensor_msgs/msg/Image'](
        header=header,
        height=height,
        width=width,
        encoding='32FC1',
        is_bigendian=0,
        step=width * 4,
        data=np.ascontiguousarray(pixels).reshape(-1).view(np.uint8),
    )
    x, y, h, w = valid_window
    roi = types['sensor_msgs/msg/RegionOfInterest'](
        x_offset=x, y_offset=y, height=h, width=w, do_rectify=False
    )
    baseline = {'T' if ros1 else 't': float(t)}
    message = types[DISPARITY_IMAGE](
        header=header,
        image=image,
        f=float(f),
        valid_window=roi,
        min_disparity=float(min_disparity),
        max_disparity=float(max_disparity),
        delta_d=float(delta_d),
        **baseline,
    )
    if ros1:
        return bytes(store.serialize_ros1(message, DISPARITY_IMAGE))
    return bytes(store.serialize_cdr(message, DISPARITY_IMAGE))


def parse_disparity_image(data: bytes | memoryview, *, ros1: bool = False) -> DisparityMessage:
    """A DisparityImage's fields; ``DecodeError`` (one line) for one that is not 32FC1 or
    whose image data does not fill its size."""
    store = typestore(ros1)
    raw = bytes(data)
    try:
        message: Any = (
            store.deserialize_ros1(raw, DISPARITY_IMAGE)
            if ros1
            else store.deserialize_cdr(raw, DISPARITY_IMAGE)
        )
    except Exception as err:  # noqa: BLE001 - rosbags raises several kinds for bad bytes
        msg = f'not a {DISPARITY_IMAGE}: {type(err).__name__}: {err}'.splitlines()[0]
        raise DecodeError(msg) from None
    image = message.image
    if image.encoding != '32FC1':
        msg = f'a DisparityImage of encoding {image.encoding!r}, not 32FC1'
        raise DecodeError(msg)
    height, width, step = int(image.height), int(image.width), int(image.step)
    buffer = np.asarray(image.data, dtype=np.uint8)
    if step < width * 4 or buffer.size < step * height:
        msg = f'a DisparityImage of {width}x{height} with {buffer.size} bytes at step {step}'
        raise DecodeError(msg)
    dtype = np.dtype('>f4' if image.is_bigendian else '<f4')
    rows = buffer[: step * height].reshape(height, step)[:, : width * 4]
    disparity = np.ascontiguousarray(rows).view(dtype).reshape(height, width).astype(np.float32)
    roi = message.valid_window
    stamp = message.header.stamp
    return DisparityMessage(
        stamp_ns=int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec),
        frame_id=str(message.header.frame_id),
        disparity=disparity,
        f=float(message.f),
        t=float(message.T if ros1 else message.t),
        min_disparity=float(message.min_disparity),
        max_disparity=float(message.max_disparity),
        delta_d=float(message.delta_d),
        valid_window=(int(roi.x_offset), int(roi.y_offset), int(roi.height), int(roi.width)),
    )
