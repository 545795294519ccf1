"""research.metrics: PSNR and SSIM against straightforward references written from the definitions."""

from __future__ import annotations

import numpy as np
import pytest

from research.metrics import gaussian_window_1d, psnr, ssim


def ssim_reference(x: np.ndarray, y: np.ndarray, data_range: float = 1.0) -> float:
    """Window by window: weighted means, variances, covariance, the SSIM formula, averaged."""
    w1 = gaussian_window_1d(11, 1.5)
    w = np.outer(w1, w1)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    x = x[..., None] if x.ndim == 2 else x
    y = y[..., None] if y.ndim == 2 else y
    per_channel = []
    for c in range(x.shape[2]):
        vals = []
        for i in range(x.shape[0] - 10):
            for j in range(x.shape[1] - 10):
                px, py = x[i:i + 11, j:j + 11, c], y[i:i + 11, j:j + 11, c]
                mx, my = (w * px).sum(), (w * py).sum()
                vx, vy = (w * (px - mx) ** 2).sum(), (w * (py - my) ** 2).sum()
                cxy = (w * (px - mx) * (py - my)).sum()
                vals.append((2 * mx * my + c1) * (2 * cxy + c2) / ((mx**2 + my**2 + c1) * (vx + vy + c2)))
        per_channel.append(np.mean(vals))
    return float(np.mean(per_channel))


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("shape", [(16, 19), (14, 13, 3)])
def test_ssim_matches_reference(seed, shape):
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 1, shape)
    y = np.clip(x + rng.normal(0, 0.1, shape), 0, 1)
    assert ssim(x, y) == pytest.approx(ssim_reference(x, y), abs=1e-12)
    assert ssim(x, y, data_range=2.0) == pytest.approx(ssim_reference(x, y, 2.0), abs=1e-12)


def test_ssim_identity_and_bounds():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (20, 20, 3))
    assert ssim(x, x) == pytest.approx(1.0, abs=1e-12)
    assert ssim(x, 1.0 - x) < 0.0  # anti-correlated structure


def test_psnr_matches_definition():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (8, 9, 3))
    y = np.clip(x + rng.normal(0, 0.05, x.shape), 0.0, 1.0)  # PSNR needs both images in [0, 1]
    assert psnr(y, x) == pytest.approx(10 * np.log10(1.0 / np.mean((y - x) ** 2)), rel=1e-12)
    mask = rng.uniform(size=(8, 9)) > 0.5
    assert psnr(y, x, mask=mask) == pytest.approx(10 * np.log10(1.0 / np.mean((y - x)[mask] ** 2)), rel=1e-12)
    assert psnr(x, x) == float("inf")


def test_bad_inputs():
    x = np.zeros((12, 12))
    with pytest.raises(ValueError, match="shapes differ"):
        ssim(x, np.zeros((12, 13)))
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(np.zeros((5, 5)), np.zeros((5, 5)))
    with pytest.raises(ValueError, match="NaN"):
        psnr(np.full((4, 4), np.nan), np.zeros((4, 4)))
    with pytest.raises(ValueError, match="mask"):
        psnr(x, x, mask=np.zeros((12, 12), bool))


def test_evaluation_image_is_the_srgb_of_the_composite_on_black():
    from research.metrics import srgb_on_black
    from research.metrics import srgb_targets

    # A half-covered pixel of linear colour 0.4 stores premultiplied 0.2: its evaluation value is
    # sRGB(0.2) (the image on black), not 0.5 * sRGB(0.4) (straight colour encoded, then scaled).
    rgba = np.array([[[[0.2, 0.0, 1.5, 0.5], [0.04, 0.3, 0.0031308, 1.0]]]])
    expected = np.array([[[[0.48452920448170694, 0.0, 1.0], [0.22091636254849623, 0.5838314900602575, 0.0031308 * 12.92]]]])
    np.testing.assert_allclose(srgb_on_black(rgba), expected, atol=1e-8)
    targets = srgb_targets(rgba)
    assert targets.dtype == np.float32 and targets.shape == (1, 1, 2, 4)
    np.testing.assert_allclose(targets[..., :3], expected, atol=1e-6)
    np.testing.assert_array_equal(targets[..., 3], rgba[..., 3].astype(np.float32))


def test_ssim_mask_averages_the_map_over_the_selected_window_centres():
    rng = np.random.default_rng(4)
    a = rng.uniform(0, 1, (40, 40, 3))
    b = a.copy()
    b[:, 20:] = rng.uniform(0, 1, (40, 20, 3))  # the right half differs
    full = np.ones((40, 40), bool)
    assert ssim(a, b, mask=full) == pytest.approx(ssim(a, b), rel=1e-12)
    left = np.zeros((40, 40), bool)
    left[:, :12] = True  # windows centred here (radius 5) see only equal pixels
    assert ssim(a, b, mask=left) == pytest.approx(1.0, abs=1e-12)
    assert ssim(a, b, mask=~left) < ssim(a, b)
    with pytest.raises(ValueError, match="^mask: expected shape"):
        ssim(a, b, mask=full[:-1])
    border = np.zeros((40, 40), bool)
    border[:3] = True
    with pytest.raises(ValueError, match="^mask: selects no window centre"):
        ssim(a, b, mask=border)
