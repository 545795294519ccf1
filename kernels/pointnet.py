"""PointNet's symmetric max-pool and PointNet++'s set-abstraction grouping, forward and backward.

PointNet (Qi et al., "PointNet: Deep Learning on Point Sets for 3D Classification and Segmentation",
CVPR 2017) applies one MLP h to every point of a set and pools the features with a maximum,

    f(P) = gamma( max_{i = 1..K} h(p_i) ),      max taken per feature channel,

which is invariant to the order of the points. The shared per-point MLP h is drlab's ReLU MLP
(kernels.volume.mlp.MLP) applied to the rows of a (G K, C_in) array: a set of K points is K rows, so
nothing new is needed for it. This module adds the two operations around it.

Max-pool (`max_pool`). For x (G, K, C) (G sets of K feature rows),

    y[g, c] = max_k x[g, k, c],     a[g, c] = the first k at which the maximum is reached,

scanning k = 0 .. K-1 with a strict comparison, so ties go to the smallest k. The maximum is
piecewise linear: its gradient is the argmax routing

    dL/dx[g, k, c] = dL/dy[g, c] if k = a[g, c], else 0,

one-sided where two entries tie (the gradient then goes to the first of them, a subgradient). Where
the tied rows are copies of one point (ball-query padding, below), every choice gives the same
gradient of the parameters and of the point, since the copies are the same function of both.
A NaN would make the result depend on where it sits (one in row 0 is never beaten, one later
never wins), so inputs are checked finite instead.

Grouping in local coordinates (`group_local`; PointNet++: Qi et al., "PointNet++: Deep Hierarchical
Feature Learning on Point Sets in a Metric Space", NeurIPS 2017, its set-abstraction layer). For B
clouds p[b] (N, 3), S centre indices c[b, s] and K neighbour indices j[b, s, k] per centre,

    u[b, s, k] = (p[b, j[b, s, k]] - p[b, c[b, s]]) / r,

the neighbourhood in the centre's frame, divided by the ball radius r so it lies in the unit ball
(PointNet++'s grouping subtracts the centre; the division keeps the MLP's inputs of order one).
Its backward, for a cotangent g = dL/du (B, S, K, 3), scatters

    dL/dp[b, n] = (1/r) ( sum_{(s,k): j[b,s,k] = n} g[b, s, k] - sum_{(s,k): c[b,s] = n} g[b, s, k] ).

The scatter adds into shared slots, so it runs as one launch (one CPU thread, where Warp's atomics
are safe and the order of the additions is fixed, so the result is deterministic on the CPU;
docs/warp.md section 2). On CUDA the atomic additions land in any order (float rounding may differ
from run to run). The indices themselves (farthest-point sampling and ball query) are piecewise
constant in the points: they carry no gradient.

Indices (`group_indices`): per cloud, S centres by farthest-point sampling from index 0 and the first
K points within r of each centre, ball-query padding included (kernels.points). A centre is a point
of its cloud, so its ball holds at least itself and no index is -1.

The set-abstraction layer is then: centres and neighbours -> u -> shared MLP on the B S K rows ->
max-pool over K -> (B, S, C) features at the S centres. kernels/reference/pointnet.py is the NumPy
reference of every forward; research/checks/pointnet.py checks every backward by float64 finite
differences.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels import points as kp

wp.set_module_options({"enable_backward": False})


@wp.func
def _set_channel(t: int, n_ch: int):
    """Thread t's (set g, channel c) of a (G, C) max-pool output, row-major."""
    g = t / n_ch
    return g, t - g * n_ch


@wp.kernel
def _max_pool_kernel(x: wp.array3d(dtype=typing.Any), y: wp.array2d(dtype=typing.Any),
                     arg: wp.array2d(dtype=wp.int32), offset: int):
    g, c = _set_channel(wp.tid() + offset, x.shape[2])
    best = x[g, 0, c]
    best_k = int(0)
    for k in range(1, x.shape[1]):
        v = x[g, k, c]
        if v > best:  # strict: ties go to the first k
            best = v
            best_k = k
    y[g, c] = best
    arg[g, c] = best_k


@wp.kernel
def _max_pool_backward_kernel(grad_y: wp.array2d(dtype=typing.Any), arg: wp.array2d(dtype=wp.int32),
                              grad_x: wp.array3d(dtype=typing.Any), offset: int):
    # grad_x is zero on entry; thread (g, c) writes only grad_x[g, arg[g, c], c]: disjoint slots.
    g, c = _set_channel(wp.tid() + offset, grad_y.shape[1])
    grad_x[g, arg[g, c], c] = grad_y[g, c]


@wp.func
def _group_slot(t: int, centers: wp.array2d(dtype=wp.int32), neighbors: wp.array3d(dtype=wp.int32)):
    """Thread t's slot (b, s, k) of the (B, S, K) grouping, row-major, with its centre c[b, s] and
    neighbour j[b, s, k]."""
    n_s = neighbors.shape[1]
    n_k = neighbors.shape[2]
    b = t / (n_s * n_k)
    rest = t - b * n_s * n_k
    s = rest / n_k
    k = rest - s * n_k
    return b, s, k, centers[b, s], neighbors[b, s, k]


@wp.kernel
def _group_kernel(points: wp.array3d(dtype=typing.Any), centers: wp.array2d(dtype=wp.int32),
                  neighbors: wp.array3d(dtype=wp.int32), inv_r: typing.Any, out: wp.array4d(dtype=typing.Any),
                  offset: int):
    b, s, k, c, j = _group_slot(wp.tid() + offset, centers, neighbors)
    for a in range(3):
        out[b, s, k, a] = (points[b, j, a] - points[b, c, a]) * inv_r


@wp.kernel
def _group_backward_kernel(grad: wp.array4d(dtype=typing.Any), centers: wp.array2d(dtype=wp.int32),
                           neighbors: wp.array3d(dtype=wp.int32), inv_r: typing.Any,
                           grad_points: wp.array3d(dtype=typing.Any)):
    # A scatter into shared slots: launched once, never split (module docstring).
    b, s, k, c, j = _group_slot(wp.tid(), centers, neighbors)
    for a in range(3):
        v = grad[b, s, k, a] * inv_r
        wp.atomic_add(grad_points, b, j, a, v)
        wp.atomic_sub(grad_points, b, c, a, v)


for _kernel in (_max_pool_kernel, _max_pool_backward_kernel, _group_kernel, _group_backward_kernel):
    A.declare_float_overloads(_kernel)


# =========================================================================== max-pool


@dataclass
class MaxPoolResult:
    """value (G, C): the maximum over each set; argmax (G, C) int32: the first k reaching it."""

    value: Any
    argmax: Any


def max_pool(x: Any, *, device: Any = None) -> MaxPoolResult:
    """Per-channel maximum of x (G, K, C) over its K rows, with the first argmax (module docstring).

    G, K, C >= 1 (an empty set has no maximum) and finite values. NumPy or wp.array, as `x`."""
    a = A.Inputs(device, x)
    xw = a.floats("x", x, ndim=3, finite=False)
    if min(x.shape) == 0:
        raise ValueError(f"x: expected a non-empty (G, K, C) array (sets of K >= 1 rows), got shape {tuple(x.shape)}")
    if A.values_checked() and not A.all_finite(x):
        raise ValueError("x: expected finite values, found NaN or infinite entries")
    g, _, c = (int(s) for s in x.shape)
    y = a.empty((g, c))
    arg = a.empty((g, c), dtype=wp.int32)
    a.launch(_max_pool_kernel, g * c, [xw, y, arg], min_chunk=256)
    return MaxPoolResult(a.out(y), a.out(arg))


def max_pool_backward(result: MaxPoolResult, grad: Any, n_rows: int, *, device: Any = None) -> dict[str, Any]:
    """{"x": dL/dx (G, K, C)} for the cotangent grad = dL/dy (G, C) of `max_pool`'s result, K = `n_rows`:
    the argmax routing (module docstring). In the kind of `grad`."""
    a = A.Inputs(device, grad)
    n_rows = A.check_int("n_rows", n_rows, minimum=1)
    gw = a.floats("grad", grad, ndim=2)
    shape = tuple(int(s) for s in grad.shape)
    arg = a.ints("argmax", result.argmax, shape, minimum=0)
    if A.values_checked() and arg.size:
        h = A.host_view(arg)
        top = int((arg.numpy() if h is None else h).max())
        if top >= n_rows:
            raise ValueError(f"argmax: expected values < n_rows = {n_rows}, got a maximum of {top}")
    gx = a.zeros((shape[0], n_rows, shape[1]))
    if gw.size:
        a.launch(_max_pool_backward_kernel, shape[0] * shape[1], [gw, arg, gx], min_chunk=256)
    return {"x": a.out(gx)}


# =========================================================================== grouping


def _check_group_args(a: A.Inputs, points: Any, centers: Any, neighbors: Any, radius: float
                      ) -> tuple[wp.array, wp.array, wp.array, float]:
    pts = a.floats("points", points, (None, None, 3), finite=False)
    if points.shape[0] == 0 or points.shape[1] == 0:
        raise ValueError("points: expected B >= 1 non-empty clouds of shape (B, N, 3), "
                         f"got shape {tuple(points.shape)}")
    if A.values_checked() and not A.all_finite(points):
        raise ValueError("points: expected finite coordinates, found NaN or infinite entries")
    b, n = int(points.shape[0]), int(points.shape[1])
    cw = a.ints("centers", centers, (b, None), minimum=0)
    nw = a.ints("neighbors", neighbors, (b, centers.shape[1], None), minimum=0)
    if A.values_checked():
        for name, arr in (("centers", cw), ("neighbors", nw)):
            if arr.size:
                h = A.host_view(arr)
                top = int((arr.numpy() if h is None else h).max())
                if top >= n:
                    raise ValueError(f"{name}: expected point indices < N = {n}, got a maximum of {top}")
    r = A.check_float("radius", radius, positive=True)
    return pts, cw, nw, r


def group_local(points: Any, centers: Any, neighbors: Any, radius: float, *, device: Any = None) -> Any:
    """u (B, S, K, 3) = (p[b, neighbors[b, s, k]] - p[b, centers[b, s]]) / radius for clouds `points`
    (B, N, 3), `centers` (B, S) and `neighbors` (B, S, K) int indices in [0, N) (module docstring).
    NumPy or wp.array, as `points`."""
    a = A.Inputs(device, points)
    pts, cw, nw, r = _check_group_args(a, points, centers, neighbors, radius)
    b, s, k = (int(v) for v in neighbors.shape)
    out = a.empty((b, s, k, 3))
    if out.size:
        a.launch(_group_kernel, b * s * k, [pts, cw, nw, a.s(1.0 / r), out], min_chunk=1024)
    return a.out(out)


def group_local_backward(points: Any, centers: Any, neighbors: Any, radius: float, grad: Any, *,
                         device: Any = None) -> dict[str, Any]:
    """{"points": dL/dp (B, N, 3)} for the cotangent grad = dL/du (B, S, K, 3) of `group_local`
    (module docstring: a scatter, one launch). In the kind of `points`."""
    a = A.Inputs(device, points, grad)
    pts, cw, nw, r = _check_group_args(a, points, centers, neighbors, radius)
    b, s, k = (int(v) for v in neighbors.shape)
    gw = a.floats("grad", grad, (b, s, k, 3))
    gp = a.zeros(tuple(int(v) for v in points.shape))
    if gw.size:
        wp.launch(_group_backward_kernel, dim=b * s * k, inputs=[gw, cw, nw, a.s(1.0 / r), gp], device=a.device)
    return {"points": a.out(gp)}


@dataclass
class GroupIndices:
    """centers (B, S) int32: farthest-point samples; neighbors (B, S, K) int32: ball query around each
    (padded with the first found, never -1); count (B, S) int32: points found within r (<= K)."""

    centers: np.ndarray
    neighbors: np.ndarray
    count: np.ndarray


def group_indices(points: Any, n_centers: int, radius: float, max_neighbors: int, *,
                  device: Any = None) -> GroupIndices:
    """Set-abstraction indices of clouds `points` (B, N, 3): per cloud, `n_centers` farthest points from
    index 0 and the first `max_neighbors` points within `radius` of each (kernels.points). NumPy results."""
    a = A.Inputs(device, points)
    a.floats("points", points, (None, None, 3), finite=False)
    if points.shape[0] == 0 or points.shape[1] == 0:
        raise ValueError("points: expected B >= 1 non-empty clouds of shape (B, N, 3), "
                         f"got shape {tuple(points.shape)}")
    b, n = int(points.shape[0]), int(points.shape[1])
    s = A.check_int("n_centers", n_centers, minimum=1)
    if s > n:
        raise ValueError(f"n_centers: expected an integer in [1, {n}] (at most the points per cloud), got {s}")
    k = A.check_int("max_neighbors", max_neighbors, minimum=1)
    r = A.check_float("radius", radius, positive=True)
    host = points.numpy() if isinstance(points, wp.array) else np.asarray(points)
    if A.values_checked() and not np.all(np.isfinite(host)):
        raise ValueError("points: expected finite coordinates, found NaN or infinite entries")
    centers = np.empty((b, s), np.int32)
    neighbors = np.empty((b, s, k), np.int32)
    count = np.empty((b, s), np.int32)
    for i in range(b):
        cloud = np.ascontiguousarray(host[i])
        c = np.asarray(kp.farthest_point_sampling(cloud, s, device=a.device))
        ball = kp.ball_query(cloud, np.ascontiguousarray(cloud[c]), r, k, device=a.device)
        centers[i], neighbors[i], count[i] = c, np.asarray(ball.idx), np.asarray(ball.count)
    return GroupIndices(centers, neighbors, count)
