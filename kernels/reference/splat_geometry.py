"""NumPy reference of kernels/splat/depth.py and kernels/splat/normals.py: median and expected depth,
splat shortest-axis normals, normals from a depth map, in float64 loops written from those modules'
docstrings (2DGS's median depth, gsplat's expected depth and depth_to_normal, PGSR's splat normal)."""

from __future__ import annotations

import numpy as np

from kernels.reference.splat import _pixel_blends, quat_to_rotmat, tile_lists


def median_depth(m2, conics, opacities, depths, radii, width, height, mode: str = "3dgs"):
    """(median (H, W), splat (H, W) int, -1 where none): the z of the last blended splat with T_i > 1/2."""
    lists = tile_lists(m2, conics, opacities, radii, depths, width, height, square=True, mode=mode)
    tiles_x = (width + 15) // 16
    med, who = np.zeros((height, width)), np.full((height, width), -1)
    for py in range(height):
        for px in range(width):
            blended, _ = _pixel_blends(m2, conics, opacities, lists, tiles_x, px, py, mode)
            for i, _a, t_i, _c, _d in blended:
                if t_i > 0.5:
                    med[py, px], who[py, px] = depths[i], i
    return med, who


def crossing_margin(m2, conics, opacities, depths, radii, width, height, mode: str = "3dgs") -> float:
    """The smallest |T - 1/2| over every transmittance a pixel passes through (how far the median's
    choice of splat is from changing)."""
    lists = tile_lists(m2, conics, opacities, radii, depths, width, height, square=True, mode=mode)
    tiles_x = (width + 15) // 16
    margin = np.inf
    for py in range(height):
        for px in range(width):
            blended, t_final = _pixel_blends(m2, conics, opacities, lists, tiles_x, px, py, mode)
            for t in [b[2] for b in blended] + [t_final]:
                margin = min(margin, abs(t - 0.5))
    return float(margin)


def expected_depth(depth, alpha):
    return depth / np.maximum(alpha, 1e-10)


def splat_normals(means, quats, log_scales, viewmat):
    """(N, 3): W R(q) e_k for the smallest log-scale k, flipped to face the camera (n . p <= 0)."""
    W, t = viewmat[:3, :3], viewmat[:3, 3]
    out = np.zeros((len(means), 3))
    for i in range(len(means)):
        k = int(np.argmin(log_scales[i]))
        n = W @ quat_to_rotmat(quats[i])[:, k]
        out[i] = -n if n @ (W @ means[i] + t) > 0 else n
    return out


def normals_from_depth(depth, K):
    """(H, W, 3): normalize(cross(P(x, y+1) - P(x, y-1), P(x+1, y) - P(x-1, y))) inside the border, 0 on it."""
    h, w = depth.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    def point(x, y):
        return depth[y, x] * np.array([(x + 0.5 - cx) / fx, (y + 0.5 - cy) / fy, 1.0])

    out = np.zeros((h, w, 3))
    for y in range(1, h - 1):
        for x in range(1, w - 1):
            c = np.cross(point(x, y + 1) - point(x, y - 1), point(x + 1, y) - point(x - 1, y))
            out[y, x] = c / max(np.linalg.norm(c), 1e-12)
    return out
