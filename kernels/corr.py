"""RAFT's correlation machinery: all-pairs volume, pyramid, windowed lookups, and an on-the-fly path.

Follows Teed and Deng, "RAFT: Recurrent All-Pairs Field Transforms for Optical
Flow" (ECCV 2020), section 3.2 and its CorrBlock / AlternateCorrBlock.

Features. f1 and f2 are (C, H, W) feature maps of the two frames; p = (h, w) is
a pixel of frame 1 and q = (h', w') a pixel of frame 2.

All-pairs volume (H, W, H, W):

    V[p, q] = sum_c f1[c, p] f2[c, q] / sqrt(C).                          (1)

Pyramid. V^0 = V and, pooling 2x2 over frame 2's dimensions only,

    V^l[p, h', w'] = 1/4 sum_{a, b in {0, 1}} V^{l-1}[p, 2h' + a, 2w' + b],   (2)

of shape (H, W, H >> l, W >> l) (odd trailing rows and columns are dropped, as
avg_pool2d does). Pooling is linear in f2, so V^l equals (1) computed with
f2 pooled l times, P^l(f2): the on-the-fly path below rests on that identity.

Coordinates. coords (2, H, W) holds, for each pixel of frame 1, a continuous
position (x, y) in frame 2 in the project's convention: x right, y down, the
centre of pixel (h', w') at (w' + 0.5, h' + 0.5). At level l the position is
(x, y) / 2^l, which is exact for 2x2 pooling with this convention (RAFT indexes
pixel centres at integers, so its coarser levels sit (1 - 2^-l)/2 level-l pixels
off; at level 0 our lookup at coords equals RAFT's at coords - 0.5).

Bilinear sampling with zeros outside. A level-l map S (H_l, W_l) sampled at
(x, y): with u = x - 1/2, v = y - 1/2, i = floor(u), j = floor(v),
fx = u - i, fy = v - j,

    S(x, y) = (1-fx)(1-fy) S[j, i] + fx (1-fy) S[j, i+1]
            + (1-fx) fy S[j+1, i] + fx fy S[j+1, i+1],                     (3)

where every tap outside [0, H_l) x [0, W_l) counts as 0 (grid_sample's zero
padding, tap by tap).

Lookup with radius r. For each level l and offsets a, b in {0, ..., 2r},

    out[l (2r+1)^2 + a (2r+1) + b, p] = V^l[p](x_p / 2^l + a - r, y_p / 2^l + b - r).   (4)

This is RAFT's channel order: levels outermost, and within a level the x offset
varies slowest (RAFT stacks meshgrid(dy, dx) and adds its first component to x).
All (2r+1)^2 samples of a level share fx and fy, so they read the
(2r+2) x (2r+2) tap patch starting at (floor(u0), floor(v0)), u0 = x/2^l - 1/2 - r.

Backward of (4), with cotangent g = d loss / d out:
  * to the pyramid: d V^l[p, tap] += (weight of tap in (3)) g, scattered into row p
    only, so per-pixel threads never collide;
  * to the coordinates: d x_p += 2^-l sum_{a,b} g ((1-fy)(S[j,i+1] - S[j,i]) + fy (S[j+1,i+1] - S[j+1,i])),
    and the same for y with the roles of x and y swapped. (3) is piecewise
    bilinear: its derivative jumps where u or v crosses an integer;
  * through (2): d V^{l-1}[p, 2h'+a, 2w'+b] += d V^l[p, h', w'] / 4;
  * through (1): d f1 = f2 dV^T / sqrt(C) and d f2 = f1 dV / sqrt(C) (per pixel).

On the fly ("alternate"). The same output (4) from f1 and the pooled features
P^l(f2) without storing V: for each pixel and level, the (2r+2)^2 tap patch
T[p, ty, tx] = f1[:, p] . P^l(f2)[:, tap] / sqrt(C) is computed, then sampled by
(3). Memory is one patch buffer of H W (2r+2)^2 values instead of the whole
pyramid's H W sum_l H_l W_l. Its backward recomputes the patch, forms
d T from g and (3), then d f1[:, p] = sum_tap dT P^l(f2)[:, tap] / sqrt(C) (a
gather per pixel) and d P^l(f2)[:, tap] = sum_p dT f1[:, p] / sqrt(C), a scatter
across pixels: on the CPU each thread accumulates into its own buffer and the
buffers are summed afterwards (notes/warp.md: float atomics race between CPU
launches). d f2 then follows by the adjoint of the pooling, `pool_features_backward`.

Layout and speed. The volume is a blocked matrix product: each thread computes
4 rows x 16 columns, the columns as two 8-wide vectors (f2 padded to a multiple
of 16 pixels), which the CPU compiler turns into SIMD. The on-the-fly path keeps
features channels-last in 8-wide vectors (channels zero-padded to a multiple of 8).

Entry points take NumPy arrays or wp.arrays (float32 or float64, one dtype for
all inputs) and return the same kind on the same device. Every argument is
checked before any launch; bad input raises ValueError naming the argument.
Warp's own autodiff is off for this module: every backward here is written by hand.
"""

from __future__ import annotations

import math
import typing
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Sequence

import numpy as np
import warp as wp

from kernels.launch import chunk_bounds, default_threads, launch_split

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

VEC = 8  # SIMD width of the vector types below
vec8f = wp.types.vector(length=VEC, dtype=wp.float32)
vec8d = wp.types.vector(length=VEC, dtype=wp.float64)
_VEC_OF = {wp.float32: vec8f, wp.float64: vec8d}
_SCALAR_OF_NP = {np.dtype(np.float32): wp.float32, np.dtype(np.float64): wp.float64}
# Columns per thread of the blocked product: two vectors.
GEMM_COLS = 2 * VEC
GEMM_ROWS = 4

Array = Any  # np.ndarray or wp.array


# --------------------------------------------------------------------------- shared device functions


@wp.func
def _tap(s: wp.array3d(dtype=typing.Any), p: int, row: int, col: int):
    """S[p, row, col], or 0 outside the level's image."""
    if row < 0 or col < 0 or row >= s.shape[1] or col >= s.shape[2]:
        return s.dtype(0.0)
    return s[p, row, col]


@wp.func
def _window_origin(coords: wp.array3d(dtype=typing.Any), axis: int, h: int, w: int, scale: typing.Any, radius: int):
    """Integer tap origin and fraction of the window's first sample: coords[axis, h, w] * scale - 1/2 - r split."""
    u0 = coords[axis, h, w] * scale - coords.dtype(0.5) - coords.dtype(radius)
    i0 = wp.floor(u0)
    return int(i0), u0 - i0


# --------------------------------------------------------------------------- the all-pairs product


@wp.kernel
def _pack_rows_v(x: wp.array2d(dtype=typing.Any), out_v: wp.array2d(dtype=typing.Any), offset: int):
    """out_v[k, j] = x[k, 8j : 8j + 8] as one vector, zero past x's last column."""
    t = wp.tid() + offset
    k = t // out_v.shape[1]
    j = t % out_v.shape[1]
    v = out_v.dtype()
    for t in range(VEC):
        col = j * VEC + t
        if col < x.shape[1]:
            v[t] = x[k, col]
    out_v[k, j] = v


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


@wp.kernel
def _gemm_tn(
    a: wp.array2d(dtype=typing.Any),
    b_v: wp.array2d(dtype=typing.Any),
    out: wp.array2d(dtype=typing.Any),
    scale: typing.Any,
    n_col_blocks: int,
    offset: int,
):
    """out[m, n] = scale * sum_k a[k, m] b[k, n] for a 4 x 16 block of (m, n) per thread."""
    t = wp.tid() + offset
    m0 = (t // n_col_blocks) * GEMM_ROWS
    jv = (t % n_col_blocks) * 2
    # a's columns are padded to a multiple of 4, so all four rows can be read (padding is not written).
    r0 = m0
    r1 = m0 + 1
    r2 = m0 + 2
    r3 = m0 + 3
    b0 = b_v[0, jv]
    b1 = b_v[0, jv + 1]
    a0 = a[0, r0]
    a1 = a[0, r1]
    a2 = a[0, r2]
    a3 = a[0, r3]
    s0 = a0 * b0
    s1 = a1 * b0
    s2 = a2 * b0
    s3 = a3 * b0
    t0 = a0 * b1
    t1 = a1 * b1
    t2 = a2 * b1
    t3 = a3 * b1
    for k in range(1, a.shape[0]):
        b0 = b_v[k, jv]
        b1 = b_v[k, jv + 1]
        a0 = a[k, r0]
        a1 = a[k, r1]
        a2 = a[k, r2]
        a3 = a[k, r3]
        s0 += a0 * b0
        s1 += a1 * b0
        s2 += a2 * b0
        s3 += a3 * b0
        t0 += a0 * b1
        t1 += a1 * b1
        t2 += a2 * b1
        t3 += a3 * b1
    n0 = jv * VEC
    # Literal bounds: Warp unrolls these loops, so every vector index is static and the
    # accumulators stay in registers (a runtime index would force them to memory).
    for q in range(8):
        _store_col(out, m0, n0 + q, s0[q] * scale, s1[q] * scale, s2[q] * scale, s3[q] * scale)
        _store_col(out, m0, n0 + 8 + q, t0[q] * scale, t1[q] * scale, t2[q] * scale, t3[q] * scale)


@wp.kernel
def _copy_cols(x: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=typing.Any), offset: int):
    """out[:, :M] = x for x (K, M) and a wider out."""
    t = wp.tid() + offset
    i = t // x.shape[1]
    j = t % x.shape[1]
    out[i, j] = x[i, j]


@wp.kernel
def _transpose(x: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=typing.Any), offset: int):
    t = wp.tid() + offset
    i = t // x.shape[0]
    j = t % x.shape[0]
    out[i, j] = x[j, i]


# --------------------------------------------------------------------------- 2x2 average pooling


@wp.kernel
def _pool2x2(x: wp.array3d(dtype=typing.Any), out: wp.array3d(dtype=typing.Any), offset: int):
    """out[n, h, w] = mean of x[n, 2h : 2h + 2, 2w : 2w + 2]  (equation (2))."""
    t = wp.tid() + offset
    per = out.shape[1] * out.shape[2]
    n = t // per
    h = (t % per) // out.shape[2]
    w = t % out.shape[2]
    s = x[n, 2 * h, 2 * w] + x[n, 2 * h, 2 * w + 1] + x[n, 2 * h + 1, 2 * w] + x[n, 2 * h + 1, 2 * w + 1]
    out[n, h, w] = s * x.dtype(0.25)


@wp.kernel
def _pool2x2_adjoint_add(g_coarse: wp.array3d(dtype=typing.Any), g_fine: wp.array3d(dtype=typing.Any), offset: int):
    """g_fine[n, h, w] += g_coarse[n, h // 2, w // 2] / 4 where that coarse pixel exists (adjoint of (2))."""
    t = wp.tid() + offset
    per = g_fine.shape[1] * g_fine.shape[2]
    n = t // per
    h = (t % per) // g_fine.shape[2]
    w = t % g_fine.shape[2]
    hc = h // 2
    wc = w // 2
    if hc < g_coarse.shape[1] and wc < g_coarse.shape[2]:
        g_fine[n, h, w] = g_fine[n, h, w] + g_coarse[n, hc, wc] * g_fine.dtype(0.25)


# --------------------------------------------------------------------------- dense lookup


@wp.kernel
def _lookup_level(
    vol: wp.array3d(dtype=typing.Any),
    coords: wp.array3d(dtype=typing.Any),
    out: wp.array3d(dtype=typing.Any),
    scale: typing.Any,
    radius: int,
    channel0: int,
    offset: int,
):
    """Equation (4) for one level and one x offset a; thread = pixel * (2r+1) + a."""
    t = wp.tid() + offset
    side = 2 * radius + 1
    p = t // side
    a = t % side
    width = coords.shape[2]
    h = p // width
    w = p % width
    i0, fx = _window_origin(coords, 0, h, w, scale, radius)
    j0, fy = _window_origin(coords, 1, h, w, scale, radius)
    one = coords.dtype(1.0)
    col = i0 + a
    # Sample b's lower taps are sample b + 1's upper taps: each row of taps is read once.
    top = (one - fx) * _tap(vol, p, j0, col) + fx * _tap(vol, p, j0, col + 1)
    for b in range(side):
        row = j0 + b + 1
        bottom = (one - fx) * _tap(vol, p, row, col) + fx * _tap(vol, p, row, col + 1)
        out[channel0 + a * side + b, h, w] = (one - fy) * top + fy * bottom
        top = bottom


@wp.func
def _scatter_tap(g: wp.array3d(dtype=typing.Any), p: int, row: int, col: int, value: typing.Any):
    if row >= 0 and col >= 0 and row < g.shape[1] and col < g.shape[2]:
        g[p, row, col] = g[p, row, col] + value


@wp.kernel
def _lookup_level_adjoint(
    vol: wp.array3d(dtype=typing.Any),
    coords: wp.array3d(dtype=typing.Any),
    grad_out: wp.array3d(dtype=typing.Any),
    grad_vol: wp.array3d(dtype=typing.Any),
    grad_coords: wp.array3d(dtype=typing.Any),
    scale: typing.Any,
    radius: int,
    channel0: int,
    offset: int,
):
    """Adjoint of (4) for one level; thread = pixel. Writes row p of grad_vol and pixel p of grad_coords only."""
    p = wp.tid() + offset
    side = 2 * radius + 1
    width = coords.shape[2]
    h = p // width
    w = p % width
    i0, fx = _window_origin(coords, 0, h, w, scale, radius)
    j0, fy = _window_origin(coords, 1, h, w, scale, radius)
    one = coords.dtype(1.0)
    gx = coords.dtype(0.0)
    gy = coords.dtype(0.0)
    for a in range(side):
        col = i0 + a
        for b in range(side):
            row = j0 + b
            g = grad_out[channel0 + a * side + b, h, w]
            s00 = _tap(vol, p, row, col)
            s01 = _tap(vol, p, row, col + 1)
            s10 = _tap(vol, p, row + 1, col)
            s11 = _tap(vol, p, row + 1, col + 1)
            gx += g * ((one - fy) * (s01 - s00) + fy * (s11 - s10))
            gy += g * ((one - fx) * (s10 - s00) + fx * (s11 - s01))
            _scatter_tap(grad_vol, p, row, col, (one - fx) * (one - fy) * g)
            _scatter_tap(grad_vol, p, row, col + 1, fx * (one - fy) * g)
            _scatter_tap(grad_vol, p, row + 1, col, (one - fx) * fy * g)
            _scatter_tap(grad_vol, p, row + 1, col + 1, fx * fy * g)
    grad_coords[0, h, w] = grad_coords[0, h, w] + gx * scale
    grad_coords[1, h, w] = grad_coords[1, h, w] + gy * scale


# --------------------------------------------------------------------------- on-the-fly lookup


@wp.kernel
def _pack_channels_last_v(x: wp.array2d(dtype=typing.Any), out_v: wp.array2d(dtype=typing.Any), offset: int):
    """out_v[n, j] = x[8j : 8j + 8, n] as one vector (x is (C, N)); channels past C are 0."""
    t = wp.tid() + offset
    n = t // out_v.shape[1]
    j = t % out_v.shape[1]
    v = out_v.dtype()
    for k in range(VEC):
        c = j * VEC + k
        if c < x.shape[0]:
            v[k] = x[c, n]
    out_v[n, j] = v


@wp.kernel
def _unpack_channels_last_v(x_v: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=typing.Any), offset: int):
    """Inverse of _pack_channels_last_v: out (C, N)."""
    t = wp.tid() + offset
    c = t // out.shape[1]
    n = t % out.shape[1]
    out[c, n] = x_v[n, c // VEC][c % VEC]


@wp.func
def _dot_v(a_v: wp.array2d(dtype=typing.Any), i: int, b_v: wp.array2d(dtype=typing.Any), j: int):
    acc = wp.cw_mul(a_v[i, 0], b_v[j, 0])
    for k in range(1, a_v.shape[1]):
        acc += wp.cw_mul(a_v[i, k], b_v[j, k])
    s = acc[0]
    for q in range(1, VEC):
        s += acc[q]
    return s


@wp.kernel
def _patch_level(
    f1_v: wp.array2d(dtype=typing.Any),
    f2l_v: wp.array2d(dtype=typing.Any),
    coords: wp.array3d(dtype=typing.Any),
    patch: wp.array3d(dtype=typing.Any),
    height_l: int,
    width_l: int,
    scale: typing.Any,
    radius: int,
    inv_sqrt_c: typing.Any,
    offset: int,
):
    """patch[p, ty, tx] = f1[:, p] . P^l(f2)[:, tap] / sqrt(C), 0 outside; thread = pixel * (2r+2) + ty."""
    t = wp.tid() + offset
    side = 2 * radius + 2
    p = t // side
    ty = t % side
    width = coords.shape[2]
    h = p // width
    w = p % width
    i0, fx = _window_origin(coords, 0, h, w, scale, radius)
    j0, fy = _window_origin(coords, 1, h, w, scale, radius)
    row = j0 + ty
    for tx in range(side):
        col = i0 + tx
        v = coords.dtype(0.0)
        if row >= 0 and col >= 0 and row < height_l and col < width_l:
            v = _dot_v(f1_v, p, f2l_v, row * width_l + col) * inv_sqrt_c
        patch[p, ty, tx] = v


@wp.kernel
def _sample_patch(
    patch: wp.array3d(dtype=typing.Any),
    coords: wp.array3d(dtype=typing.Any),
    out: wp.array3d(dtype=typing.Any),
    scale: typing.Any,
    radius: int,
    channel0: int,
    offset: int,
):
    """Equation (4) from the tap patch; thread = pixel * (2r+1) + a."""
    t = wp.tid() + offset
    side = 2 * radius + 1
    p = t // side
    a = t % side
    width = coords.shape[2]
    h = p // width
    w = p % width
    i0, fx = _window_origin(coords, 0, h, w, scale, radius)
    j0, fy = _window_origin(coords, 1, h, w, scale, radius)
    one = coords.dtype(1.0)
    top = (one - fx) * patch[p, 0, a] + fx * patch[p, 0, a + 1]
    for b in range(side):
        bottom = (one - fx) * patch[p, b + 1, a] + fx * patch[p, b + 1, a + 1]
        out[channel0 + a * side + b, h, w] = (one - fy) * top + fy * bottom
        top = bottom


@wp.kernel
def _sample_patch_adjoint(
    patch: wp.array3d(dtype=typing.Any),
    coords: wp.array3d(dtype=typing.Any),
    grad_out: wp.array3d(dtype=typing.Any),
    grad_patch: wp.array3d(dtype=typing.Any),
    grad_coords: wp.array3d(dtype=typing.Any),
    scale: typing.Any,
    radius: int,
    channel0: int,
    offset: int,
):
    """Adjoint of _sample_patch; thread = pixel. Overwrites row p of grad_patch, adds into pixel p of grad_coords."""
    p = wp.tid() + offset
    side = 2 * radius + 1
    width = coords.shape[2]
    h = p // width
    w = p % width
    i0, fx = _window_origin(coords, 0, h, w, scale, radius)
    j0, fy = _window_origin(coords, 1, h, w, scale, radius)
    one = coords.dtype(1.0)
    zero = coords.dtype(0.0)
    for ty in range(side + 1):
        for tx in range(side + 1):
            grad_patch[p, ty, tx] = zero
    gx = zero
    gy = zero
    for a in range(side):
        for b in range(side):
            g = grad_out[channel0 + a * side + b, h, w]
            s00 = patch[p, b, a]
            s01 = patch[p, b, a + 1]
            s10 = patch[p, b + 1, a]
            s11 = patch[p, b + 1, a + 1]
            gx += g * ((one - fy) * (s01 - s00) + fy * (s11 - s10))
            gy += g * ((one - fx) * (s10 - s00) + fx * (s11 - s01))
            grad_patch[p, b, a] = grad_patch[p, b, a] + (one - fx) * (one - fy) * g
            grad_patch[p, b, a + 1] = grad_patch[p, b, a + 1] + fx * (one - fy) * g
            grad_patch[p, b + 1, a] = grad_patch[p, b + 1, a] + (one - fx) * fy * g
            grad_patch[p, b + 1, a + 1] = grad_patch[p, b + 1, a + 1] + fx * fy * g
    grad_coords[0, h, w] = grad_coords[0, h, w] + gx * scale
    grad_coords[1, h, w] = grad_coords[1, h, w] + gy * scale


@wp.kernel
def _patch_adjoint_f1(
    grad_patch: wp.array3d(dtype=typing.Any),
    f2l_v: wp.array2d(dtype=typing.Any),
    coords: wp.array3d(dtype=typing.Any),
    grad_f1_v: wp.array2d(dtype=typing.Any),
    height_l: int,
    width_l: int,
    scale: typing.Any,
    radius: int,
    inv_sqrt_c: typing.Any,
    offset: int,
):
    """grad_f1[:, p] += sum_tap dT[p, tap] P^l(f2)[:, tap] / sqrt(C); thread = pixel (writes its own row)."""
    p = wp.tid() + offset
    side = 2 * radius + 2
    width = coords.shape[2]
    h = p // width
    w = p % width
    i0, fx = _window_origin(coords, 0, h, w, scale, radius)
    j0, fy = _window_origin(coords, 1, h, w, scale, radius)
    for ty in range(side):
        row = j0 + ty
        if row >= 0 and row < height_l:
            for tx in range(side):
                col = i0 + tx
                if col >= 0 and col < width_l:
                    g = grad_patch[p, ty, tx] * inv_sqrt_c
                    q = row * width_l + col
                    for k in range(grad_f1_v.shape[1]):
                        grad_f1_v[p, k] = grad_f1_v[p, k] + f2l_v[q, k] * g


@wp.kernel
def _patch_adjoint_f2(
    grad_patch: wp.array3d(dtype=typing.Any),
    f1_v: wp.array2d(dtype=typing.Any),
    coords: wp.array3d(dtype=typing.Any),
    grad_f2l_v: wp.array3d(dtype=typing.Any),
    height_l: int,
    width_l: int,
    scale: typing.Any,
    radius: int,
    inv_sqrt_c: typing.Any,
    atomic: int,
    slot: int,
    offset: int,
):
    """grad_f2l[slot, tap] += dT[p, tap] f1[:, p] / sqrt(C); thread = pixel. This scatters across pixels:
    on the CPU each concurrent launch owns its slot (plain adds); on CUDA (`atomic` = 1) adds are atomic."""
    p = wp.tid() + offset
    side = 2 * radius + 2
    width = coords.shape[2]
    h = p // width
    w = p % width
    i0, fx = _window_origin(coords, 0, h, w, scale, radius)
    j0, fy = _window_origin(coords, 1, h, w, scale, radius)
    for ty in range(side):
        row = j0 + ty
        if row >= 0 and row < height_l:
            for tx in range(side):
                col = i0 + tx
                if col >= 0 and col < width_l:
                    g = grad_patch[p, ty, tx] * inv_sqrt_c
                    q = row * width_l + col
                    if atomic != 0:
                        for k in range(f1_v.shape[1]):
                            wp.atomic_add(grad_f2l_v, slot, q, k, f1_v[p, k] * g)
                    else:
                        for k in range(f1_v.shape[1]):
                            grad_f2l_v[slot, q, k] = grad_f2l_v[slot, q, k] + f1_v[p, k] * g


@wp.kernel
def _sum_slots(slots_v: wp.array3d(dtype=typing.Any), out_v: wp.array2d(dtype=typing.Any), offset: int):
    t = wp.tid() + offset
    n = t // out_v.shape[1]
    k = t % out_v.shape[1]
    acc = slots_v[0, n, k]
    for s in range(1, slots_v.shape[0]):
        acc += slots_v[s, n, k]
    out_v[n, k] = acc


# --------------------------------------------------------------------------- overloads


def _instantiate(kernel: Any) -> None:
    """Declare the float32 and float64 overloads up front, so the module compiles once.

    Arrays whose argument name ends in `_v` hold 8-wide vectors of the scalar type.
    """
    for scalar in (wp.float32, wp.float64):
        types: dict[str, Any] = {}
        for arg in kernel.adj.args:
            if wp.types.is_array(arg.type) and arg.type.dtype is typing.Any:
                dtype = _VEC_OF[scalar] if arg.label.endswith("_v") else scalar
                types[arg.label] = wp.array(dtype=dtype, ndim=arg.type.ndim)
            elif arg.type is typing.Any:
                types[arg.label] = scalar
        wp.overload(kernel, types)


for _k in (_pack_rows_v, _gemm_tn, _copy_cols, _transpose, _pool2x2, _pool2x2_adjoint_add, _lookup_level,
           _lookup_level_adjoint, _pack_channels_last_v, _unpack_channels_last_v, _patch_level, _sample_patch,
           _sample_patch_adjoint, _patch_adjoint_f1, _patch_adjoint_f2, _sum_slots):
    _instantiate(_k)


# --------------------------------------------------------------------------- input handling


class _Ctx:
    """Where the computation runs, in which dtype, and what kind of arrays to hand back."""

    def __init__(self, device: wp.Device, scalar: Any, as_numpy: bool):
        self.device = device
        self.scalar = scalar
        self.as_numpy = as_numpy

    def s(self, value: float) -> Any:
        return self.scalar(value)

    def zeros(self, shape: tuple[int, ...], vec: bool = False) -> wp.array:
        return wp.zeros(shape, dtype=_VEC_OF[self.scalar] if vec else self.scalar, device=self.device)

    def empty(self, shape: tuple[int, ...], vec: bool = False) -> wp.array:
        """An array the caller overwrites entirely."""
        return wp.empty(shape, dtype=_VEC_OF[self.scalar] if vec else self.scalar, device=self.device)

    def out(self, x: wp.array) -> Array:
        return x.numpy() if self.as_numpy else x

    def launch(self, kernel: Any, dim: int, inputs: list[Any]) -> None:
        if dim > 0:
            launch_split(kernel, dim, inputs, device=self.device)


def _shape(x: Array) -> tuple[int, ...]:
    return tuple(int(s) for s in x.shape)


def _kind(x: Any, name: str) -> str:
    if isinstance(x, np.ndarray):
        return "numpy"
    if isinstance(x, wp.array):
        return "warp"
    raise ValueError(f"{name}: expected a numpy array or a wp.array, got {type(x).__name__}")


def _scalar_type(x: Array, name: str) -> Any:
    if isinstance(x, np.ndarray):
        scalar = _SCALAR_OF_NP.get(x.dtype)
    else:
        scalar = x.dtype if x.dtype in (wp.float32, wp.float64) else None
    if scalar is None:
        raise ValueError(f"{name}: expected dtype float32 or float64, got {x.dtype}")
    return scalar


def _context(named: dict[str, Array], device: str | None) -> _Ctx:
    """Check kinds, dtypes and devices of the inputs (all alike); pick the device."""
    kinds = {name: _kind(x, name) for name, x in named.items()}
    scalars = {name: _scalar_type(x, name) for name, x in named.items()}
    first = next(iter(named))
    for name, scalar in scalars.items():
        if scalar is not scalars[first]:
            raise ValueError(f"{name}: expected dtype {scalars[first].__name__} like {first}, "
                             f"got {scalar.__name__}")
    want = wp.get_device(device) if device is not None else None
    for name, x in named.items():
        if kinds[name] == "warp":
            if want is None:
                want = x.device
            if x.device != want:
                raise ValueError(f"{name}: expected an array on device {want}, got one on {x.device}")
            if not x.is_contiguous:
                raise ValueError(f"{name}: expected a contiguous wp.array")
    return _Ctx(want if want is not None else wp.get_device("cpu"), scalars[first], kinds[first] == "numpy")


def _host(x: Array) -> np.ndarray:
    return x if isinstance(x, np.ndarray) else x.numpy()


def _check_finite(x: Array, name: str) -> None:
    bad = int(np.count_nonzero(~np.isfinite(_host(x))))
    if bad:
        raise ValueError(f"{name}: expected finite values, found {bad} NaN or infinite entries")


def _to_wp(x: Array, ctx: _Ctx, shape: tuple[int, ...] | None = None) -> wp.array:
    arr = x if isinstance(x, wp.array) else wp.array(np.ascontiguousarray(x), dtype=ctx.scalar, device=ctx.device)
    return arr.reshape(shape) if shape is not None and _shape(arr) != shape else arr


def _check_list(levels: Any, name: str, shape: str) -> None:
    if not isinstance(levels, (list, tuple)) or len(levels) < 1:
        raise ValueError(f"{name}: expected a non-empty list of levels, each {shape}")


def _check_features(f1: Array, f2: Array) -> tuple[int, int, int]:
    s1, s2 = _shape(f1), _shape(f2)
    if len(s1) != 3 or min(s1) < 1:
        raise ValueError(f"f1: expected a (C, H, W) feature map with C, H, W >= 1, got shape {s1}")
    if s2 != s1:
        raise ValueError(f"f2: expected the shape of f1 {s1} (C, H, W), got {s2}")
    _check_finite(f1, "f1")
    _check_finite(f2, "f2")
    return s1


def _check_levels(levels: Any, height: int, width: int) -> int:
    if not isinstance(levels, (int, np.integer)) or isinstance(levels, bool) or levels < 1:
        raise ValueError(f"levels: expected an integer >= 1, got {levels!r}")
    levels = int(levels)
    need = 2 ** (levels - 1)
    if height < need or width < need:
        raise ValueError(f"levels: a pyramid of {levels} levels needs frame 2 at least {need}x{need} pixels "
                         f"(H, W >= 2**(levels-1)), got {height}x{width}; use at most "
                         f"{min(height, width).bit_length()} levels")
    return levels


def _check_radius(radius: Any) -> int:
    if not isinstance(radius, (int, np.integer)) or isinstance(radius, bool) or radius < 0:
        raise ValueError(f"radius: expected an integer >= 0, got {radius!r}")
    return int(radius)


def _check_coords(coords: Array, height: int, width: int) -> None:
    if _shape(coords) != (2, height, width):
        raise ValueError(f"coords: expected shape (2, {height}, {width}) (x, y per pixel of frame 1), "
                         f"got {_shape(coords)}")
    bad = int(np.count_nonzero(~np.isfinite(_host(coords))))
    if bad:
        raise ValueError(f"coords: expected finite coordinates, found {bad} NaN or infinite entries")


def level_shapes(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    """(H_l, W_l) of each pyramid level: halved and floored, as avg_pool2d(2, stride 2) does."""
    return [(height >> lvl, width >> lvl) for lvl in range(levels)]


def _check_volume_pyramid(pyramid: Sequence[Array], coords: Array) -> tuple[int, int]:
    s0 = _shape(pyramid[0])
    if len(s0) != 4 or s0[:2] != s0[2:] or min(s0) < 1:
        raise ValueError(f"pyramid[0]: expected shape (H, W, H, W), got {s0}")
    height, width = s0[:2]
    _check_levels(len(pyramid), height, width)
    for lvl, (hl, wl) in enumerate(level_shapes(height, width, len(pyramid))):
        if _shape(pyramid[lvl]) != (height, width, hl, wl):
            raise ValueError(f"pyramid[{lvl}]: expected shape {(height, width, hl, wl)}, got {_shape(pyramid[lvl])}")
    _check_coords(coords, height, width)
    return height, width


def _check_feature_pyramid(f1: Array, f2_pyramid: Sequence[Array], coords: Array) -> tuple[int, int, int]:
    s1 = _shape(f1)
    if len(s1) != 3 or min(s1) < 1:
        raise ValueError(f"f1: expected a (C, H, W) feature map with C, H, W >= 1, got shape {s1}")
    channels, height, width = s1
    _check_levels(len(f2_pyramid), height, width)
    for lvl, (hl, wl) in enumerate(level_shapes(height, width, len(f2_pyramid))):
        if _shape(f2_pyramid[lvl]) != (channels, hl, wl):
            raise ValueError(f"f2_pyramid[{lvl}]: expected shape {(channels, hl, wl)} (f1's channels, "
                             f"frame size halved {lvl} times), got {_shape(f2_pyramid[lvl])}")
    _check_finite(f1, "f1")
    for lvl, f in enumerate(f2_pyramid):
        _check_finite(f, f"f2_pyramid[{lvl}]")
    _check_coords(coords, height, width)
    return s1


def _check_grad(grad: Array, name: str, shape: tuple[int, ...]) -> None:
    if _shape(grad) != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {_shape(grad)}")
    _check_finite(grad, name)


# --------------------------------------------------------------------------- product helpers


def _gemm_tn_wp(a: wp.array, b: wp.array, scale: float, ctx: _Ctx) -> wp.array:
    """a^T b * scale for a (K, M), b (K, N): the blocked product."""
    k, m = a.shape
    n = b.shape[1]
    if m % GEMM_ROWS:
        a_pad = ctx.zeros((k, m + GEMM_ROWS - m % GEMM_ROWS))
        ctx.launch(_copy_cols, k * m, [a, a_pad])
        a = a_pad
    n_col_blocks = -(-n // GEMM_COLS)
    b_v = ctx.empty((k, n_col_blocks * 2), vec=True)
    ctx.launch(_pack_rows_v, b_v.size, [b, b_v])
    out = ctx.empty((m, n))
    n_blocks = -(-m // GEMM_ROWS) * n_col_blocks
    ctx.launch(_gemm_tn, n_blocks, [a, b_v, out, ctx.s(scale), n_col_blocks])
    return out


def _transpose_wp(x: wp.array, ctx: _Ctx) -> wp.array:
    out = ctx.empty((x.shape[1], x.shape[0]))
    ctx.launch(_transpose, x.shape[0] * x.shape[1], [x, out])
    return out


def _pool_wp(x: wp.array, ctx: _Ctx) -> wp.array:
    n, h, w = x.shape
    out = ctx.empty((n, h // 2, w // 2))
    ctx.launch(_pool2x2, out.size, [x, out])
    return out


def _pyramid_adjoint_wp(grads: list[wp.array], ctx: _Ctx) -> wp.array:
    """Total gradient of level 0 given each level's direct gradient (3D views (N, H_l, W_l))."""
    acc = grads[-1]
    for lvl in range(len(grads) - 2, -1, -1):
        fine = wp.clone(grads[lvl])
        ctx.launch(_pool2x2_adjoint_add, fine.size, [acc, fine])
        acc = fine
    return acc


# --------------------------------------------------------------------------- public entry points: dense


def correlation_volume(f1: Array, f2: Array, *, device: str | None = None) -> Array:
    """All-pairs volume (H, W, H, W) of (1): V[p, q] = f1[:, p] . f2[:, q] / sqrt(C)."""
    ctx = _context({"f1": f1, "f2": f2}, device)
    channels, height, width = _check_features(f1, f2)
    n = height * width
    a = _to_wp(f1, ctx, (channels, n))
    b = _to_wp(f2, ctx, (channels, n))
    vol = _gemm_tn_wp(a, b, 1.0 / math.sqrt(channels), ctx)
    return ctx.out(vol.reshape((height, width, height, width)))


def correlation_volume_backward(f1: Array, f2: Array, grad_volume: Array, *,
                                device: str | None = None) -> tuple[Array, Array]:
    """Adjoint of (1): (d f1, d f2) = (f2 dV^T, f1 dV) / sqrt(C), each (C, H, W)."""
    ctx = _context({"f1": f1, "f2": f2, "grad_volume": grad_volume}, device)
    channels, height, width = _check_features(f1, f2)
    n = height * width
    _check_grad(grad_volume, "grad_volume", (height, width, height, width))
    a = _to_wp(f1, ctx, (channels, n))
    b = _to_wp(f2, ctx, (channels, n))
    g = _to_wp(grad_volume, ctx, (n, n))
    inv = 1.0 / math.sqrt(channels)
    # d f1 (C, N1) = f2 g^T = (f2^T)^T g^T;  d f2 (C, N2) = f1 g = (f1^T)^T g.
    grad_f1 = _gemm_tn_wp(_transpose_wp(b, ctx), _transpose_wp(g, ctx), inv, ctx)
    grad_f2 = _gemm_tn_wp(_transpose_wp(a, ctx), g, inv, ctx)
    shape = (channels, height, width)
    return ctx.out(grad_f1.reshape(shape)), ctx.out(grad_f2.reshape(shape))


def correlation_pyramid(volume: Array, levels: int, *, device: str | None = None) -> list[Array]:
    """Levels V^0..V^{L-1} of (2), each (H, W, H_l, W_l), pooling frame 2's dimensions."""
    ctx = _context({"volume": volume}, device)
    shape = _shape(volume)
    if len(shape) != 4 or shape[:2] != shape[2:] or min(shape) < 1:
        raise ValueError(f"volume: expected shape (H, W, H, W), got {shape}")
    height, width = shape[:2]
    levels = _check_levels(levels, height, width)
    n = height * width
    cur = _to_wp(volume, ctx, (n, height, width))
    out = [cur]
    for _ in range(1, levels):
        cur = _pool_wp(cur, ctx)
        out.append(cur)
    return [ctx.out(v.reshape((height, width, v.shape[1], v.shape[2]))) for v in out]


def correlation_pyramid_backward(grad_pyramid: Sequence[Array], *, device: str | None = None) -> Array:
    """Adjoint of (2): the gradient (H, W, H, W) of V^0 given a gradient for every level."""
    _check_list(grad_pyramid, "grad_pyramid", "(H, W, H_l, W_l)")
    ctx = _context({f"grad_pyramid[{i}]": g for i, g in enumerate(grad_pyramid)}, device)
    s0 = _shape(grad_pyramid[0])
    if len(s0) != 4 or s0[:2] != s0[2:] or min(s0) < 1:
        raise ValueError(f"grad_pyramid[0]: expected shape (H, W, H, W), got {s0}")
    height, width = s0[:2]
    _check_levels(len(grad_pyramid), height, width)
    n = height * width
    grads = []
    for lvl, (hl, wl) in enumerate(level_shapes(height, width, len(grad_pyramid))):
        _check_grad(grad_pyramid[lvl], f"grad_pyramid[{lvl}]", (height, width, hl, wl))
        grads.append(_to_wp(grad_pyramid[lvl], ctx, (n, hl, wl)))
    return ctx.out(_pyramid_adjoint_wp(grads, ctx).reshape((height, width, height, width)))


def lookup(pyramid: Sequence[Array], coords: Array, radius: int, *, device: str | None = None) -> Array:
    """Windowed lookup (4) in a volume pyramid: (L (2r+1)^2, H, W) in RAFT's channel order."""
    radius = _check_radius(radius)
    _check_list(pyramid, "pyramid", "(H, W, H_l, W_l)")
    ctx = _context({**{f"pyramid[{i}]": v for i, v in enumerate(pyramid)}, "coords": coords}, device)
    height, width = _check_volume_pyramid(pyramid, coords)
    side = 2 * radius + 1
    n = height * width
    xy = _to_wp(coords, ctx)
    out = ctx.zeros((len(pyramid) * side * side, height, width))
    for lvl, vol in enumerate(pyramid):
        v = _to_wp(vol, ctx, (n, vol.shape[2], vol.shape[3]))
        ctx.launch(_lookup_level, n * side, [v, xy, out, ctx.s(0.5 ** lvl), radius, lvl * side * side])
    return ctx.out(out)


def lookup_backward(pyramid: Sequence[Array], coords: Array, radius: int, grad_out: Array, *,
                    device: str | None = None) -> tuple[list[Array], Array]:
    """Adjoint of (4): (gradient of every pyramid level, gradient of coords (2, H, W))."""
    radius = _check_radius(radius)
    _check_list(pyramid, "pyramid", "(H, W, H_l, W_l)")
    ctx = _context({**{f"pyramid[{i}]": v for i, v in enumerate(pyramid)}, "coords": coords,
                    "grad_out": grad_out}, device)
    height, width = _check_volume_pyramid(pyramid, coords)
    side = 2 * radius + 1
    n = height * width
    _check_grad(grad_out, "grad_out", (len(pyramid) * side * side, height, width))
    xy = _to_wp(coords, ctx)
    g = _to_wp(grad_out, ctx)
    grad_coords = ctx.zeros((2, height, width))
    grads = []
    for lvl, vol in enumerate(pyramid):
        shape3 = (n, vol.shape[2], vol.shape[3])
        gv = ctx.zeros(shape3)
        ctx.launch(_lookup_level_adjoint, n, [_to_wp(vol, ctx, shape3), xy, g, gv, grad_coords,
                                              ctx.s(0.5 ** lvl), radius, lvl * side * side])
        grads.append(ctx.out(gv.reshape(_shape(vol))))
    return grads, ctx.out(grad_coords)


def dense_bytes(height: int, width: int, levels: int, itemsize: int = 4) -> int:
    """Bytes of the stored volume pyramid: H W sum_l H_l W_l values."""
    return itemsize * height * width * sum(hl * wl for hl, wl in level_shapes(height, width, levels))


# --------------------------------------------------------------------------- public entry points: on the fly


def pool_features(f2: Array, levels: int, *, device: str | None = None) -> list[Array]:
    """P^0(f2) = f2, ..., P^{L-1}(f2): (C, H_l, W_l) by repeated 2x2 average pooling."""
    ctx = _context({"f2": f2}, device)
    shape = _shape(f2)
    if len(shape) != 3 or min(shape) < 1:
        raise ValueError(f"f2: expected a (C, H, W) feature map with C, H, W >= 1, got shape {shape}")
    levels = _check_levels(levels, shape[1], shape[2])
    _check_finite(f2, "f2")
    cur = _to_wp(f2, ctx)
    out = [cur]
    for _ in range(1, levels):
        cur = _pool_wp(cur, ctx)
        out.append(cur)
    return [ctx.out(x) for x in out]


def pool_features_backward(grad_pyramid: Sequence[Array], *, device: str | None = None) -> Array:
    """Adjoint of pool_features: the gradient (C, H, W) of f2 given one for every level."""
    _check_list(grad_pyramid, "grad_pyramid", "(C, H_l, W_l)")
    ctx = _context({f"grad_pyramid[{i}]": g for i, g in enumerate(grad_pyramid)}, device)
    s0 = _shape(grad_pyramid[0])
    if len(s0) != 3 or min(s0) < 1:
        raise ValueError(f"grad_pyramid[0]: expected shape (C, H, W), got {s0}")
    channels, height, width = s0
    _check_levels(len(grad_pyramid), height, width)
    grads = []
    for lvl, (hl, wl) in enumerate(level_shapes(height, width, len(grad_pyramid))):
        _check_grad(grad_pyramid[lvl], f"grad_pyramid[{lvl}]", (channels, hl, wl))
        grads.append(_to_wp(grad_pyramid[lvl], ctx))
    return ctx.out(_pyramid_adjoint_wp(grads, ctx))


def _channels_last_v(x: wp.array, ctx: _Ctx) -> wp.array:
    """(C, N) scalars -> (N, ceil(C / 8)) vectors."""
    channels, n = x.shape
    out = ctx.zeros((n, -(-channels // VEC)), vec=True)
    ctx.launch(_pack_channels_last_v, out.size, [x, out])
    return out


def _channels_first(x_v: wp.array, channels: int, ctx: _Ctx) -> wp.array:
    out = ctx.zeros((channels, x_v.shape[0]))
    ctx.launch(_unpack_channels_last_v, out.size, [x_v, out])
    return out


def onthefly_bytes(height: int, width: int, channels: int, levels: int, radius: int, itemsize: int = 4) -> int:
    """Bytes the on-the-fly forward holds: f1 and the pooled f2 pyramid channels-last (padded to 8) + one patch."""
    c_pad = -(-channels // VEC) * VEC
    pixels = height * width + sum(hl * wl for hl, wl in level_shapes(height, width, levels))
    return itemsize * (c_pad * pixels + height * width * (2 * radius + 2) ** 2)


def lookup_onthefly(f1: Array, f2_pyramid: Sequence[Array], coords: Array, radius: int, *,
                    device: str | None = None) -> Array:
    """Equation (4) computed from f1 and pooled f2 (`pool_features`) without the volume."""
    radius = _check_radius(radius)
    _check_list(f2_pyramid, "f2_pyramid", "(C, H_l, W_l)")
    named = {"f1": f1, **{f"f2_pyramid[{i}]": f for i, f in enumerate(f2_pyramid)}, "coords": coords}
    ctx = _context(named, device)
    channels, height, width = _check_feature_pyramid(f1, f2_pyramid, coords)
    n = height * width
    side = 2 * radius + 1
    xy = _to_wp(coords, ctx)
    f1_v = _channels_last_v(_to_wp(f1, ctx, (channels, n)), ctx)
    inv = ctx.s(1.0 / math.sqrt(channels))
    patch = ctx.zeros((n, side + 1, side + 1))
    out = ctx.zeros((len(f2_pyramid) * side * side, height, width))
    for lvl, f2l in enumerate(f2_pyramid):
        hl, wl = _shape(f2l)[1:]
        f2l_v = _channels_last_v(_to_wp(f2l, ctx, (channels, hl * wl)), ctx)
        scale = ctx.s(0.5 ** lvl)
        ctx.launch(_patch_level, n * (side + 1), [f1_v, f2l_v, xy, patch, hl, wl, scale, radius, inv])
        ctx.launch(_sample_patch, n * side, [patch, xy, out, scale, radius, lvl * side * side])
    return ctx.out(out)


def _launch_slots(kernel: Any, dim: int, inputs: list[Any], n_slots: int, device: wp.Device) -> None:
    """Chunk s of [0, dim) launched on its own thread with `slot = s` (kernel params end `slot, offset`)."""
    if device.is_cuda or n_slots == 1:
        wp.launch(kernel, dim=dim, inputs=[*inputs, 0, 0], device=device)
        return
    bounds = chunk_bounds(dim, n_slots)
    with ThreadPoolExecutor(max_workers=n_slots - 1) as pool:
        futures = [pool.submit(wp.launch, kernel, dim=size, inputs=[*inputs, s, off], device=device)
                   for s, (off, size) in enumerate(bounds[1:], start=1)]
        off, size = bounds[0]
        wp.launch(kernel, dim=size, inputs=[*inputs, 0, off], device=device)
        for fut in futures:
            fut.result()



def lookup_onthefly_backward(f1: Array, f2_pyramid: Sequence[Array], coords: Array, radius: int, grad_out: Array,
                             *, device: str | None = None) -> tuple[Array, list[Array], Array]:
    """Adjoint of `lookup_onthefly`: (d f1 (C, H, W), [d P^l(f2) (C, H_l, W_l)], d coords (2, H, W))."""
    radius = _check_radius(radius)
    _check_list(f2_pyramid, "f2_pyramid", "(C, H_l, W_l)")
    named = {"f1": f1, **{f"f2_pyramid[{i}]": f for i, f in enumerate(f2_pyramid)}, "coords": coords,
             "grad_out": grad_out}
    ctx = _context(named, device)
    channels, height, width = _check_feature_pyramid(f1, f2_pyramid, coords)
    n = height * width
    side = 2 * radius + 1
    _check_grad(grad_out, "grad_out", (len(f2_pyramid) * side * side, height, width))
    xy = _to_wp(coords, ctx)
    g = _to_wp(grad_out, ctx)
    f1_v = _channels_last_v(_to_wp(f1, ctx, (channels, n)), ctx)
    n_vec = f1_v.shape[1]
    inv = ctx.s(1.0 / math.sqrt(channels))
    patch = ctx.zeros((n, side + 1, side + 1))
    grad_patch = ctx.zeros((n, side + 1, side + 1))
    grad_f1_v = ctx.zeros((n, n_vec), vec=True)
    grad_coords = ctx.zeros((2, height, width))
    n_slots = 1 if ctx.device.is_cuda else max(1, min(default_threads(), n))
    grads_f2 = []
    for lvl, f2l in enumerate(f2_pyramid):
        hl, wl = _shape(f2l)[1:]
        f2l_v = _channels_last_v(_to_wp(f2l, ctx, (channels, hl * wl)), ctx)
        scale = ctx.s(0.5 ** lvl)
        ctx.launch(_patch_level, n * (side + 1), [f1_v, f2l_v, xy, patch, hl, wl, scale, radius, inv])
        ctx.launch(_sample_patch_adjoint, n, [patch, xy, g, grad_patch, grad_coords, scale, radius,
                                              lvl * side * side])
        ctx.launch(_patch_adjoint_f1, n, [grad_patch, f2l_v, xy, grad_f1_v, hl, wl, scale, radius, inv])
        slots = ctx.zeros((n_slots, hl * wl, n_vec), vec=True)
        _launch_slots(_patch_adjoint_f2, n, [grad_patch, f1_v, xy, slots, hl, wl, scale, radius, inv,
                                             int(ctx.device.is_cuda)], n_slots, ctx.device)
        grad_f2l_v = ctx.zeros((hl * wl, n_vec), vec=True)
        ctx.launch(_sum_slots, grad_f2l_v.size, [slots, grad_f2l_v])
        grads_f2.append(ctx.out(_channels_first(grad_f2l_v, channels, ctx).reshape((channels, hl, wl))))
    grad_f1 = _channels_first(grad_f1_v, channels, ctx).reshape((channels, height, width))
    return ctx.out(grad_f1), grads_f2, ctx.out(grad_coords)
