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

This module holds the entry points and the level-by-level forward (`_forward`); the Warp kernels
are in `onthefly_kernels`, the channels-last copies, BLAS full products and pixel grouping in
`onthefly_layout`, and the every-level-at-once schedule on several threads in `onthefly_phased`.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np
import warp as wp

from kernels import fast_paths
from kernels._arrays import Inputs
from kernels.corr import patch_cpu, window_cpu
from kernels.corr._common import (VEC, VEC_OF, Array, check_levels, check_list, check_radius, coords_in, features_in,
                                  full_product_level, level_shapes, levels_in, pool_levels, pool_levels_adjoint,
                                  sample_windows, sample_windows_adjoint)
from kernels.corr.onthefly_kernels import _patch_adjoint_features, _patch_level, _patch_sample_level, _sum_slots
from kernels.corr.onthefly_layout import (_channels_first, _channels_last_later, _channels_last_v,
                                          _group_pixels, _launch_slots, _rows,
                                          _sample_full_product, _scaled_level)
from kernels.corr.onthefly_phased import _forward_phased, _phased_ready
from kernels.corr.stored import OnTheFlyFeatures, check_feature_dtype, refuse_backward, store, widen
from kernels.launch import default_threads

from kernels.corr.onthefly_phased import _replay, _run_ordered, _weighted_pieces  # noqa: F401 (the tests' names)

__all__ = ["pool_features", "pool_features_backward", "lookup_onthefly", "onthefly_features",
           "lookup_onthefly_features", "lookup_onthefly_backward"]


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



def _cpu_patches(a: Inputs, f1_rows: wp.array) -> bool:
    """Whether the patches go through `patch_cpu` (its C++ kernels): on the CPU, rows contiguous, stored in
    the working dtype or in float16 with float32 work."""
    if not fast_paths.on(a.device) or f1_rows.strides[1] != wp.types.type_size_in_bytes(f1_rows.dtype):
        return False
    return f1_rows.dtype == a.scalar or (f1_rows.dtype == wp.float16 and a.scalar == wp.float32)



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
