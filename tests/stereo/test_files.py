"""Middlebury PFM and KITTI PNG disparities, DisparityImage messages, the pictures."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from replaybench.errors import DecodeError, StereoError
from replaybench.msgs import ros2msg_schema
from replaybench.stereo.files import (
    read_disparity_file,
    read_kitti_png,
    read_pfm,
    write_kitti_png,
    write_pfm,
)
from replaybench.stereo.msgs import parse_disparity_image, serialize_disparity_image
from replaybench.stereo.thumbnail import disparity_picture, error_picture


def test_a_pfm_is_read_with_its_rows_bottom_first_in_either_byte_order():
    # 2x2, rows bottom first: the file's first row is the image's last
    little = b'Pf\n2 2\n-1.0\n' + struct.pack('<4f', 3.0, 4.0, 1.0, 2.0)
    big = b'Pf\n2 2\n1.0\n' + struct.pack('>4f', 3.0, 4.0, 1.0, float('inf'))
    assert read_pfm(little).tolist() == [[1.0, 2.0], [3.0, 4.0]]
    assert read_pfm(big).tolist() == [[1.0, float('inf')], [3.0, 4.0]]


@pytest.mark.parametrize('little_endian', [True, False])
def test_pfm_files_written_are_read_back(tmp_path, little_endian):
    image = np.arange(12, dtype=np.float32).reshape(3, 4)
    path = write_pfm(tmp_path / 'd.pfm', image, little_endian=little_endian)
    assert np.array_equal(read_disparity_file(path), image)
    colour = np.arange(24, dtype=np.float32).reshape(2, 4, 3)
    assert np.array_equal(read_pfm(write_pfm(tmp_path / 'c.pfm', colour)), colour)


def test_a_kitti_png_is_value_over_256_with_0_unknown(tmp_path):
    d = np.array([[0.0, 1.5, 255.99609375], [np.nan, -3.0, 20.25]])
    path = write_kitti_png(tmp_path / 'd.png', d)
    back = read_kitti_png(path)
    assert back[0, 1] == 1.5
    assert back[0, 2] == 255.99609375
    assert back[1, 2] == 20.25
    assert np.isnan(back[[0, 1, 1], [0, 0, 1]]).all()
    assert np.array_equal(read_disparity_file(path), back, equal_nan=True)


def test_files_that_are_no_disparity_are_one_line(tmp_path):
    (tmp_path / 'x.pfm').write_bytes(b'P6\n1 1\n255\n\0\0\0')
    with pytest.raises(StereoError, match='not a PFM file'):
        read_pfm(tmp_path / 'x.pfm')
    (tmp_path / 'short.pfm').write_bytes(b'Pf\n4 4\n-1.0\n' + bytes(8))
    with pytest.raises(StereoError, match='holds 8 bytes, not 64'):
        read_pfm(tmp_path / 'short.pfm')
    import cv2

    cv2.imwrite(str(tmp_path / 'eight.png'), np.zeros((2, 2), np.uint8))
    with pytest.raises(StereoError, match='not a KITTI disparity PNG'):
        read_kitti_png(tmp_path / 'eight.png')
    with pytest.raises(StereoError, match=r'not \.txt'):
        read_disparity_file(tmp_path / 'd.txt')


@pytest.mark.parametrize('ros1', [False, True])
def test_a_disparity_image_round_trips_with_no_match_below_min_disparity(ros1):
    d = np.array([[np.nan, 1.5, 2.0], [3.0625, np.inf, 63.0]], dtype=np.float32)
    data = serialize_disparity_image(
        1_700_000_000_250_000_000,
        'left_optical',
        d,
        f=256.0,
        t=0.12,
        min_disparity=0.0,
        max_disparity=63.0,
        delta_d=1 / 16,
        valid_window=(70, 7, 225, 242),
        ros1=ros1,
    )
    msg = parse_disparity_image(data, ros1=ros1)
    assert msg.stamp_ns == 1_700_000_000_250_000_000
    assert msg.frame_id == 'left_optical'
    assert msg.disparity.tolist() == [[-1.0, 1.5, 2.0], [3.0625, -1.0, 63.0]]
    assert (msg.f, msg.min_disparity, msg.max_disparity, msg.delta_d) == (256.0, 0.0, 63.0, 0.0625)
    assert msg.t == pytest.approx(0.12)
    assert msg.valid_window == (70, 7, 225, 242)


def test_the_disparity_image_type_is_stereo_msgs_as_released():
    schema = ros2msg_schema('stereo_msgs/msg/DisparityImage').split('=' * 80)[0].split()
    assert schema == [
        'std_msgs/Header', 'header', 'sensor_msgs/Image', 'image', 'float32', 'f',
        'float32', 't', 'sensor_msgs/RegionOfInterest', 'valid_window', 'float32',
        'min_disparity', 'float32', 'max_disparity', 'float32', 'delta_d',
    ]  # fmt: skip


def test_bytes_that_are_no_disparity_image_are_a_decode_error():
    with pytest.raises(DecodeError, match='not a stereo_msgs/msg/DisparityImage'):
        parse_disparity_image(b'\x00\x01\x00\x00\x01')


def test_the_pictures_colour_disparity_and_error_and_black_out_what_is_unknown():
    d = np.array([[np.nan, 10.0, 20.0, 40.0]], dtype=np.float32)
    picture = disparity_picture(d, max_disparity=40.0)
    assert picture.shape == (1, 4, 3)
    assert picture[0, 0].tolist() == [0, 0, 0]
    assert picture[0, 3].tolist() != picture[0, 1].tolist()
    truth = np.array([[10.0, 10.5, 0.0, 30.0]])
    error = error_picture(d, truth)
    assert error[0, 0].tolist() == [200, 40, 200]  # truth, no estimate
    assert error[0, 1].tolist() == [40, 180, 60]  # within 1 px
    assert error[0, 2].tolist() == [0, 0, 0]  # no truth
    assert error[0, 3].tolist() == [215, 40, 40]  # 10 px off
    assert disparity_picture(np.zeros((240, 1000)), width=320).shape == (60, 250, 3)
