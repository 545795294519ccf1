"""NumPy reference of the lens camera models (kernels/lens.py states the maths).

`project` maps camera-frame points to normalised image points with their validity, `jacobian`
gives dm/dp by the complex step (f(p + i h e_j) = f(p) + i h J e_j + O(h^2): exact to rounding
for these analytic models, and independent of the hand-derived Jacobians of kernels/lens.py),
and `unproject` inverts `project` (Newton, vectorised, the same criteria as the kernels).
Tests hold these to OpenCV (cv2.projectPoints, cv2.undistortPoints, cv2.fisheye.*) and COLMAP
(pycolmap.Camera.img_from_cam / cam_from_img).
"""

from __future__ import annotations

import numpy as np

from kernels.lens import NEWTON_ITERS, Lens


def _distort(lens: Lens, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """D(w) for w = (a, b) (real or complex arrays)."""
    s = a * a + b * b
    if lens.model == "opencv":
        k1, k2, p1, p2, k3 = lens.coeffs
        R = 1 + k1 * s + k2 * s**2 + k3 * s**3
        return a * R + 2 * p1 * a * b + p2 * (s + 2 * a * a), b * R + p1 * (s + 2 * b * b) + 2 * p2 * a * b
    if lens.model == "fisheye":
        k1, k2, k3, k4 = lens.coeffs
        r = np.sqrt(s)
        th = np.arctan(r)
        td = th * (1 + k1 * th**2 + k2 * th**4 + k3 * th**6 + k4 * th**8)
        safe = np.where(r == 0, 1.0, r)
        g = np.where(r == 0, 1.0, td / safe)
        return g * a, g * b
    return a, b


def project(lens: Lens, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(m (N, 2), valid (N,) bool) of camera-frame points p (N, 3) (kernels/lens.py)."""
    p = np.asarray(p)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if lens.model == "orthographic":
        return np.stack([x, y], axis=1), np.ones(len(p), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        zs = np.where(np.real(z) > 0, z, 1.0)
        a, b = x / zs, y / zs
    s = np.real(a * a + b * b)
    valid = (np.real(z) > 0) & (s < lens.s_limit())
    mx, my = _distort(lens, a, b)
    return np.stack([mx, my], axis=1), valid


def jacobian(lens: Lens, p: np.ndarray, h: float = 1e-30) -> np.ndarray:
    """dm/dp (N, 2, 3) by the complex step (module docstring) at float64 points p (N, 3)."""
    p = np.asarray(p, dtype=np.float64)
    J = np.empty((len(p), 2, 3))
    for j in range(3):
        dp = p.astype(np.complex128)
        dp[:, j] += 1j * h
        m, _ = project(lens, dp)
        J[:, :, j] = m.imag / h
    return J


def unproject(lens: Lens, m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origins q (N, 3), unit directions e (N, 3), valid (N,)) in the camera frame of normalised image
    points m (N, 2) (kernels/lens.py: Newton with the same stopping rules; central models: q = 0)."""
    m = np.asarray(m, dtype=np.float64)
    n = len(m)
    q = np.zeros((n, 3))
    if lens.model == "orthographic":
        q[:, :2] = m
        return q, np.tile([0.0, 0.0, 1.0], (n, 1)), np.ones(n, dtype=bool)
    s_lim = lens.s_limit()
    if lens.model == "fisheye":
        k1, k2, k3, k4 = lens.coeffs
        rd = np.linalg.norm(m, axis=1)
        th_lim = np.arctan(np.sqrt(s_lim))
        th = np.minimum(rd, th_lim)
        done = np.zeros(n, dtype=bool)
        for _ in range(NEWTON_ITERS):
            t2 = th * th
            T = th * (1 + k1 * t2 + k2 * t2**2 + k3 * t2**3 + k4 * t2**4)
            T1 = 1 + 3 * k1 * t2 + 5 * k2 * t2**2 + 7 * k3 * t2**3 + 9 * k4 * t2**4
            step = np.where(done | (T1 <= 0), 0.0, (T - rd) / np.where(T1 <= 0, 1.0, T1))
            th = th - step
            done |= (np.abs(step) <= 1e-14 * (1 + np.abs(th))) & (T1 > 0)
        valid = done & (th >= 0) & (th < th_lim)
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = np.where(rd[:, None] > 0, m / np.where(rd > 0, rd, 1.0)[:, None], 0.0)
        e = np.concatenate([np.sin(th)[:, None] * unit, np.cos(th)[:, None]], axis=1)
        e[~valid] = (0.0, 0.0, 1.0)
        return q, e, valid
    w = m.copy()
    if lens.model == "opencv":
        tol = 1e-12 * (1 + np.linalg.norm(m, axis=1))
        done = np.zeros(n, dtype=bool)
        for it in range(NEWTON_ITERS + 1):
            dx, dy = _distort(lens, w[:, 0], w[:, 1])
            r = np.stack([dx, dy], axis=1) - m
            met = np.abs(r).max(axis=1) <= tol
            if it == NEWTON_ITERS:
                done |= met
                break
            J = jacobian(lens, np.concatenate([w, np.ones((n, 1))], axis=1))[:, :, :2]  # J_D at z = 1
            step = np.linalg.solve(J, r[:, :, None])[:, :, 0]
            w = np.where(done[:, None], w, w - step)  # the step after the criterion is met is the last
            done |= met
            if done.all():
                break
        valid = done & ((w**2).sum(axis=1) < s_lim)
    else:
        valid = np.ones(n, dtype=bool)
    e = np.concatenate([w, np.ones((n, 1))], axis=1)
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    e[~valid] = (0.0, 0.0, 1.0)
    return q, e, valid


def pixels(lens: Lens, K: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pixel coordinates (N, 2), valid (N,)) of camera-frame points through `lens` and K."""
    m, valid = project(lens, p)
    return np.stack([K[0, 0] * m[:, 0] + K[0, 2], K[1, 1] * m[:, 1] + K[1, 2]], axis=1), valid


def normalised(K: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The normalised image points ((u - cx) / fx, (v - cy) / fy) of pixel coordinates uv (N, 2)."""
    uv = np.asarray(uv, dtype=np.float64)
    return np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]], axis=1)
