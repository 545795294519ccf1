"""The on-the-fly lookup's patches on the CPU, in C++, read from the stored features' own dtype.

The C++ is in kernels/native/patch_groups.cpp, patch_group_pixels.cpp and patch_widen_rows.cpp,
loaded by `kernels.native.source`.

Same math, same operations and the same order per tap as `onthefly_kernels._patch_row` (then
`_common.sample_window`, by `window_cpu.sample_patches_cpu`), so the same outputs bit for bit.
For pixel p at level l, window origin (j0, i0) (`_common.pixel_window`), tap row ty and tap
column tx (0 .. 2r+1), with x = f1[:, p] and y = P^l(f2)[:, (j0 + ty, i0 + tx)] channels-last in
8-lane vectors x_k, y_k (k = 0 .. C8/8 - 1, channels zero-padded to C8):

    acc    = x_0 * y_0;   acc = acc + x_k * y_k  (k = 1, 2, ...; a product, then a sum, per lane)
    T[ty, tx] = (((acc[0] + acc[1]) + acc[2]) + ... + acc[7]) * (1 / sqrt(C)),   0 outside the level

each product and each sum a separate C++ statement (no fused multiply-add), as Warp's generated
code computes `_dot_v`. Except for float16 storage with float32 work, where each step is one fused
multiply-add, fma(x_k, y_k, acc) = round(acc + x_k y_k): the same value, because the product of
two float16 values is exact in float32 (two 11-bit significands make at most 22 bits, of float32's
24; |x y| <= 65504^2 < 2^32, and a nonzero |x y| >= 2^-48, far above float32's smallest normal
2^-126), so round(x y) = x y and the separate product and sum round once, as the fused one does.
Taps whose column lies outside the level are computed on a clamped column and replaced by 0 (the
order of every in-frame tap's sum is unchanged); rows outside are 0.

Grouped pixels (`group_pixels_cpu`, then `patch_groups_cpu`). Pixels whose windows have the same
column origin i0 need the same 2r + 2 tap columns; those whose windows also hold level row j need
the same tap row, P^l(f2)[:, (j, i0 .. i0 + 2r + 1)]. So the pixels are sorted by (i0, j0) (a
counting sort, one thread: a group per i0, clamped to [-(2r+2), W_l], where the clamped ends hold
the windows with no column inside), and a thread takes a group: it walks the level's rows, and for
each row j the group's pixels with j0 <= j <= j0 + 2r + 1 (consecutive in the sorted order) form
their tap rows ty = j - j0 together, up to 8 pixels at a time: each tap vector y_k is converted
and loaded once for them, and pairs of pixels share a 16-lane vector (lanes 0-7 one pixel's
x_k * y_k, lanes 8-15 the other's: per lane the same operations as above). A row's taps run in
two halves of r + 1, so 8 pixels' accumulators (20 16-lane vectors) stay in registers. The
windows are then sampled from the patches by `window_cpu.sample_patches_cpu` (4 pixels a thread, in
pixel order: 10% less time a level than sampling each group's pixels one by one after its patches).
With one pixel a tap row, each loaded and converted tap vector feeds one multiply-add: ~21 GMAC/s
on one thread against BLAS's 52 on the same core (the 2-vCPU Intel Xeon bench host), and neither the
vector width nor where the bytes come from changes that; with
eight pixels, one conversion feeds 8 pixels' multiply-adds (four 16-lane instructions): 35-43
GMAC/s. The kernel's module is compiled with `-mprefer-vector-width=512` (16-lane vectors stay
whole on AVX-512; elsewhere the compiler splits them in two). The order of the pixels, the rows and
the groups changes no value: every tap's sum is its own.

Storage. The features are read in their stored dtype, S = float32, float64 or float16
(`kernels.corr.stored`): the level's tap vectors widened in registers (`__builtin_convertvector`:
F16C conversions for float16, exact), f1 from its widened rows (`stored.widen`, exact; no copy
for float32), so a float16 lookup computes on exactly the values a widened copy would hold,
hence the same outputs bit for bit.

The kernels run on the CPU only (CUDA keeps `onthefly_kernels._patch_level` and `sample_windows`); one
kernel per (radius, working dtype, storage dtype), its own Warp module, compiled on first use.

`widen_rows_cpu`: float16 rows (N, C8) widened to float32 by the same vector conversions (exact;
`stored.widen` on the CPU).
"""

from typing import Any

import warp as wp

from kernels.corr._common import pixel_window
from kernels.native import built_once, source

# the C type of each storage dtype (patch_groups.cpp's STORE)
_STORE_C = {wp.float32: "float", wp.float64: "double", wp.float16: "_Float16"}
_group_kernels: dict[tuple[int, Any, Any], Any] = {}
_grouping_kernels: dict[tuple[int, Any], Any] = {}


def _build_group(radius: int, scalar: Any, storage: Any) -> Any:
    # No `from __future__ import annotations` in this module: Warp reads the stub's and the
    # kernel's annotations as objects, and these name the closure's types.
    side = 2 * radius + 1
    rows = wp.array2d(dtype=storage)
    wrows = wp.array2d(dtype=scalar)
    ints = wp.array(dtype=wp.int32)
    array3 = wp.array3d(dtype=scalar)

    def group_func(f1: wrows, f2l: rows, order: ints, j0s: ints, starts: ints, g: int, height_l: int,
                   width_l: int, inv: scalar, patch: array3): ...

    # A name of its own per radius and types: Warp keys native functions by name.
    group_func.__name__ = group_func.__qualname__ = f"onthefly_group_cpu_r{radius}_{scalar.__name__}_{storage.__name__}"
    fused = storage == wp.float16 and scalar == wp.float32
    # with float16 storage and float32 work the product is exact, so one fused multiply-add rounds the same sum
    # (module docstring)
    group_func = wp.func_native(source("patch_groups.cpp", SIDE=side + 1, STORE=_STORE_C[storage],
                                       FUSED=fused))(group_func)
    # Warp's default flags (or the configured ones), asking for whole 16-lane vectors (module docstring)
    base_flags = wp.config.cpu_compiler_flags if wp.config.cpu_compiler_flags is not None else "-march=native"

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3,
                                                "cpu_compiler_flags": base_flags + " -mprefer-vector-width=512"})
    def patch_groups_cpu(f1: wrows, f2l: rows, order: ints, j0s: ints, starts: ints, height_l: int,
                         width_l: int, inv: scalar, patch: array3, offset: int):
        # thread = group g: its pixels' patches
        group_func(f1, f2l, order, j0s, starts, wp.tid() + offset, height_l, width_l, inv, patch)

    return patch_groups_cpu


def patch_groups_cpu(radius: int, scalar: Any, storage: Any) -> Any:
    """The CPU kernel computing a level's patches group by group, for this radius, working dtype
    `scalar` and storage dtype `storage` (built once, cached); `window_cpu.sample_patches_cpu` then
    samples the windows from them.

    Arguments: (f1, f2l, order, sorted_j0, starts, height_l, width_l, inv, patch, offset), with f1
    (N, C8) rows of `scalar` (f1 widened), f2l (H_l W_l, C8) rows of `storage` (C8 a multiple of 8,
    rows contiguous), (order, sorted_j0, starts) from `group_pixels_cpu`, patch (N, 2r+2, 2r+2) as
    `onthefly_kernels._patch_level`'s; thread = group, over W_l + 2r + 3 groups.
    """
    return built_once(_group_kernels, (radius, scalar, storage), lambda: _build_group(radius, scalar, storage))


def _build_grouping(radius: int, scalar: Any) -> Any:
    array3 = wp.array3d(dtype=scalar)
    ints = wp.array(dtype=wp.int32)
    side = 2 * radius + 2

    def sort_func(i0s: ints, j0s: ints, order: ints, sorted_j0: ints, starts: ints, counts: ints, height_l: int,
                  width_l: int): ...

    sort_func.__name__ = sort_func.__qualname__ = f"onthefly_group_pixels_r{radius}"
    sort_func = wp.func_native(source("patch_group_pixels.cpp", SIDE=side))(sort_func)

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3})
    def group_pixels_cpu(coords: array3, scale: scalar, i0s: ints, j0s: ints, order: ints, sorted_j0: ints,
                         starts: ints, counts: ints, height_l: int, width_l: int, offset: int):
        # one thread: every pixel's window origin, then the counting sort
        for p in range(i0s.shape[0]):
            h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
            i0s[p] = i0
            j0s[p] = j0
        sort_func(i0s, j0s, order, sorted_j0, starts, counts, height_l, width_l)

    return group_pixels_cpu


def group_pixels_cpu(radius: int, scalar: Any) -> Any:
    """The CPU kernel grouping a level's pixels for `patch_groups_cpu` (launch on one thread).

    Arguments: (coords, scale, i0s, j0s, order, sorted_j0, starts, counts, height_l, width_l,
    offset): i0s, j0s (N,) receive each pixel's window origin (`pixel_window`); order (N,) the pixels
    sorted by (i0, j0), both clamped to [-(2r+2), W_l] and [-(2r+2), H_l] (a clamped origin holds the
    same taps: none inside), pixels in order within a key; sorted_j0 (N,) their clamped j0; starts
    (W_l + 2r + 4,) each group's first position in order (group g: column origin g - (2r + 2)), and
    N at the end; counts (G (H_l + 2r + 3) + 1,) scratch, G the number of groups. Built once, cached.
    """
    return built_once(_grouping_kernels, (radius, scalar), lambda: _build_grouping(radius, scalar))


_widen_kernels: dict[None, Any] = {}  # one kernel, under the key None


def _build_widen() -> Any:
    rows16 = wp.array2d(dtype=wp.float16)
    rows32 = wp.array2d(dtype=wp.float32)

    def widen_row(x: rows16, out: rows32, n: int): ...

    widen_row.__name__ = widen_row.__qualname__ = "widen_row_float16_cpu"
    widen_row = wp.func_native(source("patch_widen_rows.cpp"))(widen_row)

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3})
    def widen_rows_cpu(x: rows16, out: rows32, offset: int):
        widen_row(x, out, wp.tid() + offset)

    return widen_rows_cpu


def widen_rows_cpu() -> Any:
    """The CPU kernel widening float16 rows (N, C8) to float32 rows, exactly (a row a thread, 8-lane
    vector conversions; arguments (x, out, offset), both rows contiguous); built once, cached."""
    return built_once(_widen_kernels, None, _build_widen)
