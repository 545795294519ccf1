"""kernels.corr: RAFT's all-pairs volume, pyramid and lookups against kernels.reference.corr, FD gradients, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import corr
from kernels._arrays import value_checks
from kernels.reference import corr as ref
from research.checks import corr as checks
from research.gradcheck import assert_gradcheck

DTYPES = [np.float32, np.float64]
# float32 results are compared with float64 references: sums of C products of O(1) numbers.
TOL = {np.float32: dict(rtol=1e-5, atol=2e-5), np.float64: dict(rtol=1e-12, atol=1e-12)}


# --------------------------------------------------------------------------- forward


def random_case(rng: np.random.Generator, dtype, shape=(5, 9, 11)):
    c, h, w = shape
    f1 = rng.standard_normal(shape).astype(dtype)
    f2 = rng.standard_normal(shape).astype(dtype)
    # Positions well past every border, so zero-padded taps and fully outside windows occur.
    coords = np.stack([rng.uniform(-6, w + 6, (h, w)), rng.uniform(-6, h + 6, (h, w))]).astype(dtype)
    return f1, f2, coords


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.usefixtures("warp_device")
def test_volume_and_pyramid_match_reference(dtype):
    f1, f2, _ = random_case(np.random.default_rng(1), dtype)
    volume = corr.correlation_volume(f1, f2)
    assert volume.dtype == dtype and volume.shape == (9, 11, 9, 11)
    want = ref.volume(f1.astype(np.float64), f2.astype(np.float64))
    np.testing.assert_allclose(volume, want, **TOL[dtype])
    pyramid = corr.correlation_pyramid(volume, 4)
    assert [p.shape for p in pyramid] == [(9, 11, 9, 11), (9, 11, 4, 5), (9, 11, 2, 2), (9, 11, 1, 1)]
    for got, expected in zip(pyramid, ref.pyramid(want, 4)):
        np.testing.assert_allclose(got, expected, **TOL[dtype])


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.cpu_fast_path
def test_volume_backends_agree(dtype):
    """BLAS ("numpy", the CPU default) and the blocked Warp product give the volume and its adjoint to rounding."""
    f1, f2, _ = random_case(np.random.default_rng(5), dtype, shape=(37, 9, 13))  # odd sizes: every padding path
    g = np.random.default_rng(6).standard_normal((9, 13, 9, 13)).astype(dtype)
    tol = TOL[dtype]
    np.testing.assert_allclose(corr.correlation_volume(f1, f2, backend="numpy"),
                               corr.correlation_volume(f1, f2, backend="warp"), **tol)
    # bit-equal by construction: with the fast paths on (cpu_fast_path), the CPU default IS backend="numpy",
    # the same BLAS calls on the same arrays in one process
    np.testing.assert_array_equal(corr.correlation_volume(f1, f2), corr.correlation_volume(f1, f2, backend="numpy"))
    got = corr.correlation_volume_backward(f1, f2, g, backend="numpy")
    want = corr.correlation_volume_backward(f1, f2, g, backend="warp")
    for key in ("f1", "f2"):
        assert got[key].dtype == dtype and got[key].shape == f1.shape
        np.testing.assert_allclose(got[key], want[key], rtol=tol["rtol"], atol=10 * tol["atol"])  # sums of 117 terms


def test_volume_backend_warp_arrays():
    """The BLAS backend writes into wp.arrays and returns wp.arrays for wp.array inputs."""
    f1, f2, _ = random_case(np.random.default_rng(7), np.float32)
    vol = corr.correlation_volume(wp.array(f1), wp.array(f2))
    assert isinstance(vol, wp.array) and vol.shape == (9, 11, 9, 11)
    np.testing.assert_allclose(vol.numpy(), corr.correlation_volume(f1, f2, backend="warp"), **TOL[np.float32])


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("radius", [0, 2])
@pytest.mark.usefixtures("warp_device")
def test_lookup_matches_reference(dtype, radius):
    f1, f2, coords = random_case(np.random.default_rng(2 + radius), dtype)
    pyramid = corr.correlation_pyramid(corr.correlation_volume(f1, f2), 3)
    out = corr.lookup(pyramid, coords, radius)
    assert out.shape == (3 * (2 * radius + 1) ** 2, 9, 11) and out.dtype == dtype
    want = ref.lookup([p.astype(np.float64) for p in pyramid], coords.astype(np.float64), radius)
    np.testing.assert_allclose(out, want, **TOL[dtype])
    assert np.count_nonzero(want == 0.0) > 0  # some windows lie wholly outside frame 2


@pytest.mark.cpu_fast_path
def test_onthefly_independent_of_thread_count(monkeypatch):
    """The full-product levels run BLAS on row chunks fixed in advance, the patches in race-free split
    launches: the same bytes with 1 and 3 launch threads (576 pixels: three BLAS chunks at the 6x6 level,
    radius 4)."""
    f1, f2, coords = random_case(np.random.default_rng(13), np.float32, shape=(16, 24, 24))
    f2_pyramid = corr.pool_features(f2, 3)
    assert corr.full_product_level(6, 6, 4, wp.get_device("cpu"))
    outs = []
    for threads in ("1", "3"):
        monkeypatch.setenv("DRLAB_THREADS", threads)
        outs.append(corr.lookup_onthefly(f1, f2_pyramid, coords, 4))
    # bit-equal by drlab's blocking: the BLAS calls (256-row chunks, one BLAS thread each) and the window kernels
    # are the same whatever the thread count; only which thread runs a chunk changes
    assert outs[0].tobytes() == outs[1].tobytes()


def test_lookup_more_levels_than_one_launch_covers():
    """Five levels: the dense forward samples four levels a launch, so the fifth takes a second launch."""
    f1, f2, coords = random_case(np.random.default_rng(9), np.float64, shape=(3, 16, 20))
    pyramid = corr.correlation_pyramid(corr.correlation_volume(f1, f2), 5)
    out = corr.lookup(pyramid, coords, 1)
    np.testing.assert_allclose(out, ref.lookup(pyramid, coords, 1), **TOL[np.float64])
    assert np.count_nonzero(out[4 * 9:]) > 0  # the last level's channels were written


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("radius", [0, 1, 4, 8])
def test_lookup_cpu_kernel_is_the_warp_kernel_bit_for_bit(dtype, radius):
    """The CPU's forward (window_cpu, C++) equals `_common.sample_levels` (the Warp kernel CUDA runs) bit
    for bit: windows inside level 0 (positions near each pixel) and overhanging or outside every level
    (positions past the borders), a NaN position, a strided (non-contiguous) level and output, and a
    frame whose last block of pixels is partial."""
    from kernels.corr import _common, window_cpu

    rng = np.random.default_rng(50 + radius)
    c, h, w = 4, 26, 29  # 754 pixels: a last, partial block of LANES
    f1, f2, coords = random_case(rng, dtype, shape=(c, h, w))
    near = np.stack(np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)) + rng.uniform(-2, 2, (2, h, w))
    coords[:, : h // 2] = near[:, : h // 2]  # the top half: windows inside level 0 at small radii
    coords[0, 3, 4] = np.nan
    pyramid = corr.correlation_pyramid(corr.correlation_volume(f1, f2), 4)
    with value_checks(False):  # a NaN position (checked positions raise before any kernel runs)
        got = corr.lookup(pyramid, coords, radius)
    levels = [wp.array(v.reshape(h * w, *v.shape[2:])) for v in pyramid]
    scalar = levels[0].dtype
    side = 2 * radius + 1
    want = wp.zeros((4 * side * side, h, w), dtype=scalar)
    wp.launch(_common.sample_levels, h * w, [*levels, 4, wp.array(coords), want, scalar(1.0), radius, 0, 0],
              device="cpu")
    want = want.numpy()
    nan = np.isnan(want)
    assert nan.any() and np.array_equal(np.isnan(got), nan)
    # bit-equal by construction (kernels.corr.window_cpu): every tap the Warp kernel's float operations in its order,
    # one per C++ statement, so no multiply-add is contracted in either (Warp's generated code never fuses across
    # statements), and the SIMD width (AVX2 or AVX-512) changes no lane's arithmetic
    assert got[~nan].tobytes() == want[~nan].tobytes()
    # A level read through strides (every other column of a wider array): the tested, clamped reads;
    # written through strides too (lane by lane instead of a vector a channel).
    wide = wp.array(np.repeat(pyramid[1].reshape(h * w, h // 2, w // 2), 2, axis=2))
    strided = wide[:, :, ::2]
    assert not strided.is_contiguous
    kernel = window_cpu.sample_levels_cpu(radius, scalar)
    xy = wp.array(coords)
    out_a = wp.zeros((side * side, h, 2 * w), dtype=scalar)[:, :, ::2]
    out_b = wp.zeros((side * side, h, w), dtype=scalar)
    assert (h * w) % window_cpu.LANES  # a last, partial block: the one-pixel path
    wp.launch(kernel, window_cpu.blocks(h * w), [strided, strided, strided, strided, 1, xy, out_a, scalar(0.5), 0, 0],
              device="cpu")
    wp.launch(_common.sample_levels, h * w, [levels[1], levels[1], levels[1], levels[1], 1, xy, out_b,
                                             scalar(0.5), radius, 0, 0], device="cpu")
    a, b = out_a.numpy(), out_b.numpy()
    assert np.array_equal(np.isnan(a), np.isnan(b)) and a[~np.isnan(a)].tobytes() == b[~np.isnan(b)].tobytes()


def test_lookup_channel_order_is_rafts():
    """One bright cell at frame-2 offset (+1, -2) from a pixel: it appears in channel (r + 1)(2r + 1) + (r - 2)."""
    h, w, radius = 6, 7, 2
    side = 2 * radius + 1
    volume = np.zeros((h, w, h, w))
    y1, x1 = 3, 2
    volume[y1, x1, y1 - 2, x1 + 1] = 1.0
    coords = np.stack(np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5))  # pixel centres: zero flow
    out = corr.lookup([volume], coords, radius)
    hit = np.argwhere(out[:, y1, x1] == 1.0).ravel()
    assert hit.tolist() == [(radius + 1) * side + (radius - 2)]
    assert np.count_nonzero(out) == 1


@pytest.mark.parametrize("dtype", DTYPES)
def test_onthefly_equals_dense_forward_and_backward(dtype):
    rng = np.random.default_rng(5)
    f1, f2, coords = random_case(rng, dtype, shape=(11, 10, 13))
    levels, radius = 4, 3
    pyramid = corr.correlation_pyramid(corr.correlation_volume(f1, f2), levels)
    f2_pyramid = corr.pool_features(f2, levels)
    for got, expected in zip(f2_pyramid, ref.pyramid(f2.astype(np.float64), levels)):
        np.testing.assert_allclose(got, expected, **TOL[dtype])
    dense = corr.lookup(pyramid, coords, radius)
    onthefly = corr.lookup_onthefly(f1, f2_pyramid, coords, radius)
    np.testing.assert_allclose(onthefly, dense, **TOL[dtype])

    grad_out = rng.standard_normal(dense.shape).astype(dtype)
    dense_grads = corr.lookup_backward(pyramid, coords, radius, grad_out)
    assert sorted(dense_grads) == ["coords", "pyramid"]
    grad_volume = corr.correlation_pyramid_backward(dense_grads["pyramid"])["volume"]
    grads_dense = corr.correlation_volume_backward(f1, f2, grad_volume)
    grads = corr.lookup_onthefly_backward(f1, f2_pyramid, coords, radius, grad_out)
    assert sorted(grads) == ["coords", "f1", "f2_pyramid"] and len(grads["f2_pyramid"]) == levels
    g2 = corr.pool_features_backward(grads["f2_pyramid"])["f2"]
    tol = dict(rtol=1e-4, atol=1e-4) if dtype == np.float32 else TOL[dtype]  # sums of ~10^3 float32 terms
    np.testing.assert_allclose(grads["f1"], grads_dense["f1"], **tol)
    np.testing.assert_allclose(g2, grads_dense["f2"], **tol)
    np.testing.assert_allclose(grads["coords"], dense_grads["coords"], **tol)


def test_warp_arrays_in_warp_arrays_out():
    f1, f2, coords = random_case(np.random.default_rng(7), np.float32, shape=(3, 8, 8))
    wf1, wf2, wc = (wp.array(a, device="cpu") for a in (f1, f2, coords))
    pyramid = corr.correlation_pyramid(corr.correlation_volume(wf1, wf2), 2)
    assert all(isinstance(p, wp.array) for p in pyramid)
    out = corr.lookup(pyramid, wc, 1)
    assert isinstance(out, wp.array)
    np.testing.assert_allclose(out.numpy(), corr.lookup(corr.correlation_pyramid(
        corr.correlation_volume(f1, f2), 2), coords, 1), rtol=1e-6, atol=1e-6)
    out2 = corr.lookup_onthefly(wf1, corr.pool_features(wf2, 2), wc, 1)
    assert isinstance(out2, wp.array)
    grads = corr.lookup_backward(pyramid, wc, 1, out)
    assert all(isinstance(g, wp.array) for g in [*grads["pyramid"], grads["coords"]])
    grads = corr.lookup_onthefly_backward(wf1, corr.pool_features(wf2, 2), wc, 1, out2)
    assert all(isinstance(g, wp.array) for g in [grads["f1"], *grads["f2_pyramid"], grads["coords"]])
    assert isinstance(corr.correlation_volume_backward(wf1, wf2, corr.correlation_volume(wf1, wf2))["f1"], wp.array)


@pytest.mark.cpu_fast_path
def test_memory_accounting():
    pixels = 46 * 62 + 23 * 31 + 11 * 15 + 5 * 7
    assert corr.dense_bytes(46, 62, 4) == 4 * 46 * 62 * pixels
    assert corr.onthefly_held_bytes(46, 62, 256, 4) == 4 * 256 * (46 * 62 + pixels)  # f1 and the pooled f2
    # The peak (every level at once, `onthefly._forward_phased`, several threads) adds f1 and levels
    # 0-2 channels-last, two patch buffers, level 3's rows of V^l (the full product: 2 * 5x7 <= 10^2
    # taps) and its scaled P^3(f2); the patch kernel's groupings of levels 0-2: four int32 a pixel,
    # the counting sort's (W_l + 11) (H_l + 11) + 1 counts and W_l + 12 group starts.
    n = 46 * 62
    work = 256 * n + 256 * (n + 23 * 31 + 11 * 15) + 2 * n * 10 ** 2 + (n + 256) * 5 * 7
    grouping = sum(4 * n + (wl + 11) * (hl + 11) + 1 + wl + 12 for hl, wl in [(46, 62), (23, 31), (11, 15)])
    assert corr.onthefly_bytes(46, 62, 256, 4, 4) == (corr.onthefly_held_bytes(46, 62, 256, 4) + 4 * work
                                                      + 4 * grouping)


# (shape, levels, radius, which levels take the full product). Levels 0 and 1 of the first case (130
# and 30 taps) go through patches, level 2 (6 taps, 2 * 6 <= 6^2) through the product; the second
# case's level 2 (3x4, 2 * 12 <= 8^2) likewise, at radius 3. (A full-product level holds at most half
# the patch's taps, so its rows fit the patch buffer in one block.)
FULL_PRODUCT_CASES = [((16, 10, 13), 3, 2, [False, False, True]), ((8, 12, 16), 3, 3, [False, False, True])]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape,levels,radius,full", FULL_PRODUCT_CASES, ids=["radius2", "radius3"])
@pytest.mark.cpu_fast_path
def test_onthefly_full_product_levels(dtype, shape, levels, radius, full):
    """Levels small enough for the full product f1^T P^l(f2) by BLAS (CPU, C a multiple of 8) give the
    reference lookup, as the patch levels of the same call do."""
    f1, f2, coords = random_case(np.random.default_rng(11), dtype, shape=shape)
    shapes = corr.level_shapes(shape[1], shape[2], levels)
    assert [corr.full_product_level(h, w, radius, wp.get_device("cpu")) for h, w in shapes] == full
    out = corr.lookup_onthefly(f1, corr.pool_features(f2, levels), coords, radius)
    want = ref.lookup(ref.pyramid(ref.volume(f1.astype(np.float64), f2.astype(np.float64)), levels),
                      coords.astype(np.float64), radius)
    np.testing.assert_allclose(out, want, **TOL[dtype])
    per = (2 * radius + 1) ** 2
    assert np.count_nonzero(want[per:] == 0.0) > 0 and np.count_nonzero(want[per:]) > 0  # taps in and outside


# --------------------------------------------------------------------------- gradients (float64, FD)


@pytest.mark.parametrize("seed", checks.SEEDS)
@pytest.mark.usefixtures("warp_device")
def test_gradcheck_volume_pyramid_pool(seed):
    assert_gradcheck(checks.check_volume(seed) + checks.check_pyramid(seed) + checks.check_pool_features(seed))


@pytest.mark.parametrize("seed", checks.SEEDS)
@pytest.mark.usefixtures("warp_device")
def test_gradcheck_volume_warp_backend(seed):
    assert_gradcheck(checks.check_volume_warp(seed))


@pytest.mark.parametrize("seed", checks.SEEDS)
@pytest.mark.usefixtures("warp_device")
def test_gradcheck_lookup(seed):
    assert_gradcheck(checks.check_lookup(seed, radius=checks.radius_of(seed)))


@pytest.mark.parametrize("seed", checks.SEEDS)
@pytest.mark.usefixtures("warp_device")
def test_gradcheck_lookup_onthefly(seed):
    assert_gradcheck(checks.check_lookup_onthefly(seed, radius=checks.radius_of(seed)))


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.usefixtures("warp_device")
def test_gradcheck_whole_paths(seed):
    assert_gradcheck(checks.check_dense_chain(seed) + checks.check_onthefly_chain(seed))


# --------------------------------------------------------------------------- bad input


def test_mismatched_feature_shapes():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=r"f2: expected shape \(4, 8, 8\), got \(5, 8, 8\)"):
        corr.correlation_volume(rng.standard_normal((4, 8, 8)), rng.standard_normal((5, 8, 8)))
    with pytest.raises(ValueError, match=r"f2: expected shape \(4, 8, 8\), got \(4, 8, 9\)"):
        corr.correlation_volume(rng.standard_normal((4, 8, 8)), rng.standard_normal((4, 8, 9)))
    with pytest.raises(ValueError, match="f1: expected 3 dimensions"):
        corr.correlation_volume(rng.standard_normal((8, 8)), rng.standard_normal((8, 8)))
    f1 = rng.standard_normal((4, 8, 8))
    coords = checks.smooth_coords(rng, 8, 8)
    with pytest.raises(ValueError, match=r"f2_pyramid\[1\]: expected shape \(4, 4, 4\)"):
        corr.lookup_onthefly(f1, [rng.standard_normal((4, 8, 8)), rng.standard_normal((3, 4, 4))], coords, 1)


def _with_nan_coordinate(index: tuple[int, int, int]):
    """Features f1, f2 (3, 8, 8), coordinates (2, 8, 8) holding NaN at `index`, and the 2-level pyramid."""
    rng = np.random.default_rng(0)
    f1, f2 = rng.standard_normal((2, 3, 8, 8))
    coords = checks.smooth_coords(rng, 8, 8)
    coords[index] = np.nan
    return f1, f2, coords, corr.correlation_pyramid(corr.correlation_volume(f1, f2), 2)


def test_nan_coordinates():
    f1, f2, coords, pyramid = _with_nan_coordinate((1, 2, 3))
    with pytest.raises(ValueError, match="coords: expected finite values, found NaN"):
        corr.lookup(pyramid, coords, 2)
    with pytest.raises(ValueError, match="coords: expected finite values"):
        corr.lookup_onthefly(f1, corr.pool_features(f2, 2), coords, 2)
    with pytest.raises(ValueError, match="coords: expected finite values"):
        corr.lookup_backward(pyramid, coords, 2, np.zeros((50, 8, 8)))


def test_value_checks_switch():
    """value_checks(False) skips the NaN checks (for training loops); shape checks stay on."""
    _, _, coords, pyramid = _with_nan_coordinate((0, 1, 1))
    with value_checks(False):
        out = corr.lookup(pyramid, coords, 1)
        with pytest.raises(ValueError, match=r"coords: expected shape \(2, 8, 8\)"):
            corr.lookup(pyramid, coords[:, :4], 1)
    assert np.isnan(out[:, 1, 1]).all() and np.isfinite(np.delete(out.reshape(18, -1), 9, axis=1)).all()
    with pytest.raises(ValueError, match="coords: expected finite values"):
        corr.lookup(pyramid, coords, 1)


def test_pyramid_too_deep():
    rng = np.random.default_rng(0)
    volume = corr.correlation_volume(*rng.standard_normal((2, 3, 8, 12)))
    with pytest.raises(ValueError, match="levels: a pyramid of 5 levels needs frame 2 at least 16x16"):
        corr.correlation_pyramid(volume, 5)
    with pytest.raises(ValueError, match="levels: a pyramid of 5 levels"):
        corr.pool_features(rng.standard_normal((3, 8, 12)), 5)
    with pytest.raises(ValueError, match="levels: expected an integer >= 1"):
        corr.correlation_pyramid(volume, 0)


def test_other_bad_input():
    rng = np.random.default_rng(0)
    f1, f2 = rng.standard_normal((2, 3, 8, 8))
    coords = checks.smooth_coords(rng, 8, 8)
    pyramid = corr.correlation_pyramid(corr.correlation_volume(f1, f2), 2)
    with pytest.raises(ValueError, match="f2: expected dtype float64 like the other inputs, got float32"):
        corr.correlation_volume(f1, f2.astype(np.float32))
    with pytest.raises(ValueError, match="f1: expected dtype float32 or float64"):
        corr.correlation_volume(f1.astype(np.int32), f2.astype(np.int32))
    with pytest.raises(ValueError, match="f1: expected a NumPy array or a wp.array, got list"):
        corr.correlation_volume(f1.tolist(), f2)
    f1_nan = f1.copy()
    f1_nan[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="f1: expected finite values"):
        corr.correlation_volume(f1_nan, f2)
    with pytest.raises(ValueError, match=r"coords: expected shape \(2, 8, 8\)"):
        corr.lookup(pyramid, coords[:, :4], 1)
    with pytest.raises(ValueError, match="radius: expected an integer >= 0"):
        corr.lookup(pyramid, coords, -1)
    with pytest.raises(ValueError, match=r"pyramid\[1\]: expected shape \(8, 8, 4, 4\)"):
        corr.lookup([pyramid[0], pyramid[1][:, :, :3]], coords, 1)
    with pytest.raises(ValueError, match="pyramid: expected a non-empty list"):
        corr.lookup([], coords, 1)
    with pytest.raises(ValueError, match=r"grad_out: expected shape \(18, 8, 8\)"):
        corr.lookup_backward(pyramid, coords, 1, np.zeros((9, 8, 8)))
    with pytest.raises(ValueError, match="backend: expected one of numpy, warp or None, got 'blas'"):
        corr.correlation_volume(f1, f2, backend="blas")
    with pytest.raises(ValueError, match="backend: expected one of numpy, warp or None"):
        corr.correlation_volume_backward(f1, f2, np.zeros((8, 8, 8, 8)), backend="torch")
    with pytest.raises(ValueError, match="grad_volume: expected shape"):
        corr.correlation_volume_backward(f1, f2, np.zeros((8, 8, 8)))
    with pytest.raises(ValueError, match=r"volume: expected shape \(H, W, H, W\), got \(8, 8, 4, 4\)"):
        corr.correlation_pyramid(np.zeros((8, 8, 4, 4)), 2)
    with pytest.raises(ValueError, match="grad_pyramid: expected a non-empty list"):
        corr.correlation_pyramid_backward([])
    with pytest.raises(ValueError, match=r"grad_pyramid\[1\]: expected shape \(8, 8, 4, 4\)"):
        corr.correlation_pyramid_backward([np.zeros((8, 8, 8, 8)), np.zeros((8, 8, 4, 3))])
    with pytest.raises(ValueError, match=r"grad_pyramid\[1\]: expected shape \(3, 4, 4\)"):
        corr.pool_features_backward([np.zeros((3, 8, 8)), np.zeros((2, 4, 4))])
    f2_pyramid = corr.pool_features(f2, 2)
    with pytest.raises(ValueError, match=r"grad_out: expected shape \(18, 8, 8\)"):
        corr.lookup_onthefly_backward(f1, f2_pyramid, coords, 1, np.zeros((9, 8, 8)))
    with pytest.raises(ValueError, match=r"f2_pyramid\[0\]: expected dtype float64 like the other inputs"):
        corr.lookup_onthefly(f1, [f.astype(np.float32) for f in f2_pyramid], coords, 1)
