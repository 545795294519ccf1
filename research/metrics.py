"""Image-quality metrics: PSNR and SSIM (NumPy/SciPy).

PSNR = 10 log10(L^2 / MSE) over every pixel and channel (or over a mask), L the data range.

SSIM (Wang, Bovik, Sheikh & Simoncelli 2004, "Image quality assessment: from error visibility
to structural similarity"), with the paper's constants: an 11x11 Gaussian window of standard
deviation 1.5 (normalised to sum 1), K1 = 0.01, K2 = 0.03, C1 = (K1 L)^2, C2 = (K2 L)^2. For
windowed means mu, variances s^2 and covariance s_xy (population, weighted by the window),

    SSIM(x, y) = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2)),

averaged over every window position lying fully inside the image ("valid"), then over the
channels. This matches skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=L) and the usual NeRF evaluation code.

Domain: `psnr` and `ssim` refuse (ValueError naming the argument) images of different shapes,
NaN or infinite values, a `data_range` that is not finite and > 0, and pixel values outside
[0, data_range] beyond a rounding slack of 1e-6 data_range: a 0-255 image scored against a 0-1
one, or with the default data_range 1, gives a meaningless number (-43.6 dB) instead of an error
otherwise. `mse` compares any finite images.

Novel-view evaluation (`EVAL_PROTOCOL`, shared by fit_nerf and fit_splats so that their rows in
results/comparison are comparable): the linear image composited on black (premultiplied RGB),
clipped to [0, 1], then sRGB-encoded (`srgb_on_black`) -- for prediction and ground truth alike.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d

from research.io import linear_to_srgb

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
EVAL_PROTOCOL = "test split; sRGB of linear RGB premultiplied on black, clipped to [0,1]; research.metrics"


def srgb_on_black(rgb_linear_premultiplied: np.ndarray) -> np.ndarray:
    """The sRGB encoding of a linear image composited on black (the last axis is RGB; any alpha is dropped)."""
    rgb = np.asarray(rgb_linear_premultiplied)[..., :3]
    return linear_to_srgb(np.clip(rgb, 0.0, 1.0))


def srgb_targets(rgba_linear: np.ndarray) -> np.ndarray:
    """Linear premultiplied RGBA (N, H, W, 4) -> (sRGB of the image on black, alpha), float32.

    The RGB is exactly what this module evaluates against (`srgb_on_black`), so a field trained
    on a black background is fitted to its evaluation target, edge pixels included.
    """
    rgb = srgb_on_black(rgba_linear.astype(np.float64))
    return np.concatenate([rgb, rgba_linear[..., 3:].astype(np.float64)], axis=-1).astype(np.float32)


def _pair(pred: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(pred, dtype=np.float64)
    b = np.asarray(target, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"pred, target: shapes differ ({a.shape} vs {b.shape})")
    if a.ndim not in (2, 3):
        raise ValueError(f"pred: expected an image (H, W) or (H, W, C), got shape {a.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("pred, target: contain NaN or infinite values")
    return a, b


RANGE_SLACK = 1e-6  # relative to data_range: sRGB encoding of 1.0 may land an ulp above it


def _check_data_range(data_range: float) -> float:
    if isinstance(data_range, bool) or not isinstance(data_range, (int, float, np.number)) \
            or not np.isfinite(data_range) or not data_range > 0:
        raise ValueError(f"data_range: expected a finite number > 0, got {data_range!r}")
    return float(data_range)


def _check_in_range(a: np.ndarray, name: str, data_range: float) -> None:
    slack = RANGE_SLACK * data_range
    lo, hi = float(a.min()), float(a.max())
    if lo < -slack or hi > data_range + slack:
        hint = " (a 0-255 image? divide it by 255, or pass data_range=255 for both)" if 2 < hi <= 255 else ""
        raise ValueError(f"{name}: expected values in [0, data_range={data_range:g}], got [{lo:.6g}, {hi:.6g}]"
                         f"{hint}")


def mse(pred: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> float:
    a, b = _pair(pred, target)
    return _mse(a, b, mask)


def _mse(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None) -> float:
    """mse of a pair already checked by `_pair`."""
    err = (a - b) ** 2
    if mask is None:
        return float(err.mean())
    m = np.asarray(mask, dtype=bool)
    if m.shape != a.shape[:2]:
        raise ValueError(f"mask: expected shape {a.shape[:2]}, got {m.shape}")
    if not m.any():
        raise ValueError("mask: selects no pixel")
    return float(err[m].mean())


def psnr(pred: np.ndarray, target: np.ndarray, data_range: float = 1.0, mask: np.ndarray | None = None) -> float:
    """10 log10(L^2 / MSE); +inf for identical images. Both images must lie in [0, L] (module docstring)."""
    data_range = _check_data_range(data_range)
    a, b = _pair(pred, target)
    _check_in_range(a, "pred", data_range)
    _check_in_range(b, "target", data_range)
    e = _mse(a, b, mask)
    return float("inf") if e == 0 else float(10.0 * np.log10(data_range**2 / e))


def gaussian_window_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    x = np.arange(size) - (size - 1) / 2.0
    g = np.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


def _filter_valid(img: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Separable windowed mean, keeping only fully-inside window positions."""
    r = (len(g) - 1) // 2
    out = correlate1d(correlate1d(img, g, axis=0, mode="constant"), g, axis=1, mode="constant")
    return out[r:img.shape[0] - r, r:img.shape[1] - r]


def ssim(pred: np.ndarray, target: np.ndarray, data_range: float = 1.0, mask: np.ndarray | None = None) -> float:
    """Mean SSIM (module docstring); images (H, W) or (H, W, C) with H, W >= 11, in [0, data_range].

    With `mask` (H, W) bool, the mean of the SSIM map over the windows whose centre pixel it selects
    (the map's windows lie inside the image, so a border of 5 pixels is never a centre)."""
    data_range = _check_data_range(data_range)
    a, b = _pair(pred, target)
    _check_in_range(a, "pred", data_range)
    _check_in_range(b, "target", data_range)
    if min(a.shape[:2]) < SSIM_WINDOW:
        raise ValueError(f"pred: SSIM needs images at least {SSIM_WINDOW}x{SSIM_WINDOW}, got {a.shape[:2]}")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    centres = None
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != a.shape[:2]:
            raise ValueError(f"mask: expected shape {a.shape[:2]}, got {m.shape}")
        r = (SSIM_WINDOW - 1) // 2
        centres = m[r:m.shape[0] - r, r:m.shape[1] - r]
        if not centres.any():
            raise ValueError(f"mask: selects no window centre (pixels at least {r} from the border)")
    g = gaussian_window_1d()
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    values = []
    for c in range(a.shape[2]):
        x, y = a[..., c], b[..., c]
        mx, my = _filter_valid(x, g), _filter_valid(y, g)
        sxx = _filter_valid(x * x, g) - mx * mx
        syy = _filter_valid(y * y, g) - my * my
        sxy = _filter_valid(x * y, g) - mx * my
        s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
        values.append(s.mean() if centres is None else s[centres].mean())
    return float(np.mean(values))
