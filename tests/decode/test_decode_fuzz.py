"""Corrupted messages: decoding either succeeds or raises DecodeError, never anything else."""

from __future__ import annotations

import contextlib

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from replaybench.decode import decode_camera_info, decode_image
from replaybench.errors import DecodeError

SETTINGS = settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def corrupt(data: bytes, edits: list[tuple[int, int]], cut: int | None) -> bytes:
    buf = bytearray(data)
    for pos, value in edits:
        buf[pos % len(buf)] = value
    return bytes(buf[:cut] if cut is not None else buf)


EDITS = st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=6)
CUTS = st.one_of(st.none(), st.integers(0, 400))


@pytest.mark.parametrize('serialization', ['cdr', 'ros1'])
@pytest.mark.parametrize('encoding', ['rgb8', '16UC1', 'nv12', 'bayer_grbg8'])
@SETTINGS
@given(edits=EDITS, cut=CUTS)
def test_corrupted_raw_images_raise_only_decode_error(mk, serialization, encoding, edits, cut):
    pixels = np.arange(6 * 8 * 3, dtype=np.uint8).reshape(6, 8, 3)
    if encoding == '16UC1':
        pixels = pixels[..., 0].astype(np.uint16)
    elif encoding != 'rgb8':
        pixels = pixels[..., 0]
    msg = mk.simple(pixels, serialization, encoding)
    bad = msg._replace(data=corrupt(msg.data, edits, cut))
    try:
        decoded = decode_image(bad)
    except DecodeError:
        return
    assert decoded.image.ndim in {2, 3}


@pytest.mark.parametrize('ext', ['.jpg', '.png'])
@SETTINGS
@given(edits=EDITS, cut=st.one_of(st.none(), st.integers(0, 3000)))
def test_corrupted_compressed_images_raise_only_decode_error(mk, ext, edits, cut):
    image = np.zeros((24, 32, 3), np.uint8)
    image[4:12, 6:20] = (10, 200, 30)
    ok, buf = cv2.imencode(ext, image)
    assert ok
    msg = mk.compressed('cdr', buf.tobytes(), 'rgb8; jpeg compressed bgr8')
    bad = msg._replace(data=corrupt(msg.data, edits, cut))
    try:
        decoded = decode_image(bad)
    except DecodeError:
        return
    # a corrupted header may change the size; whatever decodes stays within the size limits
    height, width = decoded.image.shape[:2]
    assert 0 < height <= 32768
    assert 0 < width <= 32768


@SETTINGS
@given(data=st.binary(max_size=300))
def test_random_bytes_raise_only_decode_error(data):
    from replaybench.types import RawMessage, Serialization

    both: tuple[Serialization, ...] = ('cdr', 'ros1')
    for msgtype in ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage'):
        for serialization in both:
            with contextlib.suppress(DecodeError):
                decode_image(RawMessage('/t', msgtype, serialization, 0, 0, data))
    for serialization in both:
        with contextlib.suppress(DecodeError):
            decode_camera_info(
                RawMessage('/t', 'sensor_msgs/msg/CameraInfo', serialization, 0, 0, data)
            )
