"""sensor_msgs/Image decoding, CDR and ROS 1, against arrays built here."""

from __future__ import annotations

import time
import tracemalloc

import cv2
import numpy as np
import pytest

from replaybench.decode import decode_image, to_bgr8
from replaybench.errors import DecodeError
from replaybench.types import CANONICAL_ENCODINGS, RawMessage

SERIALIZATIONS = ['cdr', 'ros1']
RNG = np.random.default_rng(1234)


def random_pixels(height: int, width: int, channels: int, dtype: str = 'u1') -> np.ndarray:
    shape = (height, width) if channels == 1 else (height, width, channels)
    info = np.iinfo(dtype)
    return RNG.integers(info.min, info.max, size=shape, endpoint=True).astype(dtype)


def colour_blocks(height: int, width: int) -> np.ndarray:
    """A BGR image of four flat colour quadrants (demosaicing / chroma subsampling keep them)."""
    bgr = np.zeros((height, width, 3), np.uint8)
    h2, w2 = height // 2, width // 2
    bgr[:h2, :w2] = (30, 120, 220)
    bgr[:h2, w2:] = (200, 40, 60)
    bgr[h2:, :w2] = (50, 210, 90)
    bgr[h2:, w2:] = (128, 128, 128)
    return bgr


def quadrant_centres(image: np.ndarray) -> list[np.ndarray]:
    h, w = image.shape[:2]
    return [image[y * h // 2 + h // 8 : (y + 1) * h // 2 - h // 8,
                  x * w // 2 + w // 8 : (x + 1) * w // 2 - w // 8]
            for y in (0, 1) for x in (0, 1)]  # fmt: skip


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize(
    ('encoding', 'channels'),
    [('rgb8', 3), ('bgr8', 3), ('rgba8', 4), ('bgra8', 4), ('mono8', 1)],
)
def test_canonical_8bit_encodings_decode_to_the_same_pixels_at_an_odd_size(
    mk, serialization, encoding, channels
):
    pixels = random_pixels(171, 224, channels)
    msg = mk.simple(pixels, serialization, encoding)
    decoded = decode_image(msg)
    assert decoded.encoding == encoding
    assert decoded.source_encoding == encoding
    assert decoded.is_depth is False
    assert decoded.image.shape == pixels.shape
    assert decoded.image.dtype == np.uint8
    np.testing.assert_array_equal(decoded.image, pixels)


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
def test_header_stamp_and_frame_id_are_read(mk, serialization):
    msg = mk.simple(
        random_pixels(4, 6, 1),
        serialization,
        'mono8',
        stamp_ns=1_650_000_123_000_000_999,
        frame_id='gripper_camera_ünïcode',
    )
    decoded = decode_image(msg)
    assert decoded.stamp_ns == 1_650_000_123_000_000_999
    assert decoded.frame_id == 'gripper_camera_ünïcode'


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
def test_rgb8_is_a_zero_copy_read_only_view_of_the_message(mk, serialization):
    pixels = random_pixels(48, 64, 3)
    msg = mk.simple(pixels, serialization, 'rgb8')
    decoded = decode_image(msg)
    assert np.shares_memory(decoded.image, np.frombuffer(msg.data, np.uint8))
    assert not decoded.image.flags.writeable
    # the same through a memoryview of a writable buffer: still a view, still read-only
    buffer = bytearray(msg.data)
    decoded = decode_image(msg._replace(data=memoryview(buffer)))
    assert np.shares_memory(decoded.image, np.frombuffer(buffer, np.uint8))
    assert not decoded.image.flags.writeable
    np.testing.assert_array_equal(decoded.image, pixels)


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
def test_padded_rows_are_a_strided_view_without_the_padding(mk, serialization):
    pixels = random_pixels(171, 224, 3)
    step = 224 * 3 + 13
    data = mk.pack_rows(pixels, step)
    msg = mk.image(serialization, data, width=224, height=171, step=step, encoding='bgr8')
    decoded = decode_image(msg)
    np.testing.assert_array_equal(decoded.image, pixels)
    assert decoded.image.strides[0] == step
    assert not decoded.image.flags.c_contiguous
    assert np.shares_memory(decoded.image, np.frombuffer(msg.data, np.uint8))


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize('encoding', ['mono8', 'rgb8'])
def test_is_bigendian_on_8bit_data_changes_nothing(mk, serialization, encoding):
    pixels = random_pixels(171, 224, 1 if encoding == 'mono8' else 3)
    msg = mk.simple(pixels, serialization, encoding, is_bigendian=1)
    decoded = decode_image(msg)
    np.testing.assert_array_equal(decoded.image, pixels)
    assert np.shares_memory(decoded.image, np.frombuffer(msg.data, np.uint8))


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize('big', [0, 1])
@pytest.mark.parametrize(('encoding', 'is_depth'), [('mono16', False), ('16UC1', True)])
def test_16bit_images_honour_is_bigendian(mk, serialization, big, encoding, is_depth):
    pixels = random_pixels(30, 41, 1, 'u2')
    msg = mk.simple(pixels, serialization, encoding, is_bigendian=big)
    decoded = decode_image(msg)
    assert decoded.encoding == 'mono16'
    assert decoded.source_encoding == encoding
    assert decoded.is_depth is is_depth
    assert decoded.image.dtype.isnative
    assert decoded.image.dtype.itemsize == 2
    np.testing.assert_array_equal(decoded.image, pixels)


def test_big_endian_16bit_bytes_really_are_swapped(mk):
    msg = mk.image(
        'cdr', np.array([0x01, 0x02, 0x03, 0x04], np.uint8),
        width=2, height=1, step=4, encoding='16UC1', is_bigendian=1,
    )  # fmt: skip
    assert decode_image(msg).image.tolist() == [[0x0102, 0x0304]]
    msg = mk.image(
        'cdr', np.array([0x01, 0x02, 0x03, 0x04], np.uint8),
        width=2, height=1, step=4, encoding='16UC1', is_bigendian=0,
    )  # fmt: skip
    assert decode_image(msg).image.tolist() == [[0x0201, 0x0403]]


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize('big', [0, 1])
def test_32fc1_depth_honours_is_bigendian_and_keeps_nan(mk, serialization, big):
    depth = RNG.uniform(0.2, 12.0, size=(17, 23)).astype(np.float32)
    depth[3, 4] = np.nan
    depth[5, 6] = np.inf
    msg = mk.simple(depth, serialization, '32FC1', is_bigendian=big)
    decoded = decode_image(msg)
    assert decoded.encoding == '32FC1'
    assert decoded.is_depth is True
    assert decoded.image.dtype == np.float32
    np.testing.assert_array_equal(decoded.image, depth)


def test_unaligned_16bit_data_comes_back_aligned(mk):
    # ROS 1 has no alignment: a 2-character frame_id puts the data at an odd offset
    pixels = random_pixels(8, 10, 1, 'u2')
    for frame_id in ('ab', 'abc'):
        decoded = decode_image(mk.simple(pixels, 'ros1', '16UC1', frame_id=frame_id))
        assert decoded.image.flags.aligned
        np.testing.assert_array_equal(decoded.image, pixels)


def test_big_endian_cdr_encapsulation_is_read(mk):
    pixels = random_pixels(9, 11, 1, 'u2')
    data = mk.pack_rows(pixels, 22)
    msg = mk.image(
        'cdr', data, width=11, height=9, step=22, encoding='mono16', little_endian=False,
        stamp_ns=12_000_000_034, frame_id='be',
    )  # fmt: skip
    assert bytes(msg.data[:2]) == b'\x00\x00'
    decoded = decode_image(msg)
    np.testing.assert_array_equal(decoded.image, pixels)
    assert (decoded.stamp_ns, decoded.frame_id) == (12_000_000_034, 'be')


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize(
    ('encoding', 'channels', 'canonical'),
    [('8UC1', 1, 'mono8'), ('8UC3', 3, 'bgr8'), ('8UC4', 4, 'bgra8')],
)
def test_opencv_type_names_map_to_canonical_encodings(
    mk, serialization, encoding, channels, canonical
):
    pixels = random_pixels(12, 14, channels)
    decoded = decode_image(mk.simple(pixels, serialization, encoding))
    assert decoded.encoding == canonical
    assert decoded.source_encoding == encoding
    np.testing.assert_array_equal(decoded.image, pixels)


def bayer_mosaic(bgr: np.ndarray, pattern: str) -> np.ndarray:
    """Sample a BGR image through a Bayer filter; ``pattern`` names the top-left 2x2 cells."""
    channel = {'b': 0, 'g': 1, 'r': 2}
    mosaic = np.zeros(bgr.shape[:2], np.uint8)
    for cell, (dy, dx) in zip(pattern, [(0, 0), (0, 1), (1, 0), (1, 1)], strict=True):
        mosaic[dy::2, dx::2] = bgr[dy::2, dx::2, channel[cell]]
    return mosaic


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize('pattern', ['rggb', 'bggr', 'gbrg', 'grbg'])
def test_bayer_demosaicing_recovers_the_original_colours(mk, serialization, pattern):
    bgr = colour_blocks(64, 96)
    mosaic = bayer_mosaic(bgr, pattern)
    decoded = decode_image(mk.simple(mosaic, serialization, f'bayer_{pattern}8'))
    assert decoded.encoding == 'bgr8'
    assert decoded.source_encoding == f'bayer_{pattern}8'
    assert decoded.image.shape == bgr.shape
    for got, want in zip(quadrant_centres(decoded.image), quadrant_centres(bgr), strict=True):
        np.testing.assert_allclose(got, want, atol=2)


def test_bayer_with_padded_rows_decodes_the_same(mk):
    bgr = colour_blocks(32, 48)
    mosaic = bayer_mosaic(bgr, 'rggb')
    packed = decode_image(mk.simple(mosaic, 'cdr', 'bayer_rggb8')).image
    data = mk.pack_rows(mosaic, 64)
    padded = decode_image(
        mk.image('cdr', data, width=48, height=32, step=64, encoding='bayer_rggb8')
    ).image
    np.testing.assert_array_equal(padded, packed)


def yuv_planes(bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Full-resolution Y, U, V planes of a BGR image (OpenCV's BT.601 video range)."""
    h, w = bgr.shape[:2]
    i420 = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420)
    y = i420[:h]
    u = i420[h : h + h // 4].reshape(h // 2, w // 2)
    v = i420[h + h // 4 :].reshape(h // 2, w // 2)
    return y, u, v


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize(
    ('encoding', 'order'),
    [('yuv422', 'uyvy'), ('uyvy', 'uyvy'), ('yuv422_yuy2', 'yuyv'), ('yuyv', 'yuyv')],
)
def test_packed_yuv422_decodes_to_the_original_colours(mk, serialization, encoding, order):
    bgr = colour_blocks(40, 64)
    y, u, v = yuv_planes(bgr)
    h, w = y.shape
    u_full = np.repeat(u, 2, axis=0)  # 4:2:0 chroma -> one row per image row
    v_full = np.repeat(v, 2, axis=0)
    packed = np.zeros((h, w // 2, 4), np.uint8)
    if order == 'uyvy':
        packed[..., 0], packed[..., 1], packed[..., 2], packed[..., 3] = (
            u_full,
            y[:, 0::2],
            v_full,
            y[:, 1::2],
        )
    else:
        packed[..., 0], packed[..., 1], packed[..., 2], packed[..., 3] = (
            y[:, 0::2],
            u_full,
            y[:, 1::2],
            v_full,
        )
    pixels = packed.reshape(h, w, 2)
    decoded = decode_image(mk.simple(pixels, serialization, encoding))
    assert decoded.encoding == 'bgr8'
    assert decoded.image.shape == (h, w, 3)
    code = cv2.COLOR_YUV2BGR_UYVY if order == 'uyvy' else cv2.COLOR_YUV2BGR_YUYV
    np.testing.assert_array_equal(decoded.image, cv2.cvtColor(pixels, code))
    for got, want in zip(quadrant_centres(decoded.image), quadrant_centres(bgr), strict=True):
        np.testing.assert_allclose(got, want, atol=4)


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize('step_pad', [0, 16])
def test_nv12_decodes_to_the_original_colours(mk, serialization, step_pad):
    bgr = colour_blocks(48, 64)
    y, u, v = yuv_planes(bgr)
    h, w = y.shape
    uv = np.stack([u, v], axis=-1).reshape(h // 2, w)
    nv12 = np.concatenate([y, uv])
    step = w + step_pad
    msg = mk.image(
        serialization, mk.pack_rows(nv12, step),
        width=w, height=h, step=step, encoding='nv12',
    )  # fmt: skip
    decoded = decode_image(msg)
    assert decoded.encoding == 'bgr8'
    assert decoded.image.shape == (h, w, 3)
    np.testing.assert_array_equal(decoded.image, cv2.cvtColor(nv12, cv2.COLOR_YUV2BGR_NV12))
    for got, want in zip(quadrant_centres(decoded.image), quadrant_centres(bgr), strict=True):
        np.testing.assert_allclose(got, want, atol=4)


def test_packed_yuv_with_an_odd_width_is_rejected(mk):
    msg = mk.image('cdr', np.zeros(6 * 4, np.uint8), width=3, height=4, step=6, encoding='uyvy')
    with pytest.raises(DecodeError, match='even'):
        decode_image(msg)


def assert_rejected_without_allocating(msg: RawMessage, match: str) -> None:
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


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
@pytest.mark.parametrize(
    ('width', 'height', 'encoding'),
    [
        (100_000, 100_000, 'rgb8'),
        (100_000, 1, 'mono8'),
        (20_000, 20_000, 'bayer_rggb8'),  # each side allowed, 4e8 pixels not
        (0, 10, 'mono8'),
    ],
)
def test_absurd_dimensions_are_rejected_before_any_allocation(
    mk, serialization, width, height, encoding
):
    msg = mk.image(
        serialization, np.zeros(64, np.uint8),
        width=width, height=height, step=width * 3, encoding=encoding,
    )  # fmt: skip
    assert_rejected_without_allocating(msg, 'out of range')


def test_step_smaller_than_a_row_is_rejected(mk):
    msg = mk.image('cdr', np.zeros(100 * 10, np.uint8), width=50, height=10, step=100,
                   encoding='rgb8')  # fmt: skip
    with pytest.raises(DecodeError, match='step 100 is less than'):
        decode_image(msg)


def test_data_shorter_than_step_times_height_is_rejected(mk):
    msg = mk.image('ros1', np.zeros(30 * 9, np.uint8), width=10, height=10, step=30,
                   encoding='rgb8')  # fmt: skip
    with pytest.raises(DecodeError, match='needs 300'):
        decode_image(msg)


def test_a_few_trailing_bytes_are_accepted_but_a_whole_extra_row_is_not(mk):
    pixels = random_pixels(10, 10, 3)
    data = mk.pack_rows(pixels, 30)
    ok = mk.image('cdr', np.concatenate([data, np.zeros(29, np.uint8)]),
                  width=10, height=10, step=30, encoding='rgb8')  # fmt: skip
    np.testing.assert_array_equal(decode_image(ok).image, pixels)
    bad = mk.image('cdr', np.concatenate([data, np.zeros(30, np.uint8)]),
                   width=10, height=10, step=30, encoding='rgb8')  # fmt: skip
    with pytest.raises(DecodeError, match='more than step'):
        decode_image(bad)


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
def test_unknown_encoding_is_rejected_by_name(mk, serialization):
    msg = mk.image(serialization, np.zeros(16, np.uint8), width=4, height=4, step=4,
                   encoding='bayer_xyzw42')  # fmt: skip
    with pytest.raises(DecodeError, match="'bayer_xyzw42'"):
        decode_image(msg)


@pytest.mark.parametrize('serialization', SERIALIZATIONS)
def test_truncated_messages_are_rejected(mk, serialization):
    msg = mk.simple(random_pixels(8, 8, 3), serialization, 'rgb8')
    for cut in (3, 10, 30, 60, len(msg.data) - 1):
        with pytest.raises(DecodeError):
            decode_image(msg._replace(data=msg.data[:cut]))


def test_non_cdr_encapsulation_is_rejected(mk):
    msg = mk.simple(random_pixels(2, 2, 1), 'cdr', 'mono8')
    with pytest.raises(DecodeError, match='CDR'):
        decode_image(msg._replace(data=b'\x00\x03\x00\x00' + bytes(msg.data[4:])))


def test_messages_that_are_not_images_are_rejected(mk):
    msg = mk.simple(random_pixels(2, 2, 1), 'cdr', 'mono8')
    with pytest.raises(DecodeError, match='not an image'):
        decode_image(msg._replace(msgtype='sensor_msgs/msg/CameraInfo'))
    with pytest.raises(DecodeError, match='protobuf'):
        decode_image(msg._replace(serialization='protobuf'))


def test_to_bgr8_converts_every_canonical_encoding():
    bgr = colour_blocks(8, 8)
    rgb = bgr[..., ::-1]
    assert to_bgr8(bgr, 'bgr8') is bgr
    np.testing.assert_array_equal(to_bgr8(rgb, 'rgb8'), bgr)
    np.testing.assert_array_equal(
        to_bgr8(np.dstack([rgb, np.full((8, 8), 9, np.uint8)]), 'rgba8'), bgr
    )
    np.testing.assert_array_equal(
        to_bgr8(np.dstack([bgr, np.full((8, 8), 9, np.uint8)]), 'bgra8'), bgr
    )
    mono = bgr[..., 1]
    out = to_bgr8(mono, 'mono8')
    assert out.shape == (8, 8, 3)
    np.testing.assert_array_equal(out[..., 2], mono)
    for encoding in CANONICAL_ENCODINGS:
        image = {
            'rgb8': rgb, 'bgr8': bgr, 'mono8': mono,
            'rgba8': np.dstack([rgb, mono]), 'bgra8': np.dstack([bgr, mono]),
            'mono16': mono.astype(np.uint16) * 100, '32FC1': mono.astype(np.float32) / 10,
        }[encoding]  # fmt: skip
        out = to_bgr8(image, encoding)
        assert out.shape == (8, 8, 3)
        assert out.dtype == np.uint8


def test_to_bgr8_scales_depth_by_the_finite_maximum():
    depth16 = np.array([[0, 1000], [2000, 4000]], np.uint16)
    assert to_bgr8(depth16, 'mono16')[..., 0].tolist() == [[0, 64], [128, 255]]
    depth32 = np.array([[np.nan, 1.0], [np.inf, 4.0]], np.float32)
    assert to_bgr8(depth32, '32FC1')[..., 0].tolist() == [[0, 64], [0, 255]]
    assert to_bgr8(np.full((2, 2), np.nan, np.float32), '32FC1').max() == 0
    with pytest.raises(DecodeError):
        to_bgr8(depth16, 'bayer_rggb8')
