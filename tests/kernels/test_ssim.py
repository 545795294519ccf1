"""kernels/ssim.py against a plain NumPy reference, finite differences, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import ssim as kssim
from research.checks import ssim as cssim
from research.gradcheck import assert_gradcheck


def filter_same_zero_pad(img: np.ndarray, window: np.ndarray) -> np.ndarray:
    """'Same'-size correlation of every channel of img (H, W, C) with a 2-D window, zero padding."""
    h, w, _ = img.shape
    r = window.shape[0] // 2
    padded = np.zeros((h + 2 * r, w + 2 * r, img.shape[2]))
    padded[r:r + h, r:r + w] = img
    out = np.zeros(img.shape)
    for dy in range(window.shape[0]):
        for dx in range(window.shape[1]):
            out += window[dy, dx] * padded[dy:dy + h, dx:dx + w]
    return out


def ssim_map_ref(x: np.ndarray, y: np.ndarray, data_range: float = 1.0) -> np.ndarray:
    k = np.arange(11) - 5
    g = np.exp(-(k**2) / (2 * 1.5**2))
    window = np.outer(g, g) / np.outer(g, g).sum()
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mu_x, mu_y = filter_same_zero_pad(x, window), filter_same_zero_pad(y, window)
    var_x = filter_same_zero_pad(x * x, window) - mu_x**2
    var_y = filter_same_zero_pad(y * y, window) - mu_y**2
    cov = filter_same_zero_pad(x * y, window) - mu_x * mu_y
    return (2 * mu_x * mu_y + c1) * (2 * cov + c2) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(20, 23, 3), (7, 5, 1)])
def test_ssim_map_matches_reference(dtype, shape):
    rng = np.random.default_rng(0)
    y = rng.uniform(0, 1, shape)
    x = np.clip(y + rng.normal(0, 0.1, shape), 0, 1)
    got = kssim.ssim_map(x.astype(dtype), y.astype(dtype)).map.numpy()
    want = ssim_map_ref(x.astype(dtype).astype(np.float64), y.astype(dtype).astype(np.float64))
    assert got.dtype == dtype
    tol = dict(rtol=1e-4, atol=1e-5) if dtype == np.float32 else dict(rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(got, want, **tol)


def test_ssim_identical_images_is_one_and_stationary():
    y = np.random.default_rng(1).uniform(0, 1, (16, 16, 3))
    value, grad = kssim.ssim(y, y)
    assert value == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(grad.numpy(), 0.0, atol=1e-12)


def test_ssim_gradients():
    assert_gradcheck(cssim.ssim_checks())


def test_ssim_mean_gradient_matches_map_gradient():
    rng = np.random.default_rng(2)
    x, y = rng.uniform(0, 1, (9, 10, 3)), rng.uniform(0, 1, (9, 10, 3))
    value, grad = kssim.ssim(x, y)
    state = kssim.ssim_map(x, y)
    dx, _ = kssim.ssim_map_backward(state, np.full(x.shape, 1.0 / x.size))
    assert value == pytest.approx(ssim_map_ref(x, y).mean(), rel=1e-12)
    np.testing.assert_array_equal(grad.numpy(), dx.numpy())


@pytest.mark.parametrize("x, y, match", [
    (np.zeros((4, 4)), np.zeros((4, 4)), "x: expected an image of shape"),
    (np.zeros((4, 4, 3)), np.zeros((4, 5, 3)), "y: expected shape"),
    (np.zeros((4, 4, 3)), np.zeros((4, 4, 3), dtype=np.float32), "y: expected dtype float64"),
    (np.zeros((4, 4, 3), dtype=np.int32), np.zeros((4, 4, 3)), "x: expected float32 or float64"),
    (np.full((4, 4, 3), np.nan), np.zeros((4, 4, 3)), "x: contains NaN"),
    (np.zeros((0, 4, 3)), np.zeros((0, 4, 3)), "x: expected a non-empty image"),
])
def test_ssim_bad_input(x, y, match):
    with pytest.raises(ValueError, match=match):
        kssim.ssim_map(x, y)


def test_ssim_bad_data_range_and_grad():
    x = np.zeros((4, 4, 3))
    with pytest.raises(ValueError, match="data_range"):
        kssim.ssim_map(x, x, data_range=0.0)
    state = kssim.ssim_map(x, x)
    with pytest.raises(ValueError, match="grad_map: expected shape"):
        kssim.ssim_map_backward(state, np.zeros((4, 4, 1)))
