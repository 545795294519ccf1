"""NumPy reference of kernels/ba.py: pinhole reprojection residuals, float64, one observation at a time.

r_k = pi(R_c p_j + t_c) - (u_k, v_k), pi(X) = (fx X/Z + cx, fy Y/Z + cy). The forward only (the
Jacobians are checked against finite differences through research.gradcheck and scipy).
"""

from __future__ import annotations

import numpy as np


def reproject(poses: np.ndarray, points: np.ndarray, observations: np.ndarray, cam_idx: np.ndarray,
              pt_idx: np.ndarray, intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(residuals (M, 2), depth Z (M,)) of world-to-camera poses (C, 3|4, 4) and points (N, 3)."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    res = np.zeros((len(cam_idx), 2))
    depth = np.zeros(len(cam_idx))
    for k, (c, j) in enumerate(zip(cam_idx, pt_idx)):
        R, t = poses[c][:3, :3], poses[c][:3, 3]
        X = R @ points[j] + t
        res[k] = (fx * X[0] / X[2] + cx - observations[k, 0], fy * X[1] / X[2] + cy - observations[k, 1])
        depth[k] = X[2]
    return res, depth
