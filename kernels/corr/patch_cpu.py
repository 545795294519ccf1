"""The on-the-fly lookup's patches on the CPU, in C++, read from the stored features' own dtype.

Same math, same operations and the same order as `onthefly._patch_row` (then
`_common.sample_window`, by `window_cpu`'s one-pixel C++ window), so the same outputs
bit for bit. For pixel p at level l, window origin (j0, i0) (`_common.pixel_window`),
tap row ty and tap column tx (0 .. 2r+1), with x = f1[:, p] and y = P^l(f2)[:, (j0 + ty, i0 + tx)]
channels-last in 8-lane vectors x_k, y_k (k = 0 .. C8/8 - 1, channels zero-padded to C8):

    acc    = x_0 * y_0;   acc = acc + x_k * y_k  (k = 1, 2, ...; a product, then a sum, per lane)
    T[ty, tx] = (((acc[0] + acc[1]) + acc[2]) + ... + acc[7]) * (1 / sqrt(C)),   0 outside the level

each product and each sum a separate C++ statement (no fused multiply-add), as Warp's generated
code computes `_dot_v`. Except for float16 storage with float32 work, where each step is one fused
multiply-add, fma(x_k, y_k, acc) = round(acc + x_k y_k): the same value, because the product of
two float16 values is exact in float32 (two 11-bit significands make at most 22 bits, of float32's
24; |x y| <= 65504^2 < 2^32, and a nonzero |x y| >= 2^-48, far above float32's smallest normal
2^-126), so round(x y) = x y and the separate product and sum round once, as the fused one does.
(Measured: 18-20% less time for a level's patches, one thread.) The (2r + 2)^2 taps go into
patch[p] and the window is sampled from it at once (`window_cpu.window_func`), while it is in
cache.

Why C++. Warp's kernel reads a tap's vectors through runtime-strided array accesses, with the
taps of a row taken five, four, two or one at a time; here a patch row's 2r + 2 taps are one
pass over the channels with 2r + 2 accumulators held in registers (the side is a literal, the
loops unrolled), each f1 vector loaded once for the row; the lane sums of a row's first 8 taps
run as 7 vector additions on the transposed accumulators (the same additions in the same order
a tap, 10% less time a level than one tap at a time). Taps whose column lies outside the level
are computed on a clamped column and replaced by 0 (the order of every in-frame tap's sum is
unchanged); rows outside are 0.

Storage. The features are read in their stored dtype, S = float32, float64 or float16
(`kernels.corr.stored`), and widened in registers (`__builtin_convertvector`: F16C conversions for
float16, exact), so a float16 lookup needs no widened copy of f1 or of the level: it computes on
exactly the values the widened copy held, hence the same outputs bit for bit.

The kernel runs on the CPU only (CUDA keeps `onthefly._patch_level` and `sample_windows`); one
kernel per (radius, working dtype, storage dtype), its own Warp module, compiled on first use.

`widen_rows_cpu`: float16 rows (N, C8) widened to float32 by the same vector conversions (exact;
`stored.widen` on the CPU, for f1 at the full-product levels).

`full_sample_cpu`: the windows of a full-product level (`onthefly._sample_full_product`, rows of
V^l formed by BLAS) sampled by the same one-pixel C++ window in place of `_common.sample_windows`
(the same values bit for bit).
"""

from typing import Any

import warp as wp

from kernels.corr._common import pixel_window
from kernels.corr.window_cpu import built_once, window_func

_PATCH_CPP = r"""
    typedef decltype(inv) T;
    typedef STORE S;
    typedef T V __attribute__((ext_vector_type(8)));
    typedef S SV __attribute__((ext_vector_type(8), aligned(sizeof(S))));
    const int side = SIDE;  // taps a patch row: 2r + 2
    const int n_vec = f1.shape[1] / 8;
    const int height = height_l;
    const int width = width_l;
    const char* x_row = reinterpret_cast<const char*>(f1.data) + (long long)p * f1.strides[0];
    const char* level = reinterpret_cast<const char*>(f2l.data);
    const long long tap_stride = f2l.strides[0];
    char* patch_p = reinterpret_cast<char*>(patch.data) + (long long)p * patch.strides[0];
    const T zero = T(0.0);
    const T outside = inv * zero;  // `_tap_or_zero`'s 0
    long long col_offset[SIDE];
    bool col_ok[SIDE];
    _Pragma("unroll") for (int c = 0; c < side; ++c) {
        const int col = col0 + c;
        col_ok[c] = col >= 0 && col < width;
        col_offset[c] = (long long)(col < 0 ? 0 : (col >= width ? width - 1 : col)) * tap_stride;
    }
    const SV* xs = reinterpret_cast<const SV*>(x_row);
    for (int ty = 0; ty < side; ++ty) {
        const int row = row0 + ty;
        T* out_row = reinterpret_cast<T*>(patch_p + (long long)ty * patch.strides[1]);
        const long long col_step = patch.strides[2] / (long long)sizeof(T);
        if (row < 0 || row >= height) {
            _Pragma("unroll") for (int c = 0; c < side; ++c)
                out_row[c * col_step] = zero;
            continue;
        }
        const char* base = level + (long long)row * width * tap_stride;
        const SV* ys[SIDE];
        _Pragma("unroll") for (int c = 0; c < side; ++c)
            ys[c] = reinterpret_cast<const SV*>(base + col_offset[c]);
        V acc[SIDE];
        {
            const V x = __builtin_convertvector(xs[0], V);
            _Pragma("unroll") for (int c = 0; c < side; ++c) {
                const V y = __builtin_convertvector(ys[c][0], V);
                acc[c] = x * y;
            }
        }
        for (int k = 1; k < n_vec; ++k) {
            const V x = __builtin_convertvector(xs[k], V);
            _Pragma("unroll") for (int c = 0; c < side; ++c) {
                const V y = __builtin_convertvector(ys[c][k], V);
                MULTIPLY_ADD
            }
        }
        int c0 = 0;
        if (SIDE >= 8 && col_step == 1) {
            // taps 0..7: the 8x8 transpose of their accumulators, B[q][c] = acc[c][q], so the
            // lane sums ((acc[c][0] + acc[c][1]) + ...) + acc[c][7] run as 7 vector additions,
            // the same additions in the same order for every tap
            V P[8], Q[8], B[8];
            _Pragma("unroll") for (int i = 0; i < 4; ++i) {
                P[2 * i] = __builtin_shufflevector(acc[2 * i], acc[2 * i + 1], 0, 8, 2, 10, 4, 12, 6, 14);
                P[2 * i + 1] = __builtin_shufflevector(acc[2 * i], acc[2 * i + 1], 1, 9, 3, 11, 5, 13, 7, 15);
            }
            // P[2i]: lanes (acc[2i][q], acc[2i+1][q]) for q = 0, 2, 4, 6; P[2i+1]: q = 1, 3, 5, 7
            _Pragma("unroll") for (int j = 0; j < 2; ++j) {
                _Pragma("unroll") for (int e = 0; e < 2; ++e) {
                    const V a = P[4 * j + e];
                    const V b = P[4 * j + 2 + e];
                    Q[4 * j + e] = __builtin_shufflevector(a, b, 0, 1, 8, 9, 4, 5, 12, 13);
                    Q[4 * j + 2 + e] = __builtin_shufflevector(a, b, 2, 3, 10, 11, 6, 7, 14, 15);
                }
            }
            // Q[4j + e]: taps 4j..4j+3 at q = e, 4 + e; Q[4j + 2 + e]: at q = 2 + e, 6 + e
            _Pragma("unroll") for (int m = 0; m < 4; ++m) {
                const int q = (m & 1) + 2 * (m >> 1);  // m = 0, 1, 2, 3 -> q = 0, 1, 2, 3
                B[q] = __builtin_shufflevector(Q[m], Q[4 + m], 0, 1, 2, 3, 8, 9, 10, 11);
                B[q + 4] = __builtin_shufflevector(Q[m], Q[4 + m], 4, 5, 6, 7, 12, 13, 14, 15);
            }
            V sum = B[0];
            _Pragma("unroll") for (int q = 1; q < 8; ++q)
                sum = sum + B[q];
            const V taps = sum * inv;
            V kept;
            _Pragma("unroll") for (int c = 0; c < 8; ++c)
                kept[c] = col_ok[c] ? taps[c] : outside;
            __builtin_memcpy(out_row, &kept, sizeof(V));
            c0 = 8;
        }
        _Pragma("unroll") for (int c = c0; c < side; ++c) {
            T s = acc[c][0];
            _Pragma("unroll") for (int q = 1; q < 8; ++q)
                s = s + acc[c][q];
            const T tap = s * inv;
            out_row[c * col_step] = col_ok[c] ? tap : outside;
        }
    }
"""

_STORE_CPP = {wp.float32: "float", wp.float64: "double", wp.float16: "_Float16"}
# acc + x * y, a product then a sum; with float16 storage and float32 work the product is exact, so one
# fused multiply-add rounds the same sum (module docstring) in one instruction.
_SEPARATE = "const V prod = x * y;\n                acc[c] = acc[c] + prod;"
_FUSED = "acc[c] = __builtin_elementwise_fma(x, y, acc[c]);"

_kernels: dict[tuple[int, Any, Any], Any] = {}
_full_kernels: dict[tuple[int, Any], Any] = {}


def _build(radius: int, scalar: Any, storage: Any) -> Any:
    # No `from __future__ import annotations` in this module: Warp reads the stub's and the
    # kernel's annotations as objects, and these name the closure's types.
    side = 2 * radius + 1
    rows = wp.array2d(dtype=storage)
    array3 = wp.array3d(dtype=scalar)
    window = window_func(radius, scalar)

    def patch_func(f1: rows, f2l: rows, p: int, row0: int, col0: int, height_l: int, width_l: int, inv: scalar,
                   patch: array3): ...

    # A name of its own per radius and types: Warp keys native functions by name.
    patch_func.__name__ = patch_func.__qualname__ = f"onthefly_patch_cpu_r{radius}_{scalar.__name__}_{storage.__name__}"
    fused = storage == wp.float16 and scalar == wp.float32
    source = _PATCH_CPP.replace("SIDE", str(side + 1)).replace("STORE", _STORE_CPP[storage])
    patch_func = wp.func_native(source.replace("MULTIPLY_ADD", _FUSED if fused else _SEPARATE))(patch_func)

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3})
    def patch_sample_cpu(f1: rows, f2l: rows, coords: array3, patch: array3, out: array3, height_l: int,
                         width_l: int, scale: scalar, inv: scalar, channel0: int, offset: int):
        # thread = pixel: its patch, then its window sampled from the patch
        p = wp.tid() + offset
        h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
        patch_func(f1, f2l, p, j0, i0, height_l, width_l, inv, patch)
        window(patch, p, 0, 0, fx, fy, out, channel0, h, w)

    return patch_sample_cpu


def patch_sample_cpu(radius: int, scalar: Any, storage: Any) -> Any:
    """The CPU kernel computing a level's patches and sampling them, for this radius, working dtype
    `scalar` and storage dtype `storage` (built once, cached).

    Arguments: (f1, f2l, coords, patch, out, height_l, width_l, scale, inv, channel0, offset), with
    f1 (N, C8) and f2l (H_l W_l, C8) channels-last rows of `storage` (C8 a multiple of 8, rows
    contiguous), patch (N, 2r+2, 2r+2) and out as `onthefly._patch_sample_level`'s; thread = pixel.
    """
    return built_once(_kernels, (radius, scalar, storage), lambda: _build(radius, scalar, storage))


def _build_full(radius: int, scalar: Any) -> Any:
    array3 = wp.array3d(dtype=scalar)
    window = window_func(radius, scalar)

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3})
    def full_sample_cpu(s: array3, coords: array3, out: array3, scale: scalar, channel0: int, block0: int,
                        offset: int):
        # thread = pixel p = block0 + row: its window sampled from s[row], the rows of V^l of the block
        row = wp.tid() + offset
        p = row + block0
        h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
        window(s, row, j0, i0, fx, fy, out, channel0, h, w)

    return full_sample_cpu


def full_sample_cpu(radius: int, scalar: Any) -> Any:
    """The CPU kernel sampling a full-product level's block of rows of V^l: `_common.sample_windows`
    with `from_patch` = 0 (arguments (s, coords, out, scale, channel0, block0, offset), its own less
    `radius` and `from_patch`), by `window_cpu`'s one-pixel C++ window (bit-identical); built once, cached."""
    return built_once(_full_kernels, (radius, scalar), lambda: _build_full(radius, scalar))


_WIDEN_CPP = r"""
    typedef _Float16 S;
    typedef float T;
    typedef S SV __attribute__((ext_vector_type(8), aligned(sizeof(S))));
    typedef T V __attribute__((ext_vector_type(8), aligned(sizeof(T))));
    const int n_vec = x.shape[1] / 8;
    const SV* in = reinterpret_cast<const SV*>(reinterpret_cast<const char*>(x.data) + (long long)n * x.strides[0]);
    V* o = reinterpret_cast<V*>(reinterpret_cast<char*>(out.data) + (long long)n * out.strides[0]);
    for (int k = 0; k < n_vec; ++k)
        o[k] = __builtin_convertvector(in[k], V);
"""

_widen_kernels: dict[None, Any] = {}  # one kernel, under the key None


def _build_widen() -> Any:
    rows16 = wp.array2d(dtype=wp.float16)
    rows32 = wp.array2d(dtype=wp.float32)

    def widen_row(x: rows16, out: rows32, n: int): ...

    widen_row.__name__ = widen_row.__qualname__ = "widen_row_float16_cpu"
    widen_row = wp.func_native(_WIDEN_CPP)(widen_row)

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3})
    def widen_rows_cpu(x: rows16, out: rows32, offset: int):
        widen_row(x, out, wp.tid() + offset)

    return widen_rows_cpu


def widen_rows_cpu() -> Any:
    """The CPU kernel widening float16 rows (N, C8) to float32 rows, exactly (a row a thread, 8-lane
    vector conversions; arguments (x, out, offset), both rows contiguous); built once, cached."""
    return built_once(_widen_kernels, None, _build_widen)
