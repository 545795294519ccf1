"""Normals by local principal component analysis over the k nearest neighbours.

For each point p_i with its k nearest points N_i (kernels/points/grid.py `knn`, p_i itself included),

    mu_i = (1/k) sum_{j in N_i} p_j,      C_i = (1/k) sum_{j in N_i} (p_j - mu_i)(p_j - mu_i)^T,

with eigenvalues lambda_0 <= lambda_1 <= lambda_2 of C_i (Warp's `eig3`, a symmetric 3 x 3 solver). The
normal n_i is the unit eigenvector of lambda_0 (the direction of least spread; Hoppe et al., "Surface
reconstruction from unorganized points", SIGGRAPH 1992), oriented toward the viewpoint v:
n_i . (v - p_i) >= 0, flipped otherwise (Open3D's orient_normals_towards_camera_location convention;
v defaults to the origin, as there).

Degenerate neighbourhoods. The plane through N_i is undefined when its points are collinear or fewer
than 3 are distinct; then lambda_1 = 0 as well. A neighbourhood is called degenerate when
lambda_1 <= ratio * lambda_2 (ratio 1e-6 by default; lambda_2 = 0 when all k points coincide): its
normal is NaN in all three components and `valid` is False. Choosing k (>= 3) and a ratio is the
caller's business; bad arguments raise before any kernel runs.

Each point writes its own row (split-safe). No gradients.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.points.grid import _build, _host, check_cloud, check_count, density_cell_size, knn_grid

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _normals_kernel(points: wp.array2d(dtype=typing.Any), nbr: wp.array2d(dtype=wp.int32), k: int,
                    vx: typing.Any, vy: typing.Any, vz: typing.Any, ratio: typing.Any,
                    normals: wp.array2d(dtype=typing.Any), valid: wp.array(dtype=wp.uint8), offset: int):
    i = wp.tid() + offset
    zero = type(vx)(0.0)
    inv_k = type(vx)(1.0) / type(vx)(float(k))
    mx = zero
    my = zero
    mz = zero
    for m in range(k):
        j = nbr[i, m]
        mx += points[j, 0]
        my += points[j, 1]
        mz += points[j, 2]
    mx = mx * inv_k
    my = my * inv_k
    mz = mz * inv_k
    cxx = zero
    cxy = zero
    cxz = zero
    cyy = zero
    cyz = zero
    czz = zero
    for m in range(k):
        j = nbr[i, m]
        ex = points[j, 0] - mx
        ey = points[j, 1] - my
        ez = points[j, 2] - mz
        cxx += ex * ex
        cxy += ex * ey
        cxz += ex * ez
        cyy += ey * ey
        cyz += ey * ez
        czz += ez * ez
    cov = wp.matrix(cxx, cxy, cxz, cxy, cyy, cyz, cxz, cyz, czz, shape=(3, 3)) * inv_k
    Q, lam = wp.eig3(cov)  # eigenvectors are Q's columns, in no particular order
    # sort the three eigenvalues: a (smallest), b (middle), c (largest)
    a = int(0)
    c = int(0)
    for m in range(1, 3):
        if lam[m] < lam[a]:
            a = m
        if lam[m] > lam[c]:
            c = m
    if a == c:  # all three equal
        c = 2
        if a == 2:
            c = 1
    b = 3 - a - c
    nx = Q[0, a]
    ny = Q[1, a]
    nz = Q[2, a]
    if lam[b] <= ratio * lam[c]:
        nan = wp.nan
        normals[i, 0] = type(vx)(nan)
        normals[i, 1] = type(vx)(nan)
        normals[i, 2] = type(vx)(nan)
        valid[i] = wp.uint8(0)
    else:
        norm = wp.sqrt(nx * nx + ny * ny + nz * nz)
        sgn = type(vx)(1.0) / norm
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        if nx * (vx - px) + ny * (vy - py) + nz * (vz - pz) < zero:
            sgn = -sgn
        normals[i, 0] = nx * sgn
        normals[i, 1] = ny * sgn
        normals[i, 2] = nz * sgn
        valid[i] = wp.uint8(1)


A.declare_float_overloads(_normals_kernel)


@dataclass
class NormalsResult:
    """normals (N, 3): unit normals toward the viewpoint, NaN where degenerate; valid (N,) bool
    (uint8 for wp.array inputs). NumPy or wp.array, as the input."""

    normals: Any
    valid: Any


def estimate_normals(points: Any, k: int = 16, *, viewpoint=(0.0, 0.0, 0.0), degenerate_ratio: float = 1e-6,
                     device: Any = None) -> NormalsResult:
    """PCA normals of `points` (N, 3) over each point's `k` nearest (module docstring)."""
    a = A.Inputs(device, points)
    pts = check_cloud(a, "points", points)
    n = int(pts.shape[0])
    k = check_count("k", k, 3, n)
    try:
        v = [A.check_float("viewpoint", c) for c in viewpoint]
    except TypeError:
        raise ValueError(f"viewpoint: expected 3 finite numbers, got {viewpoint!r}") from None
    if len(v) != 3:
        raise ValueError(f"viewpoint: expected 3 finite numbers, got {viewpoint!r}")
    ratio = A.check_float("degenerate_ratio", degenerate_ratio, nonnegative=True)
    grid = _build(a, pts, density_cell_size(_host(pts), k))
    res = knn_grid(A.Inputs.like(a.device, a.scalar, False), grid, pts, k)
    normals = a.empty((n, 3))
    valid = a.empty(n, dtype=wp.uint8)
    a.launch(_normals_kernel, n, [pts, res.idx, k, a.s(v[0]), a.s(v[1]), a.s(v[2]), a.s(ratio), normals, valid],
             min_chunk=256)
    return NormalsResult(a.out(normals), a.out_mask(valid))
