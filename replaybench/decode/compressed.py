"""CompressedImage payloads: JPEG, PNG, WebP and image_transport's compressedDepth.

The codec is recognised from the payload's magic bytes; the format string (as
image_transport writes it, e.g. ``'rgb8; jpeg compressed bgr8'``, ``'16UC1; compressedDepth png'``)
says what the source encoding was. Image dimensions are read from the file header and checked
before the decoder allocates anything: besides the size limits of every image, a header claiming
more than ``FREE_PIXELS`` pixels must come with at least one payload byte per
``MAX_PIXELS_PER_BYTE`` pixels, so a few corrupted header bytes cannot make the decoder allocate
gigabytes.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replaybench.decode.encodings import check_dimensions
from replaybench.errors import DecodeError

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    'FREE_PIXELS',
    'MAX_PIXELS_PER_BYTE',
    'CompressedFormat',
    'check_payload_size',
    'decode_compressed',
    'image_size',
    'parse_format',
    'sniff_codec',
]

#: Compressed images up to this many pixels (2048 x 2048) are decoded whatever their payload size.
FREE_PIXELS = 1 << 22
#: Above ``FREE_PIXELS``, the most pixels one payload byte may stand for. Camera JPEGs hold
#: 2-20 pixels per byte, a black frame about 85; only PNGs of blank images compress further.
MAX_PIXELS_PER_BYTE = 256

_PNG_MAGIC = b'\x89PNG\r\n\x1a\n'
_JPEG_MAGIC = b'\xff\xd8\xff'
# compressed_depth_image_transport ConfigHeader: format (enum, int32) + depthParam[2] (float32)
_DEPTH_HEADER = struct.Struct('<iff')
# JPEG start-of-frame markers: C0..CF except DHT (C4), JPG (C8) and DAC (CC)
_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


class CompressedFormat(NamedTuple):
    """What an image_transport format string says.

    ``source_encoding`` is the raw encoding before compression ('' for bare 'jpeg' / 'png'),
    ``target`` the encoding handed to the codec ('' when not stated), ``depth`` whether it is
    the compressedDepth transport.
    """

    source_encoding: str
    codec: str
    target: str
    depth: bool


def parse_format(fmt: str) -> CompressedFormat:
    """Split an image_transport format string ('rgb8; jpeg compressed bgr8', 'jpg', ...)."""
    source, sep, rest = fmt.partition(';')
    if not sep:
        source, rest = '', fmt
    words = rest.lower().split()
    depth = 'compresseddepth' in words or 'compresseddepth' in fmt.lower()
    codec = ''
    target = ''
    for i, word in enumerate(words):
        if word == 'compressed':
            target = words[i + 1] if i + 1 < len(words) else ''
        elif word in {'jpeg', 'jpg', 'png', 'webp', 'rvl'}:
            codec = 'jpeg' if word == 'jpg' else word
    return CompressedFormat(source.strip(), codec, target, depth)


def sniff_codec(data: memoryview) -> str:
    """'jpeg', 'png' or 'webp' from the payload's magic bytes; '' when none matches."""
    head = bytes(data[:16])
    if head.startswith(_JPEG_MAGIC):
        return 'jpeg'
    if head.startswith(_PNG_MAGIC):
        return 'png'
    if head[:4] == b'RIFF' and head[8:12] == b'WEBP':
        return 'webp'
    return ''


def _png_size(data: memoryview) -> tuple[int, int]:
    if len(data) < 24 or bytes(data[12:16]) != b'IHDR':
        msg = 'PNG without an IHDR header'
        raise DecodeError(msg)
    width, height = struct.unpack_from('>II', data, 16)
    return width, height


def _jpeg_size(data: memoryview) -> tuple[int, int]:
    n = len(data)
    pos = 2
    while pos + 4 <= n:
        if data[pos] != 0xFF:  # stray bytes between segments: skip to the next marker
            pos += 1
            continue
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        pos += 2
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # markers without a length
            continue
        if marker in {0xD9, 0xDA}:  # end of image / start of scan before any frame header
            break
        (length,) = struct.unpack_from('>H', data, pos)
        if marker in _SOF_MARKERS:
            if pos + 7 > n:
                break
            height, width = struct.unpack_from('>HH', data, pos + 3)
            return width, height
        if length < 2:
            break
        pos += length
    msg = 'JPEG without a frame header (SOF marker)'
    raise DecodeError(msg)


def _webp_size(data: memoryview) -> tuple[int, int]:
    if len(data) >= 30:
        chunk = bytes(data[12:16])
        if chunk == b'VP8X':
            width = 1 + int.from_bytes(data[24:27], 'little')
            height = 1 + int.from_bytes(data[27:30], 'little')
            return width, height
        if chunk == b'VP8 ' and bytes(data[23:26]) == b'\x9d\x01\x2a':
            width, height = struct.unpack_from('<HH', data, 26)
            return width & 0x3FFF, height & 0x3FFF
        if chunk == b'VP8L' and data[20] == 0x2F:
            bits = int.from_bytes(data[21:25], 'little')
            return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    msg = 'WebP without a recognisable VP8/VP8L/VP8X header'
    raise DecodeError(msg)


def image_size(data: memoryview, codec: str) -> tuple[int, int]:
    """(width, height) as the JPEG / PNG / WebP header claims it."""
    if codec == 'png':
        return _png_size(data)
    if codec == 'jpeg':
        return _jpeg_size(data)
    if codec == 'webp':
        return _webp_size(data)
    msg = f'unsupported codec {codec!r}'
    raise DecodeError(msg)


def check_payload_size(width: int, height: int, nbytes: int, codec: str) -> None:
    """DecodeError when a header claims far more pixels than ``nbytes`` of data can hold."""
    pixels = width * height
    if pixels > FREE_PIXELS and pixels > nbytes * MAX_PIXELS_PER_BYTE:
        msg = (
            f'{codec} header claims {width}x{height} pixels for {nbytes} bytes of data '
            f'(more than {MAX_PIXELS_PER_BYTE} pixels per byte); not decoded'
        )
        raise DecodeError(msg)


def _imdecode(data: memoryview, codec: str) -> npt.NDArray[Any]:
    import cv2

    width, height = image_size(data, codec)
    check_dimensions(width, height, f'{codec} image')
    check_payload_size(width, height, len(data), codec)
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as err:
        msg = f'{codec} decoding failed: {err}'
        raise DecodeError(msg) from err
    if image is None:
        msg = f'{codec} decoding failed ({len(data)} bytes)'
        raise DecodeError(msg)
    return np.asarray(image)


def _decode_depth(
    data: memoryview, fmt: CompressedFormat
) -> tuple[npt.NDArray[Any], str, str, bool]:
    if bytes(data[12:20]) == _PNG_MAGIC:
        png = data[12:]
    elif bytes(data[:8]) == _PNG_MAGIC:  # no config header
        png = data
    elif fmt.codec == 'rvl':
        msg = 'compressedDepth with RVL compression is not supported'
        raise DecodeError(msg)
    else:
        msg = 'compressedDepth payload is not a 12-byte config header followed by a PNG'
        raise DecodeError(msg)
    image = _imdecode(png, 'png')
    if image.ndim != 2 or image.dtype != np.uint16:
        msg = f'compressedDepth PNG is {image.dtype} with shape {image.shape}, not 16-bit mono'
        raise DecodeError(msg)
    if fmt.source_encoding.lower() != '32fc1':
        return image, 'mono16', 'compressedDepth', True
    if png is data:
        msg = '32FC1 compressedDepth without its config header'
        raise DecodeError(msg)
    _, quant_a, quant_b = _DEPTH_HEADER.unpack_from(data, 0)
    depth = np.full(image.shape, np.nan, dtype=np.float32)
    valid = image != 0
    with np.errstate(divide='ignore', invalid='ignore'):
        depth[valid] = np.float32(quant_a) / (image[valid].astype(np.float32) - np.float32(quant_b))
    return depth, '32FC1', 'compressedDepth', True


def decode_compressed(
    data: memoryview, format_string: str
) -> tuple[npt.NDArray[Any], str, str, bool]:
    """Decode a CompressedImage payload: (image, canonical encoding, codec, is_depth).

    Three-channel results are BGR (``'bgr8'``) as the codec returns them, unless the format
    says the codec was fed RGB (``'... compressed rgb8'``); 16-bit colour is scaled to 8 bits.
    ``is_depth`` when the source encoding was 16UC1 / 32FC1, or is not stated (bare 'png') and
    the image is 16-bit mono.
    """
    fmt = parse_format(format_string)
    if fmt.depth:
        return _decode_depth(data, fmt)
    codec = sniff_codec(data)
    if not codec:
        msg = f'unrecognised compressed image data (format {format_string!r}, {len(data)} bytes)'
        raise DecodeError(msg)
    image = _imdecode(data, codec)
    source = fmt.source_encoding.lower()
    is_depth = source in {'16uc1', '32fc1'}
    if image.ndim == 2:
        if image.dtype == np.uint8:
            return image, 'mono8', codec, is_depth
        if image.dtype == np.uint16:  # 16-bit mono of unstated origin is taken for depth
            return image, 'mono16', codec, is_depth or not source
    elif image.ndim == 3 and image.shape[2] in {3, 4}:
        if image.dtype == np.uint16:
            image = (image >> 8).astype(np.uint8)
        if image.dtype == np.uint8:
            rgb = fmt.target.startswith('rgb')
            if image.shape[2] == 3:
                return image, 'rgb8' if rgb else 'bgr8', codec, False
            return image, 'rgba8' if rgb else 'bgra8', codec, False
    msg = f'{codec} decoded to unsupported {image.dtype} array of shape {image.shape}'
    raise DecodeError(msg)
