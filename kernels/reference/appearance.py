"""NumPy reference of the bilateral-grid slice (kernels/appearance.py states the maths).

Written with scipy.ndimage.map_coordinates (order 1: multilinear interpolation; mode "nearest": the
coordinate clamped to the grid, grid_sample's border padding) instead of the kernel's corner loop:
each of the 12 affine entries is interpolated as its own (L, GH, GW) volume at (z, y, x), then the
3x4 transform is applied with a matrix product.
"""

from __future__ import annotations

import numpy as np

LUMA = np.array([0.299, 0.587, 0.114])


def grid_coords(h: int, w: int, rgb: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """(3, H, W) grid coordinates (z, y, x) of every pixel, in grid units, clamped to the grid."""
    gl, gh, gw = shape
    y = (np.arange(h) + 0.5) / h * (gh - 1)
    x = (np.arange(w) + 0.5) / w * (gw - 1)
    z = np.clip(np.asarray(rgb, np.float64) @ LUMA, 0.0, 1.0) * (gl - 1)
    return np.stack([z, np.broadcast_to(y[:, None], (h, w)), np.broadcast_to(x[None, :], (h, w))])


def sliced_affine(grid: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3, 4): every pixel's affine transform, interpolated from `grid` (L, GH, GW, 12) in float64."""
    from scipy.ndimage import map_coordinates

    grid = np.asarray(grid, np.float64)
    h, w = rgb.shape[:2]
    coords = grid_coords(h, w, rgb, grid.shape[:3])
    mats = np.stack([map_coordinates(grid[..., e], coords, order=1, mode="nearest") for e in range(12)], -1)
    return mats.reshape(h, w, 3, 4)


def bilateral_slice(grid: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """out (H, W, 3) = A[:, :3] rgb + A[:, 3] per pixel, in float64."""
    rgb = np.asarray(rgb, np.float64)
    mats = sliced_affine(grid, rgb)
    return np.einsum("hwck,hwk->hwc", mats[..., :3], rgb) + mats[..., 3]
