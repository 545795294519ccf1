"""kernels/ssim.py against its NumPy reference (kernels/reference/ssim.py), finite differences, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import ssim as kssim
from kernels.reference import ssim as ref
from research.checks import ssim as cssim
from research.gradcheck import assert_gradcheck


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(20, 23, 3), (7, 5, 1)])
@pytest.mark.usefixtures("warp_device")
def test_ssim_map_matches_reference(dtype, shape):
    rng = np.random.default_rng(0)
    y = rng.uniform(0, 1, shape)
    x = np.clip(y + rng.normal(0, 0.1, shape), 0, 1)
    got = kssim.ssim_map(x.astype(dtype), y.astype(dtype)).map
    want = ref.ssim_map(x.astype(dtype).astype(np.float64), y.astype(dtype).astype(np.float64))
    assert isinstance(got, np.ndarray) and got.dtype == dtype
    tol = dict(rtol=1e-4, atol=1e-5) if dtype == np.float32 else dict(rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(got, want, **tol)


def test_ssim_identical_images_is_one_and_stationary():
    y = np.random.default_rng(1).uniform(0, 1, (16, 16, 3))
    value, grad = kssim.ssim(y, y)
    assert value == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(grad, 0.0, atol=1e-12)


@pytest.mark.usefixtures("warp_device")
def test_ssim_gradients():
    assert_gradcheck(cssim.ssim_checks())


def test_ssim_mean_gradient_matches_map_gradient():
    rng = np.random.default_rng(2)
    x, y = rng.uniform(0, 1, (9, 10, 3)), rng.uniform(0, 1, (9, 10, 3))
    value, grad = kssim.ssim(x, y)
    state = kssim.ssim_map(x, y)
    dx, _ = kssim.ssim_map_backward(state, np.full(x.shape, 1.0 / x.size))
    assert value == pytest.approx(ref.ssim_map(x, y).mean(), rel=1e-12)
    np.testing.assert_array_equal(grad, dx)


@pytest.mark.parametrize("x, y, match", [
    (np.zeros((4, 4)), np.zeros((4, 4)), "x: expected 3 dimensions"),
    (np.zeros((4, 4, 3)), np.zeros((4, 5, 3)), "y: expected shape"),
    (np.zeros((4, 4, 3)), np.zeros((4, 4, 3), dtype=np.float32), "y: expected dtype float64"),
    (np.zeros((4, 4, 3), dtype=np.int32), np.zeros((4, 4, 3)), "x: expected dtype float32 or float64"),
    (np.full((4, 4, 3), np.nan), np.zeros((4, 4, 3)), "x: expected finite values"),
    (np.zeros((0, 4, 3)), np.zeros((0, 4, 3)), "x: expected a non-empty array"),
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


def test_ssim_warp_inputs_give_warp_outputs():
    import warp as wp

    rng = np.random.default_rng(3)
    x, y = rng.uniform(0, 1, (9, 10, 3)).astype(np.float32), rng.uniform(0, 1, (9, 10, 3)).astype(np.float32)
    value_np, grad_np = kssim.ssim(x, y)
    value_wp, grad_wp = kssim.ssim(wp.array(x), wp.array(y))
    assert isinstance(grad_np, np.ndarray) and isinstance(grad_wp, wp.array)
    assert value_np == value_wp
    np.testing.assert_array_equal(grad_np, grad_wp.numpy())


@pytest.mark.parametrize("shape", [(64, 71, 3), (9, 30, 2), (30, 4, 1), (3, 3, 3)])
def test_ssim_cpu_fast_path_is_the_warp_kernel_bit_for_bit(shape, monkeypatch):
    """The float32 row-at-a-time C++ blur (kernels/native/ssim_blur_row.cpp) adds the same terms in the
    same order as _blur_kernel, each product and sum its own statement, so map, mean and both input
    gradients are bit-identical with the fast path on and off; images narrower or lower than the
    window exercise every zero-padded edge."""
    from kernels import _arrays, fast_paths

    rng = np.random.default_rng(7)
    y = rng.uniform(0, 1, shape).astype(np.float32)
    x = np.clip(y + rng.normal(0, 0.2, shape), 0, 1).astype(np.float32)
    g = rng.normal(0, 1, shape).astype(np.float32)
    launched = []
    launch = _arrays.Inputs.launch
    monkeypatch.setattr(_arrays.Inputs, "launch", lambda self, k, *a, **kw: (launched.append(k), launch(self, k, *a, **kw)))

    def run():
        state = kssim.ssim_map(x, y, device="cpu")
        return (state.map, state.mean(), *kssim.ssim_map_backward(state, g))

    fast_paths.set_enabled(True)  # also under DRLAB_FAST_PATHS=0 (make test's second pass)
    try:
        fast = run()
    finally:
        fast_paths.set_enabled(None)
    assert kssim._blur_rows_cpu_kernel in launched and kssim._blur_kernel not in launched
    launched.clear()
    with fast_paths.disabled():
        plain = run()
    assert kssim._blur_kernel in launched and kssim._blur_rows_cpu_kernel not in launched
    assert fast[1] == plain[1]
    for a, b in zip(fast[:1] + fast[2:], plain[:1] + plain[2:]):
        np.testing.assert_array_equal(a, b)
