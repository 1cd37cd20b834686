"""``Disparity``, the stereo task's output: checked on construction, depth from f and t."""

from __future__ import annotations

import numpy as np
import pytest

from replaybench.errors import StereoError
from replaybench.stereo import Disparity
from replaybench.stereo.msgs import parse_disparity_image, serialize_disparity_image


def test_a_disparity_refuses_what_is_not_a_float32_image() -> None:
    with pytest.raises(StereoError, match='float32 H x W'):
        Disparity(
            np.zeros((4, 4), np.float64), f=1, t=1, min_disparity=0, max_disparity=1, delta_d=0
        )
    with pytest.raises(StereoError, match='float32 H x W'):
        Disparity(np.zeros(4, np.float32), f=1, t=1, min_disparity=0, max_disparity=1, delta_d=0)


def test_depth_is_f_times_t_over_the_disparity_less_the_offset_and_nan_without_estimate() -> None:
    d = np.array([[10.0, np.nan, -2.0, 3.0]], np.float32)
    out = Disparity(
        d, f=100.0, t=0.1, min_disparity=0.0, max_disparity=63.0, delta_d=1 / 16, cx_offset=1.0
    )
    z = out.depth()
    assert z[0, 0] == pytest.approx(100 * 0.1 / 9)
    assert np.isnan(z[0, 1])
    assert np.isnan(z[0, 2])
    assert z[0, 3] == pytest.approx(100 * 0.1 / 2)
    assert out.estimated().tolist() == [[True, False, False, True]]
    assert out.size == (4, 1)


def test_a_recorded_disparity_image_becomes_the_same_disparity() -> None:
    d = np.array([[1.5, np.nan], [3.25, 7.0]], np.float32)
    data = serialize_disparity_image(
        5,
        'left',
        d,
        f=200.0,
        t=0.12,
        min_disparity=0.0,
        max_disparity=63.0,
        delta_d=0.0625,
        valid_window=(1, 0, 2, 1),
    )
    out = Disparity.of_message(parse_disparity_image(data))
    assert out.estimated().tolist() == [[True, False], [True, True]]
    assert out.disparity[out.estimated()].tolist() == [1.5, 3.25, 7.0]
    assert (out.f, out.delta_d, out.valid_window) == (200.0, 0.0625, (1, 0, 2, 1))
    assert out.t == pytest.approx(0.12)
