"""kernels.stereo against the NumPy references of kernels.reference.stereo, finite-difference checks, and bad input.

The references loop pixel by pixel and window cell by window cell, written for clarity rather
than speed, so the sizes are small.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import stereo
from kernels.reference import stereo as ref
from research.checks.stereo import check_feature_correlation, check_soft_argmin
from research.gradcheck import assert_gradcheck

DTYPES = (np.float32, np.float64)
# float32 kernels accumulate window sums in float64 but round the cost to float32; SGM sums
# D-long recurrences in float32, so its rounding grows with the path length.
RTOL = {np.float32: 2e-5, np.float64: 1e-12}
SGM_RTOL = {np.float32: 1e-4, np.float64: 1e-12}


def _images(seed: int, shape=(9, 13), dtype=np.float64):
    rng = np.random.default_rng(seed)
    left = rng.uniform(0.0, 1.0, shape)
    right = np.roll(left, -2, axis=1) + 0.05 * rng.standard_normal(shape)  # true disparity 2, plus noise
    return left.astype(dtype), right.astype(dtype)


# =========================================================================== forward checks


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed,drange,radius", [(0, (0, 5), 2), (1, (-2, 4), 1), (2, (3, 9), 3)])
@pytest.mark.usefixtures("warp_device")
def test_sad_matches_reference(dtype, seed, drange, radius):
    L, R = _images(seed, dtype=dtype)
    got = stereo.sad_cost(L, R, *drange, radius)
    assert got.dtype == dtype and got.shape == (9, 13, drange[1] - drange[0])
    np.testing.assert_allclose(got, ref.sad_cost(L, R, *drange, radius), rtol=RTOL[dtype], atol=1e-12)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed,drange,radius", [(0, (0, 5), 2), (1, (-3, 3), 3)])
@pytest.mark.usefixtures("warp_device")
def test_zncc_matches_reference(dtype, seed, drange, radius):
    L, R = _images(seed, dtype=dtype)
    got = stereo.zncc_cost(L, R, *drange, radius, eps=1e-4)
    # ZNCC divides small differences of window sums: float32 inputs rounded once keep ~1e-5 relative.
    np.testing.assert_allclose(got, ref.zncc_cost(L, R, *drange, radius, 1e-4), rtol=RTOL[dtype], atol=1e-6)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed,drange,radius,channels", [(0, (0, 5), 2, 0), (1, (-2, 4), 1, 3), (2, (3, 9), 0, 3)])
@pytest.mark.usefixtures("warp_device")
def test_bt_matches_reference(dtype, seed, drange, radius, channels):
    rng = np.random.default_rng(seed)
    shape = (7, 11, channels) if channels else (7, 11)
    L = rng.uniform(0.0, 1.0, shape)
    R = np.clip(np.roll(L, -2, axis=1) + 0.05 * rng.standard_normal(shape), 0, 1)
    L, R = L.astype(dtype), R.astype(dtype)
    got = stereo.bt_cost(L, R, *drange, radius)
    assert got.dtype == dtype and got.shape == (7, 11, drange[1] - drange[0])
    np.testing.assert_allclose(got, ref.bt_cost(L, R, *drange, radius), rtol=RTOL[dtype], atol=1e-7)


def test_bt_is_insensitive_to_half_pixel_sampling():
    # A linear ramp and its copy shifted by half a pixel: BT costs 0 at the nearest integer shifts (SAD does not).
    x = np.arange(16, dtype=np.float64)
    L = np.tile(x / 32.0, (4, 1))
    R = np.tile((x + 0.5) / 32.0, (4, 1))  # I_R(u) = I_L(u + 0.5): true disparity 0.5
    bt, sad = stereo.bt_cost(L, R, 0, 2, 0), stereo.sad_cost(L, R, 0, 2, 0)
    assert np.abs(bt[:, 1:-1, :]).max() < 1e-12
    assert sad[:, 1:-1, :].min() > 0.01


@pytest.mark.parametrize("cost", ["sad", "zncc", "census", "bt", "adcensus"])
def test_out_of_range_cells_cost_at_least_any_match(cost):
    # Images with disjoint value ranges: the out-of-range fill must still bound every real cost from above.
    rng = np.random.default_rng(12)
    L, R = rng.uniform(0.0, 0.1, (6, 10)), rng.uniform(0.9, 1.0, (6, 10))
    if cost == "adcensus":
        C = stereo.adcensus_cost(L, R, -3, 5, census_radii=(1, 1), radius=1, bt_weight=1.0)
    elif cost == "census":
        C = stereo.census_cost(L, R, -3, 5, 1, 1)
    else:
        C = getattr(stereo, f"{cost}_cost")(L, R, -3, 5, 1)
    d = np.arange(-3, 5)
    x = np.arange(10)[:, None]
    out_of_range = np.broadcast_to((x - d < 0) | (x - d >= 10), C.shape)
    assert out_of_range.any() and (~out_of_range).any()
    assert C[out_of_range].min() >= C[~out_of_range].max()


def test_zncc_flat_window_is_finite():
    L = np.full((6, 9), 0.5)
    got = stereo.zncc_cost(L, L.copy(), 0, 3, 1)
    assert np.all(np.isfinite(got)) and np.allclose(got[:, 2:], 1.0)  # zero variance: zero correlation


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed,drange,radii", [(0, (0, 5), (1, 2)), (1, (-2, 6), (3, 4)), (2, (-3, 13), (2, 2))])
@pytest.mark.usefixtures("warp_device")
def test_census_matches_reference(dtype, seed, drange, radii):
    L, R = _images(seed, shape=(9, 21), dtype=dtype)  # D = 16: the 8-wide vector path; 5: the scalar one
    np.testing.assert_array_equal(stereo.census_transform(L, *radii), ref.census_transform(L, *radii))
    got = stereo.census_cost(L, R, *drange, *radii)
    assert got.dtype == dtype
    np.testing.assert_array_equal(got, ref.census_cost(L, R, *drange, *radii))


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed,drange", [(0, (0, 4)), (1, (-3, 5))])
@pytest.mark.usefixtures("warp_device")
def test_correlation_matches_reference(dtype, seed, drange):
    rng = np.random.default_rng(seed)
    FL, FR = (rng.standard_normal((6, 4, 10)).astype(dtype) for _ in range(2))
    got = stereo.feature_correlation(FL, FR, *drange)
    np.testing.assert_allclose(got, ref.feature_correlation(FL, FR, *drange), rtol=RTOL[dtype], atol=1e-6)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.usefixtures("warp_device")
def test_sgm_matches_reference(dtype, paths, seed):
    rng = np.random.default_rng(seed)
    C = rng.uniform(0.0, 4.0, (6, 8, 5)).astype(dtype)
    got = stereo.sgm(C, 0.5, 2.0, paths)
    np.testing.assert_allclose(got, ref.sgm(C, 0.5, 2.0, paths), rtol=SGM_RTOL[dtype])


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("paths", [4, 8])
def test_sgm_running_minimum_when_costs_jump_or_are_negative(dtype, paths):
    # Costs that rise by far more than 2 P2 between neighbours, and negative costs (a negated correlation):
    # the running minimum must be the true one (an earlier kernel started it at min + 2 P2 and drifted).
    rng = np.random.default_rng(9)
    C = rng.uniform(0.0, 0.2, (5, 14, 8))
    C[:, 6:, :] += 5.0
    C[2:, :, :] -= 3.0
    C[:, 10:, :] = -rng.uniform(0.0, 1.0, (5, 4, 8))
    got = stereo.sgm(C.astype(dtype), 0.1, 0.5, paths)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, ref.sgm(C.astype(dtype), 0.1, 0.5, paths), rtol=SGM_RTOL[dtype], atol=1e-5)


def test_sgm_single_path_edge_cases():
    # P1 = P2 = 0: every L_r(p, k) = C(p, k) + min over the predecessor's hypotheses, relative to it: = C.
    C = np.random.default_rng(3).uniform(0.0, 1.0, (4, 5, 3))
    np.testing.assert_allclose(stereo.sgm(C, 0.0, 0.0, 4), 4 * C, rtol=1e-12)
    # One row, one column and a single hypothesis all work.
    for shape in [(1, 6, 2), (6, 1, 1), (1, 1, 1)]:
        C = np.random.default_rng(4).uniform(0.0, 1.0, shape)
        np.testing.assert_allclose(stereo.sgm(C, 0.2, 0.9, 8), ref.sgm(C, 0.2, 0.9, 8), rtol=1e-12)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("dmin,uniqueness", [(0, 0.0), (-2, 0.0), (1, 0.15)])
@pytest.mark.usefixtures("warp_device")
def test_wta_matches_reference(dtype, dmin, uniqueness):
    C = np.random.default_rng(5).uniform(0.0, 3.0, (5, 9, 6)).astype(dtype)
    disp, valid = stereo.wta(C, dmin, uniqueness=uniqueness)
    rdisp, rvalid = ref.wta(C, dmin, uniqueness)
    np.testing.assert_allclose(disp, rdisp, rtol=RTOL[dtype], atol=1e-6)
    np.testing.assert_array_equal(valid, rvalid)
    assert valid.dtype == bool and not valid.all()
    disp0, _ = stereo.wta(C, dmin, subpixel=False)
    np.testing.assert_array_equal(disp0, dmin + np.argmin(C, axis=2))


def test_wta_subpixel_recovers_parabola_vertex():
    k = np.arange(8.0)
    C = np.broadcast_to((k - 3.3) ** 2, (2, 8, 8)).copy()
    disp, _ = stereo.wta(C, 0)
    np.testing.assert_allclose(disp, 3.3, rtol=1e-12)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("dmin", [0, -1])
@pytest.mark.usefixtures("warp_device")
def test_wta_right_matches_reference(dtype, dmin):
    C = np.random.default_rng(6).uniform(0.0, 3.0, (4, 9, 5)).astype(dtype)
    disp, valid = stereo.wta_right(C, dmin)
    rdisp, rvalid = ref.wta_right(C, dmin)
    np.testing.assert_array_equal(valid, rvalid)
    np.testing.assert_allclose(disp[valid], rdisp[rvalid], rtol=RTOL[dtype], atol=1e-6)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("dmin,uniqueness,subpixel", [(0, 0.0, True), (-3, 0.2, True), (2, 0.0, False)])
def test_wta_left_right_equals_the_two_passes(dtype, dmin, uniqueness, subpixel):
    rng = np.random.default_rng(4)
    C = rng.uniform(0.0, 1.0, (5, 17, 7)).astype(dtype)
    C[0, :, 2] = C[0, :, 3]  # ties: the first minimum wins in both views
    dl, vl, dr, vr = stereo.wta_left_right(C, dmin, uniqueness=uniqueness, subpixel=subpixel)
    dl0, vl0 = stereo.wta(C, dmin, uniqueness=uniqueness, subpixel=subpixel)
    dr0, vr0 = stereo.wta_right(C, dmin, subpixel=subpixel)
    for got, want in ((dl, dl0), (vl, vl0), (dr, dr0), (vr, vr0)):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("drange", [(0, 16), (-3, 13), (0, 13)])
def test_compact_census_sgm_and_winners_equal_the_float_pipeline(drange):
    # uint8 census costs, a uint16 aggregate: every value is an integer, so each stage equals float32's exactly.
    L, R = _images(5, shape=(11, 23), dtype=np.float32)
    c8 = stereo.census_cost(L, R, *drange, 2, 3, compact=True)
    c32 = stereo.census_cost(L, R, *drange, 2, 3)
    assert c8.dtype == np.uint8
    # bit-equal on any CPU: census costs, P1, P2 and every SGM sum and minimum are small integers, exact in
    # float32 (< 2^24) and uint16, so no order, scheme or SIMD width can round them differently
    np.testing.assert_array_equal(c8.astype(np.float32), c32)
    for paths in (4, 8):
        s16, s32 = stereo.sgm(c8, 8, 64, paths), stereo.sgm(c32, 8.0, 64.0, paths)
        assert s16.dtype == np.uint16
        np.testing.assert_array_equal(s16.astype(np.float32), s32)
        # The two SGM schemes (two sweeps on the CPU, one launch per axis on a GPU) agree exactly.
        np.testing.assert_array_equal(stereo.sgm(c32, 8.0, 64.0, paths, method="axes"), s32)
        if (drange[1] - drange[0]) % 8:
            with pytest.raises(ValueError, match="cost: a uint8 volume needs a multiple of 8"):
                stereo.sgm(c8, 8, 64, paths, method="axes")
        else:
            np.testing.assert_array_equal(stereo.sgm(c8, 8, 64, paths, method="axes"), s16)
    dmin = drange[0]
    for got, want in ((stereo.wta(s16, dmin, uniqueness=0.1), stereo.wta(s32, dmin, uniqueness=0.1)),
                      (stereo.wta_right(s16, dmin), stereo.wta_right(s32, dmin)),
                      (stereo.wta_left_right(s16, dmin), stereo.wta_left_right(s32, dmin))):
        for g, w in zip(got, want):
            assert g.dtype == w.dtype
            np.testing.assert_array_equal(g, w)


def test_wta_left_and_right_agree_on_a_shifted_pair():
    # A textured pair with a constant disparity 3: both views find it, and the LR check keeps those pixels.
    L, R = _images(7, shape=(12, 24))
    R = np.roll(L, -3, axis=1)
    C = stereo.census_cost(L, R, 0, 6, 2, 3)
    dl, vl = stereo.wta(C, 0, subpixel=False)
    dr, vr = stereo.wta_right(C, 0, subpixel=False)
    assert np.all(dl[:, 3:-3] == 3) and np.all(dr[:, 3:-6] == 3)  # away from the census windows' borders
    ok = stereo.left_right_check(dl, dr, 0.5, valid_left=vl, valid_right=vr)
    assert ok[:, 6:-3].all()  # left x looks at right x - 3


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("temperature", [0.25, 1.0, 3.0])
@pytest.mark.usefixtures("warp_device")
def test_soft_argmin_matches_reference(dtype, temperature):
    C = np.random.default_rng(8).uniform(0.0, 5.0, (4, 7, 6)).astype(dtype)
    got = stereo.soft_argmin(C, -1, temperature)
    np.testing.assert_allclose(got, ref.soft_argmin(C, -1, temperature), rtol=RTOL[dtype], atol=1e-6)


def test_soft_argmin_is_stable_for_large_costs():
    C = np.random.default_rng(9).uniform(0.0, 1.0, (2, 6, 4)) * 1e4
    got = stereo.soft_argmin(C, 0, 1.0)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, np.argmin(C, axis=2), atol=1e-9)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.usefixtures("warp_device")
def test_left_right_check_matches_reference(dtype):
    rng = np.random.default_rng(10)
    dl = rng.uniform(0.0, 4.0, (6, 11)).astype(dtype)
    dr = (dl + rng.choice([0.0, 0.3, 2.0], dl.shape)).astype(dtype)
    vl, vr = rng.random(dl.shape) > 0.2, rng.random(dl.shape) > 0.2
    got = stereo.left_right_check(dl, dr, 0.5, valid_left=vl, valid_right=vr)
    expected = ref.left_right_check(dl, dr, 0.5, vl, vr)
    np.testing.assert_array_equal(got, expected)
    assert 0 < expected.sum() < expected.size


@pytest.mark.parametrize("dtype", DTYPES)
def test_depth_from_disparity(dtype):
    d = np.array([[2.0, 0.5, 0.0, -1.0], [np.nan, np.inf, 1e-30, 4.0]], dtype=dtype)
    valid = np.array([[True, True, True, True], [True, True, True, False]])
    depth, ok = stereo.depth_from_disparity(d, 100.0, 0.2, valid=valid)
    # f b / 1e-30 = 2e31 is finite in float32 too: valid in both dtypes.
    expected_ok = np.array([[True, True, False, False], [False, False, True, False]])
    np.testing.assert_array_equal(ok, expected_ok)
    assert np.all(np.isfinite(depth)) and np.all(depth[~ok] == 0)
    np.testing.assert_allclose(depth[ok], 20.0 / d[ok].astype(np.float64), rtol=RTOL[dtype])
    rdepth, rok = ref.depth_from_disparity(d, 100.0, 0.2, valid)
    np.testing.assert_array_equal(ok, rok)
    np.testing.assert_allclose(depth, rdepth, rtol=RTOL[dtype])
    tiny = np.array([[1e-45]], dtype=np.float32)  # 20 / 1.4e-45 overflows float32: invalid, not inf
    depth, ok = stereo.depth_from_disparity(tiny, 100.0, 0.2)
    assert not ok.any() and depth[0, 0] == 0.0
    assert not ref.depth_from_disparity(tiny, 100.0, 0.2)[1].any()


def test_wp_arrays_in_give_wp_arrays_out():
    L, R = _images(11)
    wl, wr = wp.array(L, dtype=wp.float64), wp.array(R, dtype=wp.float64)
    C = stereo.census_cost(wl, wr, 0, 4, 1, 1)
    assert isinstance(C, wp.array)
    disp, valid = stereo.wta(stereo.sgm(C, 1.0, 4.0, 4), 0)
    assert isinstance(disp, wp.array) and valid.dtype == wp.uint8
    ref_disp, ref_valid = stereo.wta(stereo.sgm(C.numpy(), 1.0, 4.0, 4), 0)
    np.testing.assert_array_equal(disp.numpy(), ref_disp)
    np.testing.assert_array_equal(valid.numpy().astype(bool), ref_valid)


def test_outputs_follow_the_first_array_argument():
    # NumPy and wp.arrays may be mixed (NumPy ones are copied to the device); the first array sets the kind.
    L, R = _images(11)
    expected = stereo.sad_cost(L, R, 0, 4)
    on_device = stereo.sad_cost(wp.array(L, dtype=wp.float64), R, 0, 4)
    assert isinstance(on_device, wp.array)
    np.testing.assert_array_equal(on_device.numpy(), expected)
    on_host = stereo.sad_cost(L, wp.array(R, dtype=wp.float64), 0, 4)
    assert isinstance(on_host, np.ndarray)
    np.testing.assert_array_equal(on_host, expected)
    dl, vl = stereo.wta(expected, 0)
    ok = stereo.left_right_check(dl, wp.array(dl), valid_left=wp.array(vl.astype(np.uint8)))
    assert isinstance(ok, np.ndarray) and ok.dtype == bool


def test_backward_returns_gradients_by_argument_name():
    rng = np.random.default_rng(13)
    FL, FR = rng.standard_normal((3, 4, 6)), rng.standard_normal((3, 4, 6))
    g = stereo.feature_correlation_backward(FL, FR, rng.standard_normal((4, 6, 3)), -1)
    assert set(g) == {"feat_left", "feat_right"} and g["feat_left"].shape == FL.shape
    wg = stereo.soft_argmin_backward(wp.array(rng.uniform(0.0, 1.0, (4, 6, 3))), 0, rng.standard_normal((4, 6)))
    assert set(wg) == {"cost"} and isinstance(wg["cost"], wp.array) and wg["cost"].shape == (4, 6, 3)


# =========================================================================== gradients


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.usefixtures("warp_device")
def test_feature_correlation_gradcheck(seed):
    assert_gradcheck(check_feature_correlation(seed))


@pytest.mark.parametrize("seed,temperature", [(0, 0.3), (1, 0.7), (2, 2.0)])
@pytest.mark.usefixtures("warp_device")
def test_soft_argmin_gradcheck(seed, temperature):
    assert_gradcheck(check_soft_argmin(seed, temperature=temperature))


def test_gradchecks_are_registered():
    from research.gradcheck import CHECKS, load_checks

    load_checks()
    assert {"stereo.feature_correlation", "stereo.soft_argmin"} <= set(CHECKS)


# =========================================================================== bad input


def test_mismatched_shapes():
    L, R = _images(0)
    with pytest.raises(ValueError, match="right: expected shape"):
        stereo.sad_cost(L, R[:, :-1], 0, 4)
    with pytest.raises(ValueError, match="feat_right: expected shape"):
        stereo.feature_correlation(np.zeros((2, 3, 5)), np.zeros((3, 3, 5)), 0, 2)
    with pytest.raises(ValueError, match="disp_right: expected shape"):
        stereo.left_right_check(np.zeros((3, 5)), np.zeros((3, 4)))


@pytest.mark.parametrize("drange,match", [((4, 4), "empty"), ((5, 2), "empty"), ((0, 14), "more than the image"),
                                          ((-13, -5), "within"), ((1.5, 4), "integer")])
def test_bad_disparity_range(drange, match):
    L, R = _images(0)  # width 13
    for fn in (stereo.sad_cost, stereo.zncc_cost, stereo.census_cost):
        with pytest.raises(ValueError, match=match):
            fn(L, R, *drange)
    with pytest.raises(ValueError, match="dmin|dmax"):
        stereo.wta(np.zeros((3, 4, 5)), 0)  # 5 hypotheses on a 4-pixel-wide image
    with pytest.raises(ValueError, match="^cost: holds 5 disparity hypotheses"):
        stereo.wta(np.zeros((3, 4, 5)), 0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_pixels(bad):
    L, R = _images(0)
    L[3, 4] = bad
    for fn in (stereo.sad_cost, stereo.zncc_cost, stereo.census_cost):
        with pytest.raises(ValueError, match="left: expected finite values"):
            fn(L, R, 0, 4)
        with pytest.raises(ValueError, match="right: expected finite values"):
            fn(R, L, 0, 4)
    with pytest.raises(ValueError, match="cost: expected finite values"):
        stereo.sgm(np.full((2, 3, 2), bad), 1.0, 2.0)


def test_value_checks_off_skips_the_finiteness_check_only():
    from kernels._arrays import value_checks

    L, R = _images(0)
    L[3, 4] = np.nan
    with value_checks(False):
        bits = stereo.census_transform(L, 1, 1)  # NaN compares false: the pixel's own bits are all 0
        assert bits[3, 4] == 0
        with pytest.raises(ValueError, match="right: expected shape"):
            stereo.census_cost(L, R[:, :-1], 0, 4)


def test_bad_dtypes_devices_and_parameters():
    L, R = _images(0)
    with pytest.raises(ValueError, match="left: expected dtype float32 or float64, got uint8"):
        stereo.census_cost((L * 255).astype(np.uint8), R, 0, 4)
    with pytest.raises(ValueError, match="right: expected dtype float64 like the other inputs, got float32"):
        stereo.sad_cost(L, R.astype(np.float32), 0, 4)
    with pytest.raises(ValueError, match="left: expected 2 dimensions"):
        stereo.sad_cost(L[..., None], R[..., None], 0, 4)
    with pytest.raises(ValueError, match="right: expected dtype float64 like the other inputs, got float32"):
        stereo.sad_cost(wp.array(L, dtype=wp.float64), R.astype(np.float32), 0, 4)  # mixed kinds, mixed dtypes
    with pytest.raises(ValueError, match="grad_corr: expected shape"):
        stereo.feature_correlation_backward(np.zeros((2, 3, 5)), np.zeros((2, 3, 5)), np.zeros((3, 4, 2)), 0)
    with pytest.raises(ValueError, match="device"):
        stereo.sad_cost(L, R, 0, 4, device="tpu")
    with pytest.raises(ValueError, match="p2"):
        stereo.sgm(np.zeros((2, 3, 2)), 2.0, 1.0)
    with pytest.raises(ValueError, match="paths"):
        stereo.sgm(np.zeros((2, 3, 2)), 1.0, 2.0, paths=6)
    with pytest.raises(ValueError, match="paths"):
        stereo.sgm(np.zeros((2, 3, 2)), 1.0, 2.0, paths=4.0)
    with pytest.raises(ValueError, match="radius_y, radius_x"):
        stereo.census_cost(L, R, 0, 4, 4, 4)  # 9x9 - 1 = 80 bits
    with pytest.raises(ValueError, match="temperature"):
        stereo.soft_argmin(np.zeros((2, 3, 2)), 0, 0.0)
    with pytest.raises(ValueError, match="uniqueness"):
        stereo.wta(np.zeros((2, 3, 2)), 0, uniqueness=1.0)
    with pytest.raises(ValueError, match="baseline"):
        stereo.depth_from_disparity(np.ones((2, 2)), 100.0, -0.1)
    with pytest.raises(ValueError, match="grad_disp: expected shape"):
        stereo.soft_argmin_backward(np.zeros((2, 3, 2)), 0, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="valid_left: expected dtype bool or uint8"):
        stereo.left_right_check(np.zeros((2, 3)), np.zeros((2, 3)), valid_left=np.zeros((2, 3), dtype=np.int64))


# =========================================================================== adcensus


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("channels,cap", [(0, 0.25), (3, 0.1)])
@pytest.mark.usefixtures("warp_device")
def test_sobel_x_clipped_matches_reference(dtype, channels, cap):
    rng = np.random.default_rng(3)
    img = rng.uniform(0.0, 1.0, (6, 9, channels) if channels else (6, 9)).astype(dtype)
    got = stereo.sobel_x_clipped(img, cap)
    assert got.dtype == dtype and got.shape == img.shape and got.min() >= 0 and got.max() <= 1
    np.testing.assert_allclose(got, ref.sobel_x_clipped(img, cap), rtol=RTOL[dtype], atol=1e-7)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("seed,drange,channels,bt_weight,eps", [(0, (0, 5), 0, 0.0, 0.0), (1, (-2, 4), 3, 0.5, 0.0),
                                                                 (2, (3, 9), 3, 0.0, 0.0), (3, (0, 6), 0, 0.3, 0.05),
                                                                 (4, (-1, 5), 3, 0.3, 0.2)])
@pytest.mark.usefixtures("warp_device")
def test_adcensus_matches_reference(dtype, seed, drange, channels, bt_weight, eps):
    rng = np.random.default_rng(seed)
    shape = (7, 11, channels) if channels else (7, 11)
    L = rng.uniform(0.0, 1.0, shape)
    R = np.clip(np.roll(L, -2, axis=1) + 0.05 * rng.standard_normal(shape), 0, 1)
    L, R = L.astype(dtype), R.astype(dtype)
    grey = (L.mean(axis=2), R.mean(axis=2)) if channels else None
    kw = dict(census_radii=(1, 2), radius=1, grad_cap=0.2, lambda_census=5.0, lambda_grad=0.05, bt_weight=bt_weight,
              lambda_bt=0.03, census_eps=eps)
    got = stereo.adcensus_cost(L, R, *drange, grey=grey, **kw)
    assert got.dtype == dtype and got.shape == (7, 11, drange[1] - drange[0])
    np.testing.assert_allclose(got, ref.adcensus_cost(L, R, *drange, grey=grey, **kw), rtol=RTOL[dtype], atol=1e-6)


def _rho_sum(terms, dtype):
    """sum of w (1 - exp(-c / lambda)) over (volume, lambda, w), in `dtype`, terms added in order."""
    total = None
    for c, lam, w in terms:
        t = dtype(w) * (dtype(1.0) - np.exp(-np.asarray(c, dtype) * dtype(1.0 / lam)))
        total = t if total is None else total + t
    return total


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("channels,drange,radius,bt_weight", [(0, (0, 16), 2, 0.3), (3, (-3, 9), 1, 0.0),
                                                              (3, (2, 19), 3, 1.0)])
def test_adcensus_fused_equals_its_terms_composed(dtype, channels, drange, radius, bt_weight):
    """The one fused launch gives the volume of composing census_cost, bt_cost on the clipped gradient and on the
    intensity, and the rho sums, on rows spanning several of the fused kernel's bands. Tolerance: NumPy's exp and
    Warp's may differ in the last bit, which 1 - exp(-c / lambda) turns into an absolute difference of about one
    ulp of 1 (6e-8 in float32), large relative to small costs; so an absolute bound of a few ulps of 1."""
    rng = np.random.default_rng(11)
    shape = (41, 23, channels) if channels else (41, 23)
    L = rng.uniform(0.0, 1.0, shape).astype(dtype)
    R = np.clip(np.roll(L, -3, axis=1) + 0.05 * rng.standard_normal(shape), 0, 1).astype(dtype)
    grey = (L.mean(axis=2), R.mean(axis=2)) if channels else (L, R)
    got = stereo.adcensus_cost(L, R, *drange, grey=grey if channels else None, radius=radius, bt_weight=bt_weight)
    terms = [(stereo.census_cost(*grey, *drange, 3, 4), 30.0, 1.0),
             (stereo.bt_cost(stereo.sobel_x_clipped(L), stereo.sobel_x_clipped(R), *drange, radius), 0.04, 1.0)]
    if bt_weight:
        terms.append((stereo.bt_cost(L, R, *drange, radius), 0.04, bt_weight))
    np.testing.assert_allclose(got, _rho_sum(terms, dtype), rtol=0, atol=5e-7 if dtype == np.float32 else 1e-15)


@pytest.mark.parametrize("dtype,channels,levels,vector_rho", [(d, c, 0, False) for d in DTYPES for c in (0, 3)] +
                         [(np.float32, 0, 110, False), (np.float32, 0, 110, True), (np.float32, 3, 110, True)])
def test_adcensus_vector_and_scalar_hypotheses_agree_bit_for_bit(dtype, channels, levels, vector_rho):
    """The fused kernel computes whole vectors of hypotheses (16 float32 or 8 float64 lanes) where every lane's
    window is in range and a lane at a time elsewhere (a partial last vector). A cell's value depends only on
    (x, y, d), so the range [o, o + n) (n = the vector width: all in vectors) and [0, o + n) (the last o
    hypotheses a lane at a time) must agree exactly on their common disparities."""
    n = 16 if dtype == np.float32 else 8
    rng = np.random.default_rng(5)
    shape = (13, 70, channels) if channels else (13, 70)
    L = rng.uniform(0.0, 1.0, shape).astype(dtype)
    R = np.clip(np.roll(L, -4, axis=1) + 0.05 * rng.standard_normal(shape), 0, 1).astype(dtype)
    grey = (L.mean(axis=2), R.mean(axis=2)) if channels else None
    for o in (1, n // 2 + 1, n - 1):
        vec = stereo.adcensus_cost(L, R, o, o + n, grey=grey, bt_weight=0.3, levels=levels, vector_rho=vector_rho)
        mixed = stereo.adcensus_cost(L, R, 0, o + n, grey=grey, bt_weight=0.3, levels=levels, vector_rho=vector_rho)
        # bit-equal by construction: the same kernel and the same per-cell operations whatever the first disparity
        np.testing.assert_array_equal(vec, mixed[:, :, o:])


@pytest.mark.parametrize("bt_weight", [0.0, 0.3])
def test_adcensus_compact_is_the_rounded_float_cost(bt_weight):
    L, R = (x.astype(np.float32) for x in _images(6, shape=(12, 20)))
    q = stereo.compact_levels(bt_weight)
    assert q * (2 + bt_weight) <= 255 < (q + 1) * (2 + bt_weight)
    full = stereo.adcensus_cost(L, R, 0, 8, bt_weight=bt_weight)
    got = stereo.adcensus_cost(L, R, 0, 8, bt_weight=bt_weight, levels=q)
    assert got.dtype == np.uint8
    expected = np.floor(full * np.float32(q) + np.float32(0.5))
    np.testing.assert_array_equal(got, expected.astype(np.uint8))
    assert np.abs(got / q - full).max() <= 0.5 / q + 1e-6


@pytest.mark.parametrize("bt_weight,channels,drange", [(0.0, 0, (0, 8)), (0.3, 0, (0, 37)), (0.3, 3, (-5, 20)),
                                                       (1.0, 3, (2, 34))])
def test_adcensus_vector_rho_is_the_rounded_float_cost_within_its_bound(bt_weight, channels, drange):
    """Compact mode with the vector rho (the BT terms' 1 - exp(-z) by a polynomial and squarings, z clipped at 24):
    every cell is round(C q) of the float cost C, or one level off where C q lies within the polynomial's error
    (under 1e-4 levels per term, so such cells are rare) of a rounding boundary; the scalar-exp volume otherwise."""
    rng = np.random.default_rng(8)
    shape = (30, 45, channels) if channels else (30, 45)
    L = rng.uniform(0.0, 1.0, shape).astype(np.float32)
    R = np.clip(np.roll(L, -6, axis=1) + 0.05 * rng.standard_normal(shape), 0, 1).astype(np.float32)
    grey = (L.mean(axis=2), R.mean(axis=2)) if channels else None
    q = stereo.compact_levels(bt_weight)
    full = stereo.adcensus_cost(L, R, *drange, grey=grey, bt_weight=bt_weight)
    scalar = stereo.adcensus_cost(L, R, *drange, grey=grey, bt_weight=bt_weight, levels=q)
    got = stereo.adcensus_cost(L, R, *drange, grey=grey, bt_weight=bt_weight, levels=q, vector_rho=True)
    assert got.dtype == np.uint8 and got.shape == full.shape
    x = full.astype(np.float64) * q
    diff = got.astype(np.int64) - scalar.astype(np.int64)
    assert np.abs(diff).max() <= 1
    # a cell may differ only where C q is within 1e-3 (a generous bound of the polynomial's error) of k + 1/2
    near = np.abs(x - np.floor(x) - 0.5) < 1e-3
    assert not np.any((diff != 0) & ~near)
    assert np.mean(diff != 0) < 1e-3


def test_adcensus_vector_rho_needs_compact_mode():
    L, R = (x.astype(np.float32) for x in _images(6, shape=(12, 20)))
    with pytest.raises(ValueError, match="vector_rho"):
        stereo.adcensus_cost(L, R, 0, 8, vector_rho=True)
    with pytest.raises(ValueError, match="vector_rho"):
        stereo.adcensus_cost(L, R, 0, 8, levels=110, vector_rho=1)


def test_adcensus_is_unchanged_by_an_intensity_offset_where_no_clip_binds():
    """Census and the x-gradient do not see a constant offset (nor does the clip, away from 0 and 1)."""
    L, R = _images(4, shape=(10, 16))
    L, R = 0.25 + 0.5 * L, 0.25 + 0.5 * np.clip(R, 0, 1)
    a = stereo.adcensus_cost(L, R, 0, 6)
    b = stereo.adcensus_cost(L, R + 0.1, 0, 6)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    # The intensity term does see it.
    assert not np.allclose(stereo.adcensus_cost(L, R, 0, 6, bt_weight=1.0),
                           stereo.adcensus_cost(L, R + 0.1, 0, 6, bt_weight=1.0))
    # Nor does the census tolerance.
    np.testing.assert_allclose(stereo.adcensus_cost(L, R, 0, 6, census_eps=0.05),
                               stereo.adcensus_cost(L, R + 0.1, 0, 6, census_eps=0.05), rtol=0, atol=1e-9)


def test_adcensus_census_tolerance_flattens_a_noisy_flat_surface():
    """Below the tolerance, noise on a flat image sets no census bit: the census term is 0 at every hypothesis."""
    rng = np.random.default_rng(8)
    L, R = 0.5 + 0.004 * rng.standard_normal((9, 14)), 0.5 + 0.004 * rng.standard_normal((9, 14))
    plain = stereo.adcensus_cost(L, R, 0, 4, census_radii=(1, 1))
    tol = stereo.adcensus_cost(L, R, 0, 4, census_radii=(1, 1), census_eps=0.05)
    grad_only = stereo.adcensus_cost(L, R, 0, 4, census_radii=(1, 1), census_eps=0.05, lambda_census=1e-3)
    np.testing.assert_array_equal(tol[:, 3:], grad_only[:, 3:])  # census distance 0 wherever in range, any lambda
    assert not np.array_equal(plain[:, 4:], tol[:, 4:])


def test_adcensus_wp_arrays_in_give_wp_arrays_out():
    rng = np.random.default_rng(5)
    L, R = rng.uniform(0, 1, (6, 10, 3)), rng.uniform(0, 1, (6, 10, 3))
    grey = (L.mean(axis=2), R.mean(axis=2))
    expected = stereo.adcensus_cost(L, R, 0, 4, grey=grey, bt_weight=0.3)
    got = stereo.adcensus_cost(wp.array(L, dtype=wp.float64), wp.array(R, dtype=wp.float64), 0, 4, grey=grey,
                               bt_weight=0.3)
    assert isinstance(got, wp.array)
    np.testing.assert_array_equal(got.numpy(), expected)
    assert isinstance(stereo.sobel_x_clipped(wp.array(L, dtype=wp.float64)), wp.array)


@pytest.mark.parametrize("shape, dmin, paths, uniqueness, subpixel, lr", [
    ((7, 9, 8), 0, 8, 0.0, True, 1.0),
    ((13, 40, 40), -3, 8, 0.1, True, 1.0),
    ((16, 70, 64), 2, 4, 0.0, False, 0.5),
    ((5, 40, 33), -10, 8, 0.0, True, None),
    ((1, 50, 32), 0, 8, 0.05, True, 2.0),
], ids=["tiny", "d40-negative-dmin-uniqueness", "d64-4-paths-integer", "d33-no-lr-check", "one-row"])
def test_sgm_disparity_equals_the_separate_calls(shape, dmin, paths, uniqueness, subpixel, lr):
    # Small integer costs make ties and equal minima common, which the first-minimum rules must settle alike.
    c8 = np.random.default_rng(11).integers(0, 20, shape).astype(np.uint8)
    d, v = stereo.sgm_disparity(c8, dmin, 3, 20, paths, subpixel=subpixel, uniqueness=uniqueness, lr_max_diff=lr)
    for cost in (c8, c8.astype(np.float32)):
        S = stereo.sgm(cost, 3, 20, paths)
        if lr is None:
            want_d, want_v = stereo.wta(S, dmin, subpixel=subpixel, uniqueness=uniqueness)
        else:
            dl, vl, dr, vr = stereo.wta_left_right(S, dmin, subpixel=subpixel, uniqueness=uniqueness)
            want_d, want_v = dl, stereo.left_right_check(dl, dr, lr, valid_left=vl, valid_right=vr)
        np.testing.assert_array_equal(d, want_d)
        np.testing.assert_array_equal(v, want_v)
    assert 0.0 < v.mean() < 1.0  # both outcomes occur
    # The float path of sgm_disparity (the separate calls) on the float32 volume: the same again.
    d32, v32 = stereo.sgm_disparity(c8.astype(np.float32), dmin, 3.0, 20.0, paths, subpixel=subpixel,
                                    uniqueness=uniqueness, lr_max_diff=lr)
    np.testing.assert_array_equal(d32, d)
    np.testing.assert_array_equal(v32, v)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("D", [5, 16, 21])
def test_sgm_sweep_and_axes_agree_on_float_costs(dtype, D):
    # Float costs: the two schemes add the same L_r in another order, so they agree to rounding, and both
    # match the NumPy reference.
    C = np.random.default_rng(12).normal(0.0, 1.0, (6, 11, D)).astype(dtype)
    sweep_s = stereo.sgm(C, 0.3, 1.5, 8, method="sweep")
    axes_s = stereo.sgm(C, 0.3, 1.5, 8, method="axes")
    np.testing.assert_allclose(sweep_s, axes_s, rtol=SGM_RTOL[dtype], atol=1e-5 if dtype == np.float32 else 1e-12)
    np.testing.assert_allclose(sweep_s, ref.sgm(C, 0.3, 1.5, 8), rtol=SGM_RTOL[dtype],
                               atol=1e-5 if dtype == np.float32 else 1e-12)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape, dmin, uniqueness, lr", [((9, 30, 21), -4, 0.0, 1.0), ((6, 40, 16), 3, 0.2, 0.5),
                                                         ((4, 25, 9), 0, 0.0, None)],
                         ids=["d21-negative-dmin", "d16-uniqueness", "d9-no-lr-check"])
def test_sgm_disparity_on_float_costs_equals_the_separate_calls(dtype, shape, dmin, uniqueness, lr):
    # Real-valued costs (the float back end: vector minima, then the first hypothesis holding each).
    c = np.random.default_rng(13).normal(0.0, 1.0, shape).astype(dtype)
    d, v = stereo.sgm_disparity(c, dmin, 0.2, 0.9, 8, uniqueness=uniqueness, lr_max_diff=lr)
    S = stereo.sgm(c, 0.2, 0.9, 8)
    if lr is None:
        want_d, want_v = stereo.wta(S, dmin, uniqueness=uniqueness)
    else:
        dl, vl, dr, vr = stereo.wta_left_right(S, dmin, uniqueness=uniqueness)
        want_d, want_v = dl, stereo.left_right_check(dl, dr, lr, valid_left=vl, valid_right=vr)
    assert d.dtype == dtype
    np.testing.assert_array_equal(d, want_d)
    np.testing.assert_array_equal(v, want_v)
    assert 0.0 < v.mean() < 1.0


@pytest.mark.parametrize("volume", ["uint8", "float64"])
def test_sgm_disparity_matches_the_numpy_reference(volume):
    # Against the NumPy chain ref.sgm -> ref.wta / ref.wta_right -> ref.left_right_check (no parabola, so the
    # integer disparities compare exactly whatever the float type).
    rng = np.random.default_rng(14)
    c = rng.integers(0, 30, (8, 26, 12)) if volume == "uint8" else rng.normal(0.0, 1.0, (8, 26, 12))
    c = c.astype(np.uint8 if volume == "uint8" else np.float64)
    p1, p2 = (4, 24) if volume == "uint8" else (0.2, 0.9)
    d, v = stereo.sgm_disparity(c, -2, p1, p2, 8, subpixel=False, uniqueness=0.05, lr_max_diff=1.0)
    S = ref.sgm(c.astype(np.float64), p1, p2, 8)
    dl, vl = ref.wta(S, -2, uniqueness=0.05, subpixel=False)
    dr, vr = ref.wta_right(S, -2)  # always refined: its offset lies within 0.5 of the integer winner
    np.testing.assert_array_equal(d, dl)
    np.testing.assert_array_equal(v, ref.left_right_check(dl, np.round(dr), 1.0, vl, vr))
    assert 0.0 < v.mean() < 1.0


@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (8, 25), (13, 40), (40, 33), (37, 90)])
@pytest.mark.parametrize("radii", [(3, 4), (1, 1), (0, 2), (2, 0), (4, 3)])
def test_census_rows_in_vector_lanes_equal_the_pixel_kernel(shape, radii):
    """kernels.stereo.census.census_rows_f32 (float32 on the CPU, a row per thread, 16 pixels a vector inside the
    image) gives census_kernel's bit strings exactly: images with ties and NaN, windows wider than the image,
    and a non-contiguous view (the rows read pixel by pixel)."""
    from kernels.launch import launch_split
    from kernels.stereo.census import census_kernel, census_rows_f32

    rng = np.random.default_rng(sum(shape) + 7 * radii[0] + radii[1])
    H, W = shape
    base = (rng.integers(0, 6, (H, 2 * W)) / 5).astype(np.float32)
    base[rng.random(base.shape) < 0.02] = np.nan
    for img in (wp.array(base[:, :W].copy(), device="cpu"), wp.array(base, device="cpu")[:, ::2]):
        want, got = (wp.zeros((H, W), dtype=wp.uint64, device="cpu") for _ in range(2))
        launch_split(census_kernel(*radii), H * W, [img, want], device="cpu")
        launch_split(census_rows_f32, H, [img, got, *radii], device="cpu")
        assert want.numpy().any() or H * W == 1
        np.testing.assert_array_equal(got.numpy(), want.numpy())
