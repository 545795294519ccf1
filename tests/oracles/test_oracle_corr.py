"""kernels/corr against its Dr.Jit oracle (research/oracles/corr.py): the dense path (volume, pyramid,
lookup) and the on-the-fly path, forward and VJPs (f1, f2, coords), float64 and float32."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import corr
from research.oracles.corr import lookup_oracle
from tests.oracles.conftest import U32, close64, within


def _case(seed: int, C: int, H: int, W: int, levels: int, radius: int, dtype):
    rng = np.random.default_rng(seed)
    f1 = rng.normal(size=(C, H, W))
    f2 = rng.normal(size=(C, H, W))
    # Positions inside and outside frame 2 (zero padding), off the integer lattice of every level.
    coords = np.stack([rng.uniform(-5, W + 5, (H, W)), rng.uniform(-5, H + 5, (H, W))])
    g = rng.normal(size=(levels * (2 * radius + 1) ** 2, H, W))
    return [a.astype(dtype) for a in (f1, f2, coords, g)]


def _dense(f1, f2, coords, levels, radius, g):
    pyr = corr.correlation_pyramid(corr.correlation_volume(f1, f2), levels)
    out = corr.lookup(pyr, coords, radius)
    lb = corr.lookup_backward(pyr, coords, radius, g)
    vol_grad = corr.correlation_pyramid_backward(lb["pyramid"])
    fg = corr.correlation_volume_backward(f1, f2, next(iter(vol_grad.values())))
    return out, {"f1": fg["f1"], "f2": fg["f2"], "coords": lb["coords"]}


def _onthefly(f1, f2, coords, levels, radius, g):
    fp = corr.pool_features(f2, levels)
    out = corr.lookup_onthefly(f1, fp, coords, radius)
    b = corr.lookup_onthefly_backward(f1, fp, coords, radius, g)
    f2g = corr.pool_features_backward(b["f2_pyramid"])
    return out, {"f1": b["f1"], "f2": next(iter(f2g.values())), "coords": b["coords"]}


@pytest.mark.parametrize("path", [_dense, _onthefly], ids=["dense", "onthefly"])
@pytest.mark.parametrize("seed, C, H, W, levels, radius", [(0, 5, 9, 11, 2, 1), (1, 8, 12, 10, 3, 2)])
def test_float64_matches_the_oracle(path, seed, C, H, W, levels, radius):
    f1, f2, coords, g = _case(seed, C, H, W, levels, radius, np.float64)
    out, grads = path(f1, f2, coords, levels, radius, g)
    want, wgrads = lookup_oracle(f1, f2, coords, levels, radius, g)
    close64("lookup", out, want)
    for k in ("f1", "f2", "coords"):
        close64(f"d{k}", grads[k], wgrads[k])


@pytest.mark.parametrize("path", [_dense, _onthefly], ids=["dense", "onthefly"])
def test_float32_within_the_rounding_bound(path):
    """The volume is a C-term dot product, pooling adds 2 levels of 4-term means per level, bilinear
    sampling 4 more terms (n = C + 2 L + 8 rounded operations on sums of |terms|, which the oracle
    on |f1|, |f2|, |g| gives); the bilinear weights come from fx = u - floor(u), whose absolute error
    is u (|x| + r + 1), which moves each of the 4 weights: + 4 u (max|coords| + r + 1) max|V|.
    The coordinate VJP sums 4 (2r+1)^2 L products g (V_b - V_a) per pixel: its error is at most
    n u times 2 max|V| sum_taps |g|, plus the same weight term."""
    C, H, W, levels, radius = 12, 10, 13, 3, 2
    f1, f2, coords, g = _case(2, C, H, W, levels, radius, np.float32)
    out, grads = path(f1, f2, coords, levels, radius, g)
    a64 = [a.astype(np.float64) for a in (f1, f2, coords, g)]
    want, wgrads = lookup_oracle(a64[0], a64[1], a64[2], levels, radius, a64[3])
    mag, mgrads = lookup_oracle(np.abs(a64[0]), np.abs(a64[1]), a64[2], levels, radius, np.abs(a64[3]))
    vmax = float(np.abs(a64[0]).sum(0).max() * np.abs(a64[1]).max() / np.sqrt(C))  # >= every |V| entry
    n = C + 2 * levels + 8
    weights = 4 * (float(np.abs(a64[2]).max()) + radius + 1)
    within("lookup", out, want, U32 * (n * mag.max() + weights * vmax))
    for k in ("f1", "f2"):
        within(f"d{k}", grads[k], wgrads[k], U32 * (n + weights) * mgrads[k].max())
    g_sum = float(np.abs(a64[3]).sum(0).max())
    within("dcoords", grads["coords"], wgrads["coords"], U32 * (n + weights) * 2 * vmax * g_sum)
