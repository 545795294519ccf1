"""The on-the-fly lookup's Warp kernels: correlation patches from f1 and pooled f2, and their adjoint.

For pixel p and level l, with (i0, j0) the top-left tap of p's lookup window at that level
(`_common.pixel_window`), the (2r + 2)^2 tap patch is

    T[p, ty, tx] = f1[:, p] . P^l(f2)[:, (j0 + ty, i0 + tx)] / sqrt(C)   (0 outside frame 2),

P^l(f2) the features pooled l times (`_common.pool_levels`). `_patch_level` forms it (a thread per
patch row: CUDA's forward and the backward's recomputation); `_patch_sample_level` forms a pixel's
patch and samples its window from it while it is in cache (`_common.sample_window`, exactly as the
dense lookup samples V^l). The features are channels-last in 8-wide vectors (channels zero-padded
to a multiple of 8), so a tap's dot product is a few vector multiply-adds, and the taps of a patch
row go five, four or two at a time with each sum formed in one order (`_patch_row`): the same bits
as one tap at a time.

Backward, with dT the patch's cotangent (from `_common.sample_windows_adjoint`):

    d f1[:, p]        = sum_tap dT[p, tap] P^l(f2)[:, tap] / sqrt(C)   (a gather per pixel),
    d P^l(f2)[:, tap] = sum_p dT[p, tap] f1[:, p] / sqrt(C)            (a scatter across pixels).

`_patch_adjoint_features` does both; on the CPU each concurrent launch adds the scatter into its own
slot and `_sum_slots` sums the slots (no Warp atomic is atomic between concurrent CPU launches,
docs/warp.md); on CUDA one launch adds atomically. `_unpack_channels_last_v` returns a gradient to
channels-first (C, N).
"""

from __future__ import annotations

import typing

import warp as wp

from kernels._arrays import declare_float_overloads
from kernels.corr._common import VEC, VEC_OF, pixel_window, sample_window

wp.set_module_options({"enable_backward": False, "optimization_level": 3})


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
