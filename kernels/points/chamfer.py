"""The chamfer distance between two clouds, and its gradient with respect to both.

For clouds X = {x_i} (N points) and Y = {y_j} (M points), as PyTorch3D's chamfer_distance (its
default point_reduction="mean", one cloud per batch) and Kaolin's chamfer_distance (weights 1, 1)
define it, with squared Euclidean distances:

    CD(X, Y) = (1/N) sum_i |x_i - y_a(i)|^2 + (1/M) sum_j |y_j - x_b(j)|^2,
    a(i) = the nearest y to x_i,   b(j) = the nearest x to y_j,

the nearest found by the exact 1-NN of kernels/points/grid.py (ties broken by the smaller index).

Gradient. Away from ties of the nearest neighbour, CD is a sum of squared differences of fixed pairs:

    dCD/dx_i = (2/N)(x_i - y_a(i)) + (2/M) sum_{j: b(j) = i} (x_i - y_j),
    dCD/dy_j = (2/M)(y_j - x_b(j)) + (2/N) sum_{i: a(i) = j} (y_j - x_i).

Where two points are equally near, CD has a kink: the gradient given is the one-sided gradient of the
pair the tie-break picks. The sums over {j: b(j) = i} are gathers: the indices j are sorted by b(j)
(stable radix sort, so each run is in index order and the sum's order is fixed) and every x_i sums its
own run, so each thread writes only its own row (split-safe, the same on every thread count; no
atomics, docs/warp.md section 2).
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.points.grid import _build, _host, _runs_kernel, check_cloud, density_cell_size, knn_grid

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _pair_grad_kernel(x: wp.array2d(dtype=typing.Any), y: wp.array2d(dtype=typing.Any),
                      near_y: wp.array(dtype=wp.int32), by_b: wp.array(dtype=wp.int32),
                      start: wp.array(dtype=wp.int32), end: wp.array(dtype=wp.int32), wx: typing.Any,
                      wy: typing.Any, gx: wp.array2d(dtype=typing.Any), offset: int):
    """gx_i = wx (x_i - y_a(i)) + wy sum_{j: b(j) = i} (x_i - y_j), wx = 2g/N, wy = 2g/M (module docstring)."""
    i = wp.tid() + offset
    j0 = near_y[i]
    for c in range(3):
        xi = x[i, c]
        acc = type(wx)(0.0)
        for t in range(start[i], end[i]):
            acc += xi - y[by_b[t], c]
        gx[i, c] = wx * (xi - y[j0, c]) + wy * acc


A.declare_float_overloads(_pair_grad_kernel)


@dataclass
class ChamferResult:
    """value: CD(X, Y) (a Python float); near_y (N,) = a(i), near_x (M,) = b(j) int32; sq_xy (N,) =
    |x_i - y_a(i)|^2, sq_yx (M,) = |y_j - x_b(j)|^2. Arrays in the inputs' kind."""

    value: float
    near_y: Any
    near_x: Any
    sq_xy: Any
    sq_yx: Any


def _nearest(a: A.Inputs, ref: wp.array, qs: wp.array):
    grid = _build(a, ref, density_cell_size(_host(ref), 1))
    return knn_grid(A.Inputs.like(a.device, a.scalar, False), grid, qs, 1)


def chamfer_distance(x: Any, y: Any, *, device: Any = None) -> ChamferResult:
    """CD(X, Y) of clouds `x` (N, 3) and `y` (M, 3) with the nearest neighbours both ways (module docstring)."""
    a = A.Inputs(device, x, y)
    xw = check_cloud(a, "x", x)
    yw = check_cloud(a, "y", y)
    xy = _nearest(a, yw, xw)
    yx = _nearest(a, xw, yw)
    sq_xy, sq_yx = xy.sq_dist.flatten(), yx.sq_dist.flatten()
    value = float(np.mean(sq_xy.numpy(), dtype=np.float64) + np.mean(sq_yx.numpy(), dtype=np.float64))
    return ChamferResult(value, a.out(xy.idx.flatten()), a.out(yx.idx.flatten()), a.out(sq_xy), a.out(sq_yx))


def _inverse_runs(a: A.Inputs, near: wp.array, n_targets: int):
    """(sources sorted by their nearest target (stable), start, end (n_targets,)): the run of each target."""
    n = int(near.shape[0])
    keys = wp.empty(2 * n, dtype=wp.int32, device=a.device)  # radix_sort_pairs needs room for 2n
    vals = wp.empty(2 * n, dtype=wp.int32, device=a.device)
    wp.copy(keys, near, count=n)
    wp.copy(vals, wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device=a.device), count=n)
    wp.utils.radix_sort_pairs(keys, vals, n)
    start = wp.zeros(n_targets, dtype=wp.int32, device=a.device)
    end = wp.zeros(n_targets, dtype=wp.int32, device=a.device)
    a.launch(_runs_kernel, n, [keys, n, start, end])
    return vals, start, end


def chamfer_backward(x: Any, y: Any, result: ChamferResult, grad: float = 1.0, *, device: Any = None
                     ) -> dict[str, Any]:
    """{"x": dL/dx (N, 3), "y": dL/dy (M, 3)} for L = grad * CD(X, Y), from `chamfer_distance`'s result
    on the same clouds (module docstring); in the inputs' kind."""
    a = A.Inputs(device, x, y)
    xw = check_cloud(a, "x", x)
    yw = check_cloud(a, "y", y)
    g = A.check_float("grad", grad)
    n, m = int(xw.shape[0]), int(yw.shape[0])
    near_y = a.ints("result.near_y", result.near_y, (n,), minimum=0)
    near_x = a.ints("result.near_x", result.near_x, (m,), minimum=0)
    for name, arr, bound in (("result.near_y", near_y, m), ("result.near_x", near_x, n)):
        h = A.host_view(arr)
        if A.values_checked() and h is not None and int(h.max()) >= bound:
            raise ValueError(f"{name}: expected indices < {bound} (the other cloud's size), got {int(h.max())}")
    wn, wm = a.s(2.0 * g / n), a.s(2.0 * g / m)
    gx = a.empty((n, 3))
    gy = a.empty((m, 3))
    by_b, sx, ex = _inverse_runs(a, near_x, n)  # {j: b(j) = i}
    a.launch(_pair_grad_kernel, n, [xw, yw, near_y, by_b, sx, ex, wn, wm, gx], min_chunk=256)
    by_a, sy, ey = _inverse_runs(a, near_y, m)  # {i: a(i) = j}
    a.launch(_pair_grad_kernel, m, [yw, xw, near_x, by_a, sy, ey, wm, wn, gy], min_chunk=256)
    return {"x": a.out(gx), "y": a.out(gy)}
