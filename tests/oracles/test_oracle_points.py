"""kernels/points/chamfer.py against its Dr.Jit oracle (research/oracles/points.py): value and VJPs, float64
and float32."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import points as kp
from research.oracles.points import chamfer_oracle
from tests.oracles.conftest import U32, close64, within


def _clouds(seed, n, m, dtype):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)).astype(dtype), (rng.normal(size=(m, 3)) * 0.8 + 0.3).astype(dtype)


@pytest.mark.parametrize("seed, n, m, g", [(0, 700, 500, 1.0), (1, 64, 900, -0.3)])
def test_float64_value_and_vjp_match_the_oracle(seed, n, m, g):
    x, y = _clouds(seed, n, m, np.float64)
    res = kp.chamfer_distance(x, y)
    grads = kp.chamfer_backward(x, y, res, g)
    value, (ox, oy) = chamfer_oracle(x, y, g)
    close64("CD", np.array([res.value]), np.array([value]))
    close64("dL/dx", grads["x"], ox)
    close64("dL/dy", grads["y"], oy)


def test_float32_within_the_rounding_bound():
    """Each d2 takes 3 subtractions, 3 squares and 2 additions in float32, so its relative error is at most
    8u, and the value (a float64 mean of them) at most 8u CD. A gradient row is w (x_i - y_a(i)) plus w' times
    a sum of L differences (L: the longest run of points sharing one nearest neighbour); each difference is
    rounded once (u), the sum adds (L + 1) u of the sum of magnitudes, and the weights one more: so
    |d grad| <= (L + 3)^2 u D max(w, w'), D the largest component of a nearest-pair difference. The
    nearest neighbours are the same in both precisions (no pair is that close to a tie on these clouds:
    checked by the equal argmins)."""
    x, y = _clouds(2, 600, 450, np.float32)
    res = kp.chamfer_distance(x, y)
    grads = kp.chamfer_backward(x, y, res)
    x64, y64 = x.astype(np.float64), y.astype(np.float64)
    value, (ox, oy) = chamfer_oracle(x64, y64)
    r64 = kp.chamfer_distance(x64, y64)
    np.testing.assert_array_equal(res.near_y, r64.near_y)
    np.testing.assert_array_equal(res.near_x, r64.near_x)
    within("CD", np.array([res.value]), np.array([value]), 8 * U32 * value)
    runs = max(np.bincount(res.near_y).max(), np.bincount(res.near_x).max())
    d = max(np.abs(x64 - y64[res.near_y]).max(), np.abs(y64 - x64[res.near_x]).max())
    w = 2.0 / min(len(x), len(y))
    for name, got, want in (("dL/dx", grads["x"], ox), ("dL/dy", grads["y"], oy)):
        within(name, got, want, (runs + 3) ** 2 * U32 * d * w)
