"""The dense lookup's window sampling (3)-(4) on the CPU, in C++ with the window's side fixed at compile time.

Same math and the same operations as `_common.sample_window`, on the same values,
so the same outputs bit for bit. For pixel p at level l with window origin
(j0, i0) and fractions (fx, fy) (`_common.pixel_window`), gx = 1 - fx, gy = 1 - fy,
and tap rows t = 0 .. 2r+1 of S = V^l[p] (taps outside S reading 0):

    row sample   R[t, a] = gx S[j0 + t, i0 + a] + fx S[j0 + t, i0 + a + 1],      a = 0 .. 2r
    output       out[l (2r+1)^2 + a (2r+1) + b, p] = gy R[b, a] + fy R[b + 1, a],  b = 0 .. 2r

each product and each sum a separate C++ statement (so the compiler fuses no
multiply-add, exactly as Warp's generated code computes `sample_window`).

Why C++. Warp's generated code reads every tap through a runtime-strided, 3-index
array access that also wraps negative indices, and with the side a runtime value
keeps the window's loops generic: about 29 instructions an output sample at radius
4, and each output sample a scattered scalar store (out is channel-major).

Here a thread takes a block of LANES = 4 consecutive pixels, one pixel a vector
lane (`_LANES_CPP`, clang's vector extension: the same statements on vectors of 4
samples), so each output channel's 4 samples leave in one vector store. The tap
rows are read through plain pointers: a block whose windows all lie inside their
slices (most of levels 0-1) reads them without tests; otherwise (most of levels
2-3) each tap row and tap column is tested once a lane and clamped positions are
read, the outside taps set to 0. A last block of fewer than 4 pixels runs the
one-pixel version (`_WINDOW_CPP`). `sample_levels_cpu(radius, scalar)` builds one
kernel per radius and float type (its own Warp module, compiled on first use) with
the side a literal, so the compiler unrolls and schedules the window's loops.
While a block is sampled, the next block's tap rows are prefetched
(`__builtin_prefetch`, a hint): at levels 0-1 (volumes of 32 and 8 MB at 46x62
features) each window otherwise waits about one cache-miss latency.

The kernel samples up to four levels a launch, as `_common.sample_levels` does
(its arguments minus `radius`, over `blocks(H W)` threads); it is launched on the
CPU only (CUDA keeps `_common.sample_levels`). The adjoint is unchanged
(`_common.sample_windows_adjoint`). `sample_patches_cpu` is the same 4-lane window
reading each pixel's on-the-fly patch (its origin 0, 0) instead of a level slice: the
on-the-fly forward's sampling on the CPU (`_common.sample_windows` with `from_patch` = 1).
"""

from typing import Any

import warp as wp

from kernels._native import built_once
from kernels.corr._common import pixel_window

_WINDOW_CPP = r"""
    typedef decltype(fx) T;
    const int side = SIDE;
    const T one = T(1);
    const T zero = T(0);
    const T gx = one - fx;
    const T gy = one - fy;
    const int height = s.shape[1];
    const int width = s.shape[2];
    const char* slice = reinterpret_cast<const char*>(s.data) + (long long)p * s.strides[0];
    const long long row_stride = s.strides[1];
    const long long col_stride = s.strides[2];
    const long long out_stride = out.strides[0];
    // out[channel0 + a side + b, h, w] lies at first + b out_stride + a column_step
    char* first = reinterpret_cast<char*>(out.data) + (long long)h * out.strides[1]
                  + (long long)w * out.strides[2] + (long long)channel0 * out_stride;
    const long long column_step = (long long)side * out_stride;
    // every tap inside s[p] and its columns contiguous: rows of taps read without tests
    const bool inside = row0 >= 0 && col0 >= 0 && row0 + side < height && col0 + side < width
                        && col_stride == (long long)sizeof(T);
    long long col_offset[SIDE + 1];
    bool col_ok[SIDE + 1];
    if (!inside) {
        // taps outside s[p] read 0: each tap column's test and clamped offset, once
        for (int c = 0; c <= side; ++c) {
            const int col = col0 + c;
            col_ok[c] = col >= 0 && col < width;
            col_offset[c] = (long long)(col < 0 ? 0 : (col >= width ? width - 1 : col)) * col_stride;
        }
    }
    T taps[SIDE + 1];
    T top[SIDE];     // row samples R[t - 1, .]
    T bottom[SIDE];  // row samples R[t, .]
    for (int t = 0; t <= side; ++t) {
        const int row = row0 + t;
        if (inside) {
            const T* taps_row = reinterpret_cast<const T*>(slice + (long long)row * row_stride) + col0;
            for (int c = 0; c <= side; ++c)
                taps[c] = taps_row[c];
        } else {
            const bool row_ok = row >= 0 && row < height;
            const char* taps_row = slice + (long long)(row < 0 ? 0 : (row >= height ? height - 1 : row)) * row_stride;
            for (int c = 0; c <= side; ++c) {
                const T tap = *reinterpret_cast<const T*>(taps_row + col_offset[c]);
                taps[c] = (row_ok && col_ok[c]) ? tap : zero;
            }
        }
        for (int a = 0; a < side; ++a) {
            const T left = gx * taps[a];
            const T right = fx * taps[a + 1];
            bottom[a] = left + right;
        }
        if (t > 0) {
            char* o = first + (long long)(t - 1) * out_stride;
            for (int a = 0; a < side; ++a) {
                const T upper = gy * top[a];
                const T lower = fy * bottom[a];
                *reinterpret_cast<T*>(o) = upper + lower;
                o += column_step;
            }
        }
        for (int a = 0; a < side; ++a)
            top[a] = bottom[a];
    }
"""

# LANES consecutive pixels p0 .. p0 + LANES - 1 at once, a pixel a vector lane (clang's vector
# extension; this kernel is compiled for the CPU only, by Warp's clang): the same statements as
# `_WINDOW_CPP` on vectors of LANES samples, so each output channel's LANES samples leave in one
# vector store (out[c] is contiguous along the pixels) instead of LANES scattered ones. The window
# origins and fractions are `_common.pixel_window`'s operations, statement for statement.
LANES = 4  # 4 measured 1.2x faster than 8 and 1.6x faster than 2 (one thread, interleaved)

_LANES_CPP = r"""
    typedef decltype(scale) T;
    typedef T V __attribute__((ext_vector_type(LANES)));
    const int side = SIDE;
    const T radius = T((SIDE - 1) / 2);
    const int height = s.shape[1];
    const int width = s.shape[2];
    const int frame_width = coords.shape[2];
    const long long row_stride = s.strides[1];
    const long long col_stride = s.strides[2];
    const long long out_stride = out.strides[0];
    const char* xy = reinterpret_cast<const char*>(coords.data);
    V fx, fy;
    typedef decltype(fx < fy) M;  // lane masks: integers as wide as T
    int row0[LANES], col0[LANES];
    const char* slice[LANES];
    long long pixel_offset[LANES];  // of out[0, h, w]
    _Pragma("unroll") for (int l = 0; l < LANES; ++l) {
        const int p = p0 + l;
        const int h = p / frame_width;
        const int w = p % frame_width;
        const long long at = (long long)h * coords.strides[1] + (long long)w * coords.strides[2];
        T u = *reinterpret_cast<const T*>(xy + at) * scale;
        u = u - T(0.5);
        u = u - radius;
        const T i = wp::floor(u);
        T v = *reinterpret_cast<const T*>(xy + coords.strides[0] + at) * scale;
        v = v - T(0.5);
        v = v - radius;
        const T j = wp::floor(v);
        col0[l] = (int)i;
        fx[l] = u - i;
        row0[l] = (int)j;
        fy[l] = v - j;
        slice[l] = reinterpret_cast<const char*>(s.data) + (long long)p * s.strides[0];
        pixel_offset[l] = (long long)h * out.strides[1] + (long long)w * out.strides[2];
    }
    const V one = T(1);
    const V zero = T(0);
    const V gx = one - fx;
    const V gy = one - fy;
    // out[c, p0 .. p0 + LANES - 1] contiguous (a fresh output): one vector store a channel
    const bool packed = out.strides[2] == (long long)sizeof(T)
                        && pixel_offset[LANES - 1] - pixel_offset[0] == (long long)(LANES - 1) * sizeof(T);
    char* first = reinterpret_cast<char*>(out.data) + (long long)channel0 * out_stride;
    bool inside = col_stride == (long long)sizeof(T);
    _Pragma("unroll") for (int l = 0; l < LANES; ++l)
        inside = inside && row0[l] >= 0 && col0[l] >= 0 && row0[l] + side < height && col0[l] + side < width;
    long long col_offset[SIDE + 1][LANES];
    M col_ok[SIDE + 1];
    if (!inside) {
        _Pragma("unroll") for (int c = 0; c <= side; ++c) {
            _Pragma("unroll") for (int l = 0; l < LANES; ++l) {
                const int col = col0[l] + c;
                col_ok[c][l] = (col >= 0 && col < width) ? -1 : 0;
                col_offset[c][l] = (long long)(col < 0 ? 0 : (col >= width ? width - 1 : col)) * col_stride;
            }
        }
    }
    V top[SIDE];
    for (int t = 0; t <= side; ++t) {
        V taps[SIDE + 1];
        if (inside) {
            const T* rows[LANES];
            _Pragma("unroll") for (int l = 0; l < LANES; ++l)
                rows[l] = reinterpret_cast<const T*>(slice[l] + (long long)(row0[l] + t) * row_stride) + col0[l];
            _Pragma("unroll") for (int c = 0; c <= side; ++c) {
                V tap;
                _Pragma("unroll") for (int l = 0; l < LANES; ++l)
                    tap[l] = rows[l][c];
                taps[c] = tap;
            }
        } else {
            const char* rows[LANES];
            M row_ok;
            _Pragma("unroll") for (int l = 0; l < LANES; ++l) {
                const int row = row0[l] + t;
                row_ok[l] = (row >= 0 && row < height) ? -1 : 0;
                rows[l] = slice[l] + (long long)(row < 0 ? 0 : (row >= height ? height - 1 : row)) * row_stride;
            }
            _Pragma("unroll") for (int c = 0; c <= side; ++c) {
                V tap;
                _Pragma("unroll") for (int l = 0; l < LANES; ++l)
                    tap[l] = *reinterpret_cast<const T*>(rows[l] + col_offset[c][l]);
                const M ok = row_ok & col_ok[c];
                taps[c] = ok != 0 ? tap : zero;
            }
        }
        _Pragma("unroll") for (int a = 0; a < side; ++a) {
            const V left = gx * taps[a];
            const V right = fx * taps[a + 1];
            const V bottom = left + right;
            if (t > 0) {
                const V upper = gy * top[a];
                const V lower = fy * bottom;
                const V sample = upper + lower;
                char* channel = first + (long long)(a * side + t - 1) * out_stride;
                if (packed) {
                    __builtin_memcpy(channel + pixel_offset[0], &sample, sizeof(V));
                } else {
                    _Pragma("unroll") for (int l = 0; l < LANES; ++l)
                        *reinterpret_cast<T*>(channel + pixel_offset[l]) = sample[l];
                }
            }
            top[a] = bottom;
        }
    }
"""

# Touch the cache lines of a pixel's tap rows ahead of use (a hint: no value changes).
_PREFETCH_CPP = r"""
#if !defined(__CUDA_ARCH__)
    const int side = SIDE;
    const int height = s.shape[1];
    const int width = s.shape[2];
    const char* slice = reinterpret_cast<const char*>(s.data) + (long long)p * s.strides[0];
    const int first_col = col0 < 0 ? 0 : (col0 >= width ? width - 1 : col0);
    const int last_col = col0 + side < 0 ? 0 : (col0 + side >= width ? width - 1 : col0 + side);
    for (int t = 0; t <= side; ++t) {
        const int row = row0 + t;
        if (row < 0 || row >= height)
            continue;
        const char* taps_row = slice + (long long)row * s.strides[1];
        const char* last = taps_row + (long long)last_col * s.strides[2];
        for (const char* at = taps_row + (long long)first_col * s.strides[2]; at < last; at += 64)
            __builtin_prefetch(at);
        __builtin_prefetch(last);
    }
#endif
"""

_kernels: dict[tuple[int, Any], Any] = {}
_windows: dict[tuple[int, Any], Any] = {}


def window_func(radius: int, scalar: Any) -> Any:
    """The one-pixel C++ window (`_WINDOW_CPP`) for this radius and float type, a Warp native function
    (s, p, row0, col0, fx, fy, out, channel0, h, w) with `_common.sample_window`'s arguments less the
    side; built once (also used by `patch_cpu`, on the on-the-fly path's patches)."""
    return built_once(_windows, (radius, scalar), lambda: _window(radius, scalar))


def _window(radius: int, scalar: Any) -> Any:
    # No `from __future__ import annotations` in this module: Warp reads the stub's and the
    # kernel's annotations as objects, and these name the closure's types.
    side = 2 * radius + 1
    array3 = wp.array3d(dtype=scalar)

    def window(s: array3, p: int, row0: int, col0: int, fx: scalar, fy: scalar, out: array3, channel0: int,
               h: int, w: int): ...

    # A name of its own per radius and type: Warp keys native functions by name.
    window.__name__ = window.__qualname__ = f"sample_window_cpu_r{radius}_{scalar.__name__}"
    window = wp.func_native(_WINDOW_CPP.replace("SIDE", str(side)))(window)
    return window


def _build(radius: int, scalar: Any) -> Any:
    side = 2 * radius + 1
    array3 = wp.array3d(dtype=scalar)
    window = window_func(radius, scalar)

    def prefetch(s: array3, p: int, row0: int, col0: int): ...

    prefetch.__name__ = prefetch.__qualname__ = f"prefetch_window_cpu_r{radius}_{scalar.__name__}"
    prefetch = wp.func_native(_PREFETCH_CPP.replace("SIDE", str(side)))(prefetch)

    def lanes(s: array3, p0: int, coords: array3, scale: scalar, out: array3, channel0: int): ...

    lanes.__name__ = lanes.__qualname__ = f"sample_lanes_cpu_r{radius}_{scalar.__name__}"
    lanes = wp.func_native(_LANES_CPP.replace("SIDE", str(side)).replace("LANES", str(LANES)))(lanes)

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3})
    def sample_levels_cpu(v0: array3, v1: array3, v2: array3, v3: array3, n_levels: int, coords: array3,
                          out: array3, scale0: scalar, channel0: int, offset: int):
        # thread = a block of LANES consecutive pixels (the last block may hold fewer)
        p0 = (wp.tid() + offset) * LANES
        n_pixels = coords.shape[1] * coords.shape[2]
        half = scalar(0.5)
        scale = scale0
        for k in range(n_levels):  # one call site: the window's code once, not once a level
            v = v0
            if k == 1:
                v = v1
            if k == 2:
                v = v2
            if k == 3:
                v = v3
            for q in range(p0 + LANES, wp.min(p0 + 2 * LANES, n_pixels)):  # the next block's rows
                hq, wq, iq, fxq, jq, fyq = pixel_window(coords, q, scale, radius)
                prefetch(v, q, jq, iq)
            channel = channel0 + k * side * side
            if p0 + LANES <= n_pixels:
                lanes(v, p0, coords, scale, out, channel)
            else:
                for p in range(p0, n_pixels):
                    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
                    window(v, p, j0, i0, fx, fy, out, channel, h, w)
            scale = scale * half

    return sample_levels_cpu


def sample_levels_cpu(radius: int, scalar: Any) -> Any:
    """The CPU kernel sampling up to four levels for this radius and float type (built once, cached).

    Arguments: (v0, v1, v2, v3, n_levels, coords, out, scale0, channel0, offset), those of
    `_common.sample_levels` without `radius`; launched over `blocks(H W)` threads (blocks of LANES
    pixels), not one a pixel.
    """
    return built_once(_kernels, (radius, scalar), lambda: _build(radius, scalar))


def blocks(n_pixels: int) -> int:
    """Threads of a `sample_levels_cpu` launch over n_pixels pixels: one a block of LANES."""
    return -(-n_pixels // LANES)


# The on-the-fly lookup's windows, sampled from each pixel's (2r + 2)^2 patch of taps (origin 0, 0)
# instead of its level slice at the window's origin; the fractions are the same.
_PATCH_LANES_CPP = _LANES_CPP.replace("col0[l] = (int)i;", "col0[l] = 0;").replace("row0[l] = (int)j;", "row0[l] = 0;")
assert _PATCH_LANES_CPP.count("col0[l] = 0;") == 1 and _PATCH_LANES_CPP.count("row0[l] = 0;") == 1
_patch_kernels: dict[tuple[int, Any], Any] = {}


def _build_patches(radius: int, scalar: Any) -> Any:
    side = 2 * radius + 1
    array3 = wp.array3d(dtype=scalar)
    window = window_func(radius, scalar)

    def lanes(s: array3, p0: int, coords: array3, scale: scalar, out: array3, channel0: int): ...

    lanes.__name__ = lanes.__qualname__ = f"sample_patch_lanes_cpu_r{radius}_{scalar.__name__}"
    lanes = wp.func_native(_PATCH_LANES_CPP.replace("SIDE", str(side)).replace("LANES", str(LANES)))(lanes)

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3})
    def sample_patches_cpu(patch: array3, coords: array3, out: array3, scale: scalar, channel0: int, offset: int):
        # thread = a block of LANES consecutive pixels (the last block may hold fewer)
        p0 = (wp.tid() + offset) * LANES
        n_pixels = coords.shape[1] * coords.shape[2]
        if p0 + LANES <= n_pixels:
            lanes(patch, p0, coords, scale, out, channel0)
        else:
            for p in range(p0, n_pixels):
                h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
                window(patch, p, 0, 0, fx, fy, out, channel0, h, w)

    return sample_patches_cpu


def sample_patches_cpu(radius: int, scalar: Any) -> Any:
    """The CPU kernel sampling every pixel's window from its patch (the on-the-fly lookup's (3)), for this
    radius and float type: `_common.sample_windows` with `from_patch` = 1, LANES pixels a thread as
    `sample_levels_cpu` (bit-identical). Arguments (patch, coords, out, scale, channel0, offset), over
    `blocks(H W)` threads; built once, cached."""
    return built_once(_patch_kernels, (radius, scalar), lambda: _build_patches(radius, scalar))
