"""kernels._vexp's 16-lane exp (glibc expf's bits) and the stereo cost's rho on its lanes (kernels.stereo.adcensus)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels._vexp import exp16_mismatches
from kernels.stereo.adcensus import _V32, _rho_lanes, _robust_term


@wp.kernel(enable_backward=False)
def _exp16_sweep(lo: wp.uint32, stride: wp.uint32, n: int, bad: wp.array(dtype=wp.int32)):
    b = wp.tid()
    bad[b] = exp16_mismatches(lo, stride, b, n)


def test_vexp_is_expf_on_positive_inputs_and_past_the_fast_path():
    """The lanes' exp has the bits of expf (wp.exp on the CPU) on float32 inputs in [0, 100] (every 997th bit
    pattern; above 88, expf itself, lane by lane), around the fast path's end at -88 (every bit pattern of
    [-88.5, -87.5]) and on infinities and NaNs (tests/kernels/test_splat_rowblend.py sweeps [-100, 0])."""
    f = lambda v: int(np.float32(v).view(np.uint32))  # noqa: E731
    for lo, hi, stride in ((0, f(100.0), 997), (f(-87.5), f(-88.5), 1), (0x7F800000, 0x7FC00010, 4099),
                           (0xFF800000, 0xFFC00010, 4099)):
        n = (hi - lo) // stride + 1
        bad = wp.zeros((n + 15) // 16, dtype=wp.int32, device="cpu")
        wp.launch(_exp16_sweep, bad.shape[0], [wp.uint32(lo), wp.uint32(stride), n, bad], device="cpu")
        assert int(bad.numpy().sum()) == 0, (hex(lo), hex(hi))


@wp.func
def rho_block(c: wp.array(dtype=wp.float32), lam: wp.float64, weight: wp.float64, vec: wp.array(dtype=wp.float32),
              lane: wp.array(dtype=wp.float32), b: int):
    """Costs 16 b .. 16 b + 15: vec gets _rho_lanes on them as one vector, lane the scalar _robust_term of each
    (also tests/kernels/test_fast_paths.py's kernel built without AVX2)."""
    v = _V32()
    for i in range(16):
        v[i] = c[b * 16 + i]
    r = _rho_lanes(v, wp.float32(wp.float64(1.0) / lam), wp.float32(weight))
    for i in range(16):
        vec[b * 16 + i] = r[i]
        lane[b * 16 + i] = _robust_term(c[b * 16 + i], lam, weight)


@wp.kernel(enable_backward=False)
def _rho_both(c: wp.array(dtype=wp.float32), lam: wp.float64, weight: wp.float64, vec: wp.array(dtype=wp.float32),
              lane: wp.array(dtype=wp.float32)):
    rho_block(c, lam, weight, vec, lane, wp.tid())


@pytest.mark.parametrize("lam,weight", [(0.04, 1.0), (0.04, 0.3), (30.0, 1.0), (1e-3, 2.5)])
def test_rho_lanes_are_robust_term_bit_for_bit(lam, weight):
    """w (1 - exp(-c / lambda)) on 16 lanes (the BT terms' rho of kernels.stereo.adcensus' fused kernel) has the
    bits of the scalar _robust_term for costs c from 0 to past where exp underflows, denormals, huge values and
    infinity."""
    rng = np.random.default_rng(7)
    c = np.concatenate([np.linspace(0.0, 1.0, 4001), rng.uniform(0.0, 4.0, 4000), rng.exponential(0.05, 4000),
                        [0.0, 1e-45, 1e-38, 3e-39, 87.9 * lam, 88.1 * lam, 103.9 * lam, 104.1 * lam, 1e30, np.inf]])
    c = np.concatenate([c, np.zeros(-len(c) % 16)]).astype(np.float32)
    ca = wp.array(c, dtype=wp.float32, device="cpu")
    vec, lane = (wp.zeros(len(c), dtype=wp.float32, device="cpu") for _ in range(2))
    wp.launch(_rho_both, len(c) // 16, [ca, wp.float64(lam), wp.float64(weight), vec, lane], device="cpu")
    np.testing.assert_array_equal(vec.numpy().view(np.uint32), lane.numpy().view(np.uint32))
    assert np.isfinite(lane.numpy()).all() and lane.numpy().max() == np.float32(weight)
