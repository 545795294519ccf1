"""Multiresolution hash encoding (instant-ngp, Mueller et al. 2022, section 3).

A point p in the box [lo, hi] is normalised to x = clamp((p - lo) / (hi - lo), 0, 1). Level
l = 0 .. L-1 has resolution N_l = floor(N_min b^l), b = exp((ln N_max - ln N_min) / (L - 1)),
and its own table of T entries (T = 2^log2_table_size) of F features. On level l,

    u = x N_l,  i = clamp(floor(u), 0, N_l - 1),  f = u - i,
    enc_l(p) = sum_{b in {0,1}^3} w_b(f) table_l[ h_l(i + b) ]          (trilinear, as in grid.py)

with the vertex index h_l(v) = v_x + (N_l+1)(v_y + (N_l+1) v_z) when the level's (N_l+1)^3
vertices fit in T (dense level, no collisions), else the spatial hash of the paper,

    h(v) = (v_x * 1  XOR  v_y * 2654435761  XOR  v_z * 805459861)  mod T   (uint32 arithmetic).

The normalised coordinates x do not depend on the level: one pass computes them into a (3, N) array
(feature-major) before the encode or the scatter, whose kernels then start from x (the same float
operations as computing x per (point, level), so the same values).

The encoding is the concatenation enc(p) = [enc_0, ..., enc_{L-1}] (N, L F); tables are stored
as one (L T, F) array, level l in rows l T .. l T + T - 1. `encode` returns enc as the transposed
view of a contiguous (L F, N) array (feature-major): the forward's threads run level by level, and
each level's features are then written contiguously over the points instead of 2F of every 4 L F
bytes of each point's row (a 16x write amplification of cache lines at L = 16, F = 2).

Backward, for a cotangent G (N, L F): dL/dtable_l[h_l(i + b)] += w_b G[n, l F : l F + F] over all
points -- a scatter, done with atomic adds in one launch PER LEVEL (no Warp atomic is atomic
between concurrent CPU launches, docs/warp.md, but each level writes only its own rows, so the
levels' launches run concurrently on the CPU threads; the order of the additions into each row is
that of a single launch). The forward runs one thread per (level, run of BLOCK consecutive points)
through launch_split, the backward one per run of points of its level. There is no gradient to the
points. On the CPU with F = 2 the forward's sums and the scatter's additions run in C++, 8 points
at a time (kernels.volume.hashgrid_cpu: the same operations in the same order, the same values). `encode` and `backward` take
wp.arrays (the neural fields' intermediate values) and return wp.arrays on the points' device; `backward` may write into a given zeroed-on-entry buffer instead
of a new array (a training loop's workspace: no fresh pages to fault in every iteration).
"""

from __future__ import annotations

import math
import typing
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A, fast_paths
from kernels.launch import DEFAULT_MIN_CHUNK, launch_split, parallel_items
from kernels.volume._checks import check_bbox
from kernels.volume.grid import trilinear_weight
from kernels.volume.hashgrid_cpu import backward_kernel, forward_kernel
from kernels.volume.mlp import empty_array

wp.set_module_options({"enable_backward": False})

PRIME_Y = 2654435761
PRIME_Z = 805459861
_PRIME_Y = wp.constant(wp.uint32(PRIME_Y))
_PRIME_Z = wp.constant(wp.uint32(PRIME_Z))


@wp.func
def hash_index(ix: int, iy: int, iz: int, res: int, dense: int, table_size: int) -> int:
    if dense != 0:
        return ix + (res + 1) * (iy + (res + 1) * iz)
    h = wp.uint32(ix) ^ (wp.uint32(iy) * _PRIME_Y) ^ (wp.uint32(iz) * _PRIME_Z)
    return int(h & wp.uint32(table_size - 1))


@wp.kernel
def _normalise_kernel(
    points: wp.array2d(dtype=typing.Any), bbox: wp.array2d(dtype=typing.Any), x: wp.array2d(dtype=typing.Any),
    offset: int,
):
    # x (3, N), feature-major: x[a, n] = clamp((p_a - lo_a) / (hi_a - lo_a), 0, 1), the same for every level, so
    # computed once a call instead of once per (point, level).
    n = wp.tid() + offset
    for a in range(3):
        lo = bbox[0, a]
        x[a, n] = wp.clamp((points[n, a] - lo) / (bbox[1, a] - lo), x.dtype(0.0), x.dtype(1.0))


@wp.func
def level_axis(x: typing.Any, res: int):
    u = x * type(x)(res)
    i = wp.clamp(int(wp.floor(u)), 0, res - 1)
    return i, u - type(x)(i)


@wp.func
def level_cell(x: wp.array2d(dtype=typing.Any), n: int, res: int):
    """Cell (i_x, i_y, i_z) and fractions (f_x, f_y, f_z) of point n (normalised coordinates x[:, n]) on a
    level of resolution res."""
    ix, fx = level_axis(x[0, n], res)
    iy, fy = level_axis(x[1, n], res)
    iz, fz = level_axis(x[2, n], res)
    return ix, iy, iz, fx, fy, fz


@wp.func
def corner_row(c: int, l: int, ix: int, iy: int, iz: int, res: int, dense: int, table_size: int) -> int:
    """Table row of corner c of cell (i_x, i_y, i_z) on level l."""
    return l * table_size + hash_index(ix + (c & 1), iy + ((c >> 1) & 1), iz + ((c >> 2) & 1), res, dense,
                                       table_size)


# Points per CPU kernel thread in the encode and the scatter (1 on CUDA, whose threads are cheap and whose
# memory accesses coalesce over consecutive points): a thread walks a run of BLOCK consecutive
# points of one level, so the per-thread cost of a Warp CPU launch (its loop calls the kernel function
# once per thread, which reloads every argument) is paid once per run; 32 -> 26 ms for 57k points x 12
# levels on one thread. The points and their order are unchanged, so are the results.
BLOCK = 16


def _block(device: wp.Device) -> int:
    return 1 if device.is_cuda else BLOCK


@wp.kernel
def _hash_forward_kernel(
    x: wp.array2d(dtype=typing.Any), resolutions: wp.array(dtype=wp.int32),
    dense: wp.array(dtype=wp.int32), table_size: int,
    table: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=typing.Any), block: int, offset: int,
):
    # out (L F, N): feature-major, so consecutive threads (points of one level) write consecutively.
    # Level-major threads (t = l B + b over the B = ceil(N / block) runs of `block` points): a chunk of
    # consecutive threads reads one level's table (T F values, 4 MB at T = 2^19, F = 2 in float32)
    # instead of all L levels' at once, so its random reads stay in the cache (point-major: 1.6x slower
    # at 131072 points).
    t = wp.tid() + offset
    n_points = x.shape[1]
    n_runs = (n_points + block - 1) / block
    l = t / n_runs
    run = t - l * n_runs
    res = resolutions[l]
    d = dense[l]
    F = table.shape[1]
    for n in range(run * block, wp.min(n_points, (run + 1) * block)):
        ix, iy, iz, fx, fy, fz = level_cell(x, n, res)
        # Summed in registers, corners in the order c = 0..7 (a `+=` on out[...] would be a
        # read-modify-write of memory per corner).
        if F == 2:  # the usual case: both features from one pass over the corners
            s0 = x.dtype(0.0)
            s1 = x.dtype(0.0)
            for c in range(8):
                w = trilinear_weight(c, fx, fy, fz)
                row = corner_row(c, l, ix, iy, iz, res, d, table_size)
                s0 += w * table[row, 0]
                s1 += w * table[row, 1]
            out[l * 2, n] = s0
            out[l * 2 + 1, n] = s1
        else:
            for f in range(F):
                s = x.dtype(0.0)
                for c in range(8):
                    w = trilinear_weight(c, fx, fy, fz)
                    s += w * table[corner_row(c, l, ix, iy, iz, res, d, table_size), f]
                out[l * F + f, n] = s


@wp.kernel
def _hash_backward_kernel(
    x: wp.array2d(dtype=typing.Any), resolutions: wp.array(dtype=wp.int32),
    dense: wp.array(dtype=wp.int32), table_size: int,
    grad_out: wp.array2d(dtype=typing.Any), grad_table: wp.array2d(dtype=typing.Any), level: int, block: int,
):
    # One launch per level (thread b = the run of points b block .. (b + 1) block - 1, in order, so the
    # additions into every row happen in point order, as with one thread per point): a level's rows
    # l T .. l T + T - 1 are its own, so the levels' launches run concurrently and each launch's atomics
    # are exact (docs/warp.md).
    b = wp.tid()
    l = level
    res = resolutions[l]
    F = grad_table.shape[1]
    d = dense[l]
    for n in range(b * block, wp.min(x.shape[1], (b + 1) * block)):
        ix, iy, iz, fx, fy, fz = level_cell(x, n, res)
        if F == 2:  # the usual case: the point's two cotangents read once, into registers
            g0 = grad_out[n, l * 2]
            g1 = grad_out[n, l * 2 + 1]
            for c in range(8):
                w = trilinear_weight(c, fx, fy, fz)
                row = corner_row(c, l, ix, iy, iz, res, d, table_size)
                wp.atomic_add(grad_table, row, 0, w * g0)
                wp.atomic_add(grad_table, row, 1, w * g1)
        else:
            for c in range(8):
                w = trilinear_weight(c, fx, fy, fz)
                row = corner_row(c, l, ix, iy, iz, res, d, table_size)
                for f in range(F):
                    wp.atomic_add(grad_table, row, f, w * grad_out[n, l * F + f])


def level_resolutions(n_levels: int, base_resolution: int, max_resolution: int) -> np.ndarray:
    """N_l = floor(N_min b^l), b = exp((ln N_max - ln N_min) / (L - 1)) (paper, eq. 2-3)."""
    if n_levels == 1:
        return np.array([base_resolution], dtype=np.int32)
    b = math.exp((math.log(max_resolution) - math.log(base_resolution)) / (n_levels - 1))
    return np.array([math.floor(base_resolution * b**l + 1e-9) for l in range(n_levels)], dtype=np.int32)


class HashEncoding:
    """Configuration of a multiresolution hash encoding; the table itself is passed to the calls."""

    def __init__(self, bbox: Any, n_levels: int = 16, n_features: int = 2, log2_table_size: int = 19,
                 base_resolution: int = 16, max_resolution: int = 512) -> None:
        self.bbox = check_bbox("bbox", bbox)
        self.n_levels = A.check_int("n_levels", n_levels, minimum=1)
        self.n_features = A.check_int("n_features", n_features, minimum=1)
        self.table_size = 1 << A.check_int("log2_table_size", log2_table_size, minimum=1, maximum=30)
        base_resolution = A.check_int("base_resolution", base_resolution, minimum=1)
        max_resolution = A.check_int("max_resolution", max_resolution, minimum=1)
        if max_resolution < base_resolution:
            raise ValueError(f"max_resolution: expected >= base_resolution ({base_resolution}), got {max_resolution}")
        self.resolutions = level_resolutions(self.n_levels, base_resolution, max_resolution)
        self.dense = ((self.resolutions.astype(np.int64) + 1) ** 3 <= self.table_size).astype(np.int32)

    @property
    def table_shape(self) -> tuple[int, int]:
        return (self.n_levels * self.table_size, self.n_features)

    @property
    def n_outputs(self) -> int:
        return self.n_levels * self.n_features

    def init_table(self, seed: int, dtype: Any, device: wp.Device, scale: float = 1e-4) -> wp.array:
        """U(-scale, scale) entries (the paper's initialisation), from `seed`."""
        rng = np.random.default_rng(seed)
        return wp.array(rng.uniform(-scale, scale, self.table_shape).astype(A.NP_OF_WP[dtype]),
                        dtype=dtype, device=device)

    def _static(self, dtype: Any, device: wp.Device) -> list:
        return [wp.array(self.resolutions, dtype=wp.int32, device=device),
                wp.array(self.dense, dtype=wp.int32, device=device), self.table_size]

    def _normalised(self, points: wp.array, pool: A.HostPool | None) -> wp.array:
        """x (3, N): the points' coordinates in the box, clamped to [0, 1] (module docstring)."""
        x = empty_array((3, points.shape[0]), points.dtype, points.device, pool)
        launch_split(_normalise_kernel, points.shape[0],
                     [points, wp.array(self.bbox, dtype=points.dtype, device=points.device), x], device=points.device)
        return x

    def _check(self, points: wp.array, table: wp.array) -> None:
        """points (N, 3) and the table as wp.arrays of one dtype on one device."""
        for name, x in (("points", points), ("table", table)):
            if not isinstance(x, wp.array):
                raise ValueError(f"{name}: expected a wp.array, got {type(x).__name__}")
        A.check_shape("points", points, (None, 3))
        A.check_shape("table", table, self.table_shape)
        if table.dtype != points.dtype or table.device != points.device:
            raise ValueError(f"table: expected {A.type_name(points.dtype)} on {points.device} (the points'), "
                             f"got {A.type_name(table.dtype)} on {table.device}")

    def encode(self, points: wp.array, table: wp.array, pool: A.HostPool | None = None) -> wp.array:
        """enc (N, L F) for points (N, 3): the transposed view of a contiguous (L F, N) array (a block of
        `pool` on the CPU when given: kernels.volume.mlp.empty_array)."""
        self._check(points, table)
        n = points.shape[0]
        out = empty_array((self.n_outputs, n), points.dtype, points.device, pool)
        if n:
            block = _block(points.device)
            # F = 2 on the CPU: the same sums in C++, 8 points at a time (kernels.volume.hashgrid_cpu)
            kernel = (forward_kernel(points.dtype) if points.device.is_cpu and self.n_features == 2 and fast_paths.enabled()
                      else _hash_forward_kernel)
            launch_split(kernel, -(-n // block) * self.n_levels,
                         [self._normalised(points, pool), *self._static(points.dtype, points.device), table, out,
                          block], device=points.device,
                         min_chunk=max(1, DEFAULT_MIN_CHUNK // block))
        return out.transpose()

    def backward(self, points: wp.array, table: wp.array, grad_enc: wp.array, out: wp.array | None = None,
                 pool: A.HostPool | None = None) -> wp.array:
        """dL/dtable (L T, F) for the cotangent grad_enc (N, L F), any strides (fastest as the transposed
        view of a contiguous (L F, N) array, which each level's launch reads contiguously). With `out`
        (a contiguous (L T, F) wp.array of the table's dtype and device, its contents overwritten) the
        gradient is written there and `out` is returned; without it, the new array is a block of `pool` when
        given (kernels.volume.mlp.empty_array)."""
        self._check(points, table)
        A.check_shape("grad_enc", grad_enc, (points.shape[0], self.n_outputs))
        if not isinstance(grad_enc, wp.array) or grad_enc.dtype != points.dtype or grad_enc.device != points.device:
            raise ValueError(f"grad_enc: expected a wp.array of {A.type_name(points.dtype)} on {points.device}")
        if out is None:
            grad = empty_array(self.table_shape, points.dtype, points.device, pool)
            grad.zero_()
        else:
            if (not isinstance(out, wp.array) or out.dtype != points.dtype or out.device != points.device
                    or not out.is_contiguous):
                raise ValueError(f"out: expected a contiguous wp.array of {A.type_name(points.dtype)} on "
                                 f"{points.device}")
            A.check_shape("out", out, self.table_shape)
            grad = out
            grad.zero_()
        if points.shape[0]:
            static = self._static(points.dtype, points.device)
            x = self._normalised(points, pool)

            block = _block(points.device)
            runs = -(-points.shape[0] // block)

            # F = 2 on the CPU: the same additions in the same order in C++ (kernels.volume.hashgrid_cpu)
            kernel = (backward_kernel(points.dtype) if points.device.is_cpu and self.n_features == 2 and fast_paths.enabled()
                      else _hash_backward_kernel)

            def level(l: int) -> None:
                wp.launch(kernel, dim=runs, inputs=[x, *static, grad_enc, grad, l, block],
                          device=points.device)

            if points.device.is_cuda:
                for l in range(self.n_levels):
                    level(l)
            else:  # levels on the launch threads, finest (slowest: hashed, cache-missing) first
                parallel_items(lambda i: level(self.n_levels - 1 - i), self.n_levels)
        return grad


A.declare_float_overloads(_normalise_kernel)
A.declare_float_overloads(_hash_forward_kernel)
A.declare_float_overloads(_hash_backward_kernel)
