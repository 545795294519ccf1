"""The hash encoding's forward and scatter on the CPU in C++, several points at a time (kernels.volume.hashgrid).

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
table's cache misses (docs/performance.md). Here a thread's run of points is taken K = 8 at a time,
each step a loop over the 8 points with a fixed trip count (the cells, the rows, the weights, the
sums), which the compiler turns into vector instructions; only the 16 table reads per point stay
scalar loads. A last group of fewer than 8 points repeats its first point in the unused lanes and
stores only its own.

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

from kernels._native import built_once

_HEAD = r"""
    typedef decltype(zero) T;
    const int K = 8;
    const char* xb = reinterpret_cast<const char*>(x.data);
    const long long xs0 = x.strides[0];
    const long long xs1 = x.strides[1];
    const char* tb = reinterpret_cast<const char*>(table.data);
    const long long ts0 = table.strides[0];
    const long long ts1 = table.strides[1];
    const T rf = T(res);
    const int r1 = res + 1;
    const unsigned int mask = (unsigned int)(table_size - 1);
    const int base = l * table_size;
"""

# The cells, fractions and table rows of the points n0 .. n0 + m - 1 (K lanes).
_CELLS = r"""
        const int m = hi - n0 < K ? hi - n0 : K;
        int ix[K], iy[K], iz[K];
        T fx[K], fy[K], fz[K];
        _Pragma("unroll") for (int k = 0; k < K; ++k) {
            const long long n = n0 + (k < m ? k : 0);
            const T ux = *reinterpret_cast<const T*>(xb + n * xs1) * rf;
            const T uy = *reinterpret_cast<const T*>(xb + xs0 + n * xs1) * rf;
            const T uz = *reinterpret_cast<const T*>(xb + 2 * xs0 + n * xs1) * rf;
            const int a = wp::clamp((int)wp::floor(ux), 0, res - 1);
            const int b = wp::clamp((int)wp::floor(uy), 0, res - 1);
            const int c = wp::clamp((int)wp::floor(uz), 0, res - 1);
            ix[k] = a;
            iy[k] = b;
            iz[k] = c;
            fx[k] = ux - T(a);
            fy[k] = uy - T(b);
            fz[k] = uz - T(c);
        }
        int row[8][K];
        if (dense) {
            _Pragma("unroll") for (int c = 0; c < 8; ++c) {
                _Pragma("unroll") for (int k = 0; k < K; ++k) {
                    row[c][k] = base + ((ix[k] + (c & 1))
                                        + r1 * ((iy[k] + ((c >> 1) & 1)) + r1 * (iz[k] + ((c >> 2) & 1))));
                }
            }
        } else {
            _Pragma("unroll") for (int c = 0; c < 8; ++c) {
                _Pragma("unroll") for (int k = 0; k < K; ++k) {
                    const unsigned int h = (unsigned int)(ix[k] + (c & 1))
                                           ^ ((unsigned int)(iy[k] + ((c >> 1) & 1)) * 2654435761u)
                                           ^ ((unsigned int)(iz[k] + ((c >> 2) & 1)) * 805459861u);
                    row[c][k] = base + (int)(h & mask);
                }
            }
        }
"""

_ENCODE_CPP = _HEAD + r"""
    for (int n0 = lo; n0 < hi; n0 += K) {
""" + _CELLS + r"""        T s0[K], s1[K];
        _Pragma("unroll") for (int k = 0; k < K; ++k) {
            s0[k] = T(0);
            s1[k] = T(0);
        }
        _Pragma("unroll") for (int c = 0; c < 8; ++c) {
            _Pragma("unroll") for (int k = 0; k < K; ++k) {
                const T wx = (c & 1) ? fx[k] : T(1) - fx[k];
                const T wy = ((c >> 1) & 1) ? fy[k] : T(1) - fy[k];
                const T wz = ((c >> 2) & 1) ? fz[k] : T(1) - fz[k];
                const T wxy = wx * wy;
                const T w = wxy * wz;
                const char* r = tb + (long long)row[c][k] * ts0;
                const T t0 = *reinterpret_cast<const T*>(r);
                const T t1 = *reinterpret_cast<const T*>(r + ts1);
                const T p0 = w * t0;
                const T p1 = w * t1;
                s0[k] = s0[k] + p0;
                s1[k] = s1[k] + p1;
            }
        }
        char* ob = reinterpret_cast<char*>(out.data);
        const long long os1 = out.strides[1];
        char* o0 = ob + (long long)(2 * l) * out.strides[0];
        char* o1 = o0 + out.strides[0];
        for (int k = 0; k < m; ++k) {
            *reinterpret_cast<T*>(o0 + (long long)(n0 + k) * os1) = s0[k];
            *reinterpret_cast<T*>(o1 + (long long)(n0 + k) * os1) = s1[k];
        }
    }
"""

# The scatter: the rows and weights of 8 points at a time, then the additions one point after the other,
# corners c = 0 .. 7, feature 0 then 1 (the Warp kernel's order; `table` is the table's gradient).
_SCATTER_CPP = _HEAD + r"""
    char* gb = reinterpret_cast<char*>(table.data);
    const char* gob = reinterpret_cast<const char*>(grad_out.data);
    const long long g0 = (long long)(2 * l) * grad_out.strides[1];
    const long long g1 = g0 + grad_out.strides[1];
    const long long gs0 = grad_out.strides[0];
    for (int n0 = lo; n0 < hi; n0 += K) {
""" + _CELLS + r"""        T w[8][K];
        _Pragma("unroll") for (int c = 0; c < 8; ++c) {
            _Pragma("unroll") for (int k = 0; k < K; ++k) {
                const T wx = (c & 1) ? fx[k] : T(1) - fx[k];
                const T wy = ((c >> 1) & 1) ? fy[k] : T(1) - fy[k];
                const T wz = ((c >> 2) & 1) ? fz[k] : T(1) - fz[k];
                const T wxy = wx * wy;
                w[c][k] = wxy * wz;
            }
        }
        for (int k = 0; k < m; ++k) {
            const char* go = gob + (long long)(n0 + k) * gs0;
            const T a0 = *reinterpret_cast<const T*>(go + g0);
            const T a1 = *reinterpret_cast<const T*>(go + g1);
            _Pragma("unroll") for (int c = 0; c < 8; ++c) {
                char* r = gb + (long long)row[c][k] * ts0;
                T* t0 = reinterpret_cast<T*>(r);
                T* t1 = reinterpret_cast<T*>(r + ts1);
                const T p0 = w[c][k] * a0;
                *t0 = *t0 + p0;
                const T p1 = w[c][k] * a1;
                *t1 = *t1 + p1;
            }
        }
    }
"""

_kernels: dict = {}


def forward_kernel(scalar: Any) -> Any:
    """The C++ encode kernel for float type `scalar` (module docstring), built once."""
    return _built(scalar)[0]


def backward_kernel(scalar: Any) -> Any:
    """The C++ scatter kernel for float type `scalar` (module docstring), built once."""
    return _built(scalar)[1]


def _built(scalar: Any) -> Any:
    return built_once(_kernels, scalar, lambda: _build(scalar))


def _build(scalar: Any) -> Any:
    # No `from __future__ import annotations` in this module: Warp reads the stub's and the kernel's
    # annotations as objects, and these name the closure's types.
    array2 = wp.array2d(dtype=scalar)

    def encode_run(x: array2, table: array2, out: array2, l: int, res: int, dense: int, table_size: int,
                   lo: int, hi: int, zero: scalar): ...

    # A name of its own per type: Warp keys native functions by name.
    encode_run.__name__ = encode_run.__qualname__ = f"hash_encode_run_cpu_{scalar.__name__}"
    encode_run = wp.func_native(_ENCODE_CPP)(encode_run)

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

    scatter_run.__name__ = scatter_run.__qualname__ = f"hash_scatter_run_cpu_{scalar.__name__}"
    scatter_run = wp.func_native(_SCATTER_CPP)(scatter_run)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def hash_backward_cpu(x: array2, resolutions: wp.array(dtype=wp.int32), dense: wp.array(dtype=wp.int32),
                          table_size: int, grad_out: array2, grad_table: array2, level: int, block: int):
        # one launch per level; thread b = the run of points b block .. (b + 1) block - 1, in order
        b = wp.tid()
        scatter_run(x, grad_out, grad_table, level, resolutions[level], dense[level], table_size, b * block,
                    wp.min(x.shape[1], (b + 1) * block), scalar(0.0))

    return hash_forward_cpu, hash_backward_cpu
