"""sensor_msgs/CompressedImage decoding: every image_transport format string, compressedDepth."""

from __future__ import annotations

import struct
import time
import tracemalloc

import cv2
import numpy as np
import pytest

from replaybench.decode import decode_image
from replaybench.decode.compressed import image_size, parse_format
from replaybench.errors import DecodeError

SERIALIZATIONS = ['cdr', 'ros1']


def scene_bgr(height: int = 96, width: int = 128) -> np.ndarray:
    """Smooth colour gradients plus flat blocks: JPEG keeps them close."""
    y, x = np.mgrid[0:height, 0:width]
    bgr = np.dstack([x * 255 // width, y * 255 // height, np.full_like(x, 180)]).astype(np.uint8)
    bgr[10:40, 10:50] = (0, 0, 255)  # red block
    return bgr


def encode(image: np.ndarray, ext: str) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


def assert_close(got: np.ndarray, want: np.ndarray, lossy: bool) -> None:
    assert got.shape == want.shape
    assert got.dtype == want.dtype
    if lossy:
        assert np.abs(got.astype(int) - want.astype(int)).mean() < 3
    else:
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize(
    ('fmt', 'ext', 'kind', 'encoding', 'codec', 'is_depth'),
    [
        ('jpeg', '.jpg', 'bgr', 'bgr8', 'jpeg', False),
        ('jpg', '.jpg', 'bgr', 'bgr8', 'jpeg', False),
        ('png', '.png', 'bgr', 'bgr8', 'png', False),
        ('rgb8; jpeg compressed bgr8', '.jpg', 'bgr', 'bgr8', 'jpeg', False),
        ('bgr8; jpeg compressed bgr8', '.jpg', 'bgr', 'bgr8', 'jpeg', False),
        ('rgb8; png compressed bgr8', '.png', 'bgr', 'bgr8', 'png', False),
        ('bgra8; png compressed bgra8', '.png', 'bgra', 'bgra8', 'png', False),
        ('mono8; jpeg compressed ', '.jpg', 'mono8', 'mono8', 'jpeg', False),
        ('mono8; png compressed ', '.png', 'mono8', 'mono8', 'png', False),
        ('16UC1; png compressed ', '.png', 'mono16', 'mono16', 'png', True),
        ('mono16; png compressed ', '.png', 'mono16', 'mono16', 'png', False),
        ('png', '.png', 'mono16', 'mono16', 'png', True),  # 16-bit mono, origin unstated
        ('png', '.png', 'mono8', 'mono8', 'png', False),
    ],
)
def test_image_transport_format_strings_decode_to_canonical_images(
    mk, serialization, fmt, ext, kind, encoding, codec, is_depth
):
    bgr = scene_bgr()
    source = {
        'bgr': bgr,
        'bgra': np.dstack([bgr, np.arange(bgr.shape[1], dtype=np.uint8)[None].repeat(96, 0)]),
        'mono8': cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY),
        'mono16': bgr[..., 0].astype(np.uint16) * 19 + 7,
    }[kind]
    msg = mk.compressed(
        serialization, encode(source, ext), fmt, stamp_ns=5_000_000_001, frame_id='f'
    )
    decoded = decode_image(msg)
    assert decoded.encoding == encoding
    assert decoded.source_encoding == codec
    assert decoded.is_depth is is_depth
    assert (decoded.stamp_ns, decoded.frame_id) == (5_000_000_001, 'f')
    assert_close(decoded.image, source, lossy=ext == '.jpg')


def test_jpeg_of_an_rgb8_source_is_bgr_with_red_in_the_last_channel(mk):
    bgr = scene_bgr()
    msg = mk.compressed('cdr', encode(bgr, '.jpg'), 'rgb8; jpeg compressed bgr8')
    image = decode_image(msg).image
    b, g, r = image[25, 30]
    assert r > 200
    assert b < 60
    assert g < 60


def test_a_codec_fed_rgb_is_reported_as_rgb(mk):
    rgb = scene_bgr()  # bytes handed to the codec as they are
    msg = mk.compressed('cdr', encode(rgb, '.png'), 'rgb8; png compressed rgb8')
    decoded = decode_image(msg)
    assert decoded.encoding == 'rgb8'
    np.testing.assert_array_equal(decoded.image, rgb)


def test_webp_decodes_when_opencv_has_it(mk):
    ok, buf = cv2.imencode('.webp', scene_bgr(), [cv2.IMWRITE_WEBP_QUALITY, 100])
    if not ok:
        pytest.skip('this OpenCV build has no WebP')
    msg = mk.compressed('cdr', buf.tobytes(), 'webp')
    decoded = decode_image(msg)
    assert (decoded.encoding, decoded.source_encoding) == ('bgr8', 'webp')
    assert decoded.image.shape == (96, 128, 3)


def test_the_codec_is_recognised_from_the_bytes_not_the_format_string(mk):
    msg = mk.compressed('cdr', encode(scene_bgr(), '.png'), 'jpeg')
    decoded = decode_image(msg)
    assert decoded.source_encoding == 'png'
    np.testing.assert_array_equal(decoded.image, scene_bgr())


def depth_header(quant_a: float = 0.0, quant_b: float = 0.0) -> bytes:
    return struct.pack('<iff', 0, quant_a, quant_b)


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize('fmt', ['16UC1; compressedDepth', '16UC1; compressedDepth png'])
def test_compressed_depth_16uc1_skips_the_config_header(mk, serialization, fmt):
    depth = (np.arange(60 * 80, dtype=np.uint16).reshape(60, 80) * 3) % 5000
    payload = depth_header() + encode(depth, '.png')
    assert cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_UNCHANGED) is None
    decoded = decode_image(mk.compressed(serialization, payload, fmt))
    assert decoded.encoding == 'mono16'
    assert decoded.source_encoding == 'compressedDepth'
    assert decoded.is_depth is True
    np.testing.assert_array_equal(decoded.image, depth)


def test_compressed_depth_32fc1_turns_inverse_depth_back_into_metres(mk):
    # compressed_depth_image_transport's encoder, defaults depth_max=10, depth_quantization=100
    depth_max, quantization = 10.0, 100.0
    quant_a = np.float32(quantization * (quantization + 1.0))
    quant_b = np.float32(1.0 - quant_a / depth_max)
    rng = np.random.default_rng(5)
    depth = rng.uniform(0.3, 9.5, size=(40, 50)).astype(np.float32)
    depth[0, 0] = np.nan
    depth[1, 1] = 12.0  # beyond depth_max: not stored
    inverse = np.zeros(depth.shape, np.uint16)
    valid = depth < depth_max
    inverse[valid] = (quant_a / depth[valid] + quant_b).astype(np.uint16)
    payload = depth_header(float(quant_a), float(quant_b)) + encode(inverse, '.png')
    decoded = decode_image(mk.compressed('cdr', payload, '32FC1; compressedDepth png'))
    assert decoded.encoding == '32FC1'
    assert decoded.image.dtype == np.float32
    assert decoded.is_depth is True
    assert np.isnan(decoded.image[0, 0])
    assert np.isnan(decoded.image[1, 1])
    # quantisation error of 1 in inverse depth grows with depth squared: ~d^2 / A
    tolerance = depth[valid] ** 2 / quant_a * 1.5 + 1e-4
    assert np.all(np.abs(decoded.image[valid].astype(np.float32) - depth[valid]) <= tolerance)


def test_compressed_depth_rvl_is_reported_as_unsupported(mk):
    payload = depth_header() + b'\x01\x02\x03\x04' * 10
    with pytest.raises(DecodeError, match='RVL'):
        decode_image(mk.compressed('cdr', payload, '16UC1; compressedDepth rvl'))


def test_compressed_depth_without_a_png_is_rejected(mk):
    with pytest.raises(DecodeError, match='compressedDepth'):
        decode_image(mk.compressed('cdr', b'\x00' * 40, '16UC1; compressedDepth'))


def assert_rejected_without_allocating(msg, match: str) -> None:
    tracemalloc.start()
    try:
        t0 = time.perf_counter()
        with pytest.raises(DecodeError, match=match):
            decode_image(msg)
        elapsed = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, f'allocated {peak} bytes before rejecting'
    assert elapsed < 0.5


def with_png_size(png: bytes, width: int, height: int) -> bytes:
    return png[:16] + struct.pack('>II', width, height) + png[24:]


def with_jpeg_size(jpeg: bytes, width: int, height: int) -> bytes:
    sof = jpeg.index(b'\xff\xc0')
    return jpeg[: sof + 5] + struct.pack('>HH', height, width) + jpeg[sof + 9 :]


@pytest.mark.parametrize(('width', 'height'), [(60_000, 60_000), (30_000, 30_000), (0, 5)])
def test_png_claiming_absurd_dimensions_is_rejected_before_decoding(mk, width, height):
    png = with_png_size(encode(scene_bgr(), '.png'), width, height)
    assert image_size(memoryview(png), 'png') == (width, height)
    assert_rejected_without_allocating(mk.compressed('cdr', png, 'png'), 'out of range')
    depth = depth_header() + with_png_size(
        encode(np.zeros((4, 4), np.uint16), '.png'), width, height
    )
    assert_rejected_without_allocating(
        mk.compressed('cdr', depth, '16UC1; compressedDepth'), 'out of range'
    )


def test_jpeg_claiming_absurd_dimensions_is_rejected_before_decoding(mk):
    jpeg = encode(scene_bgr(), '.jpg')
    assert image_size(memoryview(jpeg), 'jpeg') == (128, 96)
    big = with_jpeg_size(jpeg, 60_000, 60_000)
    assert image_size(memoryview(big), 'jpeg') == (60_000, 60_000)
    assert_rejected_without_allocating(mk.compressed('ros1', big, 'jpeg'), 'out of range')


def test_progressive_jpeg_size_is_read_from_its_frame_header():
    ok, buf = cv2.imencode('.jpg', scene_bgr(), [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    assert ok
    assert image_size(memoryview(buf.tobytes()), 'jpeg') == (128, 96)


def test_undecodable_payloads_raise_decode_error(mk):
    png = encode(scene_bgr(), '.png')
    jpeg = encode(scene_bgr(), '.jpg')
    with pytest.raises(DecodeError, match='unrecognised'):
        decode_image(mk.compressed('cdr', b'GIF89a' + b'\x00' * 50, 'gif'))
    with pytest.raises(DecodeError, match='unrecognised'):
        decode_image(mk.compressed('cdr', b'', 'jpeg'))
    with pytest.raises(DecodeError, match='png decoding failed'):
        decode_image(mk.compressed('cdr', png[:40], 'png'))
    with pytest.raises(DecodeError, match='JPEG'):
        decode_image(mk.compressed('cdr', jpeg[:20], 'jpeg'))


def test_truncated_compressed_messages_are_rejected(mk):
    msg = mk.compressed('cdr', encode(scene_bgr(), '.png'), 'png')
    for cut in (3, 12, 20, len(msg.data) - 1):
        with pytest.raises(DecodeError):
            decode_image(msg._replace(data=msg.data[:cut]))


@pytest.mark.parametrize(
    ('fmt', 'expected'),
    [
        ('jpeg', ('', 'jpeg', '', False)),
        ('jpg', ('', 'jpeg', '', False)),
        ('rgb8; jpeg compressed bgr8', ('rgb8', 'jpeg', 'bgr8', False)),
        ('mono8; jpeg compressed ', ('mono8', 'jpeg', '', False)),
        ('16UC1; png compressed ', ('16UC1', 'png', '', False)),
        ('16UC1; compressedDepth', ('16UC1', '', '', True)),
        ('32FC1; compressedDepth png', ('32FC1', 'png', '', True)),
        ('16UC1; compressedDepth rvl', ('16UC1', 'rvl', '', True)),
    ],
)
def test_format_strings_are_split_as_image_transport_writes_them(fmt, expected):
    assert tuple(parse_format(fmt)) == expected
