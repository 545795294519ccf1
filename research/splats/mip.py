"""Mip-Splatting's 3D smoothing filter in training: each splat's filter size from the training cameras.

Yu et al., "Mip-Splatting: Alias-free 3D Gaussian Splatting" (CVPR 2024), eq. 7-9 and its code:
splat i is seen at most at the sampling rate nu_i = max_n f_n / z_n,i (pixels per world unit) over
the training cameras n in whose (slightly enlarged) view its centre lies in front of the near plane,
and is convolved with an isotropic 3D Gaussian of variance s / nu_i^2 (kernels/splat/filter3d.py):

    sigma_i = sqrt(s) min_n z_n,i / f_n,    f_n = max(fx, fy) of camera n,

for the cameras with z_n,i > near and the centre projecting within MARGIN of the image on every side
(Mip-Splatting's 1.15 x the frustum); an orthographic camera samples f_n pixels per unit at every
depth (its z / f becomes 1 / f). A splat that no training camera sees gets the largest sigma of
those seen, as in Mip-Splatting. s = 0.2 is the paper's value (its code's `filter_3D = distance /
focal * 0.2 ** 0.5`), taken as it is: nothing here was tuned on drlab's data. For a lens camera
(kernels/lens.py) the centre is projected through the lens, and f / z is the rate at the image
centre (the distortion's local scaling is not included).

The filter's sigma is a constant of each training step, as in Mip-Splatting (no gradient flows into
it); research/splats/train.py recomputes it from the splats' current means at the start, after every
densification and every densification interval afterwards, and bakes the last one into the returned
model, so evaluation, PLY export and FPS see exactly what was trained.
"""

from __future__ import annotations

import numpy as np

from kernels import splat as ks
from kernels.splat.filter3d import filter_3d, filter_3d_backward
from research.cameras import Camera

PAPER_S = 0.2  # Mip-Splatting's filter variance in units of the squared pixel footprint
MARGIN = 0.15  # of the image size on every side: Mip-Splatting's 1.15 x frustum test


def filter_sigma(means: np.ndarray, cameras: list[Camera], s: float = PAPER_S,
                 near: float = ks.DEFAULT_NEAR) -> np.ndarray:
    """sigma_i (N,) float32 for splat centres `means` (N, 3) over the training `cameras` (module docstring)."""
    means = np.asarray(means, dtype=np.float64)
    if means.ndim != 2 or means.shape[1] != 3:
        raise ValueError(f"means: expected (N, 3), got {means.shape}")
    if not cameras:
        raise ValueError("cameras: expected at least one training camera")
    if not s > 0:
        raise ValueError(f"s: expected a positive filter variance, got {s}")
    footprint = np.full(len(means), np.inf)  # min_n z / f (world units per pixel)
    for cam in cameras:
        uv, z = cam.project(means)
        f = max(cam.fx, cam.fy)
        central = cam.lens is None or cam.lens.central
        with np.errstate(invalid="ignore"):
            inside = ((uv[:, 0] >= -MARGIN * cam.width) & (uv[:, 0] <= (1 + MARGIN) * cam.width)
                      & (uv[:, 1] >= -MARGIN * cam.height) & (uv[:, 1] <= (1 + MARGIN) * cam.height))
        seen = inside & (z > near)
        per_pixel = z / f if central else np.full(len(means), 1.0 / f)
        footprint = np.where(seen, np.minimum(footprint, per_pixel), footprint)
    seen = np.isfinite(footprint)
    if len(means) and not seen.any():
        raise ValueError("means: no splat centre is in front of any training camera; cannot size the 3D filter")
    if len(means):
        footprint[~seen] = footprint[seen].max()
    return (np.sqrt(s) * footprint).astype(np.float32)


def filtered(log_scales: np.ndarray, opacity_logits: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The log-scales and opacity logits the renderer sees (kernels.splat.filter3d.filter_3d, on the CPU)."""
    return filter_3d(log_scales, opacity_logits, sigma, device="cpu")


def unfiltered_grads(log_scales: np.ndarray, opacity_logits: np.ndarray, sigma: np.ndarray,
                     grad_log_scales: np.ndarray, grad_opacity_logits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The render's gradients w.r.t. the filtered log-scales and logits, taken back to the model's own."""
    return filter_3d_backward(log_scales, opacity_logits, sigma, grad_log_scales, grad_opacity_logits, device="cpu")
