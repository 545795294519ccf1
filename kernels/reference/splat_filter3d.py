"""NumPy reference of Mip-Splatting's 3D smoothing filter (kernels/splat/filter3d.py states the maths).

Written from the covariance, not from the log-scale formulas the kernel uses: Sigma = R S^2 R^T,
Sigma' = Sigma + sigma^2 I, o' = o sqrt(det Sigma / det Sigma'), and l', a' read back from the
eigenvalues of Sigma' and the logit of o'. The rotation R comes from the quaternions (any unit
quaternion gives the same l', a'; the tests check that too).
"""

from __future__ import annotations

import numpy as np


def _rotations(quats: np.ndarray) -> np.ndarray:
    w, x, y, z = (quats / np.linalg.norm(quats, axis=1, keepdims=True)).T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def filter_3d(log_scales: np.ndarray, opacity_logits: np.ndarray, sigma: np.ndarray,
              quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(l', a') in float64 from the filtered covariances; l' in the order of the axes of R."""
    ls = np.asarray(log_scales, np.float64)
    R = _rotations(np.asarray(quats, np.float64))
    cov = R @ (np.exp(2 * ls)[:, :, None] * np.eye(3)) @ R.transpose(0, 2, 1)
    cov_f = cov + (np.asarray(sigma, np.float64) ** 2)[:, None, None] * np.eye(3)
    # Sigma' = R diag(s'^2) R^T: its diagonal in R's frame holds the filtered axis variances
    axes = np.einsum("nji,njk,nki->ni", R, cov_f, R)
    o = 1.0 / (1.0 + np.exp(-np.asarray(opacity_logits, np.float64)))
    o_f = o * np.sqrt(np.linalg.det(cov) / np.linalg.det(cov_f))
    return 0.5 * np.log(axes), np.log(o_f / (1.0 - o_f))
