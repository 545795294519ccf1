"""kernels.lucas_kanade: Lucas-Kanade against kernels.reference.lucas_kanade, recovery of known motions, bad input.

LK is forward only (an estimator; kernels/lucas_kanade.py has no adjoints), so there is no gradient check here.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from scipy.ndimage import gaussian_filter, shift

from kernels import lucas_kanade as lk
from kernels.reference import lucas_kanade as ref

DTYPES = [np.float32, np.float64]
TOL = {np.float32: dict(rtol=2e-4, atol=2e-4), np.float64: dict(rtol=1e-10, atol=1e-10)}


# --------------------------------------------------------------------------- inputs


def texture(rng: np.random.Generator, h: int, w: int, sigma: float = 1.5) -> np.ndarray:
    img = gaussian_filter(rng.standard_normal((h, w)), sigma)
    return 0.5 + 0.2 * img / img.std()


# --------------------------------------------------------------------------- forward vs reference


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.usefixtures("warp_device")
def test_gradients_downsample_upsample_match_reference(dtype):
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 1, (9, 12)).astype(dtype)
    ix, iy = lk.image_gradients(img)
    rx, ry = ref.gradients(img.astype(np.float64))
    np.testing.assert_allclose(ix, rx, **TOL[dtype])
    np.testing.assert_allclose(iy, ry, **TOL[dtype])
    np.testing.assert_allclose(lk.downsample(img), ref.downsample(img.astype(np.float64)), **TOL[dtype])
    coarse = rng.normal(0, 2, (4, 6, 2)).astype(dtype)
    np.testing.assert_allclose(lk.upsample_flow(coarse, 9, 12), ref.upsample_flow(coarse.astype(np.float64), 9, 12),
                               **TOL[dtype])


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.usefixtures("warp_device")
def test_lk_step_matches_reference(dtype):
    rng = np.random.default_rng(1)
    img1 = texture(rng, 11, 13).astype(dtype)
    img2 = texture(rng, 11, 13).astype(dtype)
    img1[:, :3] = 0.5  # a flat strip: lambda_min below threshold there
    flow_init = rng.normal(0, 1.5, (11, 13, 2)).astype(dtype)
    got, valid, lam = lk.lucas_kanade(img1, img2, half_window=2, iterations=1, min_eigenvalue=1e-3,
                                        flow_init=flow_init)
    want, want_valid, want_lam = ref.lk_step(img1.astype(np.float64), img2.astype(np.float64),
                                             flow_init.astype(np.float64), 2, 1e-3)
    np.testing.assert_allclose(lam, want_lam, **TOL[dtype])
    far = np.abs(want_lam - 1e-3) > 1e-5  # pixels whose validity float32 rounding cannot flip
    assert np.array_equal(valid[far], want_valid[far]) and 0 < want_valid.sum() < want_valid.size
    tol = dict(rtol=2e-3, atol=2e-3) if dtype == np.float32 else TOL[dtype]  # a 2x2 solve amplifies rounding
    np.testing.assert_allclose(got[far], want[far], **tol)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.usefixtures("warp_device")
def test_pyramidal_matches_reference(dtype):
    rng = np.random.default_rng(2)
    img1 = texture(rng, 20, 23).astype(dtype)
    img2 = shift(img1.astype(np.float64), (0.8, 1.6), order=3, mode="nearest").astype(dtype)
    got, valid, lam = lk.pyramidal_lucas_kanade(img1, img2, levels=2, half_window=2, iterations=2,
                                                  min_eigenvalue=1e-4)
    want, want_valid, _ = ref.pyramidal(img1.astype(np.float64), img2.astype(np.float64), 2, 2, 2, 1e-4)
    tol = dict(rtol=1e-3, atol=1e-3) if dtype == np.float32 else dict(rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got, want, **tol)
    assert np.array_equal(valid, want_valid)


# --------------------------------------------------------------------------- known motions


def test_single_scale_iterative_recovers_subpixel_translation():
    rng = np.random.default_rng(3)
    img1 = texture(rng, 48, 48, sigma=2.0)
    img2 = shift(img1, (-0.6, 0.9), order=3, mode="nearest")  # content moves +0.9 in x, -0.6 in y
    fl, valid, _ = lk.lucas_kanade(img1, img2, half_window=4, iterations=8)
    inner = (slice(8, -8), slice(8, -8))
    assert valid[inner].all()
    np.testing.assert_allclose(np.median(fl[inner], axis=(0, 1)), [0.9, -0.6], atol=0.02)


def test_pyramid_recovers_large_translation_single_scale_does_not():
    rng = np.random.default_rng(4)
    img1 = texture(rng, 64, 64, sigma=2.0)
    img2 = shift(img1, (3.0, 6.0), order=3, mode="nearest")
    inner = (slice(14, -14), slice(14, -14))
    pyr, _, _ = lk.pyramidal_lucas_kanade(img1, img2, levels=3, half_window=4, iterations=6)
    np.testing.assert_allclose(np.median(pyr[inner], axis=(0, 1)), [6.0, 3.0], atol=0.05)
    single, _, _ = lk.lucas_kanade(img1, img2, half_window=4, iterations=1)
    assert np.abs(np.median(single[inner], axis=(0, 1)) - [6.0, 3.0]).max() > 1.0


def test_textbook_square_moves_right():
    f1 = np.zeros((64, 64))
    f1[20:40, 15:35] = 1.0
    f2 = np.zeros((64, 64))
    f2[20:40, 20:40] = 1.0
    fl, valid, lam = lk.pyramidal_lucas_kanade(f1, f2, levels=3, half_window=3, iterations=10)
    assert valid.sum() > 0 and not valid[30, 25]  # corners are valid; the flat inside is not
    np.testing.assert_allclose(fl[valid].mean(axis=0), [5.0, 0.0], atol=0.01)
    # Every valid pixel converges close to the truth; the last few at symmetric pairs of corner pixels
    # stop about 0.1 px off (5 - e and 5 + e), as the binary step has no texture between them.
    assert np.abs(fl[valid] - [5.0, 0.0]).max() < 0.15
    assert np.median(np.abs(fl[valid] - [5.0, 0.0])) < 1e-3


def test_warp_arrays_in_warp_arrays_out():
    rng = np.random.default_rng(5)
    img1, img2 = (wp.array(texture(rng, 16, 16).astype(np.float32)) for _ in range(2))
    fl, valid, lam = lk.pyramidal_lucas_kanade(img1, img2, levels=2, half_window=2)
    assert isinstance(fl, wp.array) and fl.shape == (16, 16, 2) and isinstance(lam, wp.array)
    assert isinstance(valid, wp.array) and valid.dtype == wp.uint8 and valid.shape == (16, 16)
    want, want_valid, _ = lk.pyramidal_lucas_kanade(img1.numpy(), img2.numpy(), levels=2, half_window=2)
    assert np.array_equal(fl.numpy(), want) and np.array_equal(valid.numpy().astype(bool), want_valid)
    assert want_valid.dtype == bool


# --------------------------------------------------------------------------- bad input


def test_bad_input():
    rng = np.random.default_rng(0)
    a = texture(rng, 32, 40)
    with pytest.raises(ValueError, match=r"frame2: expected shape \(32, 40\), got \(32, 39\)"):
        lk.lucas_kanade(a, a[:, :39])
    nan = a.copy()
    nan[3, 4] = np.nan
    with pytest.raises(ValueError, match="frame2: expected finite values, found NaN"):
        lk.pyramidal_lucas_kanade(a, nan)
    with pytest.raises(ValueError, match="levels: a 32x40 frame with a 7-pixel window allows at most 3 levels"):
        lk.pyramidal_lucas_kanade(a, a, levels=4, half_window=3)
    with pytest.raises(ValueError, match="half_window: expected an integer >= 1"):
        lk.lucas_kanade(a, a, half_window=0)
    with pytest.raises(ValueError, match="frame2: expected dtype float64 like the other inputs, got float32"):
        lk.lucas_kanade(a, a.astype(np.float32))
    with pytest.raises(ValueError, match="frame1: expected 2 dimensions"):
        lk.lucas_kanade(np.stack([a, a, a], -1), np.stack([a, a, a], -1))
    with pytest.raises(ValueError, match="min_eigenvalue: expected a finite non-negative number"):
        lk.lucas_kanade(a, a, min_eigenvalue=-1.0)
    with pytest.raises(ValueError, match=r"flow_init: expected shape \(32, 40, 2\)"):
        lk.lucas_kanade(a, a, flow_init=np.zeros((32, 40)))
    with pytest.raises(ValueError, match="iterations: expected an integer >= 1"):
        lk.pyramidal_lucas_kanade(a, a, iterations=0)
    with pytest.raises(ValueError, match=r"flow: expected shape \(N, N, 2\)"):
        lk.upsample_flow(np.zeros((4, 5, 3)), 8, 10)
    with pytest.raises(ValueError, match="height, width: expected a level whose halves are the flow's"):
        lk.upsample_flow(np.zeros((4, 5, 2)), 8, 12)
    with pytest.raises(ValueError, match="frame: expected at least 2x2 pixels"):
        lk.downsample(np.zeros((1, 5)))
    with pytest.raises(ValueError, match="frame: expected finite values"):
        lk.image_gradients(nan)
