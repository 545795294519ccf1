"""Loop closure for the feature odometry: detection, geometric verification, pose-graph optimisation.

Detection. A keyframe j at least `min_gap` keyframes after an early keyframe i (one of the first
`early` keyframes) is matched with i's keypoints that carry landmarks by descriptor alone (ORB,
Hamming, ratio test and mutual check: research/vo/features.py; no pose prediction, since the
prediction is what drifted). Verification: cv2.solvePnPRansac of j's keypoints against those
landmarks (in the world frame of keyframe i's time, which has drifted little), at least
`min_inliers` inliers and an inlier fraction of at least `min_inlier_frac`. It yields j's pose in
i's map, T_j', and the loop measurement Z_ij = T_j' T_i^-1 (camera i to camera j).

Pose graph (world-to-camera keyframe poses T_k, research/poses/se3.py's left perturbation
T_k = exp(xi_k^) T_k0, keyframe 0 fixed). Edges: consecutive keyframes with the odometry's relative
pose Z_{k,k+1} = T_{k+1,0} T_{k,0}^-1, and the verified loops. The residual of an edge (i, j, Z) is

    e_ij = log(Z^-1 T_j T_i^-1)        (6-vector, rho first: zero when the edge is satisfied)

weighted by `loop_weight` for loop edges. scipy.optimize.least_squares (trust region reflective)
minimises sum |e|^2 with a finite-difference Jacobian over the known block sparsity (`jac_sparsity`):
a pose graph has 6 (K - 1) unknowns, small next to the bundle adjustment.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from research.poses.se3 import se3_exp, se3_log
from research.vo.features import match
from research.vo.odometry import VOResult, _pose_from_rt


@dataclass
class LoopConfig:
    early: int = 3  # keyframes at the start that later keyframes are matched against
    min_gap: int = 10  # keyframes between the two ends of a loop
    min_inliers: int = 30
    min_inlier_frac: float = 0.3
    pnp_px: float = 2.0
    ratio: float = 0.8
    loop_weight: float = 1.0

    def validate(self) -> "LoopConfig":
        for name in ("early", "min_gap", "min_inliers"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name}: expected an integer >= 1, got {v}")
        if not 0 < self.min_inlier_frac <= 1 or not 0 < self.ratio <= 1:
            raise ValueError("min_inlier_frac, ratio: expected values in (0, 1]")
        if not (self.pnp_px > 0 and self.loop_weight > 0):
            raise ValueError("pnp_px, loop_weight: expected positive values")
        return self


@dataclass
class Loop:
    i: int  # early keyframe (index into keyframes)
    j: int  # late keyframe
    Z: np.ndarray  # (4, 4) measured T_j T_i^-1
    matches: int
    inliers: int


def detect_loops(vo: VOResult, K: np.ndarray, cfg: LoopConfig | None = None) -> tuple[list[Loop], list[dict]]:
    """Verified loops (module docstring) and a record per candidate pair tried."""
    cfg = (cfg or LoopConfig()).validate()
    kfs = vo.keyframes
    loops, tried = [], []
    for j in range(len(kfs)):
        for i in range(min(cfg.early, len(kfs))):
            if j - i < cfg.min_gap:
                continue
            sel = np.nonzero(kfs[i].lm >= 0)[0]
            m = match(kfs[i].feats.desc[sel], kfs[j].feats.desc, cfg.ratio)
            rec = {"early_frame": kfs[i].frame, "frame": kfs[j].frame, "matches": len(m), "inliers": 0,
                   "accepted": False}
            if len(m) >= max(6, cfg.min_inliers):
                obj = vo.points[kfs[i].lm[sel[m[:, 0]]]]
                ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, kfs[j].feats.uv[m[:, 1]], K, None,
                                                         iterationsCount=500, reprojectionError=cfg.pnp_px,
                                                         confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE)
                n_in = 0 if (not ok or inl is None) else len(inl)
                rec["inliers"] = n_in
                if n_in >= cfg.min_inliers and n_in >= cfg.min_inlier_frac * len(m):
                    Tj = _pose_from_rt(rvec, tvec)
                    loops.append(Loop(i, j, Tj @ np.linalg.inv(kfs[i].T), len(m), n_in))
                    rec["accepted"] = True
            tried.append(rec)
    return loops, tried


def _edge_residual(Ti: np.ndarray, Tj: np.ndarray, Z: np.ndarray) -> np.ndarray:
    return se3_log(np.linalg.inv(Z) @ Tj @ np.linalg.inv(Ti))


def optimise_pose_graph(kf_T: np.ndarray, loops: list[Loop], loop_weight: float = 1.0,
                        max_nfev: int = 100) -> tuple[np.ndarray, dict]:
    """Keyframe poses (K, 4, 4) after pose-graph optimisation with odometry and loop edges (module docstring)."""
    T0 = np.asarray(kf_T, dtype=np.float64)
    n = T0.shape[0]
    edges = [(k, k + 1, T0[k + 1] @ np.linalg.inv(T0[k]), 1.0) for k in range(n - 1)]
    edges += [(lp.i, lp.j, lp.Z, float(loop_weight)) for lp in loops]

    def poses(x: np.ndarray) -> np.ndarray:
        xi = np.concatenate([np.zeros((1, 6)), x.reshape(n - 1, 6)])
        return np.stack([se3_exp(v) @ T for v, T in zip(xi, T0)])

    def fun(x: np.ndarray) -> np.ndarray:
        T = poses(x)
        return np.concatenate([w * _edge_residual(T[i], T[j], Z) for i, j, Z, w in edges])

    pattern = sp.lil_matrix((6 * len(edges), 6 * (n - 1)), dtype=int)
    for e, (i, j, _, _) in enumerate(edges):
        for node in (i, j):
            if node > 0:
                pattern[6 * e:6 * e + 6, 6 * (node - 1):6 * node] = 1
    x0 = np.zeros(6 * (n - 1))
    c0 = float(0.5 * np.sum(fun(x0) ** 2))
    sol = least_squares(fun, x0, jac_sparsity=pattern, method="trf", max_nfev=max_nfev, x_scale=1.0)
    return poses(sol.x), {"edges": len(edges), "loops": len(loops), "cost_before": c0, "cost_after": float(sol.cost),
                          "nfev": int(sol.nfev)}


__all__ = ["LoopConfig", "Loop", "detect_loops", "optimise_pose_graph"]
