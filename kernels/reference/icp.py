"""Plain NumPy reference of the ICP kernels (kernels/icp.py), in float64.

The same definitions as the kernel module's docstring: residual rows r = d . (p - q) with d the axes
(point-to-point) or the target normal (point-to-plane), their pose Jacobians J = [d^T, (p x d)^T], the
robust weights and costs, and H = sum w J^T J, g = sum w J^T r, cost = sum rho(e).
"""

from __future__ import annotations

import numpy as np


def robust_weight(e2: np.ndarray, robust: str, scale: float) -> np.ndarray:
    """w(e^2): 1 (none), Huber with c = scale, Geman-McClure s^2 / (s + e^2)^2 with s = scale."""
    e2 = np.asarray(e2, dtype=np.float64)
    if robust == "none":
        return np.ones_like(e2)
    if robust == "huber":
        e = np.sqrt(e2)
        return np.where(e > scale, scale / np.maximum(e, 1e-300), 1.0)
    if robust == "gm":
        return scale * scale / (scale + e2) ** 2
    raise ValueError(f"robust: expected none, huber or gm, got {robust!r}")


def robust_rho(e2: np.ndarray, robust: str, scale: float) -> np.ndarray:
    """rho(e) from e^2: e^2/2 (none), Huber, Geman-McClure s e^2 / (2 (s + e^2))."""
    e2 = np.asarray(e2, dtype=np.float64)
    if robust == "none":
        return 0.5 * e2
    if robust == "huber":
        e = np.sqrt(e2)
        return np.where(e > scale, scale * e - 0.5 * scale * scale, 0.5 * e2)
    if robust == "gm":
        return 0.5 * scale * e2 / (scale + e2)
    raise ValueError(f"robust: expected none, huber or gm, got {robust!r}")


def residuals(source: np.ndarray, target: np.ndarray, normals: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(r (N, R), J (N, R, 6), e^2 (N,)): R = 3 point-to-point (normals None), 1 point-to-plane."""
    p = np.asarray(source, dtype=np.float64)
    u = p - np.asarray(target, dtype=np.float64)
    n = len(p)
    if normals is None:
        d = np.broadcast_to(np.eye(3), (n, 3, 3))  # rows: e_x, e_y, e_z
    else:
        d = np.asarray(normals, dtype=np.float64)[:, None, :]
    r = np.einsum("nrc,nc->nr", d, u)
    J = np.concatenate([d, np.cross(p[:, None, :], d)], axis=2)
    return r, J, np.sum(r * r, axis=1)


def normal_equations(source: np.ndarray, target: np.ndarray, normals: np.ndarray | None = None,
                     robust: str = "none", scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
    """(H (6, 6), g (6,), cost) summed over every correspondence."""
    r, J, e2 = residuals(source, target, normals)
    w = robust_weight(e2, robust, scale)
    H = np.einsum("n,nra,nrb->ab", w, J, J)
    g = np.einsum("n,nra,nr->a", w, J, r)
    return H, g, float(np.sum(robust_rho(e2, robust, scale)))
