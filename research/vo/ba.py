"""Local bundle adjustment: reprojection error over keyframe poses and points, solved with scipy.

Parameters. Each free camera c has a pose 6-vector xi_c = (rho, phi) applied as the module-wide LEFT
perturbation of its starting world-to-camera matrix, T_c = exp(xi_c^) T_c0 (research/poses/se3.py);
points are free 3-vectors p_j. Fixed cameras (the oldest keyframes of the window, which hold the
gauge: position, orientation and, with depth-scaled points, scale) keep T_c0.

Residuals and Jacobians come from the Warp kernel kernels.ba.reproject: r_k = pi(T_c p_j) - u_k,
d r/d p_j, and d r/d delta at delta = 0 for a further left perturbation exp(delta^) T_c. Since
exp((xi + d xi)^) = exp((J_l(xi) d xi)^) exp(xi^) to first order, with J_l the SE(3) left Jacobian
(Barfoot 2017, "State Estimation for Robotics", section 7.1.5; rho first):

    J_l(xi) = [[J(phi), Q(rho, phi)], [0, J(phi)]],
    J(phi)  = I + (1 - cos a)/a^2 Phi + (a - sin a)/a^3 Phi^2,   a = |phi|, Phi = phi^,
    Q       = 1/2 P + (a - sin a)/a^3 (Phi P + P Phi + Phi P Phi)
              + (a^2/2 + cos a - 1)/a^4 (Phi^2 P + P Phi^2 - 3 Phi P Phi)
              + (2 a - 3 sin a + a cos a)/(2 a^5) (Phi P Phi^2 + Phi^2 P Phi),  P = rho^,

the exact Jacobian with respect to xi_c is d r/d delta J_l(xi_c). scipy.optimize.least_squares (trust
region reflective) takes it as a scipy.sparse matrix (one 2 x 6 block per observation and free
camera, one 2 x 3 block per observation and point) and applies an optional robust loss (`loss`,
`f_scale` in pixels). RGB-D: an observation with a measured depth z adds the residual
w (Z - z) / z, Z = (T_c p_j)_z, with d Z/d xi and d Z/d p from the same kernel (w = `depth_weight`
pixels per unit relative depth error).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from kernels.ba import reproject
from research.poses.se3 import hat, se3_exp

LOSSES = ("linear", "huber", "soft_l1", "cauchy", "arctan")


def se3_left_jacobian(xi: Any) -> np.ndarray:
    """The 6x6 SE(3) left Jacobian J_l(xi) of xi = (rho, phi) (module docstring)."""
    xi = np.asarray(xi, dtype=np.float64)
    rho, phi = xi[:3], xi[3:]
    a = float(np.linalg.norm(phi))
    Ph, P = hat(phi), hat(rho)
    Ph2 = Ph @ Ph
    if a < 0.1:  # Taylor series: the closed forms cancel catastrophically for small a (c4's numerator is a^5/60)
        a2 = a * a
        c1 = 0.5 - a2 / 24.0 + a2 * a2 / 720.0
        c2 = 1.0 / 6.0 - a2 / 120.0 + a2 * a2 / 5040.0
        c3 = 1.0 / 24.0 - a2 / 720.0 + a2 * a2 / 40320.0
        c4 = 1.0 / 120.0 - a2 / 2520.0 + a2 * a2 / 120960.0
    else:
        c1 = (1.0 - math.cos(a)) / a ** 2
        c2 = (a - math.sin(a)) / a ** 3
        c3 = (a * a / 2.0 + math.cos(a) - 1.0) / a ** 4
        c4 = (2.0 * a - 3.0 * math.sin(a) + a * math.cos(a)) / (2.0 * a ** 5)
    J = np.eye(3) + c1 * Ph + c2 * Ph2
    Q = (0.5 * P + c2 * (Ph @ P + P @ Ph + Ph @ P @ Ph) + c3 * (Ph2 @ P + P @ Ph2 - 3.0 * Ph @ P @ Ph)
         + c4 * (Ph @ P @ Ph2 + Ph2 @ P @ Ph))
    out = np.zeros((6, 6))
    out[:3, :3] = J
    out[:3, 3:] = Q
    out[3:, 3:] = J
    return out


def perturbed_poses(xi: np.ndarray, poses0: np.ndarray) -> np.ndarray:
    """exp(xi_c^) T_c0 for every camera: (C, 6), (C, 4, 4) -> (C, 4, 4)."""
    return np.stack([se3_exp(x) @ T for x, T in zip(xi, poses0)])


@dataclass
class Linearisation:
    """Residuals and Jacobians at T_c = exp(xi_c^) T_c0: r (M, 2) with d r/d xi_c (M, 2, 6) and d r/d p_j
    (M, 2, 3); the depth Z (M,) of each observation's point with d Z/d xi_c (M, 6) and d Z/d p_j (M, 3).
    Jacobians are None when not asked for."""

    r: np.ndarray
    z: np.ndarray
    jr_pose: np.ndarray | None = None
    jr_point: np.ndarray | None = None
    jz_pose: np.ndarray | None = None
    jz_point: np.ndarray | None = None


def residuals_and_jacobian(xi: np.ndarray, points: np.ndarray, observations: np.ndarray, cam_idx: np.ndarray,
                           pt_idx: np.ndarray, poses0: np.ndarray, intrinsics: Any, *, device: Any = None,
                           jacobians: bool = True) -> Linearisation:
    """The reprojection residuals and point depths with their Jacobians wrt xi (chained with J_l(xi_c)) and
    the points (module docstring); the Warp kernel runs in the dtype of `points`."""
    T = perturbed_poses(xi, poses0).astype(points.dtype)
    rep = reproject(T, points, observations, cam_idx, pt_idx, intrinsics, jacobians=jacobians, device=device)
    if not jacobians:
        return Linearisation(rep.residuals, rep.depth)
    Jl = np.stack([se3_left_jacobian(x) for x in xi])[cam_idx]
    return Linearisation(rep.residuals, rep.depth, np.einsum("kab,kbc->kac", rep.jac_pose, Jl), rep.jac_point,
                         np.einsum("kb,kbc->kc", rep.jac_depth[:, :6], Jl), rep.jac_depth[:, 6:])


@dataclass
class BAResult:
    poses: np.ndarray  # (C, 4, 4) world-to-camera after the adjustment
    points: np.ndarray  # (N, 3)
    rms_before: float  # RMS reprojection error in pixels (plain, before the robust loss)
    rms_after: float
    nfev: int
    status: int
    message: str


def bundle_adjust(poses0: Any, points0: Any, observations: Any, cam_idx: Any, pt_idx: Any, intrinsics: Any, *,
                  depths: Any = None, depth_weight: float = 100.0, fixed: Any = (0,), loss: str = "huber",
                  f_scale: float = 2.0, max_nfev: int = 30, device: Any = None) -> BAResult:
    """Adjust the free cameras' poses and every point (module docstring) with scipy's sparse least squares.

    poses0: (C, 4, 4) world-to-camera; points0: (N, 3); observations (M, 2) with camera and point
    indices (M,); `depths` (M,): measured z-depth of each observation (RGB-D; 0 = none), which adds the
    residual depth_weight (Z - z) / z (so 1% of depth weighs as much as depth_weight / 100 pixels);
    `fixed`: indices of cameras held at poses0 (at least one, to fix the gauge); `loss`: one of LOSSES
    (scipy's robust losses), `f_scale` its inlier scale in pixels. The RMS figures are of the pixel
    residuals alone.
    """
    poses0 = np.asarray(poses0, dtype=np.float64)
    points0 = np.asarray(points0, dtype=np.float64)
    obs = np.asarray(observations, dtype=np.float64)
    ci = np.asarray(cam_idx, dtype=np.int32)
    pi = np.asarray(pt_idx, dtype=np.int32)
    if loss not in LOSSES:
        raise ValueError(f"loss: expected one of {list(LOSSES)}, got {loss!r}")
    if not (math.isfinite(f_scale) and f_scale > 0):
        raise ValueError(f"f_scale: expected a positive number of pixels, got {f_scale}")
    if not (math.isfinite(depth_weight) and depth_weight >= 0):
        raise ValueError(f"depth_weight: expected a finite value >= 0, got {depth_weight}")
    C, N, M = poses0.shape[0], points0.shape[0], obs.shape[0]
    zobs = np.zeros(M) if depths is None else np.asarray(depths, dtype=np.float64)
    if zobs.shape != (M,) or not np.all(np.isfinite(zobs)) or np.any(zobs < 0):
        raise ValueError(f"depths: expected ({M},) finite values >= 0 (0 = no depth), got shape {zobs.shape}")
    fixed_set = sorted({int(c) for c in fixed})
    if not fixed_set or min(fixed_set) < 0 or max(fixed_set) >= C:
        raise ValueError(f"fixed: expected at least one camera index in [0, {C - 1}] held fixed, got {list(fixed)}")
    free = [c for c in range(C) if c not in fixed_set]
    slot = -np.ones(C, dtype=np.int64)
    slot[free] = np.arange(len(free))
    n_pose = 6 * len(free)
    kd = np.nonzero(zobs > 0)[0] if depth_weight > 0 else np.zeros(0, dtype=int)
    wd = depth_weight / zobs[kd]

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xi = np.zeros((C, 6))
        xi[free] = x[:n_pose].reshape(-1, 6)
        return xi, x[n_pose:].reshape(N, 3)

    def residuals(lin: Linearisation) -> np.ndarray:
        return np.concatenate([lin.r.ravel(), wd * (lin.z[kd] - zobs[kd])])

    def fun(x: np.ndarray) -> np.ndarray:
        xi, pts = unpack(x)
        return residuals(residuals_and_jacobian(xi, pts, obs, ci, pi, poses0, intrinsics, device=device,
                                                jacobians=False))

    # Sparsity pattern: pixel rows 2k, 2k+1, then one depth row per observation with a depth; pose
    # columns of the observation's camera when it is free, then the point's columns.
    k_pose = np.nonzero(slot[ci] >= 0)[0]
    kd_pose = kd[slot[ci[kd]] >= 0]
    row_d = 2 * M + np.searchsorted(kd, kd_pose)
    rows = ([2 * k_pose + a for a in range(2) for b in range(6)]
            + [2 * np.arange(M) + a for a in range(2) for b in range(3)]
            + [row_d for b in range(6)] + [2 * M + np.arange(len(kd)) for b in range(3)])
    cols = ([6 * slot[ci[k_pose]] + b for a in range(2) for b in range(6)]
            + [n_pose + 3 * pi + b for a in range(2) for b in range(3)]
            + [6 * slot[ci[kd_pose]] + b for b in range(6)] + [n_pose + 3 * pi[kd] + b for b in range(3)])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    wd_pose = wd[np.searchsorted(kd, kd_pose)]

    def jac(x: np.ndarray) -> sp.csr_matrix:
        xi, pts = unpack(x)
        lin = residuals_and_jacobian(xi, pts, obs, ci, pi, poses0, intrinsics, device=device)
        vals = ([lin.jr_pose[k_pose, a, b] for a in range(2) for b in range(6)]
                + [lin.jr_point[:, a, b] for a in range(2) for b in range(3)]
                + [wd_pose * lin.jz_pose[kd_pose, b] for b in range(6)] + [wd * lin.jz_point[kd, b] for b in range(3)])
        return sp.csr_matrix((np.concatenate(vals), (rows, cols)), shape=(2 * M + len(kd), n_pose + 3 * N))

    x0 = np.concatenate([np.zeros(n_pose), points0.ravel()])
    r0 = fun(x0)[:2 * M]
    sol = least_squares(fun, x0, jac=jac, method="trf", loss=loss, f_scale=f_scale, max_nfev=max_nfev,
                        x_scale="jac", tr_solver="lsmr")
    xi, pts = unpack(sol.x)
    return BAResult(perturbed_poses(xi, poses0), pts, float(np.sqrt(np.mean(r0 ** 2) * 2)),
                    float(np.sqrt(np.mean(sol.fun[:2 * M] ** 2) * 2)), int(sol.nfev), int(sol.status), str(sol.message))


__all__ = ["LOSSES", "se3_left_jacobian", "perturbed_poses", "residuals_and_jacobian", "Linearisation", "BAResult",
           "bundle_adjust"]
