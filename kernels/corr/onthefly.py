"""On-the-fly ("alternate") lookups: the output of (4) from f1 and pooled f2, without the volume.

Pooling is linear in f2, so V^l equals (1) computed with f2 pooled l times,
P^l(f2) (`pool_features`, the 2x2 pooling (2) applied to the features). For each
pixel p and level l the (2r + 2)^2 tap patch of its window

    T[p, ty, tx] = f1[:, p] . P^l(f2)[:, (j0 + ty, i0 + tx)] / sqrt(C)   (0 outside frame 2)

is computed, then sampled by (3) exactly as the dense lookup samples V^l (the
same kernels `sample_windows` and `sample_windows_adjoint`, on the patch).

Coarse levels on the CPU. Where a level has few pixels (2 H_l W_l <= (2r + 2)^2,
`full_product_level`; RAFT's coarsest at 1/8 resolution), the forward takes
every tap from the rows of the full product V^l = f1^T P^l(f2) / sqrt(C) instead,
by BLAS (its rows held in the patch buffer's memory), and samples them as the dense
lookup samples V^l. The values are
those of (1) summed in BLAS's order (float rounding apart from the patches).

Memory: the path keeps f1 and the pooled f2 pyramid between lookups, C (H W +
sum_l H_l W_l) values (`onthefly_held_bytes`), instead of the volume pyramid's
H W sum_l H_l W_l; a forward call adds channels-last copies of f1 and of one
level, and the patch buffer of H W (2r + 2)^2 values (`onthefly_bytes`), whose
memory the full-product levels reuse (both counts in kernels.corr.stored); on the
CPU with several threads (all levels at once, below) every patched level's copy,
two patch buffers and the full-product levels' rows beside them.

Stored features (`onthefly_features`, `lookup_onthefly_features`; kernels.corr.stored):
f1 and P^l(f2) kept channels-last between lookups, in float32 or float16 (half the
bytes held; widened exactly, so the arithmetic below is float32's, forward-only).

The patches on the CPU: `patch_cpu` (C++, `wp.func_native`) groups the pixels by their window's
column origin (`_group_pixels`), then forms each group's patches level row by level row, the
pixels whose windows hold a row sharing its tap vectors, reading P^l(f2) in its stored dtype
(float16 widened in registers) and f1 widened once a call (exact), then samples each pixel's
window from its patch (`window_cpu.sample_patches_cpu`): every tap the same operations in the same
order as `_patch_sample_level` (the Warp kernel, which CUDA keeps, with `_patch_level`), so the
same values bit for bit. With several threads, stored features (`lookup_onthefly_features`) and the
float32 lookup (C a multiple of 8) take all levels at once (`_forward_phased`: two patch buffers, f1's
widening handed to a thread first, then one list of items), the same values.

Backward, with g = d loss / d out: the patch is recomputed; d T follows from g
and (3) (and d coords as in the dense lookup); then

    d f1[:, p] = sum_tap dT[p, tap] P^l(f2)[:, tap] / sqrt(C)     (a gather per pixel),
    d P^l(f2)[:, tap] = sum_p dT[p, tap] f1[:, p] / sqrt(C)        (a scatter across pixels).

On the CPU each concurrent launch accumulates the scatter into its own buffer
and the buffers are summed afterwards: no Warp atomic is atomic between
concurrent CPU launches (docs/warp.md). On CUDA one launch adds atomically.
d f2 then follows by the adjoint of the pooling, `pool_features_backward`.

Layout: features are kept channels-last in 8-wide vectors (channels zero-padded
to a multiple of 8), so a tap's dot product is a few vector multiply-adds.
"""

from __future__ import annotations

import math
import threading
import typing
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Sequence

import numpy as np
import warp as wp

from kernels import fast_paths
from kernels._arrays import Inputs, declare_float_overloads
from kernels.corr import patch_cpu, window_cpu
from kernels.corr._common import (VEC, VEC_OF, Array, check_levels, check_list, check_radius, coords_in,
                                  features_in, full_product_level, level_shapes, levels_in, pack_rows, pixel_window,
                                  pool_levels, pool_levels_adjoint, sample_window, sample_windows,
                                  sample_windows_adjoint)
from kernels.corr.stored import OnTheFlyFeatures, check_feature_dtype, refuse_backward, store, widen
from kernels.launch import chunk_bounds, default_threads, parallel_items, parallel_ranges, submit

wp.set_module_options({"enable_backward": False, "optimization_level": 3})


# --------------------------------------------------------------------------- kernels


@wp.kernel
def _unpack_channels_last_v(x_v: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=typing.Any), offset: int):
    """Inverse of the channels-last packing: out (C, N) from x_v (N, ceil(C / 8))."""
    t = wp.tid() + offset
    c = t // out.shape[1]
    n = t % out.shape[1]
    out[c, n] = x_v[n, c // VEC][c % VEC]


@wp.func
def _dot_v(a_v: wp.array2d(dtype=typing.Any), i: int, b_v: wp.array2d(dtype=typing.Any), j: int):
    """a[i] . b[j] over the packed channels (8 partial sums, added at the end)."""
    acc = wp.cw_mul(a_v[i, 0], b_v[j, 0])
    for k in range(1, a_v.shape[1]):
        acc += wp.cw_mul(a_v[i, k], b_v[j, k])
    s = acc[0]
    for q in range(1, VEC):
        s += acc[q]
    return s


@wp.func
def _dot_v2(a_v: wp.array2d(dtype=typing.Any), i: int, b_v: wp.array2d(dtype=typing.Any), j: int):
    """(a[i] . b[j], a[i] . b[j + 1]): a[i]'s vectors loaded once for two taps, each sum in `_dot_v`'s order."""
    x = a_v[i, 0]
    acc0 = wp.cw_mul(x, b_v[j, 0])
    acc1 = wp.cw_mul(x, b_v[j + 1, 0])
    for k in range(1, a_v.shape[1]):
        x = a_v[i, k]
        acc0 += wp.cw_mul(x, b_v[j, k])
        acc1 += wp.cw_mul(x, b_v[j + 1, k])
    s0 = acc0[0]
    s1 = acc1[0]
    for q in range(1, VEC):
        s0 += acc0[q]
        s1 += acc1[q]
    return s0, s1


@wp.func
def _dot_v4(a_v: wp.array2d(dtype=typing.Any), i: int, b_v: wp.array2d(dtype=typing.Any), j: int):
    """a[i] . b[j + t] for t = 0..3: a[i]'s vectors loaded once for four taps, each sum in `_dot_v`'s order."""
    x = a_v[i, 0]
    acc0 = wp.cw_mul(x, b_v[j, 0])
    acc1 = wp.cw_mul(x, b_v[j + 1, 0])
    acc2 = wp.cw_mul(x, b_v[j + 2, 0])
    acc3 = wp.cw_mul(x, b_v[j + 3, 0])
    for k in range(1, a_v.shape[1]):
        x = a_v[i, k]
        acc0 += wp.cw_mul(x, b_v[j, k])
        acc1 += wp.cw_mul(x, b_v[j + 1, k])
        acc2 += wp.cw_mul(x, b_v[j + 2, k])
        acc3 += wp.cw_mul(x, b_v[j + 3, k])
    s0 = acc0[0]
    s1 = acc1[0]
    s2 = acc2[0]
    s3 = acc3[0]
    for q in range(1, VEC):
        s0 += acc0[q]
        s1 += acc1[q]
        s2 += acc2[q]
        s3 += acc3[q]
    return s0, s1, s2, s3


@wp.func
def _dot_v5(a_v: wp.array2d(dtype=typing.Any), i: int, b_v: wp.array2d(dtype=typing.Any), j: int):
    """a[i] . b[j + t] for t = 0..4: a[i]'s vectors loaded once for five taps, each sum in `_dot_v`'s order."""
    x = a_v[i, 0]
    acc0 = wp.cw_mul(x, b_v[j, 0])
    acc1 = wp.cw_mul(x, b_v[j + 1, 0])
    acc2 = wp.cw_mul(x, b_v[j + 2, 0])
    acc3 = wp.cw_mul(x, b_v[j + 3, 0])
    acc4 = wp.cw_mul(x, b_v[j + 4, 0])
    for k in range(1, a_v.shape[1]):
        x = a_v[i, k]
        acc0 += wp.cw_mul(x, b_v[j, k])
        acc1 += wp.cw_mul(x, b_v[j + 1, k])
        acc2 += wp.cw_mul(x, b_v[j + 2, k])
        acc3 += wp.cw_mul(x, b_v[j + 3, k])
        acc4 += wp.cw_mul(x, b_v[j + 4, k])
    s0 = acc0[0]
    s1 = acc1[0]
    s2 = acc2[0]
    s3 = acc3[0]
    s4 = acc4[0]
    for q in range(1, VEC):
        s0 += acc0[q]
        s1 += acc1[q]
        s2 += acc2[q]
        s3 += acc3[q]
        s4 += acc4[q]
    return s0, s1, s2, s3, s4


@wp.func
def _tap_or_zero(f1_v: wp.array2d(dtype=typing.Any), p: int, f2l_v: wp.array2d(dtype=typing.Any), row: int,
                 col: int, width_l: int, inv_sqrt_c: typing.Any):
    """f1[:, p] . P^l(f2)[:, (row, col)] / sqrt(C) for a tap in the level's row, 0 past its ends."""
    if col >= 0 and col < width_l:
        return _dot_v(f1_v, p, f2l_v, row * width_l + col) * inv_sqrt_c
    return inv_sqrt_c * inv_sqrt_c.dtype(0.0)


@wp.func
def _patch_row(f1_v: wp.array2d(dtype=typing.Any), f2l_v: wp.array2d(dtype=typing.Any),
               patch: wp.array3d(dtype=typing.Any), p: int, ty: int, i0: int, j0: int, height_l: int, width_l: int,
               radius: int, inv_sqrt_c: typing.Any):
    """Row ty of pixel p's patch: patch[p, ty, tx] = f1[:, p] . P^l(f2)[:, (j0 + ty, i0 + tx)] / sqrt(C), 0 outside.

    The taps of a row are contiguous in P^l(f2) and share f1[:, p], so they go five, four or two
    at a time (`_dot_v5`, `_dot_v4`, `_dot_v2`), loading f1[:, p] once per group: the dot products
    are bound by loads (five at a time: 12-19% less time than four, 1 KB taps, C = 256). Each tap's
    sum is formed in one order whatever its group, so the patch is bit-identical to one tap at a time.
    """
    side = 2 * radius + 2
    row = j0 + ty
    if row < 0 or row >= height_l:
        for tx in range(side):
            patch[p, ty, tx] = inv_sqrt_c.dtype(0.0)
        return
    base = row * width_l
    tx = int(0)
    while tx < side:
        col = i0 + tx
        if tx + 5 <= side and col >= 0 and col + 4 < width_l:
            s0, s1, s2, s3, s4 = _dot_v5(f1_v, p, f2l_v, base + col)
            patch[p, ty, tx] = s0 * inv_sqrt_c
            patch[p, ty, tx + 1] = s1 * inv_sqrt_c
            patch[p, ty, tx + 2] = s2 * inv_sqrt_c
            patch[p, ty, tx + 3] = s3 * inv_sqrt_c
            patch[p, ty, tx + 4] = s4 * inv_sqrt_c
            tx += 5
        elif tx + 4 <= side and col >= 0 and col + 3 < width_l:
            s0, s1, s2, s3 = _dot_v4(f1_v, p, f2l_v, base + col)
            patch[p, ty, tx] = s0 * inv_sqrt_c
            patch[p, ty, tx + 1] = s1 * inv_sqrt_c
            patch[p, ty, tx + 2] = s2 * inv_sqrt_c
            patch[p, ty, tx + 3] = s3 * inv_sqrt_c
            tx += 4
        elif tx + 2 <= side and col >= 0 and col + 1 < width_l:
            s0, s1 = _dot_v2(f1_v, p, f2l_v, base + col)
            patch[p, ty, tx] = s0 * inv_sqrt_c
            patch[p, ty, tx + 1] = s1 * inv_sqrt_c
            tx += 2
        else:
            patch[p, ty, tx] = _tap_or_zero(f1_v, p, f2l_v, row, col, width_l, inv_sqrt_c)
            tx += 1


@wp.kernel
def _patch_level(f1_v: wp.array2d(dtype=typing.Any), f2l_v: wp.array2d(dtype=typing.Any),
                 coords: wp.array3d(dtype=typing.Any), patch: wp.array3d(dtype=typing.Any),
                 height_l: int, width_l: int, scale: typing.Any, radius: int, inv_sqrt_c: typing.Any, offset: int):
    """The patch of (`_patch_row`) for every pixel; thread = pixel * (2r+2) + ty (the backward's recomputation)."""
    t = wp.tid() + offset
    side = 2 * radius + 2
    p = t // side
    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
    _patch_row(f1_v, f2l_v, patch, p, t % side, i0, j0, height_l, width_l, radius, inv_sqrt_c)


@wp.kernel
def _patch_sample_level(f1_v: wp.array2d(dtype=typing.Any), f2l_v: wp.array2d(dtype=typing.Any),
                        coords: wp.array3d(dtype=typing.Any), patch: wp.array3d(dtype=typing.Any),
                        out: wp.array3d(dtype=typing.Any), height_l: int, width_l: int, scale: typing.Any,
                        radius: int, inv_sqrt_c: typing.Any, channel0: int, offset: int):
    """Pixel p's patch (`_patch_row`, every row), then its window sampled from it (`sample_window`, from
    (0, 0)) while the patch is still in cache: the forward's level in one launch; thread = pixel."""
    p = wp.tid() + offset
    side = 2 * radius + 2
    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
    for ty in range(side):
        _patch_row(f1_v, f2l_v, patch, p, ty, i0, j0, height_l, width_l, radius, inv_sqrt_c)
    sample_window(patch, p, 0, 0, fx, fy, out, channel0, h, w, side - 1)


@wp.kernel
def _patch_adjoint_features(grad_patch: wp.array3d(dtype=typing.Any), f1_v: wp.array2d(dtype=typing.Any),
                            f2l_v: wp.array2d(dtype=typing.Any), coords: wp.array3d(dtype=typing.Any),
                            grad_f1_v: wp.array2d(dtype=typing.Any), grad_f2l_v: wp.array3d(dtype=typing.Any),
                            height_l: int, width_l: int, scale: typing.Any, radius: int, inv_sqrt_c: typing.Any,
                            atomic: int, slot: int, offset: int):
    """For every tap of pixel p's patch inside frame 2, with g = dT[p, tap] / sqrt(C):
    grad_f1[:, p] += g P^l(f2)[:, tap] (a gather: thread p writes its own row) and
    grad_f2l[slot, tap] += g f1[:, p] (a scatter across pixels: on the CPU each concurrent launch
    owns its slot and adds plainly; on CUDA, `atomic` = 1, one launch adds atomically). Thread = pixel."""
    p = wp.tid() + offset
    side = 2 * radius + 2
    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
    for ty in range(side):
        row = j0 + ty
        if row >= 0 and row < height_l:
            for tx in range(side):
                col = i0 + tx
                if col >= 0 and col < width_l:
                    g = grad_patch[p, ty, tx] * inv_sqrt_c
                    q = row * width_l + col
                    for k in range(f1_v.shape[1]):
                        grad_f1_v[p, k] = grad_f1_v[p, k] + f2l_v[q, k] * g
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



for _k in (_unpack_channels_last_v, _patch_level, _patch_sample_level, _patch_adjoint_features, _sum_slots):
    declare_float_overloads(_k, vector_types=VEC_OF)


# --------------------------------------------------------------------------- host helpers


def _channels_last_v(x: wp.array, a: Inputs) -> wp.array:
    """(C, N) scalars -> (N, ceil(C / 8)) vectors.

    On the CPU with C a multiple of 8 the vectors are the rows of x^T itself: NumPy's transposed
    copy, aliased as vectors (a quarter of the packing kernel's time, which reads x^T strided).
    """
    channels, n = x.shape
    if fast_paths.on(a.device) and channels % VEC == 0:
        rows = np.ascontiguousarray(x.numpy().T).reshape(n, channels // VEC, VEC)
        return wp.array(rows, dtype=VEC_OF[a.scalar], device=a.device, copy=False)  # keeps `rows` alive
    return pack_rows(x.transpose(), -(-channels // VEC), a)


def _channels_last_later(x: wp.array, a: Inputs) -> tuple[wp.array, Callable[[int, int], None]]:
    """(C, N) scalars (C a multiple of 8, CPU) -> the (N, C / 8) vectors of `_channels_last_v`, allocated
    here and filled by `fill(lo, hi)` row range by row range (the same values; NumPy copies without the GIL)."""
    channels, n = x.shape
    out_v = a.empty((n, channels // VEC), VEC_OF[a.scalar])
    src, dst = x.numpy(), out_v.numpy().reshape(n, channels)

    def fill(lo: int, hi: int) -> None:
        np.copyto(dst[lo:hi], src[:, lo:hi].T)

    return out_v, fill


_blas_controller = None
_BLAS_ROWS = 256  # rows of V^l per BLAS call in `_sample_full_product`


def _one_blas_thread() -> Any:
    """A context in which BLAS runs on the calling thread alone (threadpoolctl; process-wide while it lasts).

    The full products are split by rows over the launch threads (`parallel_ranges`), one BLAS thread
    each: OpenBLAS's own threads spin on cores the launch threads already use (measured on the busy
    2-core host: the on-the-fly forward took 36 ms of CPU time with them, 22 ms with one BLAS
    thread per launch thread).
    """
    global _blas_controller
    if _blas_controller is None:
        from threadpoolctl import ThreadpoolController

        _blas_controller = ThreadpoolController()
    return _blas_controller.limit(limits=1, user_api="blas")


def _sample_full_product(x1_rows: np.ndarray, f2s: np.ndarray, height_l: int, width_l: int, xy: wp.array,
                         out: wp.array, lvl: int, radius: int, scratch: wp.array, a: Inputs) -> None:
    """Level `lvl` of (4) from V^l = f1^T P^l(f2) / sqrt(C), formed by BLAS.

    x1_rows: f1 channels-last (N, C) on the host; f2s: P^l(f2) / sqrt(C) as (C, H_l W_l), C-ordered
    (`_scaled_level`). The rows of V^l ((N, H_l W_l), in the memory of `scratch`, the patch buffer:
    a full-product level holds at most half a patch's taps, `full_product_level`) are formed, then
    sampled like a dense level.
    """
    n = x1_rows.shape[0]
    taps = height_l * width_l
    if n * taps > scratch.size:
        raise AssertionError(f"full-product level of {taps} taps a pixel exceeds the patch buffer")
    flat = scratch.numpy().reshape(-1)[:n * taps].reshape(n, taps)
    buf = wp.array(flat.reshape(n, height_l, width_l), dtype=a.scalar, device=a.device, copy=False)
    side = 2 * radius + 1
    starts = range(0, n, _BLAS_ROWS)

    def products(lo: int, hi: int) -> None:
        # The same BLAS calls (row chunks of _BLAS_ROWS) whatever the thread count, so the
        # values do not depend on it (BLAS may round a product's edge rows differently).
        for r0 in starts[lo:hi]:
            r1 = min(r0 + _BLAS_ROWS, n)
            np.matmul(x1_rows[r0:r1], f2s, out=flat[r0:r1])

    with _one_blas_thread():
        parallel_ranges(products, len(starts), min_chunk=1)
    # `sample_windows`' windows (full products are CPU-only), bit for bit: the dense lookup's C++
    # kernel on this one level
    a.launch(window_cpu.sample_levels_cpu(radius, a.scalar), window_cpu.blocks(n),
             [buf, buf, buf, buf, 1, xy, out, a.s(0.5 ** lvl), lvl * side * side], min_chunk=64)


def _channels_first(x_v: wp.array, channels: int, a: Inputs) -> wp.array:
    out = a.zeros((channels, x_v.shape[0]))
    a.launch(_unpack_channels_last_v, out.size, [x_v, out])
    return out


def _launch_slots(kernel: Any, dim: int, inputs: list[Any], n_slots: int, device: wp.Device) -> None:
    """Chunk s of [0, dim) launched on its own thread with `slot = s` (kernel params end `slot, offset`).

    A CPU launch runs on one thread and releases the GIL (docs/warp.md), so the chunks run in parallel,
    each adding into its own slot; on CUDA one launch covers all of [0, dim) in slot 0.
    """
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


def _feature_pyramid(a: Inputs, f1: Array, f2_pyramid: Sequence[Array],
                     coords: Array) -> tuple[wp.array, list[wp.array], wp.array]:
    """f1 as (C, H W), the pooled f2 levels as (C, H_l W_l) and coords (2, H, W), as wp.arrays."""
    x1 = features_in(a, "f1", f1)
    channels, height, width = x1.shape
    check_levels(len(f2_pyramid), height, width)
    x2 = a.floats("f2_pyramid[0]", f2_pyramid[0], (channels, height, width))
    levels = levels_in(a, "f2_pyramid", f2_pyramid, x2, (channels,), height, width)
    xy = coords_in(a, coords, height, width)
    return x1.reshape((channels, height * width)), [x.reshape((channels, x.shape[1] * x.shape[2])) for x in levels], xy


# --------------------------------------------------------------------------- entry points


def pool_features(f2: Array, levels: int, *, device: str | None = None) -> list[Array]:
    """P^0(f2) = f2, ..., P^{L-1}(f2): (C, H_l, W_l) by repeated 2x2 average pooling."""
    levels = check_levels(levels)
    a = Inputs(device, f2)
    x = features_in(a, "f2", f2)
    check_levels(levels, x.shape[1], x.shape[2])
    return [a.out(v) for v in pool_levels(x, levels, a)]


def pool_features_backward(grad_pyramid: Sequence[Array], *, device: str | None = None) -> dict[str, Array]:
    """Adjoint of `pool_features` given a gradient (C, H_l, W_l) for every level. Returns a dict
    {"f2": the gradient (C, H, W) of f2}, in grad_pyramid[0]'s kind."""
    check_list("grad_pyramid", grad_pyramid, "(C, H_l, W_l)")
    a = Inputs(device, *grad_pyramid)
    g0 = features_in(a, "grad_pyramid[0]", grad_pyramid[0])
    channels, height, width = g0.shape
    check_levels(len(grad_pyramid), height, width)
    grads = levels_in(a, "grad_pyramid", grad_pyramid, g0, (channels,), height, width)
    return {"f2": a.out(pool_levels_adjoint(grads, a))}


def _scaled_level(level_rows: np.ndarray, channels: int, inv: float, a: Inputs) -> np.ndarray:
    """P^l(f2) / sqrt(C) as a C-ordered (C, H_l W_l) array from its channels-last rows (N_l, >= C).
    The scale goes on the small operand first, as in `volume._gemm_blas` (exact when sqrt(C) is a
    power of two)."""
    f2s = np.empty((channels, level_rows.shape[0]), dtype=a.np_dtype)
    f2s[...] = level_rows[:, :channels].T
    f2s *= a.np_dtype.type(inv)
    return f2s


def _rows(x_v: wp.array) -> wp.array:
    """Channels-last vectors (N, C8 / 8) viewed as their rows of scalars (N, C8) (no copy; x_v outlives the view)."""
    n, n_vec = x_v.shape
    return wp.array(ptr=x_v.ptr, shape=(n, n_vec * VEC), dtype=x_v.dtype._wp_scalar_type_, device=x_v.device)


def _cpu_patches(a: Inputs, f1_rows: wp.array) -> bool:
    """Whether the patches go through `patch_cpu` (its C++ kernels): on the CPU, rows contiguous, stored in
    the working dtype or in float16 with float32 work."""
    if not fast_paths.on(a.device) or f1_rows.strides[1] != wp.types.type_size_in_bytes(f1_rows.dtype):
        return False
    return f1_rows.dtype == a.scalar or (f1_rows.dtype == wp.float16 and a.scalar == wp.float32)


def _grouping_arrays(a: Inputs, n: int, radius: int, height_l: int,
                     width_l: int) -> tuple[int, list[wp.array], wp.array, wp.array]:
    """(number of groups, [i0, j0, order, sorted j0] (N,), starts, counts): `group_pixels_cpu`'s outputs and scratch."""
    side = 2 * radius + 2
    n_groups = width_l + side + 1
    ints = [a.empty(n, wp.int32) for _ in range(4)]
    return n_groups, ints, a.empty(n_groups + 1, wp.int32), a.empty(n_groups * (height_l + side + 1) + 1, wp.int32)


def _group_pixels(a: Inputs, xy: wp.array, scale: Any, radius: int, height_l: int,
                  width_l: int) -> tuple[int, wp.array, wp.array, wp.array]:
    """The pixels grouped for `patch_cpu.patch_groups_cpu` at one level (`patch_cpu.group_pixels_cpu`):
    (number of groups, pixel order, each ordered pixel's window row origin, each group's first position)."""
    n_groups, ints, starts, counts = _grouping_arrays(a, xy.shape[1] * xy.shape[2], radius, height_l, width_l)
    a.launch(patch_cpu.group_pixels_cpu(radius, a.scalar), 1, [xy, scale, *ints, starts, counts, height_l, width_l])
    return n_groups, ints[2], ints[3], starts


def _forward(a: Inputs, f1_rows: wp.array, channels: int, xy: wp.array, radius: int, n_levels: int,
             level_rows: Callable[[int], wp.array], level_scaled: Callable[[int], np.ndarray],
             stored: bool = False, fills: dict[Any, Callable[[int, int], None]] | None = None) -> wp.array:
    """Equation (4) from f1's channels-last rows (N, C8) in the storage dtype (the working dtype or
    float16), one level at a time: `level_rows(l)` gives P^l(f2)'s rows (N_l, C8) in the same dtype,
    `level_scaled(l)` P^l(f2) / sqrt(C) as (C, N_l) on the host in the working dtype.

    On the CPU the patches of a level are formed and sampled by `patch_cpu` from the stored rows
    themselves (f1 widened once); elsewhere f1 and each level are widened (`widen`, exact) for
    `_patch_sample_level` / `_patch_level`. Either way the values are the same, bit for bit.

    With `stored` (every level's rows may be held at once) on the CPU with several threads, the levels
    go through `_forward_phased` instead (the same kernels, values bit for bit). `fills` ("f1" and
    levels, set by the `level_rows` calls): row-range fills that f1's rows and a level's rows need
    before use (`_channels_last_later`); `_forward_phased` runs them as items, the path here up front.
    """
    n = f1_rows.shape[0]
    _, height, width = xy.shape
    side = 2 * radius + 1
    inv = a.s(1.0 / math.sqrt(channels))
    out = a.empty((n_levels * side * side, height, width))  # every element is written
    if stored and _cpu_patches(a, f1_rows) and default_threads() > 1:
        # which kernels the call launches: those of its dtypes, radius, patched and full-product levels
        full = {full_product_level(hl, wl, radius, a.device) and channels % VEC == 0
                for hl, wl in level_shapes(height, width, n_levels)}
        key = (radius, a.scalar, f1_rows.dtype, frozenset(full))
        if key in _phased_ready:
            _forward_phased(a, f1_rows, channels, xy, radius, n_levels, level_rows, level_scaled, out, fills or {})
            return out
        _phased_ready.add(key)  # the first call (below) compiles and loads the kernels on one thread
    if fills is not None:  # the copies made up front
        fills["f1"](0, n)
        copied_rows = level_rows

        def level_rows(lvl: int) -> wp.array:
            rows = copied_rows(lvl)
            fills[lvl](0, rows.shape[0])
            return rows

    # Every tap is written by _patch_level; a full-product level reuses the memory for its blocks.
    patch = a.empty((n, side + 1, side + 1))
    cpu_kernel = (patch_cpu.patch_groups_cpu(radius, a.scalar, f1_rows.dtype) if _cpu_patches(a, f1_rows)
                  else None)
    f1_v = None  # f1 widened to the working dtype, where needed
    for lvl, (hl, wl) in enumerate(level_shapes(height, width, n_levels)):
        scale = a.s(0.5 ** lvl)
        if full_product_level(hl, wl, radius, a.device) and channels % VEC == 0:
            f1_v = widen(f1_rows, a) if f1_v is None else f1_v
            x1_rows = f1_v.numpy().reshape(n, channels)  # f1 channels-last: the vectors' own memory
            _sample_full_product(x1_rows, level_scaled(lvl), hl, wl, xy, out, lvl, radius, patch, a)
        elif cpu_kernel is not None:
            # The pixels grouped by window column origin, then a launch over the groups: each group's
            # patches, row by row, its pixels sharing each tap row's vectors; then the windows sampled.
            f1_v = widen(f1_rows, a) if f1_v is None else f1_v
            n_groups, order, sorted_j0, starts = _group_pixels(a, xy, scale, radius, hl, wl)
            a.launch(cpu_kernel, n_groups, [_rows(f1_v), level_rows(lvl), order, sorted_j0, starts, hl, wl, inv,
                                            patch], min_chunk=2)
            a.launch(window_cpu.sample_patches_cpu(radius, a.scalar), window_cpu.blocks(n),
                     [patch, xy, out, scale, lvl * side * side], min_chunk=64)
        else:
            f1_v = widen(f1_rows, a) if f1_v is None else f1_v
            f2l_v = widen(level_rows(lvl), a)
            if fast_paths.on(a.device):
                a.launch(_patch_sample_level, n, [f1_v, f2l_v, xy, patch, out, hl, wl, scale, radius, inv,
                                                  lvl * side * side], min_chunk=64)
            else:
                # On CUDA a thread per patch row keeps more threads busy.
                a.launch(_patch_level, n * (side + 1), [f1_v, f2l_v, xy, patch, hl, wl, scale, radius, inv])
                a.launch(sample_windows, n, [patch, xy, out, scale, radius, lvl * side * side, 1, 0])
            del f2l_v  # one level's copy at a time (`onthefly_bytes`)
    return out


# (radius, working dtype, storage dtype, kinds of levels) whose kernels a call has loaded (level by level,
# on one launch thread at a time), so that `_forward_phased`'s threads never load a module at once
_phased_ready: set[tuple] = set()


def _pieces(lo: int, hi: int, k: int) -> list[tuple[int, int]]:
    """[lo, hi) cut into at most k contiguous non-empty ranges of near-equal size."""
    return [(lo + o, lo + o + s) for o, s in chunk_bounds(hi - lo, max(1, min(k, hi - lo)))]


def _weighted_pieces(starts: np.ndarray, k: int) -> list[tuple[int, int]]:
    """Groups [0, G) cut into at most k contiguous ranges holding near-equal numbers of pixels
    (starts (G + 1,): each group's first pixel position, the pixel count at the end)."""
    n_groups, total = len(starts) - 1, int(starts[-1])
    cuts = np.searchsorted(starts, [total * j / k for j in range(1, k)], side="left")
    bounds = sorted({0, n_groups, *(int(min(max(c, 0), n_groups)) for c in cuts)})
    return [(g0, g1) for g0, g1 in zip(bounds[:-1], bounds[1:]) if starts[g1] > starts[g0]]


_kept = threading.local()  # per thread: {name: {key: value}}, what a thread keeps between lookups of one size


def _thread_kept(name: str, key: tuple, limit: int, make: Callable[[], Any]) -> Any:
    """The calling thread's kept value `name` for `key`, made on first use; a few keys at a time (all are
    dropped when `limit` are held and a new one comes)."""
    kept = getattr(_kept, name, None)
    if kept is None:
        kept = {}
        setattr(_kept, name, kept)
    if key not in kept:
        if len(kept) >= limit:
            kept.clear()
        kept[key] = make()
    return kept[key]


def _kept_grouping_arrays(a: Inputs, lvl: int, n: int, radius: int, height_l: int,
                          width_l: int) -> tuple[int, list[wp.array], wp.array, wp.array]:
    """`_grouping_arrays`, kept between the calling thread's lookups of the same size (a call fills them
    entirely before reading them): 18 small allocations a call were ~0.2 ms of its Python."""
    key = (a.device.alias, lvl, n, radius, height_l, width_l)  # a level's own: the levels group at once
    return _thread_kept("arrays", key, 16, lambda: _grouping_arrays(a, n, radius, height_l, width_l))


def _kept_launches(key: tuple) -> dict[Any, Any]:
    """The calling thread's recorded launches (`_replay`) for the phased lookups of one size (`key`)."""
    return _thread_kept("launches", key, 8, dict)


def _replay(replays: dict[Any, Any], slot: Any, kernel: Any, dim: int, inputs: list[Any], device: wp.Device) -> None:
    """`wp.launch(kernel, dim, inputs)` through a launch recorded once per slot (`replays`, one call's items
    each own a slot): its arguments set from their ctypes values and replayed, ~half of `wp.launch`'s Python
    (which packs and checks every argument). The recorded launch keeps no array between calls (fwd_args
    dropped); every argument is set again before each replay. Concrete (non-generic) CPU kernels only."""
    cmd = replays.get(slot)
    if cmd is None or cmd.kernel is not kernel or len(cmd.params) != len(inputs) + 1:
        cmd = wp.launch(kernel, dim=dim, inputs=inputs, device=device, record_cmd=True)
        cmd.fwd_args = None
        replays[slot] = cmd
    else:
        cmd.set_dim(dim)
        for i, v in enumerate(inputs):
            if isinstance(v, wp.array):
                cmd.set_param_at_index_from_ctype(i, v.__ctype__())
            else:
                cmd.set_param_at_index_from_ctype(i, v if isinstance(v, int) else float(v))
    cmd.launch()


def _run_ordered(items: list[Callable[[], None]], after: list[tuple[int, ...]]) -> None:
    """Run the items on the launch threads: each thread pulls the next item in list order and, before
    running it, waits for the items it comes `after` (all earlier in the list). One hand-off to the pool
    a call, and no thread waits at a barrier for a whole stage, only for what its item reads.

    No deadlock: an item's predecessors were pulled before it, so each is done or running on another
    thread (a thread alone runs them all in order). After a failure no item starts, the waiting threads
    are released, and the first exception is re-raised here once every thread has stopped.
    """
    done = [threading.Event() for _ in items]
    order = iter(range(len(items)))
    lock = threading.Lock()
    errors: list[BaseException] = []

    def work(_: int) -> None:
        while True:
            with lock:
                i = None if errors else next(order, None)
            if i is None:
                return
            for j in after[i]:
                done[j].wait()
            if errors:
                return
            try:
                items[i]()
            except BaseException as exc:
                with lock:
                    errors.append(exc)
                for event in done:  # release every waiting thread
                    event.set()
                return
            done[i].set()

    parallel_items(work, min(default_threads(), len(items)))
    if errors:
        raise errors[0]


def _forward_phased(a: Inputs, f1_rows: wp.array, channels: int, xy: wp.array, radius: int, n_levels: int,
                    level_rows: Callable[[int], wp.array], level_scaled: Callable[[int], np.ndarray],
                    out: wp.array, fills: dict[Any, Callable[[int, int], None]]) -> None:
    """`_forward`'s CPU path on several threads: every level at once, two hand-offs to the launch threads.

    The same kernels on the same values as `_forward` (bit for bit), as items run in this order by
    `_run_ordered` (each waiting only for the items it reads):
      0. f1 widened or copied channels-last (`fills`), whole, on a launch thread from the start
         (`submit`), while this thread builds the list;
      1. each patched level's pixels grouped and its groups cut into ranges of equal pixel counts, here
         while the list is built (no item); each patched level's channels-last copy (`fills`), by row
         ranges; each full-product level's P^l(f2) / sqrt(C); then an item that waits for 0;
      2. each patched level's patches, by those ranges (after f1), and each full-product level's rows
         of V^l by BLAS (the same 256-row products; after f1 and its scaled level);
      3. each level's windows sampled, ranges of pixel blocks (after that level's patches or rows),
         interleaved with 2 (order below).
    The patched levels take turns in two patch buffers (`onthefly_bytes` counts both), each
    full-product level has its rows of its own; items running at once write disjoint memory. Against
    level by level (at two threads ~10 parallel sections, ~70 guided-chunk launches, three groupings on
    one thread): ~25 launches and two hand-offs a call (0, then the list).
    """
    n = f1_rows.shape[0]
    threads = default_threads()
    side = 2 * radius + 1
    inv = a.s(1.0 / math.sqrt(channels))
    vec = VEC_OF[a.scalar]
    shapes = level_shapes(xy.shape[1], xy.shape[2], n_levels)
    full = [full_product_level(hl, wl, radius, a.device) and channels % VEC == 0 for hl, wl in shapes]
    device = a.device
    items: list[Callable[[], None]] = []
    after: list[tuple[int, ...]] = []

    def add(fn: Callable[[], None], deps: Sequence[int] = ()) -> int:
        items.append(fn)
        after.append(tuple(deps))
        return len(items) - 1

    replays = _kept_launches((device.alias, n, tuple(shapes), radius, a.scalar, f1_rows.dtype, threads, channels))

    def launch_range(kernel: Any, lo: int, hi: int, inputs: list[Any], slot: Any) -> Callable[[], None]:
        return lambda: _replay(replays, slot, kernel, hi - lo, [*inputs, lo], device)

    # 0. f1 widened (exact; float32 storage: a view) or copied channels-last, handed whole to a launch
    # thread first: it runs (one native launch or NumPy copy, without the GIL) while this thread builds the
    # list and groups the pixels; the item `widened`, before the first patches, waits for it
    def fill_items(key: Any, rows: int) -> list[int]:
        return [add(lambda lo=lo, hi=hi: fills[key](lo, hi)) for lo, hi in _pieces(0, rows, threads)]

    early_fn = None
    if f1_rows.dtype == a.scalar:
        f1_v = widen(f1_rows, a)
        if "f1" in fills:
            early_fn = lambda: fills["f1"](0, n)  # noqa: E731
    else:  # float16 rows, float32 work (`_cpu_patches`): `widen`'s C++ conversion
        f1_v = a.empty((n, f1_rows.shape[1] // VEC), vec)
        f1_w = wp.array(ptr=f1_v.ptr, shape=f1_rows.shape, dtype=a.scalar, device=device)  # f1_v outlives it
        early_fn = lambda: wp.launch(patch_cpu.widen_rows_cpu(), dim=n, inputs=[f1_rows, f1_w, 0],  # noqa: E731
                                     device=device)
    early = None
    if early_fn is not None:
        # This thread waits (GIL released) until the launch thread has started 0: else this thread's Python
        # keeps the GIL and the woken launch thread could not start 0 before the list is built. Bounded, in
        # case every launch thread is busy.
        started = threading.Event()
        early = submit(lambda: started.set() or early_fn())
        started.wait(0.002)
    # 1. level copies, scaled levels (items); groupings (here)
    level_arrays: dict[int, wp.array] = {}
    copied: dict[int, list[int]] = {}  # level -> its copy's items
    for lvl in range(n_levels):
        if not full[lvl]:
            level_arrays[lvl] = level_rows(lvl)
            copied[lvl] = fill_items(lvl, level_arrays[lvl].shape[0]) if lvl in fills else []
    scaled: dict[int, np.ndarray] = {}
    grouping: dict[int, tuple] = {}
    pieces = 2 * threads
    cuts: dict[int, list[tuple[int, int]]] = {}  # patched level -> its groups' ranges for the patch items
    ready: dict[int, list[int]] = {}  # level -> the items its products or patches wait for (besides f1)
    for lvl, (hl, wl) in enumerate(shapes):
        if full[lvl]:
            ready[lvl] = [add(lambda lvl=lvl: scaled.__setitem__(lvl, level_scaled(lvl)))]
        else:
            grouping[lvl] = _kept_grouping_arrays(a, lvl, n, radius, hl, wl)
            n_groups, ints, starts, counts = grouping[lvl]
            inputs = [xy, a.s(0.5 ** lvl), *ints, starts, counts, hl, wl]
            # grouped here, on this thread (native launches, which release the GIL: meanwhile the launch
            # thread takes it to start 0), and cut into `pieces` ranges of equal pixel counts for the patches
            wp.launch(patch_cpu.group_pixels_cpu(radius, a.scalar), dim=1, inputs=[*inputs, 0], device=device)
            cuts[lvl] = _weighted_pieces(starts.numpy(), pieces)
            ready[lvl] = copied[lvl]
    widened = [add(early.result)] if early is not None else []  # f1 ready (re-raises a failure of it)

    # 2-3. patches and full products, then windows, in the order
    #   P0 (B) P1 S0 P2 S1 P3 S2 ... S(full) S(last): Pk = patched level k's patches (into buffer k % 2,
    #   after f1, its grouping and, from k = 2, S(k - 2), the windows that read that buffer), B = the
    #   full-product levels' rows by BLAS, Sk = level k's windows (after Pk); so a thread that pulls Sk
    #   finds Pk done (P(k+1) was pulled in between), and the full-product windows fill the last wait.
    patch_kernel = patch_cpu.patch_groups_cpu(radius, a.scalar, f1_rows.dtype)
    f1_r = _rows(f1_v)
    x1_rows = f1_v.numpy().reshape(n, -1)[:, :channels]  # f1 channels-last: the vectors' own memory
    patched = [lvl for lvl in range(n_levels) if not full[lvl]]
    patch_buffers = [a.empty((n, side + 1, side + 1)) for _ in patched[:2]]  # every tap is written
    formed: dict[int, list[int]] = {}
    sampled: dict[int, list[Any]] = {}  # a level's window kernel and first inputs, then its items
    n_blocks = window_cpu.blocks(n)

    def add_products() -> None:
        for lvl in (lvl for lvl in range(n_levels) if full[lvl]):
            hl, wl = shapes[lvl]
            buf = a.empty((n, hl, wl))
            rows = buf.numpy().reshape(n, hl * wl)
            chunks = range(0, n, _BLAS_ROWS)

            def products(c0: int, c1: int, rows: np.ndarray = rows, lvl: int = lvl, chunks: range = chunks) -> None:
                for r0 in chunks[c0:c1]:  # the same 256-row products as `_sample_full_product`
                    r1 = min(r0 + _BLAS_ROWS, n)
                    np.matmul(x1_rows[r0:r1], scaled[lvl], out=rows[r0:r1])

            formed[lvl] = [add(lambda c0=c0, c1=c1, f=products: f(c0, c1), [*widened, *ready[lvl]])
                           for c0, c1 in _pieces(0, len(chunks), pieces)]
            # the dense lookup's kernel on this one level
            sampled[lvl] = [window_cpu.sample_levels_cpu(radius, a.scalar), [buf, buf, buf, buf, 1]]

    def add_windows(lvl: int) -> None:
        kernel, head = sampled[lvl]
        inputs = [*head, xy, out, a.s(0.5 ** lvl), lvl * side * side]
        sampled[lvl] = [add(launch_range(kernel, lo, hi, inputs, ("windows", lvl, lo)), formed[lvl])
                        for lo, hi in _pieces(0, n_blocks, threads)]

    if not patched:
        add_products()
    for k, lvl in enumerate(patched):
        hl, wl = shapes[lvl]
        n_groups, ints, starts, _ = grouping[lvl]
        buf = patch_buffers[k % 2]
        inputs = [f1_r, level_arrays[lvl], ints[2], ints[3], starts, hl, wl, inv, buf]

        def patches(j: int, inputs: list[Any] = inputs, lvl: int = lvl) -> None:
            # piece j of the groups cut by pixel counts (`cuts`, made with the grouping)
            cut = cuts[lvl]
            if j < len(cut):
                _replay(replays, ("patches", lvl, j), patch_kernel, cut[j][1] - cut[j][0], [*inputs, cut[j][0]],
                        device)

        deps = [*widened, *ready[lvl], *(sampled[patched[k - 2]] if k >= 2 else [])]
        formed[lvl] = [add(lambda j=j, f=patches: f(j), deps) for j in range(pieces)]
        sampled[lvl] = [window_cpu.sample_patches_cpu(radius, a.scalar), [buf]]
        if k == 0:
            add_products()
        else:
            add_windows(patched[k - 1])
    for lvl in range(n_levels):
        if full[lvl]:
            add_windows(lvl)
    if patched:
        add_windows(patched[-1])
    with _one_blas_thread():
        _run_ordered(items, after)


def lookup_onthefly(f1: Array, f2_pyramid: Sequence[Array], coords: Array, radius: int, *,
                    feature_dtype: str = "float32", device: str | None = None) -> Array:
    """Equation (4) computed from f1 and pooled f2 (`pool_features`) without the volume.

    `feature_dtype="float16"` rounds the features to float16 first (`onthefly_features`; the
    arithmetic stays float32) and is forward-only; "float32" (the default) uses them as given.
    """
    radius = check_radius(radius)
    feature_dtype = check_feature_dtype(feature_dtype)
    check_list("f2_pyramid", f2_pyramid, "(C, H_l, W_l)")
    a = Inputs(device, f1, *f2_pyramid, coords)
    x1, levels, xy = _feature_pyramid(a, f1, f2_pyramid, coords)
    channels = x1.shape[0]
    inv = 1.0 / math.sqrt(channels)
    if feature_dtype != "float32":
        _, height, width = xy.shape
        return _lookup_stored(_store(a, x1, levels, height, width, feature_dtype), xy, radius, a)
    scaled = lambda lvl: levels[lvl].numpy().reshape(channels, -1) * a.np_dtype.type(inv)  # noqa: E731
    if fast_paths.on(a.device) and default_threads() > 1 and channels % VEC == 0:
        # Every level at once (`_forward_phased`): the channels-last copies of f1 and of every patched
        # level are made by its items, by row ranges (`fills`), and held together (`onthefly_bytes`).
        x1_v, fill_f1 = _channels_last_later(x1, a)
        fills = {"f1": fill_f1}
        level_v: dict[int, wp.array] = {}

        def all_rows(lvl: int) -> wp.array:
            if lvl not in level_v:
                level_v[lvl], fills[lvl] = _channels_last_later(levels[lvl], a)
            return _rows(level_v[lvl])

        return a.out(_forward(a, _rows(x1_v), channels, xy, radius, len(levels), all_rows, scaled, stored=True,
                              fills=fills))
    x1_v = _channels_last_v(x1, a)
    level_copy: list[wp.array] = []  # the level's vectors live while its rows are used

    def level_rows(lvl: int) -> wp.array:
        level_copy.clear()  # one level's copy at a time (`onthefly_bytes`)
        level_copy.append(_channels_last_v(levels[lvl], a))
        return _rows(level_copy[0])

    out = _forward(a, _rows(x1_v), channels, xy, radius, len(levels), level_rows, scaled)
    return a.out(out)


def onthefly_features(f1: Array, f2_pyramid: Sequence[Array], *, feature_dtype: str = "float16",
                      device: str | None = None) -> OnTheFlyFeatures:
    """f1 and the pooled f2 levels stored for repeated lookups (kernels.corr.stored), in
    `feature_dtype` ("float16": rounded to nearest, |values| <= 65504; "float32": as given)."""
    feature_dtype = check_feature_dtype(feature_dtype)
    check_list("f2_pyramid", f2_pyramid, "(C, H_l, W_l)")
    a = Inputs(device, f1, *f2_pyramid)
    x1 = features_in(a, "f1", f1)
    channels, height, width = x1.shape
    check_levels(len(f2_pyramid), height, width)
    x2 = a.floats("f2_pyramid[0]", f2_pyramid[0], (channels, height, width))
    levels = levels_in(a, "f2_pyramid", f2_pyramid, x2, (channels,), height, width)
    flat = [x.reshape((channels, x.shape[1] * x.shape[2])) for x in levels]
    return _store(a, x1.reshape((channels, height * width)), flat, height, width, feature_dtype)


def _store(a: Inputs, x1: wp.array, levels: list[wp.array], height: int, width: int,
           feature_dtype: str) -> OnTheFlyFeatures:
    """Checked f1 (C, H W) and levels (C, H_l W_l) stored as `OnTheFlyFeatures`."""
    rows = store([x1, *levels], feature_dtype, a)
    return OnTheFlyFeatures(rows[0], tuple(rows[1:]), x1.shape[0], height, width, feature_dtype, a.scalar)


def lookup_onthefly_features(features: OnTheFlyFeatures, coords: Array, radius: int) -> Array:
    """Equation (4) from stored features (`onthefly_features`), on their device, in coords' kind.

    Each call widens f1 and one level at a time to the working dtype (exact), then computes as
    `lookup_onthefly`: the float16 result equals the float32 lookup of the float16-rounded features.
    """
    if not isinstance(features, OnTheFlyFeatures):
        raise ValueError(f"features: expected the OnTheFlyFeatures of onthefly_features, got {type(features).__name__}")
    radius = check_radius(radius)
    a = Inputs(features.device, coords)
    a.scalar = features.scalar  # coords must have the stored features' working dtype (checked by coords_in)
    xy = coords_in(a, coords, features.height, features.width)
    return _lookup_stored(features, xy, radius, a)


def _lookup_stored(features: OnTheFlyFeatures, xy: wp.array, radius: int, a: Inputs) -> Array:
    channels = features.channels
    inv = 1.0 / math.sqrt(channels)
    out = _forward(a, features.f1, channels, xy, radius, len(features.levels), lambda lvl: features.levels[lvl],
                   lambda lvl: _scaled_level(features.levels[lvl].numpy(), channels, inv, a), stored=True)
    return a.out(out)


def lookup_onthefly_backward(f1: Array, f2_pyramid: Sequence[Array], coords: Array, radius: int, grad_out: Array,
                             *, feature_dtype: str = "float32",
                             device: str | None = None) -> dict[str, Array | list[Array]]:
    """Adjoint of `lookup_onthefly`. Returns a dict {"f1": d f1 (C, H, W), "f2_pyramid": [d P^l(f2)
    (C, H_l, W_l) for every level], "coords": d coords (2, H, W)}, in f1's kind. Float32 features
    only: `feature_dtype="float16"` (forward-only) raises ValueError."""
    refuse_backward(feature_dtype)
    radius = check_radius(radius)
    check_list("f2_pyramid", f2_pyramid, "(C, H_l, W_l)")
    a = Inputs(device, f1, *f2_pyramid, coords, grad_out)
    x1, levels, xy = _feature_pyramid(a, f1, f2_pyramid, coords)
    channels, n = x1.shape
    _, height, width = xy.shape
    side = 2 * radius + 1
    g = a.floats("grad_out", grad_out, (len(levels) * side * side, height, width))
    f1_v = _channels_last_v(x1, a)
    n_vec = f1_v.shape[1]
    vec = VEC_OF[a.scalar]
    inv = a.s(1.0 / math.sqrt(channels))
    patch = a.zeros((n, side + 1, side + 1))
    grad_patch = a.zeros((n, side + 1, side + 1))
    grad_f1_v = a.zeros((n, n_vec), vec)
    grad_coords = a.zeros((2, height, width))
    n_slots = 1 if a.device.is_cuda else max(1, min(default_threads(), n))
    grads_f2 = []
    for lvl, (hl, wl) in enumerate(level_shapes(height, width, len(levels))):
        f2l_v = _channels_last_v(levels[lvl], a)
        scale = a.s(0.5 ** lvl)
        a.launch(_patch_level, n * (side + 1), [f1_v, f2l_v, xy, patch, hl, wl, scale, radius, inv])
        a.launch(sample_windows_adjoint, n, [patch, xy, g, grad_patch, grad_coords, scale, radius, lvl * side * side,
                                             1])
        slots = a.zeros((n_slots, hl * wl, n_vec), vec)
        _launch_slots(_patch_adjoint_features, n, [grad_patch, f1_v, f2l_v, xy, grad_f1_v, slots, hl, wl, scale,
                                                   radius, inv, int(a.device.is_cuda)], n_slots, a.device)
        grad_f2l_v = a.zeros((hl * wl, n_vec), vec)
        a.launch(_sum_slots, grad_f2l_v.size, [slots, grad_f2l_v])
        grads_f2.append(a.out(_channels_first(grad_f2l_v, channels, a).reshape((channels, hl, wl))))
    grad_f1 = _channels_first(grad_f1_v, channels, a).reshape((channels, height, width))
    return {"f1": a.out(grad_f1), "f2_pyramid": grads_f2, "coords": a.out(grad_coords)}
