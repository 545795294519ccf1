"""kernels/stereo against its Dr.Jit oracle (research/oracles/stereo.py): SAD and ZNCC volumes, feature
correlation and soft-argmin with their VJPs, float64 and float32."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import stereo as kst
from research.oracles.stereo import feature_correlation_oracle, soft_argmin_oracle, window_cost_oracle
from tests.oracles.conftest import U32, close64, within


def _pair(seed: int, H: int = 13, W: int = 19, dtype=np.float64):
    rng = np.random.default_rng(seed)
    left = rng.uniform(0, 1, (H, W))
    right = np.roll(left, -3, axis=1) + rng.normal(0, 0.05, (H, W))
    return left.astype(dtype), right.astype(dtype)


@pytest.mark.parametrize("kind, radius", [("sad", 2), ("zncc", 3), ("zncc", 1)])
@pytest.mark.parametrize("dmin, dmax", [(0, 7), (-2, 5)])
def test_window_costs_float64(kind, radius, dmin, dmax):
    left, right = _pair(0)
    got = kst.sad_cost(left, right, dmin, dmax, radius) if kind == "sad" else kst.zncc_cost(left, right, dmin, dmax,
                                                                                             radius)
    close64(kind, got, window_cost_oracle(left, right, dmin, dmax, radius, kind))


@pytest.mark.parametrize("kind, radius", [("sad", 2), ("zncc", 3)])
def test_window_costs_float32(kind, radius):
    """drlab sums the window in float64 and rounds once; the oracle64 is exact to ~1e-16. The bound
    allows every one of the (2r+1)^2 window terms and ~10 more operations a float32 rounding each
    (n = (2r+1)^2 + 10), on the volume's largest value (kappa 1 for SAD, a sum of non-negative terms;
    for ZNCC drlab's float64 moments are exact to float32 precision, so rounding to float32 dominates)."""
    left, right = _pair(1, dtype=np.float32)
    got = kst.sad_cost(left, right, 0, 6, radius) if kind == "sad" else kst.zncc_cost(left, right, 0, 6, radius)
    want = window_cost_oracle(left.astype(np.float64), right.astype(np.float64), 0, 6, radius, kind)
    within(kind, got, want, ((2 * radius + 1) ** 2 + 10) * U32 * np.abs(want).max())


def _features(seed: int, C: int, H: int, W: int, D: int, dtype):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(C, H, W)).astype(dtype), rng.normal(size=(C, H, W)).astype(dtype),
            rng.normal(size=(H, W, D)).astype(dtype))


@pytest.mark.parametrize("dmin", [0, -3])
def test_feature_correlation_float64(dmin):
    fl, fr, g = _features(2, 7, 9, 14, 6, np.float64)
    got = kst.feature_correlation(fl, fr, dmin, dmin + 6)
    grads = kst.feature_correlation_backward(fl, fr, g, dmin)
    want, (gl, gr) = feature_correlation_oracle(fl, fr, dmin, dmin + 6, g)
    close64("corr", got, want)
    close64("dF_L", grads["feat_left"], gl)
    close64("dF_R", grads["feat_right"], gr)


def test_feature_correlation_float32():
    """Dot products of length C (and D for the VJPs): |error| <= (n + 2) u sum |terms| (n = C or D),
    the sums of |terms| being the oracle evaluated on |inputs| (every term then counts positively)."""
    C, D = 16, 6
    fl, fr, g = _features(3, C, 9, 14, D, np.float32)
    got = kst.feature_correlation(fl, fr, -1, D - 1)
    grads = kst.feature_correlation_backward(fl, fr, g, -1)
    f64 = [a.astype(np.float64) for a in (fl, fr, g)]
    want, (gl, gr) = feature_correlation_oracle(f64[0], f64[1], -1, D - 1, f64[2])
    mag, (ml, mr) = feature_correlation_oracle(*(np.abs(a) for a in f64[:2]), -1, D - 1, np.abs(f64[2]))
    within("corr", got, want, (C + 2) * U32 * mag.max())
    # dF = sum_k G F / sqrt(C): D products of which each factor carries the forward-free rounding.
    within("dF_L", grads["feat_left"], gl, (D + 2) * U32 * ml.max())
    within("dF_R", grads["feat_right"], gr, (D + 2) * U32 * mr.max())


@pytest.mark.parametrize("temperature", [1.0, 0.3])
@pytest.mark.parametrize("dmin", [0, -4])
def test_soft_argmin_float64(temperature, dmin):
    rng = np.random.default_rng(4)
    cost = rng.uniform(0, 3, (8, 11, 9))
    g = rng.normal(size=(8, 11))
    d = kst.soft_argmin(cost, dmin, temperature)
    gc = kst.soft_argmin_backward(cost, dmin, g, temperature)["cost"]
    want, wc = soft_argmin_oracle(cost, dmin, g, temperature)
    close64("disparity", d, want)
    close64("dL/dcost", gc, wc)


def test_soft_argmin_float32():
    """sigma_k = e_k / z: each e_k = exp((c_min - C_k) / T) carries relative error (2 + 2 |C|max / T) u
    (the argument's rounding, amplified by exp), z and num are D-term sums of positive terms, so
    |d_err| <= (D + 4 + 2 |C|max / T) u max|d_k|. The VJP sigma_k (d - d_k) / T g adds d's error
    and the subtraction's: |err| <= 2 (D + 4 + 2 |C|max / T) u max|d_k| max|g| / T."""
    rng = np.random.default_rng(5)
    D, T, dmin = 9, 0.5, -2
    cost = rng.uniform(0, 3, (8, 11, D)).astype(np.float32)
    g = rng.normal(size=(8, 11)).astype(np.float32)
    d = kst.soft_argmin(cost, dmin, T)
    gc = kst.soft_argmin_backward(cost, dmin, g, T)["cost"]
    want, wc = soft_argmin_oracle(cost.astype(np.float64), dmin, g.astype(np.float64), T)
    n = D + 4 + 2 * float(np.abs(cost).max()) / T
    dk = max(abs(dmin), abs(dmin + D - 1))
    within("disparity", d, want, n * U32 * dk)
    within("dL/dcost", gc, wc, 2 * n * U32 * dk * float(np.abs(g).max()) / T)
