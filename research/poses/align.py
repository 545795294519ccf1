"""Similarity alignment of two point sets (Umeyama), and pose errors after it.

Umeyama (IEEE PAMI 1991): for points x_i and y_i (i = 1..n, in R^3) find the scale s, rotation R
(det R = +1) and translation t minimising  sum_i || y_i - (s R x_i + t) ||^2.  With the means
mu_x, mu_y, the variance sigma_x^2 = 1/n sum ||x_i - mu_x||^2 and the covariance
Sigma = 1/n sum (y_i - mu_y)(x_i - mu_x)^T = U D V^T (SVD):

    S = diag(1, 1, det(U) det(V))      (a reflection is turned into the nearest rotation)
    R = U S V^T,   s = trace(D S) / sigma_x^2,   t = mu_y - s R mu_x.

Without scale (SE(3)), s = 1 and R, t as above.

Pose errors (`pose_errors`): SfM reconstructs cameras up to a similarity, so its camera centres
c_i are aligned to the ground-truth centres g_i by Umeyama; camera i's error is then the
translation error || g_i - (s R c_i + t) || (scene units) and the rotation error, the angle of
R_gt,i^T (R R_sfm,i) (camera-to-world rotations), in degrees (`rotation_angle_deg`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Sim3:
    """y = scale * R @ x + t."""

    scale: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """The transform of (n, 3) or (3,) points."""
        p = np.asarray(points, dtype=np.float64)
        return self.scale * p @ self.R.T + self.t

    def matrix(self) -> np.ndarray:
        M = np.eye(4)
        M[:3, :3] = self.scale * self.R
        M[:3, 3] = self.t
        return M

    def apply_c2w(self, c2w: np.ndarray) -> np.ndarray:
        """A camera-to-world pose moved by the transform (rotation composed, centre mapped; the camera
        frame stays orthonormal, so the scale acts on the centre only)."""
        c2w = np.asarray(c2w, dtype=np.float64)
        M = np.eye(4)
        M[:3, :3] = self.R @ c2w[:3, :3]
        M[:3, 3] = self.apply(c2w[:3, 3])
        return M


def _points(name: str, p: object) -> np.ndarray:
    a = np.asarray(p, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name}: expected an (n, 3) array of points, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains non-finite values")
    return a


def umeyama(x: object, y: object, with_scale: bool = True) -> Sim3:
    """The similarity (or, without scale, the rigid motion) taking points `x` onto `y` in the least
    squares sense (module docstring). ValueError on fewer than 3 points, mismatched shapes, or
    points that do not span a plane (the rotation is then not determined)."""
    x, y = _points("x", x), _points("y", y)
    if x.shape != y.shape:
        raise ValueError(f"y: expected the shape of x {x.shape}, got {y.shape}")
    n = len(x)
    if n < 3:
        raise ValueError(f"x: expected at least 3 point pairs, got {n}")
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    var_x = float((xc**2).sum() / n)
    sigma = yc.T @ xc / n
    U, D, Vt = np.linalg.svd(sigma)
    if var_x <= 0 or D[1] <= 1e-12 * max(D[0], 1e-300):
        raise ValueError("x: the points are collinear or coincide; a rotation is not determined")
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_x) if with_scale else 1.0
    return Sim3(s, R, my - s * R @ mx)


def rotation_angle_deg(R: np.ndarray) -> float:
    """The angle of a rotation matrix, in degrees: atan2(sin, cos) with cos = (trace - 1) / 2 and sin the
    norm of the axial vector of (R - R^T) / 2 (accurate near 0, where arccos of the trace is not)."""
    R = np.asarray(R, dtype=np.float64)
    c = (float(np.trace(R)) - 1.0) / 2.0
    s = 0.5 * float(np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]))
    return float(np.degrees(np.arctan2(s, c)))


@dataclass(frozen=True)
class PoseErrors:
    sim3: Sim3
    rotation_deg: np.ndarray  # (n,) per camera
    translation: np.ndarray  # (n,) per camera, scene units

    def summary(self) -> dict[str, float]:
        r, t = self.rotation_deg, self.translation
        return {"rotation_deg_mean": float(r.mean()), "rotation_deg_median": float(np.median(r)),
                "rotation_deg_max": float(r.max()), "translation_mean": float(t.mean()),
                "translation_median": float(np.median(t)), "translation_max": float(t.max()),
                "translation_rmse": float(np.sqrt((t**2).mean())), "sim3_scale": self.sim3.scale}


def pose_errors(c2w_est: object, c2w_gt: object) -> PoseErrors:
    """Per-camera rotation (degrees) and translation (ground-truth units) errors of estimated
    camera-to-world poses against the ground truth, after the Sim(3) Umeyama alignment of the camera
    centres (module docstring). Both (n, 4, 4) (or (n, 3, 4)), in the same camera order."""
    est, gt = np.asarray(c2w_est, dtype=np.float64), np.asarray(c2w_gt, dtype=np.float64)
    for name, a in (("c2w_est", est), ("c2w_gt", gt)):
        if a.ndim != 3 or a.shape[1:] not in ((4, 4), (3, 4)):
            raise ValueError(f"{name}: expected (n, 4, 4) camera-to-world poses, got shape {a.shape}")
    if len(est) != len(gt):
        raise ValueError(f"c2w_gt: expected {len(est)} poses (one per estimated pose), got {len(gt)}")
    sim = umeyama(est[:, :3, 3], gt[:, :3, 3], with_scale=True)
    aligned = sim.apply(est[:, :3, 3])
    trans = np.linalg.norm(aligned - gt[:, :3, 3], axis=1)
    rot = np.array([rotation_angle_deg(g[:3, :3].T @ sim.R @ e[:3, :3]) for e, g in zip(est, gt)])
    return PoseErrors(sim, rot, trans)
