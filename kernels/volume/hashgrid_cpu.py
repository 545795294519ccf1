"""The hash encoding's forward and scatter on the CPU in C++, several points at a time (kernels.volume.hashgrid).

The C++ is in kernels/native/hashgrid_encode.cpp and hashgrid_scatter.cpp (their shared set-up and
cells in hashgrid_common.h and hashgrid_cells.h), loaded by `kernels.native.source`.

Same math and the same operations as `hashgrid._hash_forward_kernel` (F = 2), on the same values, so
the same outputs bit for bit. For the normalised coordinates x (3, N) and level l of resolution N_l:

    u = x N_l,  i = clamp(floor(u), 0, N_l - 1),  f = u - i                     (per axis)
    w_c = (w_x w_y) w_z with w_a = f_a or 1 - f_a by bit a of corner c = 0 .. 7
    enc[2 l + j, n] = (...((0 + w_0 t_0j) + w_1 t_1j) + ...) + w_7 t_7j,  t_cj = table[row_c, j]

with row_c the level's dense index or spatial hash of corner c (hashgrid.hash_index), each product
and each sum a separate C++ statement (so the compiler fuses no multiply-add, as in Warp's generated
code).

Why C++. With the tables in the cache Warp's scalar code still took 0.48 s for 1M points x 16
levels on one thread: per point and level ~190 instructions (the cell, 8 weights, 8 rows with
runtime-strided 2-index addresses, 16 loads, 16 products and sums), bound by arithmetic, not by the
table's cache misses (docs/performance.md, "CPU fast paths", has what the C++ gains). Here a
thread's run of points is taken K = 8 at a time, each step a loop over the 8 points with a fixed
trip count (the cells, the rows, the weights, the sums), which the compiler turns into vector
instructions; only the 16 table reads per point stay scalar loads. A last group of fewer than 8
points repeats its first point in the unused lanes and stores only its own.

The scatter (`_hash_backward_kernel`, F = 2) computes the cells, rows and weights of 8 points the same
way, then adds w_c G[n, 2 l + j] into the table's gradient one point after the other, corners
c = 0 .. 7, feature 0 then 1: the Warp kernel's additions in its order (a CPU atomic add is a plain
read-modify-write, docs/warp.md), so the same gradient bit for bit, collisions included.

`forward_kernel(scalar)` and `backward_kernel(scalar)` build the kernels once per float type (their
own Warp module, compiled on first use), with the arguments of `_hash_forward_kernel` and
`_hash_backward_kernel`; they are launched on the CPU only, for F = 2 (CUDA and other F keep the
Warp kernels).
"""

from typing import Any

import warp as wp

from kernels.native import built_once, source

_kernels: dict = {}


def forward_kernel(scalar: Any) -> Any:
    """The C++ encode kernel for float type `scalar` (module docstring), built once."""
    return _built(scalar)[0]


def backward_kernel(scalar: Any) -> Any:
    """The C++ scatter kernel for float type `scalar` (module docstring), built once."""
    return _built(scalar)[1]


def _built(scalar: Any) -> Any:
    return built_once(_kernels, scalar, lambda: _build(scalar))


def _native(stub: Any, name: str, scalar: Any, body: str) -> Any:
    """The Warp native function of `stub`'s signature whose body is the C++ `body` (a kernels/native file's
    `source`), named <name>_<scalar> (a name of its own per type: Warp keys native functions by name)."""
    stub.__name__ = stub.__qualname__ = f"{name}_{scalar.__name__}"
    return wp.func_native(body)(stub)


def _build(scalar: Any) -> Any:
    # No `from __future__ import annotations` in this module: Warp reads the stub's and the kernel's
    # annotations as objects, and these name the closure's types.
    array2 = wp.array2d(dtype=scalar)

    def encode_run(x: array2, table: array2, out: array2, l: int, res: int, dense: int, table_size: int,
                   lo: int, hi: int, zero: scalar): ...

    encode_run = _native(encode_run, "hash_encode_run_cpu", scalar, source("hashgrid_encode.cpp"))

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def hash_forward_cpu(x: array2, resolutions: wp.array(dtype=wp.int32), dense: wp.array(dtype=wp.int32),
                         table_size: int, table: array2, out: array2, block: int, offset: int):
        # thread = a run of `block` consecutive points of one level, level-major (as _hash_forward_kernel)
        t = wp.tid() + offset
        n_points = x.shape[1]
        n_runs = (n_points + block - 1) / block
        l = t / n_runs
        run = t - l * n_runs
        encode_run(x, table, out, l, resolutions[l], dense[l], table_size, run * block,
                   wp.min(n_points, (run + 1) * block), scalar(0.0))

    def scatter_run(x: array2, grad_out: array2, table: array2, l: int, res: int, dense: int, table_size: int,
                    lo: int, hi: int, zero: scalar): ...

    scatter_run = _native(scatter_run, "hash_scatter_run_cpu", scalar, source("hashgrid_scatter.cpp"))

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def hash_backward_cpu(x: array2, resolutions: wp.array(dtype=wp.int32), dense: wp.array(dtype=wp.int32),
                          table_size: int, grad_out: array2, grad_table: array2, level: int, block: int):
        # one launch per level; thread b = the run of points b block .. (b + 1) block - 1, in order
        b = wp.tid()
        scatter_run(x, grad_out, grad_table, level, resolutions[level], dense[level], table_size, b * block,
                    wp.min(x.shape[1], (b + 1) * block), scalar(0.0))

    return hash_forward_cpu, hash_backward_cpu
