"""RawMessage -> Frame, for sensor_msgs Image / CompressedImage and Foxglove images.

``decode_image`` returns the ``Frame`` a backend receives (the replay attaches camera info):
one object per message. Raw images in CDR and ROS 1 are read by hand and returned as
read-only views into the message buffer (padded rows become a strided view). Only
byte-swapping, unaligned 16/32-bit data and encodings outside ``types.CANONICAL_ENCODINGS``
(Bayer, YUV, 8UCn) produce a new array.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np

from replaybench.decode._wire import as_bytes_view, parse_compressed, parse_image, parse_stamp
from replaybench.decode.compressed import decode_compressed
from replaybench.decode.encodings import check_dimensions, lookup
from replaybench.decode.kinds import message_kind
from replaybench.errors import DecodeError
from replaybench.types import Frame

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.types import RawMessage

__all__ = ['decode_image', 'image_header', 'image_stamp', 'raw_image_array', 'to_bgr8']


def raw_image_array(
    buf: memoryview,
    offset: int,
    size: int,
    *,
    width: int,
    height: int,
    step: int,
    encoding: str,
    is_bigendian: bool,
) -> tuple[npt.NDArray[Any], str, bool]:
    """The pixels of a raw image as (array, canonical encoding, is_depth).

    Everything is validated before any array is made. Canonical encodings give a read-only
    view of ``buf``; ``is_bigendian`` only matters for 16/32-bit samples.
    """
    spec = lookup(encoding)
    check_dimensions(width, height)
    if (spec.even_width and width % 2) or (spec.even_height and height % 2):
        msg = f'{encoding} image needs even dimensions, got {width}x{height}'
        raise DecodeError(msg)
    bpp = spec.bytes_per_pixel
    if step < width * bpp:
        msg = f'step {step} is less than width {width} * {bpp} bytes per pixel ({encoding})'
        raise DecodeError(msg)
    rows = height * spec.rows_num // spec.rows_den
    need = step * rows
    if size < need:
        msg = f'data has {size} bytes, step {step} * {rows} rows needs {need}'
        raise DecodeError(msg)
    if size - need >= step:
        msg = f'data has {size} bytes, {size - need} more than step {step} * {rows} rows'
        raise DecodeError(msg)

    order = '>' if is_bigendian and spec.itemsize > 1 else '<'
    dtype = np.dtype(order + spec.dtype)
    if spec.channels == 1:
        shape: tuple[int, ...] = (rows, width)
        strides: tuple[int, ...] = (step, spec.itemsize)
    else:
        shape = (rows, width, spec.channels)
        strides = (step, bpp, spec.itemsize)
    image: npt.NDArray[Any] = np.ndarray(
        shape, dtype=dtype, buffer=buf, offset=offset, strides=strides
    )
    if image.flags.writeable:
        image.flags.writeable = False
    if not dtype.isnative:
        image = image.astype(dtype.newbyteorder('='))
    elif not image.flags.aligned:
        image = image.copy()
    if spec.convert is not None:
        import cv2

        try:
            image = cv2.cvtColor(image, getattr(cv2, spec.convert))
        except cv2.error as err:
            msg = f'{encoding} conversion failed: {err}'
            raise DecodeError(msg) from err
    return image, spec.canonical, spec.is_depth


#: What a decoder finds besides the message's topic, seq and log time: (stamp_ns, frame_id,
#: image, encoding, source encoding, is_depth), the rest of a ``Frame``.
_Decoded = tuple[int, str, 'npt.NDArray[Any]', str, str, bool]


def _decode_ros(msg: RawMessage, compressed: bool) -> _Decoded:
    buf = as_bytes_view(msg.data)
    if compressed:
        c = parse_compressed(buf, msg.serialization)
        payload = buf[c.offset : c.offset + c.size]
        image, encoding, codec, is_depth = decode_compressed(payload, c.format)
        return c.stamp_ns, c.frame_id, image, encoding, codec, is_depth
    f = parse_image(buf, msg.serialization)
    image, encoding, is_depth = raw_image_array(
        buf,
        f.offset,
        f.size,
        width=f.width,
        height=f.height,
        step=f.step,
        encoding=f.encoding,
        is_bigendian=bool(f.is_bigendian),
    )
    return f.stamp_ns, f.frame_id, image, encoding, f.encoding, is_depth


def _decode_foxglove(msg: RawMessage, compressed: bool) -> _Decoded:
    from replaybench.decode._protobuf import parse_protobuf, stamp_ns

    pb = parse_protobuf(msg)
    data = memoryview(pb.data)
    stamp = stamp_ns(pb.timestamp)
    if compressed:
        image, encoding, codec, is_depth = decode_compressed(data, pb.format)
        return stamp, pb.frame_id, image, encoding, codec, is_depth
    # foxglove.RawImage has no endianness field; its 16/32-bit encodings are little endian
    image, encoding, is_depth = raw_image_array(
        data,
        0,
        len(data),
        width=pb.width,
        height=pb.height,
        step=pb.step,
        encoding=pb.encoding,
        is_bigendian=False,
    )
    return stamp, pb.frame_id, image, encoding, pb.encoding, is_depth


def decode_image(msg: RawMessage) -> Frame:
    """Decode an Image / CompressedImage / foxglove.RawImage / foxglove.CompressedImage message.

    The frame's ``camera_info`` is None and its ``input_index`` 0.

    Raises DecodeError for anything it cannot turn into a canonical image.
    """
    kind = message_kind(msg.msgtype)
    if kind not in {'image', 'compressed_image'}:
        err = f'{msg.msgtype} is not an image message'
        raise DecodeError(err)
    compressed = kind == 'compressed_image'
    foxglove = msg.msgtype.startswith('foxglove.')
    if foxglove != (msg.serialization == 'protobuf'):
        err = f'{msg.msgtype} in {msg.serialization} serialization is not supported'
        raise DecodeError(err)
    decoded = _decode_foxglove(msg, compressed) if foxglove else _decode_ros(msg, compressed)
    return Frame(msg.topic, msg.seq, msg.log_time_ns, *decoded)


def image_stamp(msg: RawMessage) -> int:
    """The header stamp (ns) of an image message, as ``decode_image`` reads it, without its
    pixels: the 8 bytes of the header stamp of a ROS message, the timestamp field of a
    Foxglove one (its bytes skipped). DecodeError when it has none."""
    if message_kind(msg.msgtype) not in {'image', 'compressed_image'}:
        err = f'{msg.msgtype} is not an image message'
        raise DecodeError(err)
    if msg.msgtype.startswith('foxglove.'):
        from replaybench.decode._protobuf import wire_timestamp

        return wire_timestamp(msg.data)
    return parse_stamp(as_bytes_view(msg.data), msg.serialization)


def image_header(msg: RawMessage) -> tuple[int, str]:
    """The header stamp (ns) and frame_id of an image message, as ``decode_image`` reads them,
    without decoding its pixels (a Foxglove message is parsed whole). DecodeError when it has
    none."""
    kind = message_kind(msg.msgtype)
    if kind not in {'image', 'compressed_image'}:
        err = f'{msg.msgtype} is not an image message'
        raise DecodeError(err)
    if msg.msgtype.startswith('foxglove.'):
        from replaybench.decode._protobuf import parse_protobuf, stamp_ns

        pb = parse_protobuf(msg)
        return stamp_ns(pb.timestamp), str(pb.frame_id)
    buf = as_bytes_view(msg.data)
    try:
        fields = (
            parse_compressed(buf, msg.serialization)
            if kind == 'compressed_image'
            else parse_image(buf, msg.serialization)
        )
    except (IndexError, ValueError) as exc:
        err = f'truncated message: no header in {len(buf)} bytes'
        raise DecodeError(err) from exc
    return fields.stamp_ns, fields.frame_id


_TO_BGR = {
    'rgb8': 'COLOR_RGB2BGR',
    'rgba8': 'COLOR_RGBA2BGR',
    'bgra8': 'COLOR_BGRA2BGR',
    'mono8': 'COLOR_GRAY2BGR',
}


def _scaled_to_u8(image: npt.NDArray[Any]) -> npt.NDArray[np.uint8]:
    values = image.astype(np.float32)
    finite = np.isfinite(values)
    top = float(values[finite].max()) if finite.any() else 0.0
    if top <= 0:
        return np.zeros(image.shape, dtype=np.uint8)
    values[~finite] = 0
    scaled: npt.NDArray[np.float32] = np.clip(values * np.float32(255.0 / top), 0, 255)
    np.rint(scaled, out=scaled)
    return scaled.astype(np.uint8)


def to_bgr8(image: npt.NDArray[Any], encoding: str) -> npt.NDArray[np.uint8]:
    """Any canonical image as HxWx3 uint8 BGR; mono16 / 32FC1 scaled by the frame's finite max.

    ``bgr8`` input is returned as is (possibly a read-only view).
    """
    import cv2

    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if encoding == 'bgr8':
        return cast('npt.NDArray[np.uint8]', image)
    if encoding in {'mono16', '32FC1'}:
        image = _scaled_to_u8(image)
        encoding = 'mono8'
    code = _TO_BGR.get(encoding)
    if code is None:
        msg = f'cannot convert {encoding!r} to bgr8'
        raise DecodeError(msg)
    return cast('npt.NDArray[np.uint8]', cv2.cvtColor(image, getattr(cv2, code)))
