"""kernels.stereo.post: the row fill + 3x3 median equals research.stereo.matching.fill_invalid then scipy's median."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from scipy.ndimage import median_filter

from kernels import stereo
from research.stereo.matching import fill_invalid


def _want(disp, valid):
    return median_filter(fill_invalid(disp, valid), size=3, mode="nearest")


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(1, 1), (1, 40), (40, 1), (2, 17), (3, 18), (7, 19), (12, 53), (31, 70)])
def test_fill_median3_equals_fill_invalid_then_scipy_median(dtype, shape):
    rng = np.random.default_rng(sum(shape))
    for trial, keep in enumerate((0.0, 0.3, 0.8, 1.0)):
        # ties (small integers) and distinct values; invalid pixels hold garbage, NaN included
        disp = (rng.integers(0, 5, shape) if trial % 2 else rng.normal(0, 10, shape)).astype(dtype)
        valid = rng.uniform(size=shape) < keep
        disp[~valid & (rng.uniform(size=shape) < 0.5)] = np.nan
        got = stereo.fill_median3(disp, valid)
        assert got.dtype == dtype and got.shape == shape
        np.testing.assert_array_equal(got, _want(disp, valid).astype(dtype))


def test_fill_median3_rows_without_valid_pixels_become_zero_before_the_median():
    disp = np.arange(24, dtype=np.float32).reshape(4, 6)
    valid = np.ones((4, 6), bool)
    valid[1:3] = False
    np.testing.assert_array_equal(stereo.fill_median3(disp, valid), _want(disp, valid).astype(np.float32))


def test_fill_median3_takes_wp_arrays_and_checks_its_arguments():
    disp = np.random.default_rng(0).uniform(0, 9, (20, 37)).astype(np.float32)
    valid = disp > 2.0
    got = stereo.fill_median3(wp.array(disp), wp.array(valid.astype(np.uint8)))
    assert isinstance(got, wp.array)
    np.testing.assert_array_equal(got.numpy(), _want(disp, valid).astype(np.float32))
    with pytest.raises(ValueError, match="disp"):
        stereo.fill_median3(disp[0], valid[0])
    with pytest.raises(ValueError, match="valid"):
        stereo.fill_median3(disp, valid[:, :5])
    with pytest.raises(ValueError, match="valid"):
        stereo.fill_median3(disp, valid.astype(np.float32))
