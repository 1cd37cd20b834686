"""The numeric table of raw image encodings, and the size limits every decoder enforces.

Keys are lower case; ``lookup`` matches encodings case-insensitively. OpenCV conversion codes
are kept as attribute names so this module imports nothing heavy.
"""

from __future__ import annotations

from typing import NamedTuple

from replaybench.errors import DecodeError

__all__ = [
    'ENCODINGS',
    'MAX_PIXELS',
    'MAX_SIDE',
    'EncodingSpec',
    'check_dimensions',
    'lookup',
]

#: Largest width or height accepted.
MAX_SIDE = 32768
#: Largest width * height accepted.
MAX_PIXELS = 2**28


class EncodingSpec(NamedTuple):
    """How one raw encoding is laid out and what it decodes to.

    ``channels`` and ``dtype`` describe the stored samples (``dtype`` without byte order:
    ``'u1'``, ``'u2'``, ``'f4'``). ``rows_num / rows_den`` is the number of stored rows per
    image row (3/2 for the NV12 family). ``convert`` names the ``cv2.COLOR_*`` code turning the
    stored array into ``canonical``; ``None`` means the stored array already is ``canonical``.
    ``even_width`` / ``even_height`` mark sides that must be even (chroma subsampling).
    """

    channels: int
    dtype: str
    canonical: str
    is_depth: bool = False
    convert: str | None = None
    rows_num: int = 1
    rows_den: int = 1
    even_width: bool = False
    even_height: bool = False

    @property
    def itemsize(self) -> int:
        return int(self.dtype[1:])

    @property
    def bytes_per_pixel(self) -> int:
        return self.channels * self.itemsize


ENCODINGS: dict[str, EncodingSpec] = {
    # canonical, returned as views
    'rgb8': EncodingSpec(3, 'u1', 'rgb8'),
    'bgr8': EncodingSpec(3, 'u1', 'bgr8'),
    'rgba8': EncodingSpec(4, 'u1', 'rgba8'),
    'bgra8': EncodingSpec(4, 'u1', 'bgra8'),
    'mono8': EncodingSpec(1, 'u1', 'mono8'),
    'mono16': EncodingSpec(1, 'u2', 'mono16'),
    '16uc1': EncodingSpec(1, 'u2', 'mono16', is_depth=True),
    '32fc1': EncodingSpec(1, 'f4', '32FC1', is_depth=True),
    # OpenCV type names: same bytes, canonical names
    '8uc1': EncodingSpec(1, 'u1', 'mono8'),
    '8uc3': EncodingSpec(3, 'u1', 'bgr8'),
    '8uc4': EncodingSpec(4, 'u1', 'bgra8'),
    # Bayer mosaics: ROS names the first row pair's first two pixels, OpenCV's classic
    # constants name the second row's pixels 2 and 3 (rggb -> BG).
    'bayer_rggb8': EncodingSpec(1, 'u1', 'bgr8', convert='COLOR_BayerBG2BGR'),
    'bayer_bggr8': EncodingSpec(1, 'u1', 'bgr8', convert='COLOR_BayerRG2BGR'),
    'bayer_gbrg8': EncodingSpec(1, 'u1', 'bgr8', convert='COLOR_BayerGR2BGR'),
    'bayer_grbg8': EncodingSpec(1, 'u1', 'bgr8', convert='COLOR_BayerGB2BGR'),
    # packed 4:2:2 (ROS 'yuv422' is UYVY, 'yuv422_yuy2' is YUYV)
    'yuv422': EncodingSpec(2, 'u1', 'bgr8', convert='COLOR_YUV2BGR_UYVY', even_width=True),
    'uyvy': EncodingSpec(2, 'u1', 'bgr8', convert='COLOR_YUV2BGR_UYVY', even_width=True),
    'yuv422_yuy2': EncodingSpec(2, 'u1', 'bgr8', convert='COLOR_YUV2BGR_YUYV', even_width=True),
    'yuyv': EncodingSpec(2, 'u1', 'bgr8', convert='COLOR_YUV2BGR_YUYV', even_width=True),
    # semi-planar 4:2:0: a Y plane of height rows, then height/2 rows of interleaved chroma
    'nv12': EncodingSpec(
        1,
        'u1',
        'bgr8',
        convert='COLOR_YUV2BGR_NV12',
        rows_num=3,
        rows_den=2,
        even_width=True,
        even_height=True,
    ),
    'nv21': EncodingSpec(
        1,
        'u1',
        'bgr8',
        convert='COLOR_YUV2BGR_NV21',
        rows_num=3,
        rows_den=2,
        even_width=True,
        even_height=True,
    ),
}


def lookup(encoding: str) -> EncodingSpec:
    """The spec of ``encoding``; DecodeError naming it when unknown."""
    spec = ENCODINGS.get(encoding) or ENCODINGS.get(encoding.lower())
    if spec is None:
        msg = f'unsupported image encoding {encoding!r}'
        raise DecodeError(msg)
    return spec


def check_dimensions(width: int, height: int, what: str = 'image') -> None:
    """DecodeError unless 0 < width, height <= MAX_SIDE and width * height <= MAX_PIXELS."""
    if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE) or width * height > MAX_PIXELS:
        msg = (
            f'{what} size {width}x{height} out of range '
            f'(each side 1..{MAX_SIDE}, at most {MAX_PIXELS} pixels)'
        )
        raise DecodeError(msg)
