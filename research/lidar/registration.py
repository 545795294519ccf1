"""ICP registration of a source cloud onto a target: Gauss-Newton on kernels.icp's normal equations.

Given source points s_i (sensor frame), a target cloud (with unit normals for point-to-plane) and an
initial source-to-target transform T_0, iteration k

1. moves the source, p_i = T_k s_i, and pairs each p_i with its nearest target point q_i (exact 1-NN,
   kernels.points' hash grid, built once per target); pairs with |p_i - q_i| > max_distance are dropped;
2. builds H = sum w J^T J and g = sum w J^T r (kernels.icp.normal_equations: point-to-point or
   point-to-plane rows, robust weights w; the module docstring there states them);
3. solves H dxi = -g (NumPy, 6 x 6) and updates T_{k+1} = exp(dxi^) T_k (a left update, as kernels.icp's
   Jacobians are taken: research.poses.se3.se3_exp);

and stops when |dxi| < convergence or after max_iterations. This is KISS-ICP's registration loop
(Vizzo et al., RA-L 2023) with the choice of residual added.

Errors (ValueError, before any kernel runs where the inputs are at fault): an empty or non-finite source
or target; a point-to-plane target whose every neighbourhood is degenerate (no normal: collinear or
repeated points, kernels.points.estimate_normals); fewer than `min_pairs` correspondences within
max_distance; and normal equations that do not fix all six degrees of freedom (smallest eigenvalue of H
below 1e-12 of the largest: e.g. a single plane under point-to-plane), which `RegistrationError` names.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels import icp as kicp
from kernels import points as kp
from kernels.points.grid import build_grid, density_cell_size, knn_grid
from research.poses.se3 import se3_exp

METRICS = ("point", "plane")
DEGENERATE_RATIO = 1e-12


class RegistrationError(ValueError):
    """ICP could not determine a pose (too few pairs, or normal equations of rank < 6)."""


@dataclass(frozen=True)
class IcpConfig:
    metric: str = "point"  # "point" (point-to-point) or "plane" (point-to-plane)
    robust: str = "gm"  # kernels.icp.ROBUST
    max_iterations: int = 50
    convergence: float = 1e-4  # |dxi| (translation in m and rotation in rad together)
    normal_k: int = 10  # neighbours of the target's PCA normals (point-to-plane)
    min_pairs: int = 6

    def __post_init__(self) -> None:
        if self.metric not in METRICS:
            raise ValueError(f"metric: expected one of {', '.join(METRICS)}, got {self.metric!r}")
        kicp.check_robust(self.robust, 1.0)
        for name in ("max_iterations", "normal_k", "min_pairs"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name}: expected an integer >= 1, got {v}")
        if not (math.isfinite(self.convergence) and self.convergence > 0):
            raise ValueError(f"convergence: expected a positive value, got {self.convergence}")

    def config(self) -> dict[str, Any]:
        return asdict(self)


def check_cloud(name: str, points: Any) -> np.ndarray:
    """An (N, 3) float64 copy of a non-empty finite cloud; ValueError naming `name` otherwise."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{name}: expected a cloud of shape (N, 3), got shape {p.shape}")
    if p.shape[0] == 0:
        raise ValueError(f"{name}: expected a non-empty cloud (N >= 1), got no points")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: expected finite coordinates, found NaN or infinite entries")
    return np.ascontiguousarray(p)


@dataclass
class Target:
    """A registration target: points (M, 3) float64, unit normals (M, 3) or None (point-to-point).

    Its hash grid (kernels.points) is built once, in float32, on the first search and reused by every
    iteration: the nearest neighbour is exact for the float32 coordinates, and its distance only gates
    the pairs (the residuals use the float64 points)."""

    points: np.ndarray
    normals: np.ndarray | None
    _grid: Any = None

    def nearest(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(index (N,), squared distance (N,) float32) of each query's nearest target point."""
        if self._grid is None:
            search = self.points.astype(np.float32)
            self._grid = build_grid(search, density_cell_size(search, 1))
        a = A.Inputs.like(self._grid.device, wp.float32, True)
        q = wp.array(np.ascontiguousarray(queries, dtype=np.float32), dtype=wp.float32, device=self._grid.device)
        res = knn_grid(a, self._grid, q, 1)
        return res.idx[:, 0], res.sq_dist[:, 0]


def point_normals(points: np.ndarray, normal_k: int) -> np.ndarray:
    """PCA normals (kernels.points.estimate_normals) over `normal_k` neighbours; NaN where degenerate."""
    q = check_cloud("target", points)
    if q.shape[0] < 3:
        raise ValueError(f"target: expected at least 3 points for point-to-plane normals, got {q.shape[0]}")
    return kp.estimate_normals(q, min(int(normal_k), q.shape[0])).normals


def make_target(points: Any, metric: str, normal_k: int = 10, normals: Any = None) -> Target:
    """The target for `metric`. Point-to-plane takes `normals` (NaN rows: no normal) or estimates them
    over `normal_k` neighbours; points without a normal (degenerate neighbourhoods) are dropped, and a
    ValueError is raised when none is left."""
    if metric not in METRICS:
        raise ValueError(f"metric: expected one of {', '.join(METRICS)}, got {metric!r}")
    q = check_cloud("target", points)
    if metric == "point":
        return Target(q, None)
    n = point_normals(q, normal_k) if normals is None else np.asarray(normals, dtype=np.float64)
    if n.shape != q.shape:
        raise ValueError(f"normals: expected the target's shape {q.shape}, got {n.shape}")
    valid = np.all(np.isfinite(n), axis=1)
    if not np.any(valid):
        raise ValueError("target: every neighbourhood is degenerate (collinear or repeated points): no normal "
                         "for point-to-plane ICP")
    return Target(np.ascontiguousarray(q[valid]), np.ascontiguousarray(n[valid]))


@dataclass
class IcpResult:
    T: np.ndarray  # source-to-target 4x4
    iterations: int
    pairs: int  # correspondences at the last iteration
    converged: bool
    cost: float


def _moved(T: np.ndarray, s: np.ndarray) -> np.ndarray:
    return s @ T[:3, :3].T + T[:3, 3]


def gauss_newton_step(ne: kicp.NormalEquations) -> np.ndarray:
    """dxi solving H dxi = -g; RegistrationError when H does not fix six degrees of freedom."""
    lam = np.linalg.eigvalsh(0.5 * (ne.H + ne.H.T))
    if not lam[-1] > 0 or lam[0] <= DEGENERATE_RATIO * lam[-1]:
        raise RegistrationError(f"normal equations: degenerate (eigenvalues of H from {lam[0]:.3g} to {lam[-1]:.3g}): "
                                "the correspondences do not fix all six degrees of freedom")
    return np.linalg.solve(ne.H, -ne.g)


def register(source: Any, target: Target, initial: Any = None, *, max_distance: float, kernel_scale: float = 1.0,
             config: IcpConfig = IcpConfig()) -> IcpResult:
    """Align `source` (N, 3) onto `target` from `initial` (module docstring); robust weights with
    `kernel_scale` (kernels.icp: Huber's c or Geman-McClure's s), pairs within `max_distance`."""
    s = check_cloud("source", source)
    if (target.normals is None) != (config.metric == "point"):
        raise ValueError(f"target: made for the other metric than config.metric = {config.metric!r}")
    if not (math.isfinite(max_distance) and max_distance > 0):
        raise ValueError(f"max_distance: expected a positive value, got {max_distance}")
    T = np.eye(4) if initial is None else np.array(initial, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"initial: expected a finite 4x4 transform, got shape {T.shape}")
    converged, pairs, cost, it = False, 0, 0.0, 0
    for it in range(1, config.max_iterations + 1):
        p = _moved(T, s)
        idx, sq = target.nearest(p)
        keep = sq < np.float32(max_distance) ** 2
        pairs = int(keep.sum())
        if pairs < config.min_pairs:
            raise RegistrationError(f"source: {pairs} correspondences within max_distance = {max_distance:g} "
                                    f"(fewer than {config.min_pairs})")
        j = idx[keep]
        normals = None if target.normals is None else target.normals[j]
        ne = kicp.normal_equations(p[keep], target.points[j], normals, robust=config.robust, scale=kernel_scale)
        cost = ne.cost
        dxi = gauss_newton_step(ne)
        T = se3_exp(dxi) @ T
        if float(np.linalg.norm(dxi)) < config.convergence:
            converged = True
            break
    return IcpResult(T, it, pairs, converged, cost)
