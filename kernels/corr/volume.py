"""The all-pairs correlation volume (1) and its pyramid (2), with their adjoints.

Volume. With f1, f2 the (C, H, W) feature maps flattened to (C, N), N = H W,

    V = f1^T f2 / sqrt(C),    shape (N, N) seen as (H, W, H, W),                    (1)

and its adjoint for a cotangent dV = d loss / d V:

    d f1 = f2 dV^T / sqrt(C),    d f2 = f1 dV / sqrt(C).

All three are one product out = scale * a^T b, a GEMM. Two backends compute it:
  * "numpy" (the default on the CPU): BLAS (`np.matmul`) writing straight into
    the output wp.array's memory (a zero-copy NumPy view of a CPU array), with
    the scale applied to the smaller operand first, (scale a)^T b. A Warp CPU
    launch runs each thread's loop as scalar C++ on one core per launch
    (docs/warp.md); a tuned, cache-blocked, multi-threaded BLAS is several times
    faster on the same cores. Still pure compute: no file I/O, no other library.
  * "warp" (the default on CUDA, and selectable on the CPU): a blocked Warp
    kernel where each thread forms 4 rows x 16 columns of out, the columns as two
    8-wide vectors (b packed into vectors and zero-padded to a multiple of 16
    columns; a's columns padded to a multiple of 4). Its adjoint products
    transpose their operands first: d f1 = (f2^T)^T (dV^T), d f2 = (f1^T)^T dV.
The backends agree to float rounding (BLAS sums the C terms in its own order;
scaling an operand first is exact when sqrt(C) is a power of two, as for C = 256).

Pyramid. V^l pools V^{l-1} 2x2 over frame 2's two dimensions (2); its adjoint
is `_common.pool_levels_adjoint`.
"""

from __future__ import annotations

import math
import typing
from typing import Sequence

import numpy as np
import warp as wp

from kernels import fast_paths
from kernels._arrays import Inputs, declare_float_overloads
from kernels.corr._common import (VEC, VEC_OF, Array, check_levels, check_list, features_in, level_shapes,
                                  levels_in, pack_rows, pool_levels, pool_levels_adjoint, volume_in)

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

# Columns per thread of the blocked product: two vectors.
GEMM_COLS = 2 * VEC
GEMM_ROWS = 4


# --------------------------------------------------------------------------- kernels


@wp.func
def _store_col(out: wp.array2d(dtype=typing.Any), m0: int, col: int, v0: typing.Any, v1: typing.Any,
               v2: typing.Any, v3: typing.Any):
    """out[m0 + i, col] = v_i for the rows and column that exist."""
    if col < out.shape[1]:
        rows = out.shape[0]
        if m0 < rows:
            out[m0, col] = v0
        if m0 + 1 < rows:
            out[m0 + 1, col] = v1
        if m0 + 2 < rows:
            out[m0 + 2, col] = v2
        if m0 + 3 < rows:
            out[m0 + 3, col] = v3


@wp.func
def _block_terms(a: wp.array2d(dtype=typing.Any), b_v: wp.array2d(dtype=typing.Any), k: int, m0: int, jv: int):
    """Row k's terms of a 4 x 16 block: a[k, m0 + i] times b's vectors jv (s_i) and jv + 1 (t_i), i = 0..3."""
    b0 = b_v[k, jv]
    b1 = b_v[k, jv + 1]
    a0 = a[k, m0]
    a1 = a[k, m0 + 1]
    a2 = a[k, m0 + 2]
    a3 = a[k, m0 + 3]
    return a0 * b0, a1 * b0, a2 * b0, a3 * b0, a0 * b1, a1 * b1, a2 * b1, a3 * b1


@wp.kernel
def _gemm_tn(a: wp.array2d(dtype=typing.Any), b_v: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=typing.Any),
             scale: typing.Any, n_col_blocks: int, offset: int):
    """out[m, n] = scale * sum_k a[k, m] b[k, n] for a 4 x 16 block of (m, n) per thread."""
    t = wp.tid() + offset
    m0 = (t // n_col_blocks) * GEMM_ROWS
    jv = (t % n_col_blocks) * 2
    # a's columns are padded to a multiple of 4, so all four rows can be read (padding is not written).
    s0, s1, s2, s3, t0, t1, t2, t3 = _block_terms(a, b_v, 0, m0, jv)
    for k in range(1, a.shape[0]):
        p0, p1, p2, p3, q0, q1, q2, q3 = _block_terms(a, b_v, k, m0, jv)
        s0 += p0
        s1 += p1
        s2 += p2
        s3 += p3
        t0 += q0
        t1 += q1
        t2 += q2
        t3 += q3
    n0 = jv * VEC
    # Literal bounds: Warp unrolls these loops, so every vector index is static and the
    # accumulators stay in registers (a runtime index would force them to memory).
    for q in range(8):
        _store_col(out, m0, n0 + q, s0[q] * scale, s1[q] * scale, s2[q] * scale, s3[q] * scale)
        _store_col(out, m0, n0 + 8 + q, t0[q] * scale, t1[q] * scale, t2[q] * scale, t3[q] * scale)


@wp.kernel
def _copy_cols(x: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=typing.Any), offset: int):
    """out[:, :M] = x for x (K, M), which may be a strided view (a transpose), and an out at least as wide."""
    t = wp.tid() + offset
    i = t // x.shape[1]
    j = t % x.shape[1]
    out[i, j] = x[i, j]


for _k in (_gemm_tn, _copy_cols):
    declare_float_overloads(_k, vector_types=VEC_OF)


# --------------------------------------------------------------------------- product helpers


def _gemm_tn_wp(x: wp.array, y: wp.array, scale: float, a: Inputs) -> wp.array:
    """x^T y * scale for x (K, M), y (K, N): the blocked product."""
    k, m = x.shape
    n = y.shape[1]
    if m % GEMM_ROWS:
        x_pad = a.zeros((k, m + GEMM_ROWS - m % GEMM_ROWS))
        a.launch(_copy_cols, k * m, [x, x_pad])
        x = x_pad
    n_col_blocks = -(-n // GEMM_COLS)
    y_v = pack_rows(y, n_col_blocks * 2, a)
    out = a.empty((m, n))
    n_blocks = -(-m // GEMM_ROWS) * n_col_blocks
    a.launch(_gemm_tn, n_blocks, [x, y_v, out, a.s(scale), n_col_blocks])
    return out


BACKENDS = ("numpy", "warp")


def _backend(a: Inputs, backend: str | None) -> str:
    """The product's backend: the argument, else "numpy" on the CPU and "warp" on CUDA."""
    if backend is None:
        return "numpy" if fast_paths.on(a.device) else "warp"
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {', '.join(BACKENDS)} or None, got {backend!r}")
    if backend == "numpy" and not a.device.is_cpu:
        raise ValueError(f"backend: 'numpy' runs on the CPU only, got device {a.device}")
    return backend


def _gemm_blas(x: np.ndarray, y: np.ndarray, scale: float, a: Inputs, scale_x: bool = True) -> wp.array:
    """(scale x)^T y (or x^T (scale y) when not `scale_x`) by BLAS into a new CPU wp.array."""
    out = a.empty((x.shape[1], y.shape[1]))
    s = a.np_dtype.type(scale)
    if scale_x:
        x = x * s
    else:
        y = y * s
    np.matmul(x.T, y, out=out.numpy())
    return out


def _transpose_wp(x: wp.array, a: Inputs) -> wp.array:
    out = a.empty((x.shape[1], x.shape[0]))
    a.launch(_copy_cols, out.size, [x.transpose(), out])
    return out


def _feature_pair(a: Inputs, f1: Array, f2: Array) -> tuple[wp.array, wp.array, tuple[int, int, int]]:
    """f1 and f2 (C, H, W), alike, as (C, H W) wp.arrays, and (C, H, W)."""
    x1 = features_in(a, "f1", f1)
    shape = tuple(x1.shape)
    x2 = a.floats("f2", f2, shape)
    flat = (shape[0], shape[1] * shape[2])
    return x1.reshape(flat), x2.reshape(flat), shape


# --------------------------------------------------------------------------- entry points


def correlation_volume(f1: Array, f2: Array, *, device: str | None = None, backend: str | None = None) -> Array:
    """All-pairs volume (H, W, H, W) of (1): V[p, q] = f1[:, p] . f2[:, q] / sqrt(C).

    `backend`: "numpy" (BLAS, CPU only) or "warp"; None picks "numpy" on the CPU (module docstring)."""
    a = Inputs(device, f1, f2)
    x1, x2, (channels, height, width) = _feature_pair(a, f1, f2)
    inv = 1.0 / math.sqrt(channels)
    if _backend(a, backend) == "numpy":
        vol = _gemm_blas(x1.numpy(), x2.numpy(), inv, a)
    else:
        vol = _gemm_tn_wp(x1, x2, inv, a)
    return a.out(vol.reshape((height, width, height, width)))


def correlation_volume_backward(f1: Array, f2: Array, grad_volume: Array, *, device: str | None = None,
                                backend: str | None = None) -> dict[str, Array]:
    """Adjoint of (1). Returns a dict {"f1": d f1, "f2": d f2}, each (C, H, W), in f1's kind:
    d f1 = f2 dV^T / sqrt(C), d f2 = f1 dV / sqrt(C). `backend` as in `correlation_volume`."""
    a = Inputs(device, f1, f2, grad_volume)
    x1, x2, shape = _feature_pair(a, f1, f2)
    channels, height, width = shape
    n = height * width
    g = a.floats("grad_volume", grad_volume, (height, width, height, width)).reshape((n, n))
    inv = 1.0 / math.sqrt(channels)
    if _backend(a, backend) == "numpy":
        # d f1 (C, N1) = (inv f2^T)^T g^T;  d f2 (C, N2) = (inv f1^T)^T g: the scale on the small operand.
        g_np = g.numpy()
        grad_f1 = _gemm_blas(x2.numpy().T, g_np.T, inv, a)
        grad_f2 = _gemm_blas(x1.numpy().T, g_np, inv, a)
    else:
        # d f1 (C, N1) = f2 g^T = (f2^T)^T g^T;  d f2 (C, N2) = f1 g = (f1^T)^T g.
        grad_f1 = _gemm_tn_wp(_transpose_wp(x2, a), _transpose_wp(g, a), inv, a)
        grad_f2 = _gemm_tn_wp(_transpose_wp(x1, a), g, inv, a)
    return {"f1": a.out(grad_f1.reshape(shape)), "f2": a.out(grad_f2.reshape(shape))}


def correlation_pyramid(volume: Array, levels: int, *, device: str | None = None) -> list[Array]:
    """Levels V^0..V^{L-1} of (2), each (H, W, H_l, W_l), pooling frame 2's dimensions."""
    levels = check_levels(levels)
    a = Inputs(device, volume)
    vol = volume_in(a, "volume", volume, finite=False)  # see volume_in
    height, width = vol.shape[:2]
    check_levels(levels, height, width)
    out = pool_levels(vol.reshape((height * width, height, width)), levels, a)
    return [a.out(v.reshape((height, width, v.shape[1], v.shape[2]))) for v in out]


def correlation_pyramid_backward(grad_pyramid: Sequence[Array], *, device: str | None = None) -> dict[str, Array]:
    """Adjoint of (2) given a gradient (H, W, H_l, W_l) for every level. Returns a dict
    {"volume": the gradient (H, W, H, W) of V^0}, in grad_pyramid[0]'s kind."""
    check_list("grad_pyramid", grad_pyramid, "(H, W, H_l, W_l)")
    a = Inputs(device, *grad_pyramid)
    g0 = volume_in(a, "grad_pyramid[0]", grad_pyramid[0])
    height, width = g0.shape[:2]
    check_levels(len(grad_pyramid), height, width)
    grads = levels_in(a, "grad_pyramid", grad_pyramid, g0, (height, width), height, width)
    return {"volume": a.out(pool_levels_adjoint(grads, a).reshape((height, width, height, width)))}


def dense_bytes(height: int, width: int, levels: int, itemsize: int = 4) -> int:
    """Bytes of the stored volume pyramid: H W sum_l H_l W_l values."""
    return itemsize * height * width * sum(hl * wl for hl, wl in level_shapes(height, width, levels))
