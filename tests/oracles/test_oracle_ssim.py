"""kernels/ssim.py against its Dr.Jit oracle (research/oracles/ssim.py): map and VJPs, float64 and float32."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import ssim as kssim
from kernels.reference.ssim import filter_same_zero_pad
from research.oracles.ssim import ssim_oracle
from tests.oracles.conftest import U32, close64, within


def _images(seed: int, shape, dtype):
    rng = np.random.default_rng(seed)
    y = rng.uniform(0, 1, shape)
    x = np.clip(y + rng.normal(0, 0.15, shape), 0, 1)
    return x.astype(dtype), y.astype(dtype), rng.normal(size=shape).astype(dtype)


@pytest.mark.parametrize("seed, shape", [(0, (19, 23, 3)), (1, (12, 9, 1))])
def test_float64_map_and_vjp_match_the_oracle(seed, shape):
    x, y, g = _images(seed, shape, np.float64)
    state = kssim.ssim_map(x, y)
    dx, dy = kssim.ssim_map_backward(state, g)
    s, (ox, oy) = ssim_oracle(x, y, g)
    close64("map", state.map, s)
    close64("dL/dx", dx, ox)
    close64("dL/dy", dy, oy)


def _condition(x: np.ndarray, y: np.ndarray) -> float:
    """kappa = max over pixels of (e_xx + e_yy + 2|e_xy| + mu_x^2 + mu_y^2 + 2 mu_x mu_y) / (s_xx + s_yy + C2):
    how much the cancellation in the variances s = e - mu^2 amplifies the moments' relative error."""
    k = np.arange(11) - 5
    g = np.exp(-(k**2) / 4.5)
    w = np.outer(g, g) / np.outer(g, g).sum()
    x, y = x.astype(np.float64), y.astype(np.float64)
    mx, my = filter_same_zero_pad(x, w), filter_same_zero_pad(y, w)
    exx, eyy, exy = filter_same_zero_pad(x * x, w), filter_same_zero_pad(y * y, w), filter_same_zero_pad(x * y, w)
    b2 = exx - mx**2 + eyy - my**2 + 0.03**2
    return float(np.max((exx + eyy + 2 * np.abs(exy) + mx**2 + my**2 + 2 * np.abs(mx * my)) / b2))


def test_float32_within_the_rounding_bound():
    """Each moment is a 121-term sum of non-negative terms (relative error <= 121 u; drlab's two
    separable passes sum 11 + 11), and the SSIM formula adds about 15 rounded operations; the
    variances' cancellation amplifies these by kappa (`_condition`). So |dS| <= (121 + 15) u kappa |S|_max.
    The VJP's factors are the same rational functions with squared denominators (twice the
    condition) summed again over 121 window taps: (2 (121 + 15) + 121) u kappa |VJP|_max."""
    x, y, g = _images(2, (24, 21, 3), np.float32)
    state = kssim.ssim_map(x, y)
    dx, dy = kssim.ssim_map_backward(state, g)
    s, (ox, oy) = ssim_oracle(x.astype(np.float64), y.astype(np.float64), g.astype(np.float64))
    kappa = _condition(x, y)
    within("map", state.map, s, (121 + 15) * U32 * kappa * np.abs(s).max())
    for name, got, want in (("dL/dx", dx, ox), ("dL/dy", dy, oy)):
        within(name, got, want, (2 * (121 + 15) + 121) * U32 * kappa * np.abs(want).max())
