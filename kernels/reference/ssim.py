"""NumPy reference of kernels/ssim.py: SSIM of Wang et al. (IEEE TIP 2004) as the 3DGS loss uses it.

The 2-D window is applied directly (no separable passes), as a 'same'-size correlation with zero
padding, in float64.
"""

from __future__ import annotations

import numpy as np


def filter_same_zero_pad(img: np.ndarray, window: np.ndarray) -> np.ndarray:
    """'Same'-size correlation of every channel of img (H, W, C) with a 2-D window, zero padding."""
    h, w, _ = img.shape
    r = window.shape[0] // 2
    padded = np.zeros((h + 2 * r, w + 2 * r, img.shape[2]))
    padded[r:r + h, r:r + w] = img
    out = np.zeros(img.shape)
    for dy in range(window.shape[0]):
        for dx in range(window.shape[1]):
            out += window[dy, dx] * padded[dy:dy + h, dx:dx + w]
    return out


def ssim_map(x: np.ndarray, y: np.ndarray, data_range: float = 1.0) -> np.ndarray:
    """Per-pixel SSIM of float64 images (H, W, C): 11 x 11 Gaussian window (sigma 1.5), zero padding."""
    k = np.arange(11) - 5
    g = np.exp(-(k**2) / (2 * 1.5**2))
    window = np.outer(g, g) / np.outer(g, g).sum()
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mu_x, mu_y = filter_same_zero_pad(x, window), filter_same_zero_pad(y, window)
    var_x = filter_same_zero_pad(x * x, window) - mu_x**2
    var_y = filter_same_zero_pad(y * y, window) - mu_y**2
    cov = filter_same_zero_pad(x * y, window) - mu_x * mu_y
    return (2 * mu_x * mu_y + c1) * (2 * cov + c2) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
