"""Iterative closest point: per-correspondence residuals, their pose Jacobians, robust weights, and the
Gauss-Newton normal equations of point-to-point and point-to-plane ICP.

Correspondences. Row i pairs a source point p_i (already moved by the current pose estimate, so in the
target's frame) with a target point q_i and, for point-to-plane, the target's unit normal n_i. A
correspondence has R residual rows, each a direction d applied to the offset u_i = p_i - q_i:

    point-to-point (Besl and McKay, "A method for registration of 3-D shapes", PAMI 1992):
        R = 3, d = e_x, e_y, e_z:     r_i = p_i - q_i,                e_i^2 = |p_i - q_i|^2
    point-to-plane (Chen and Medioni, "Object modelling by registration of multiple range images", 1992):
        R = 1, d = n_i:               r_i = n_i . (p_i - q_i),        e_i^2 = r_i^2

Pose Jacobian. The pose update is a LEFT-multiplied se(3) perturbation of the source,
p_i(xi) = exp(xi^) p_i with xi = (rho, phi), translation first (research/poses/se3.py's convention,
and KISS-ICP's), so dp_i/dxi at xi = 0 is [I, -p_i^] and each residual row's Jacobian is

    J = d^T [I, -p_i^] = [d^T, (p_i x d)^T]              (1 x 6; d^T (phi x p) = phi . (p x d)).

Robust weights (iteratively reweighted least squares). The cost is E(xi) = sum_i rho(e_i) with e_i >= 0;
the weight w(e^2) = rho'(e) / e makes the gradient of E at xi = 0 exactly g below:

    none:            rho = e^2 / 2,                               w = 1
    Huber (c > 0):   rho = e^2 / 2 (e <= c),  c e - c^2 / 2 (e > c);   w = 1 (e <= c),  c / e (e > c)
    Geman-McClure:   rho = s e^2 / (2 (s + e^2)),                  w = s^2 / (s + e^2)^2

Geman-McClure is written in KISS-ICP's form (Vizzo et al., "KISS-ICP: In defense of point-to-point ICP",
RA-L 2023): its scale s is added to a squared distance, and KISS-ICP passes its adaptive threshold sigma
as s. Huber has a kink in its second derivative at e = c (its gradient is continuous).

Normal equations. Over every correspondence and row,

    H = sum_i w_i sum_rows J^T J  (6 x 6),     g = sum_i w_i sum_rows J^T r,     cost = sum_i rho(e_i),

and the Gauss-Newton step solves H dxi = -g (in NumPy: research/lidar/registration.py). The weights are
held fixed inside H (IRLS), so H is the Gauss-Newton matrix of the weighted problem, not E's Hessian.

Reduction. Correspondences are summed in fixed blocks of `block` rows: each thread sums its own block in
index order into its own row of partial sums (split-safe, no atomics: docs/warp.md section 2), and the
partial sums are added in float64 on the host, so the result does not depend on the thread count.

No gradients flow through these kernels; J and g are the derivatives, and research/checks/icp.py checks
both against float64 finite differences of the residuals and of E along xi.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A

wp.set_module_options({"enable_backward": False})

ROBUST = {"none": 0, "huber": 1, "gm": 2}
# Columns of a block's partial sums: H row-major (36), then g (6), then the cost.
_G0 = 36
_COST = 42
_COLS = 43


@wp.func
def robust_terms(e2: typing.Any, robust: int, s: typing.Any):
    """(w(e^2), rho(e)) of the module docstring, from e^2 (robust: 0 none, 1 Huber with c = s, 2 Geman-McClure
    with scale s)."""
    one = type(e2)(1.0)
    half = type(e2)(0.5)
    if robust == 1:
        e = wp.sqrt(e2)
        if e > s:
            return s / e, s * e - half * s * s
        return one, half * e2
    if robust == 2:
        den = s + e2
        return s * s / (den * den), half * s * e2 / den
    return one, half * e2


@wp.func
def row_direction(n: typing.Any, plane: int, a: int):
    """d of residual row a: the normal (point-to-plane) or the axis e_a (point-to-point)."""
    if plane == 1:
        return n
    zero = type(n[0])(0.0)
    one = type(n[0])(1.0)
    if a == 0:
        return wp.vector(one, zero, zero)
    if a == 1:
        return wp.vector(zero, one, zero)
    return wp.vector(zero, zero, one)


@wp.func
def jacobian_entry(d: typing.Any, pxd: typing.Any, j: int):
    """J[j] = [d^T, (p x d)^T][j]."""
    if j < 3:
        return d[j]
    return pxd[j - 3]


@wp.func
def correspondence(source: wp.array2d(dtype=typing.Any), target: wp.array2d(dtype=typing.Any),
                   normals: wp.array2d(dtype=typing.Any), plane: int, i: int):
    """(p_i, u_i = p_i - q_i, n_i (u_i when point-to-point: unused), e_i^2)."""
    p = wp.vector(source[i, 0], source[i, 1], source[i, 2])
    u = p - wp.vector(target[i, 0], target[i, 1], target[i, 2])
    n = u
    e2 = wp.dot(u, u)
    if plane == 1:
        n = wp.vector(normals[i, 0], normals[i, 1], normals[i, 2])
        r = wp.dot(n, u)
        e2 = r * r
    return p, u, n, e2


@wp.kernel
def _residual_kernel(source: wp.array2d(dtype=typing.Any), target: wp.array2d(dtype=typing.Any),
                     normals: wp.array2d(dtype=typing.Any), plane: int, rows: int, robust: int, s: typing.Any,
                     res: wp.array2d(dtype=typing.Any), jac: wp.array3d(dtype=typing.Any),
                     weight: wp.array(dtype=typing.Any), rho: wp.array(dtype=typing.Any), offset: int):
    """Row i: r_i (R), J_i (R x 6), w(e_i^2), rho(e_i)."""
    i = wp.tid() + offset
    p, u, n, e2 = correspondence(source, target, normals, plane, i)
    w, rho_i = robust_terms(e2, robust, s)
    weight[i] = w
    rho[i] = rho_i
    for a in range(rows):
        d = row_direction(n, plane, a)
        pxd = wp.cross(p, d)
        res[i, a] = wp.dot(d, u)
        for j in range(6):
            jac[i, a, j] = jacobian_entry(d, pxd, j)


@wp.kernel
def _normal_equations_kernel(source: wp.array2d(dtype=typing.Any), target: wp.array2d(dtype=typing.Any),
                             normals: wp.array2d(dtype=typing.Any), plane: int, rows: int, robust: int,
                             s: typing.Any, n_pairs: int, block: int, partial: wp.array2d(dtype=typing.Any),
                             offset: int):
    """Block b's sums of w J^T J, w J^T r and rho over rows b*block .. (b+1)*block - 1, in index order."""
    b = wp.tid() + offset
    zero = s - s
    for c in range(_COLS):
        partial[b, c] = zero
    start = b * block
    end = wp.min(start + block, n_pairs)
    for i in range(start, end):
        p, u, n, e2 = correspondence(source, target, normals, plane, i)
        w, rho = robust_terms(e2, robust, s)
        partial[b, _COST] += rho
        for a in range(rows):
            d = row_direction(n, plane, a)
            pxd = wp.cross(p, d)
            r = wp.dot(d, u)
            for j in range(6):
                wj = w * jacobian_entry(d, pxd, j)
                partial[b, _G0 + j] += wj * r
                for k in range(6):
                    partial[b, 6 * j + k] += wj * jacobian_entry(d, pxd, k)


for _kernel in (_residual_kernel, _normal_equations_kernel):
    A.declare_float_overloads(_kernel)


# =========================================================================== entry points


@dataclass
class Residuals:
    """residuals (N, R) and jacobians (N, R, 6) (R = 3 point-to-point, 1 point-to-plane); weights (N,)
    w(e_i^2) and rho (N,) rho(e_i). NumPy or wp.array, as the inputs."""

    residuals: Any
    jacobians: Any
    weights: Any
    rho: Any


@dataclass
class NormalEquations:
    """H (6, 6) and g (6,) float64 NumPy (module docstring), cost = sum rho(e_i), count = N pairs."""

    H: np.ndarray
    g: np.ndarray
    cost: float
    count: int


@dataclass
class _Checked:
    a: A.Inputs
    source: wp.array
    target: wp.array
    normals: wp.array
    plane: int
    robust: int
    scale: float


def _check_cloud(a: A.Inputs, name: str, x: Any, n: int | None) -> wp.array:
    arr = a.floats(name, x, (None, 3) if n is None else (n, 3), finite=False)
    if x.shape[0] == 0:
        raise ValueError(f"{name}: expected a non-empty cloud of shape (N, 3) with N >= 1, got shape {tuple(x.shape)}")
    if A.values_checked() and not A.all_finite(x):
        raise ValueError(f"{name}: expected finite coordinates, found NaN or infinite entries")
    return arr


def check_robust(robust: str, scale: float) -> tuple[int, float]:
    """(kernel code, scale) for a robust kernel name in ROBUST and a positive finite scale."""
    if robust not in ROBUST:
        raise ValueError(f"robust: expected one of {', '.join(ROBUST)}, got {robust!r}")
    return ROBUST[robust], A.check_float("scale", scale, positive=True)


def _check(device: Any, source: Any, target: Any, normals: Any, robust: str, scale: float) -> _Checked:
    a = A.Inputs(device, source, target, normals)
    src = _check_cloud(a, "source", source, None)
    n = int(src.shape[0])
    tgt = _check_cloud(a, "target", target, n)
    if normals is None:
        nrm = a.zeros((0, 3))
    else:
        nrm = _check_cloud(a, "normals", normals, n)
        h = A.host_view(nrm)
        h = nrm.numpy() if h is None else h
        if A.values_checked() and np.max(np.abs(np.linalg.norm(h.astype(np.float64), axis=1) - 1.0)) > 1e-3:
            raise ValueError("normals: expected unit vectors (| |n| - 1 | <= 1e-3)")
    code, s = check_robust(robust, scale)
    return _Checked(a, src, tgt, nrm, int(normals is not None), code, s)


def icp_residuals(source: Any, target: Any, normals: Any = None, *, robust: str = "none", scale: float = 1.0,
                  device: Any = None) -> Residuals:
    """Residuals, pose Jacobians and robust weights of the correspondences (source_i, target_i[, normals_i]):
    point-to-point when `normals` is None, else point-to-plane (module docstring). All (N, 3)."""
    c = _check(device, source, target, normals, robust, scale)
    a = c.a
    n = int(c.source.shape[0])
    rows = 1 if c.plane else 3
    res = a.empty((n, rows))
    jac = a.empty((n, rows, 6))
    w = a.empty(n)
    rho = a.empty(n)
    a.launch(_residual_kernel, n, [c.source, c.target, c.normals, c.plane, rows, c.robust, a.s(c.scale), res, jac,
                                   w, rho], min_chunk=1024)
    return Residuals(a.out(res), a.out(jac), a.out(w), a.out(rho))


def normal_equations(source: Any, target: Any, normals: Any = None, *, robust: str = "none", scale: float = 1.0,
                     block: int = 256, device: Any = None) -> NormalEquations:
    """H = sum w J^T J, g = sum w J^T r and the robust cost over the correspondences (module docstring),
    point-to-point when `normals` is None, else point-to-plane; summed in blocks of `block` rows."""
    c = _check(device, source, target, normals, robust, scale)
    block = A.check_int("block", block, minimum=1)
    a = c.a
    n = int(c.source.shape[0])
    n_blocks = (n + block - 1) // block
    partial = a.empty((n_blocks, _COLS))
    a.launch(_normal_equations_kernel, n_blocks,
             [c.source, c.target, c.normals, c.plane, 1 if c.plane else 3, c.robust, a.s(c.scale), n, block, partial],
             min_chunk=4)
    sums = partial.numpy().astype(np.float64).sum(axis=0)
    return NormalEquations(sums[:_G0].reshape(6, 6), sums[_G0:_COST].copy(), float(sums[_COST]), n)


__all__ = ["ROBUST", "NormalEquations", "Residuals", "check_robust", "icp_residuals", "normal_equations",
           "robust_terms"]
