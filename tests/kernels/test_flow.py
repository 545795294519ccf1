"""kernels.flow: Lucas-Kanade against plain NumPy, recovery of known motions, bad input.

LK is forward only (an estimator; kernels/flow.py has no adjoints), so there is no gradient check here.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from scipy.ndimage import gaussian_filter, shift

from kernels import flow

DTYPES = [np.float32, np.float64]
TOL = {np.float32: dict(rtol=2e-4, atol=2e-4), np.float64: dict(rtol=1e-10, atol=1e-10)}


# --------------------------------------------------------------------------- NumPy reference


def px(img: np.ndarray, i: int, j: int) -> float:
    """Pixel with replicated borders."""
    return img[min(max(i, 0), img.shape[0] - 1), min(max(j, 0), img.shape[1] - 1)]


def ref_gradients(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ix, iy = np.zeros_like(img), np.zeros_like(img)
    for i in range(img.shape[0]):
        for j in range(img.shape[1]):
            ix[i, j] = (px(img, i, j + 1) - px(img, i, j - 1)) / 2
            iy[i, j] = (px(img, i + 1, j) - px(img, i - 1, j)) / 2
    return ix, iy


def ref_sample(img: np.ndarray, x: float, y: float) -> float:
    u, v = x - 0.5, y - 0.5
    j, i = int(np.floor(u)), int(np.floor(v))
    ax, ay = u - j, v - i
    return ((1 - ay) * ((1 - ax) * px(img, i, j) + ax * px(img, i, j + 1))
            + ay * ((1 - ax) * px(img, i + 1, j) + ax * px(img, i + 1, j + 1)))


def ref_lk_step(img1, img2, flow_in, half_window, min_eigenvalue):
    """One step of equation (2) at every pixel, with the validity test (3)."""
    h, w = img1.shape
    ix, iy = ref_gradients(img1)
    out, lam_out, valid = flow_in.copy(), np.zeros((h, w)), np.zeros((h, w), bool)
    for i in range(h):
        for j in range(w):
            G, b, n = np.zeros((2, 2)), np.zeros(2), 0
            for qi in range(max(0, i - half_window), min(h, i + half_window + 1)):
                for qj in range(max(0, j - half_window), min(w, j + half_window + 1)):
                    g = np.array([ix[qi, qj], iy[qi, qj]])
                    e = ref_sample(img2, qj + 0.5 + flow_in[i, j, 0], qi + 0.5 + flow_in[i, j, 1]) - img1[qi, qj]
                    G += np.outer(g, g)
                    b += e * g
                    n += 1
            lam = np.linalg.eigvalsh(G / n)[0]
            lam_out[i, j] = lam
            if lam >= min_eigenvalue:
                out[i, j] += np.linalg.solve(G, -b)
                valid[i, j] = True
    return out, valid, lam_out


def ref_downsample(img: np.ndarray) -> np.ndarray:
    k = np.array([1.0, 3.0, 3.0, 1.0]) / 8
    out = np.zeros((img.shape[0] // 2, img.shape[1] // 2))
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = sum(k[a] * k[b] * px(img, 2 * i - 1 + a, 2 * j - 1 + b) for a in range(4) for b in range(4))
    return out


def ref_upsample(coarse: np.ndarray, height: int, width: int) -> np.ndarray:
    out = np.zeros((height, width, 2))
    for i in range(height):
        for j in range(width):
            for k in range(2):
                out[i, j, k] = 2 * ref_sample(coarse[..., k], (j + 0.5) / 2, (i + 0.5) / 2)
    return out


def ref_pyramidal(img1, img2, levels, half_window, iterations, min_eigenvalue):
    pyr1, pyr2 = [img1], [img2]
    for _ in range(1, levels):
        pyr1.append(ref_downsample(pyr1[-1]))
        pyr2.append(ref_downsample(pyr2[-1]))
    fl = np.zeros((*pyr1[-1].shape, 2))
    for lvl in range(levels - 1, -1, -1):
        if lvl < levels - 1:
            fl = ref_upsample(fl, *pyr1[lvl].shape)
        for _ in range(iterations):
            fl, valid, lam = ref_lk_step(pyr1[lvl], pyr2[lvl], fl, half_window, min_eigenvalue)
    return fl, valid, lam


def texture(rng: np.random.Generator, h: int, w: int, sigma: float = 1.5) -> np.ndarray:
    img = gaussian_filter(rng.standard_normal((h, w)), sigma)
    return 0.5 + 0.2 * img / img.std()


# --------------------------------------------------------------------------- forward vs reference


@pytest.mark.parametrize("dtype", DTYPES)
def test_gradients_downsample_upsample_match_reference(dtype):
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 1, (9, 12)).astype(dtype)
    ix, iy = flow.image_gradients(img)
    rx, ry = ref_gradients(img.astype(np.float64))
    np.testing.assert_allclose(ix, rx, **TOL[dtype])
    np.testing.assert_allclose(iy, ry, **TOL[dtype])
    np.testing.assert_allclose(flow.downsample(img), ref_downsample(img.astype(np.float64)), **TOL[dtype])
    coarse = rng.normal(0, 2, (4, 6, 2)).astype(dtype)
    np.testing.assert_allclose(flow.upsample_flow(coarse, 9, 12), ref_upsample(coarse.astype(np.float64), 9, 12),
                               **TOL[dtype])


@pytest.mark.parametrize("dtype", DTYPES)
def test_lk_step_matches_reference(dtype):
    rng = np.random.default_rng(1)
    img1 = texture(rng, 11, 13).astype(dtype)
    img2 = texture(rng, 11, 13).astype(dtype)
    img1[:, :3] = 0.5  # a flat strip: lambda_min below threshold there
    flow_init = rng.normal(0, 1.5, (11, 13, 2)).astype(dtype)
    got, valid, lam = flow.lucas_kanade(img1, img2, half_window=2, iterations=1, min_eigenvalue=1e-3,
                                        flow_init=flow_init)
    want, want_valid, want_lam = ref_lk_step(img1.astype(np.float64), img2.astype(np.float64),
                                             flow_init.astype(np.float64), 2, 1e-3)
    np.testing.assert_allclose(lam, want_lam, **TOL[dtype])
    far = np.abs(want_lam - 1e-3) > 1e-5  # pixels whose validity float32 rounding cannot flip
    assert np.array_equal(valid[far], want_valid[far]) and 0 < want_valid.sum() < want_valid.size
    tol = dict(rtol=2e-3, atol=2e-3) if dtype == np.float32 else TOL[dtype]  # a 2x2 solve amplifies rounding
    np.testing.assert_allclose(got[far], want[far], **tol)


@pytest.mark.parametrize("dtype", DTYPES)
def test_pyramidal_matches_reference(dtype):
    rng = np.random.default_rng(2)
    img1 = texture(rng, 20, 23).astype(dtype)
    img2 = shift(img1.astype(np.float64), (0.8, 1.6), order=3, mode="nearest").astype(dtype)
    got, valid, lam = flow.pyramidal_lucas_kanade(img1, img2, levels=2, half_window=2, iterations=2,
                                                  min_eigenvalue=1e-4)
    want, want_valid, _ = ref_pyramidal(img1.astype(np.float64), img2.astype(np.float64), 2, 2, 2, 1e-4)
    tol = dict(rtol=1e-3, atol=1e-3) if dtype == np.float32 else dict(rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got, want, **tol)
    assert np.array_equal(valid, want_valid)


# --------------------------------------------------------------------------- known motions


def test_single_scale_iterative_recovers_subpixel_translation():
    rng = np.random.default_rng(3)
    img1 = texture(rng, 48, 48, sigma=2.0)
    img2 = shift(img1, (-0.6, 0.9), order=3, mode="nearest")  # content moves +0.9 in x, -0.6 in y
    fl, valid, _ = flow.lucas_kanade(img1, img2, half_window=4, iterations=8)
    inner = (slice(8, -8), slice(8, -8))
    assert valid[inner].all()
    np.testing.assert_allclose(np.median(fl[inner], axis=(0, 1)), [0.9, -0.6], atol=0.02)


def test_pyramid_recovers_large_translation_single_scale_does_not():
    rng = np.random.default_rng(4)
    img1 = texture(rng, 64, 64, sigma=2.0)
    img2 = shift(img1, (3.0, 6.0), order=3, mode="nearest")
    inner = (slice(14, -14), slice(14, -14))
    pyr, _, _ = flow.pyramidal_lucas_kanade(img1, img2, levels=3, half_window=4, iterations=6)
    np.testing.assert_allclose(np.median(pyr[inner], axis=(0, 1)), [6.0, 3.0], atol=0.05)
    single, _, _ = flow.lucas_kanade(img1, img2, half_window=4, iterations=1)
    assert np.abs(np.median(single[inner], axis=(0, 1)) - [6.0, 3.0]).max() > 1.0


def test_textbook_square_moves_right():
    f1 = np.zeros((64, 64))
    f1[20:40, 15:35] = 1.0
    f2 = np.zeros((64, 64))
    f2[20:40, 20:40] = 1.0
    fl, valid, lam = flow.pyramidal_lucas_kanade(f1, f2, levels=3, half_window=3, iterations=10)
    assert valid.sum() > 0 and not valid[30, 25]  # corners are valid; the flat inside is not
    np.testing.assert_allclose(fl[valid].mean(axis=0), [5.0, 0.0], atol=0.01)
    # Every valid pixel converges close to the truth; the last few at symmetric pairs of corner pixels
    # stop about 0.1 px off (5 - e and 5 + e), as the binary step has no texture between them.
    assert np.abs(fl[valid] - [5.0, 0.0]).max() < 0.15
    assert np.median(np.abs(fl[valid] - [5.0, 0.0])) < 1e-3


def test_warp_arrays_in_warp_arrays_out():
    rng = np.random.default_rng(5)
    img1, img2 = (wp.array(texture(rng, 16, 16).astype(np.float32)) for _ in range(2))
    fl, valid, lam = flow.pyramidal_lucas_kanade(img1, img2, levels=2, half_window=2)
    assert isinstance(fl, wp.array) and fl.shape == (16, 16, 2) and valid.dtype == bool


# --------------------------------------------------------------------------- bad input


def test_bad_input():
    rng = np.random.default_rng(0)
    a = texture(rng, 32, 40)
    with pytest.raises(ValueError, match=r"frame2: expected the shape of frame1 \(32, 40\)"):
        flow.lucas_kanade(a, a[:, :39])
    nan = a.copy()
    nan[3, 4] = np.nan
    with pytest.raises(ValueError, match="frame2: expected finite intensities, found 1 NaN"):
        flow.pyramidal_lucas_kanade(a, nan)
    with pytest.raises(ValueError, match="levels: a 32x40 frame with a 7-pixel window allows at most 3 levels"):
        flow.pyramidal_lucas_kanade(a, a, levels=4, half_window=3)
    with pytest.raises(ValueError, match="half_window: expected an integer >= 1"):
        flow.lucas_kanade(a, a, half_window=0)
    with pytest.raises(ValueError, match="frame2: expected dtype float64 like frame1"):
        flow.lucas_kanade(a, a.astype(np.float32))
    with pytest.raises(ValueError, match=r"frame1: expected a grey image \(H, W\)"):
        flow.lucas_kanade(np.stack([a, a, a], -1), np.stack([a, a, a], -1))
    with pytest.raises(ValueError, match="min_eigenvalue: expected a finite number >= 0"):
        flow.lucas_kanade(a, a, min_eigenvalue=-1.0)
    with pytest.raises(ValueError, match=r"flow_init: expected shape \(32, 40, 2\)"):
        flow.lucas_kanade(a, a, flow_init=np.zeros((32, 40)))
    with pytest.raises(ValueError, match="iterations: expected an integer >= 1"):
        flow.pyramidal_lucas_kanade(a, a, iterations=0)
