"""Farthest-point sampling (PointNet++'s sampling layer).

For a cloud p_0 .. p_{N-1} and S <= N samples, starting from a given index (0 by default, as
PointNet++'s furthest_point_sampling kernel starts; Qi et al., "PointNet++", NeurIPS 2017):

    s_0 = start,   d_i^(0) = d2(p_i, p_{s_0}),
    s_t = argmax_i d_i^(t-1),   d_i^(t) = min(d_i^(t-1), d2(p_i, p_{s_t}))     for t = 1 .. S - 1,

with d2 the squared distance of kernels/points/grid.py (same order of operations) and ties of the
argmax broken by the smallest index, so the result is deterministic. Once every distinct point is
taken the remaining d_i are 0 and the argmax picks index 0 onwards of the points at distance 0: a
cloud with fewer than S distinct points repeats points, as PointNet++ does.

Each step is two launches that read the last sample from the device (no host round trip):
`_step_kernel` over B blocks of points updates d_i and writes the block's maximum and its first
index (each block its own slots); `_pick_kernel`, one thread, takes the first block maximum over the
B blocks and writes s_t. Both are recorded once and replayed S - 1 times (`wp.launch(record_cmd=True)`):
a replay costs a few microseconds where a split launch over CPU threads cost about 150 (20000 points,
256 samples: 47 ms split, 25 ms replayed, measured on the 2-core machine), so on the CPU the step runs
as one launch (one thread). No gradients: the result is indices.

CPU fast path (kernels.fast_paths): for a float32 cloud on the CPU the step's block runs in
C++ (kernels/native/fps_step.cpp, through `_step_cpu_kernel`) as plain loops that clang runs in vector
lanes: d_i = min(d_i, d2(p_i, p_{s_t})) with sq_dist's operations in its order, each its own statement
(so no multiply-add is fused where Warp fuses none), then the block's maximum and its first index.
Every d_i and every block's (maximum, first index) are the plain kernel's, so the samples are the same
indices, ties included (tests/kernels/test_fast_paths.py); `_pick_kernel` and the replays are shared.
It exists because the step is one thread by design and Warp's generated per-point loop is scalar: in
lanes the whole sampling is about 4.5x faster at 100000 points and 3.5x at 20000 (1024 and 256
samples alike; plain and fast runs interleaved on a shared 2-core AVX-512 machine). float64 and CUDA
run the plain kernels.
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A, fast_paths
from kernels.native import source
from kernels.points.grid import check_cloud, check_count, sq_dist

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _step_kernel(points: wp.array2d(dtype=typing.Any), mind: wp.array(dtype=typing.Any),
                 samples: wp.array(dtype=wp.int32), t: wp.array(dtype=wp.int32), block: int, n: int,
                 best: wp.array(dtype=typing.Any), best_i: wp.array(dtype=wp.int32), offset: int):
    b = wp.tid() + offset
    last = samples[t[0]]
    lx = points[last, 0]
    ly = points[last, 1]
    lz = points[last, 2]
    top = type(lx)(-1.0)
    top_i = int(-1)
    for i in range(b * block, wp.min((b + 1) * block, n)):
        d = wp.min(mind[i], sq_dist(points[i, 0], points[i, 1], points[i, 2], lx, ly, lz))
        mind[i] = d
        if d > top:  # strict: the first index of the block's maximum
            top = d
            top_i = i
    best[b] = top
    best_i[b] = top_i


@wp.kernel
def _pick_kernel(best: wp.array(dtype=typing.Any), best_i: wp.array(dtype=wp.int32), n_blocks: int,
                 samples: wp.array(dtype=wp.int32), t: wp.array(dtype=wp.int32)):
    top = best[0]
    top_i = best_i[0]
    for b in range(1, n_blocks):
        if best[b] > top:  # strict, blocks in index order: the first index of the maximum
            top = best[b]
            top_i = best_i[b]
    s = t[0] + 1
    samples[s] = top_i
    t[0] = s


for _k in (_step_kernel, _pick_kernel):
    A.declare_float_overloads(_k)


@wp.func_native(source("fps_step.cpp"))
def fps_step_f32(points: wp.array2d(dtype=wp.float32), mind: wp.array(dtype=wp.float32), last: int, lo: int,
                 hi: int, best: wp.array(dtype=wp.float32), best_i: wp.array(dtype=wp.int32), b: int): ...


@wp.kernel
def _step_cpu_kernel(points: wp.array2d(dtype=wp.float32), mind: wp.array(dtype=wp.float32),
                     samples: wp.array(dtype=wp.int32), t: wp.array(dtype=wp.int32), block: int, n: int,
                     best: wp.array(dtype=wp.float32), best_i: wp.array(dtype=wp.int32), offset: int):
    # `_step_kernel`'s block b in C++ (the CPU fast path; module docstring).
    b = wp.tid() + offset
    fps_step_f32(points, mind, samples[t[0]], b * block, wp.min((b + 1) * block, n), best, best_i, b)


# Points per block of `_step_kernel`: enough work per thread to amortise a CPU split launch.
BLOCK = 4096


def farthest_point_sampling(points: Any, n_samples: int, *, start: int = 0, device: Any = None) -> Any:
    """Indices (S,) int32 of S = `n_samples` farthest points of `points` (N, 3), from index `start`
    (module docstring). NumPy or wp.array, as `points`."""
    a = A.Inputs(device, points)
    pts = check_cloud(a, "points", points)
    n = int(pts.shape[0])
    s_count = check_count("n_samples", n_samples, 1, n)
    start = A.check_int("start", start, minimum=0, maximum=n - 1)
    dev = a.device
    samples = wp.array(np.full(s_count, start, np.int32), dtype=wp.int32, device=dev)
    t = wp.zeros(1, dtype=wp.int32, device=dev)
    mind = wp.array(np.full(n, np.finfo(a.np_dtype).max, a.np_dtype), dtype=a.scalar, device=dev)
    block = BLOCK if dev.is_cpu else 256
    n_blocks = (n + block - 1) // block
    best = a.empty(n_blocks)
    best_i = a.empty(n_blocks, dtype=wp.int32)
    # Both launches are recorded once and replayed: their arguments never change (the step reads the
    # last sample from the device), and a replay costs microseconds where wp.launch costs tens.
    fast = pts.dtype == wp.float32 and fast_paths.on(dev)  # inputs are contiguous (kernels._arrays)
    step_kernel = _step_cpu_kernel if fast else _step_kernel
    step = wp.launch(step_kernel, dim=n_blocks, inputs=[pts, mind, samples, t, block, n, best, best_i, 0],
                     device=dev, record_cmd=True)
    pick = wp.launch(_pick_kernel, dim=1, inputs=[best, best_i, n_blocks, samples, t], device=dev, record_cmd=True)
    for _ in range(s_count - 1):
        step.launch()
        pick.launch()
    return a.out(samples)
