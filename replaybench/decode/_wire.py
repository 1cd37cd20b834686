"""Hand-written readers for the fixed layouts of sensor_msgs Image, CompressedImage and
CameraInfo.

For the images they read the few header fields and return where the payload lies in the
buffer, so the payload is never copied. CameraInfo is read whole: reading it needs no type
store, whose import would cost more than the rest of a run's start.

CDR: a 4-byte encapsulation header, then fields aligned to their size
relative to the byte after it (the header is 4 bytes, so absolute offsets align the same way
for fields of up to 4 bytes; a float64 aligns to 8 relative to the byte after the header);
strings carry a trailing NUL in their length.
ROS 1: little endian, no alignment, no NUL.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from replaybench.errors import DecodeError

__all__ = [
    'CameraInfoFields',
    'CompressedFields',
    'ImageFields',
    'as_bytes_view',
    'parse_camera_info',
    'parse_compressed',
    'parse_image',
    'parse_stamp',
]


class ImageFields(NamedTuple):
    """The header fields of a sensor_msgs/Image and where its pixel data lies."""

    stamp_ns: int
    frame_id: str
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    offset: int
    size: int


class CompressedFields(NamedTuple):
    """The header fields of a sensor_msgs/CompressedImage and where its payload lies."""

    stamp_ns: int
    frame_id: str
    format: str
    offset: int
    size: int


class CameraInfoFields(NamedTuple):
    """The fields of a sensor_msgs/CameraInfo (``roi``: x_offset, y_offset, height, width,
    do_rectify)."""

    stamp_ns: int
    frame_id: str
    height: int
    width: int
    distortion_model: str
    d: tuple[float, ...]
    k: tuple[float, ...]
    r: tuple[float, ...]
    p: tuple[float, ...]
    binning_x: int
    binning_y: int
    roi: tuple[int, int, int, int, bool]


class _Layout(NamedTuple):
    u32: struct.Struct
    u32x2: struct.Struct
    stamp: struct.Struct
    start: int  # offset of the header stamp
    align: int  # alignment mask (3 for CDR, 0 for ROS 1)
    nul: bool  # strings count a trailing NUL


_CDR_LE = _Layout(struct.Struct('<I'), struct.Struct('<II'), struct.Struct('<iI'), 4, 3, True)
_CDR_BE = _Layout(struct.Struct('>I'), struct.Struct('>II'), struct.Struct('>iI'), 4, 3, True)
# ROS 1: header.seq u32, then stamp secs u32 / nsecs u32
_ROS1 = _Layout(struct.Struct('<I'), struct.Struct('<II'), struct.Struct('<II'), 4, 0, False)


def as_bytes_view(data: memoryview | bytes) -> memoryview:
    """``data`` as a flat unsigned-byte memoryview (no copy)."""
    view = data if isinstance(data, memoryview) else memoryview(data)
    if view.format != 'B' or view.ndim != 1:
        view = view.cast('B')
    return view


def _layout(buf: memoryview, serialization: str) -> _Layout:
    if serialization == 'ros1':
        return _ROS1
    if serialization != 'cdr':
        msg = f'unsupported serialization {serialization!r}'
        raise DecodeError(msg)
    if len(buf) < 4 or buf[0] != 0 or buf[1] > 1:
        msg = f'not a plain CDR message (encapsulation header {bytes(buf[:4]).hex()})'
        raise DecodeError(msg)
    return _CDR_LE if buf[1] == 1 else _CDR_BE


def _string(buf: memoryview, pos: int, lay: _Layout) -> tuple[str, int]:
    pos = (pos + lay.align) & ~lay.align
    (n,) = lay.u32.unpack_from(buf, pos)
    pos += 4
    end = pos + n
    if end > len(buf):
        raise IndexError
    stop = end - 1 if lay.nul and n and buf[end - 1] == 0 else end
    return str(buf[pos:stop], 'utf-8', 'replace'), end


def _header(buf: memoryview, lay: _Layout) -> tuple[int, str, int]:
    sec, nsec = lay.stamp.unpack_from(buf, lay.start)
    frame_id, pos = _string(buf, lay.start + 8, lay)
    return sec * 1_000_000_000 + nsec, frame_id, pos


def _payload(buf: memoryview, pos: int, lay: _Layout) -> tuple[int, int]:
    pos = (pos + lay.align) & ~lay.align
    (size,) = lay.u32.unpack_from(buf, pos)
    pos += 4
    if pos + size > len(buf):
        msg = f'data length {size} runs past the end of the message ({len(buf) - pos} bytes left)'
        raise DecodeError(msg)
    return pos, size


def parse_stamp(buf: memoryview, serialization: str) -> int:
    """The header stamp (ns) of a message that begins with a std_msgs/Header (sensor_msgs
    Image and CompressedImage, ``'cdr'`` or ``'ros1'``): 8 bytes read, nothing else."""
    lay = _layout(buf, serialization)
    try:
        sec, nsec = lay.stamp.unpack_from(buf, lay.start)
    except struct.error as err:
        msg = f'truncated message: no header stamp in {len(buf)} bytes'
        raise DecodeError(msg) from err
    return int(sec) * 1_000_000_000 + int(nsec)


def parse_image(buf: memoryview, serialization: str) -> ImageFields:
    """Read a sensor_msgs/Image (``'cdr'`` or ``'ros1'``) without touching its pixels."""
    lay = _layout(buf, serialization)
    try:
        stamp_ns, frame_id, pos = _header(buf, lay)
        pos = (pos + lay.align) & ~lay.align
        height, width = lay.u32x2.unpack_from(buf, pos)
        encoding, pos = _string(buf, pos + 8, lay)
        is_bigendian = buf[pos]
        pos = (pos + 1 + lay.align) & ~lay.align
        (step,) = lay.u32.unpack_from(buf, pos)
        offset, size = _payload(buf, pos + 4, lay)
    except (struct.error, IndexError) as err:
        msg = f'truncated sensor_msgs/Image message ({len(buf)} bytes)'
        raise DecodeError(msg) from err
    return ImageFields(
        stamp_ns, frame_id, height, width, encoding, is_bigendian, step, offset, size
    )


def parse_compressed(buf: memoryview, serialization: str) -> CompressedFields:
    """Read a sensor_msgs/CompressedImage (``'cdr'`` or ``'ros1'``) without copying its data."""
    lay = _layout(buf, serialization)
    try:
        stamp_ns, frame_id, pos = _header(buf, lay)
        fmt, pos = _string(buf, pos, lay)
        offset, size = _payload(buf, pos, lay)
    except (struct.error, IndexError) as err:
        msg = f'truncated sensor_msgs/CompressedImage message ({len(buf)} bytes)'
        raise DecodeError(msg) from err
    return CompressedFields(stamp_ns, frame_id, fmt, offset, size)


def _floats(buf: memoryview, pos: int, count: int, lay: _Layout) -> tuple[tuple[float, ...], int]:
    """``count`` float64s at ``pos`` (aligned to 8 after the CDR header), and the end."""
    if lay.align:
        pos = ((pos - lay.start + 7) & ~7) + lay.start
    order = lay.u32.format[0]
    return struct.unpack_from(f'{order}{count}d', buf, pos), pos + 8 * count  # floats already


def parse_camera_info(buf: memoryview, serialization: str) -> CameraInfoFields:
    """Read a sensor_msgs/CameraInfo (``'cdr'`` or ``'ros1'``)."""
    lay = _layout(buf, serialization)
    try:
        stamp_ns, frame_id, pos = _header(buf, lay)
        pos = (pos + lay.align) & ~lay.align
        height, width = lay.u32x2.unpack_from(buf, pos)
        distortion_model, pos = _string(buf, pos + 8, lay)
        pos = (pos + lay.align) & ~lay.align
        (n_d,) = lay.u32.unpack_from(buf, pos)
        if n_d > (len(buf) - pos) // 8:
            raise IndexError
        d, pos = _floats(buf, pos + 4, n_d, lay)
        k, pos = _floats(buf, pos, 9, lay)
        r, pos = _floats(buf, pos, 9, lay)
        p, pos = _floats(buf, pos, 12, lay)
        binning_x, binning_y = lay.u32x2.unpack_from(buf, pos)
        x_offset, y_offset = lay.u32x2.unpack_from(buf, pos + 8)
        roi_height, roi_width = lay.u32x2.unpack_from(buf, pos + 16)
        do_rectify = buf[pos + 24]
    except (struct.error, IndexError) as err:
        msg = f'truncated sensor_msgs/CameraInfo message ({len(buf)} bytes)'
        raise DecodeError(msg) from err
    roi = (x_offset, y_offset, roi_height, roi_width, bool(do_rectify))
    return CameraInfoFields(
        stamp_ns, frame_id, height, width, distortion_model, d, k, r, p, binning_x, binning_y, roi
    )


class BoxFields(NamedTuple):
    """One vision_msgs/Detection2D: its box and its first hypothesis (``class_id`` '' and
    ``score`` 1.0 without one)."""

    cx: float
    cy: float
    size_x: float
    size_y: float
    class_id: str
    score: float
    #: ``Detection2D.id``: the object's identity ('' for none)
    id: str = ''


class DetectionArrayFields(NamedTuple):
    """The fields of a vision_msgs/Detection2DArray that ground truth needs."""

    stamp_ns: int
    frame_id: str
    boxes: tuple[BoxFields, ...]


class _Cdr:
    """A strict CDR cursor over the body (after the encapsulation header): every field aligned
    to its size, strings NUL-terminated UTF-8, sequence counts that fit in the bytes left, at
    most 3 bytes of padding after the message (as rosbags' deserializer checks)."""

    __slots__ = ('body', 'lay', 'pos')

    def __init__(self, buf: memoryview, lay: _Layout) -> None:
        self.body = buf[lay.start :]
        self.lay = lay
        self.pos = 0

    def count(self, minimum: int = 1) -> int:
        self.pos = (self.pos + 3) & -4
        (n,) = self.lay.u32.unpack_from(self.body, self.pos)
        self.pos += 4
        if self.pos + n * minimum > len(self.body):
            raise IndexError
        return int(n)

    def stamp(self) -> int:
        self.pos = (self.pos + 3) & -4
        sec, nsec = self.lay.stamp.unpack_from(self.body, self.pos)
        self.pos += 8
        return int(sec) * 1_000_000_000 + int(nsec)

    def string(self) -> str:
        n = self.count(0)
        end = self.pos + n
        if n < 1 or end > len(self.body) or self.body[end - 1] != 0:
            raise IndexError
        text = bytes(self.body[self.pos : end - 1]).decode()
        self.pos = end
        return text

    def floats(self, count: int, *, skip: bool = False) -> tuple[float, ...]:
        """``count`` float64s (aligned to 8), or none read when ``skip``."""
        self.pos = (self.pos + 7) & -8
        end = self.pos + 8 * count
        if end > len(self.body):
            raise IndexError
        values = (
            ()
            if skip
            else struct.unpack_from(f'{self.lay.u32.format[0]}{count}d', self.body, self.pos)
        )
        self.pos = end
        return values

    def finish(self) -> None:
        if self.pos + 3 < len(self.body):
            raise IndexError


def _box(cur: _Cdr) -> BoxFields:
    cur.stamp()  # the detection's own header
    cur.string()
    class_id, score = '', 1.0
    for i in range(cur.count()):
        name = cur.string()  # ObjectHypothesis.class_id
        (value,) = cur.floats(1)
        cur.floats(7 + 36, skip=True)  # PoseWithCovariance: position, orientation, covariance
        if i == 0:
            class_id, score = name, value
    cx, cy, _theta, size_x, size_y = cur.floats(5)
    ident = cur.string()  # Detection2D.id
    return BoxFields(cx, cy, size_x, size_y, class_id, score, ident)


def parse_detection_array(buf: memoryview) -> DetectionArrayFields:
    """Read a vision_msgs 4.x Detection2DArray in CDR (little or big endian) as strictly as
    rosbags' deserializer: a message it refuses raises ``DecodeError`` here."""
    cur = _Cdr(buf, _layout(buf, 'cdr'))
    try:
        stamp_ns = cur.stamp()
        frame_id = cur.string()
        boxes = tuple(_box(cur) for _ in range(cur.count()))
        cur.finish()
    except (struct.error, IndexError, UnicodeDecodeError) as err:
        msg = f'malformed vision_msgs/Detection2DArray message ({len(buf)} bytes)'
        raise DecodeError(msg) from err
    return DetectionArrayFields(stamp_ns, frame_id, boxes)
