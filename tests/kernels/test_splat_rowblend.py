"""kernels/splat/rowblend.py: the float32 rasteriser's 16-lane row blend gives the scalar per-tile
loop's bytes (image, alpha, depth, final T, n_contrib), with pixels that stop, tiles cut by the
image edge, both modes, and rows whose powers leave expf's fast path (|power| >= 88)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import _arrays as A
from kernels import splat as ks
from kernels.splat.raster import _rasterize_wp, _rows_ok, background_array
from kernels.splat.rowblend import exp16_mismatches
from research.bench.splat import bench_scene
from research.checks import splat as cs
from tests.kernels.test_splat_tiles import hard_splats

pytestmark = pytest.mark.skipif(not _rows_ok(), reason="the CPU kernels have no AVX2 + FMA: no row blend")

KEYS = ("means2d", "conics", "colors", "opacities", "depths")
OUTS = ("rgb", "alpha", "depth", "final_T", "n_contrib")


def _assert_rows_equal_scalar(s, width, height, bg, mode):
    tiles = ks.bin_tiles(s, width, height, mode)
    bgw = background_array(s.inputs(), bg.astype(np.float32))
    a, _ = _rasterize_wp(s, width, height, bgw, tiles, mode, per_tile=True, rows=True)
    b, _ = _rasterize_wp(s, width, height, bgw, tiles, mode, per_tile=True, rows=False)
    for k in OUTS:
        assert getattr(a, k).numpy().tobytes() == getattr(b, k).numpy().tobytes(), k
    return a


def _scenes():
    rng = np.random.default_rng(11)
    sc = cs.random_scene(rng, n=300, width=90, height=70)  # a stack of near-opaque splats: pixels stop
    yield ks.gaussian_inputs(*(sc.params[k].astype(np.float32) for k in cs.PARAMS)), sc.camera, sc.background
    g, cam = bench_scene(2000, 100, 130)  # tiles cut by both image edges
    yield g, cam, np.array([0.2, 0.1, 0.3])


@pytest.mark.parametrize("mode", ks.MODES)
def test_row_blend_gives_the_scalar_loops_bytes(mode):
    stopped = 0
    for g, cam, bg in _scenes():
        p = ks.project(g, cam, mode=mode)
        s = ks.splats_2d(p.means2d, p.conics, p.colors, p.opacities, p.depths, p.radii)
        r = _assert_rows_equal_scalar(s, cam.width, cam.height, bg, mode)
        stopped += int(np.count_nonzero(r.final_T.numpy() < 1e-3))
    assert stopped > 0  # some pixels ran into the stop
    sp = hard_splats(1)
    s = ks.splats_2d(*(sp[k].astype(np.float32) for k in KEYS), sp["radii"])
    _assert_rows_equal_scalar(s, 56, 40, np.array([0.1, 0.3, 0.2]), mode)


def test_row_blend_outside_the_exp_fast_path():
    """Opacities far above 1 (value checks off): ln(255 o) > 88, so running lanes have powers below
    -88, which take expf itself; the bytes are still the scalar loop's."""
    sp = hard_splats(0)
    opac = sp["opacities"].astype(np.float32)
    opac[::3] = np.float32(1e38)
    thr = -np.log(255.0 * opac.astype(np.float64))
    assert np.any(thr < -88.5)
    with A.value_checks(False):
        s = ks.splats_2d(*(sp[k].astype(np.float32) for k in KEYS[:3]), opac, sp["depths"].astype(np.float32),
                         sp["radii"])
        _assert_rows_equal_scalar(s, 56, 40, np.array([0.1, 0.3, 0.2]), "3dgs")


@wp.kernel(enable_backward=False)
def _exp16_sweep(lo: wp.uint32, stride: wp.uint32, n: int, bad: wp.array(dtype=wp.int32)):
    b = wp.tid()
    bad[b] = exp16_mismatches(lo, stride, b, n)


def test_row_blend_exp_is_expf():
    """The lanes' exp has expf's bits (what wp.exp calls) on a sweep of float32 inputs in [-100, 0]
    (every 997th bit pattern; the fast path and, below -88, expf itself) and of all in [-2^-20, 0]
    and [0, 2^-20]. (All 2^32 inputs were checked once with kernels._vexp.exp16_mismatches: a 147 s sweep.)"""
    neg0, neg100 = 0x80000000, int(np.float32(-100).view(np.uint32))
    tiny = int(np.float32(2.0 ** -20).view(np.uint32))
    for lo, hi, stride in ((neg0, neg100, 997), (neg0, neg0 + tiny, 61), (0, tiny, 61)):
        n = (hi - lo) // stride + 1
        bad = wp.zeros((n + 15) // 16, dtype=wp.int32, device="cpu")
        wp.launch(_exp16_sweep, bad.shape[0], [wp.uint32(lo), wp.uint32(stride), n, bad], device="cpu")
        assert int(bad.numpy().sum()) == 0, (hex(lo), hex(hi))
