"""The on-the-fly lookup's patches on the CPU, in C++, read from the stored features' own dtype.

Same math, same operations and the same order per tap as `onthefly._patch_row` (then
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
With one pixel a tap row (the fourth round's kernel), each loaded and converted tap vector fed
one multiply-add: ~21 GMAC/s on one thread against BLAS's 52 on the same core, and neither the
vector width nor where the bytes came from changed that (docs/performance.md, "Fifth round"); with
eight pixels, one conversion feeds 8 pixels' multiply-adds (four 16-lane instructions): 35-43
GMAC/s. The kernel's module is compiled with `-mprefer-vector-width=512` (16-lane vectors stay
whole on AVX-512; elsewhere the compiler splits them in two). The order of the pixels, the rows and
the groups changes no value: every tap's sum is its own.

Storage. The features are read in their stored dtype, S = float32, float64 or float16
(`kernels.corr.stored`): the level's tap vectors widened in registers (`__builtin_convertvector`:
F16C conversions for float16, exact), f1 from its widened rows (`stored.widen`, exact; no copy
for float32), so a float16 lookup computes on exactly the values a widened copy would hold,
hence the same outputs bit for bit.

The kernels run on the CPU only (CUDA keeps `onthefly._patch_level` and `sample_windows`); one
kernel per (radius, working dtype, storage dtype), its own Warp module, compiled on first use.

`widen_rows_cpu`: float16 rows (N, C8) widened to float32 by the same vector conversions (exact;
`stored.widen` on the CPU).
"""

from typing import Any

import warp as wp

from kernels.corr._common import pixel_window
from kernels._native import built_once

# A group's patches (`patch_groups_cpu`; module docstring): thread = group g.
_GROUP_CPP = r"""
    typedef decltype(inv) T;
    typedef STORE S;
    typedef T V __attribute__((ext_vector_type(8)));
    typedef T XV __attribute__((ext_vector_type(8), aligned(sizeof(T))));
    typedef S SV __attribute__((ext_vector_type(8), aligned(sizeof(S))));
    const int side = SIDE;  // taps a patch row: 2r + 2 (even)
    const int half = SIDE / 2;
    const int n_vec = f1.shape[1] / 8;
    const int height = height_l;
    const int width = width_l;
    const int* ord = reinterpret_cast<const int*>(order.data);
    const int* gj0 = reinterpret_cast<const int*>(j0s.data);
    const int q0 = reinterpret_cast<const int*>(starts.data)[g];
    const int q1 = reinterpret_cast<const int*>(starts.data)[g + 1];
    const int col0 = g - side;  // the bucket's window column origin (clamped to [-side, width]: see `_GROUPS_CPP`)
    const char* level = reinterpret_cast<const char*>(f2l.data);
    const long long tap_stride = f2l.strides[0];
    const char* f1_base = reinterpret_cast<const char*>(f1.data);
    const long long f1_stride = f1.strides[0];
    char* patch_base = reinterpret_cast<char*>(patch.data);
    const long long patch_pixel = patch.strides[0];
    const long long patch_row = patch.strides[1];
    const long long col_step = patch.strides[2] / (long long)sizeof(T);
    const T zero = T(0.0);
    const T outside = inv * zero;  // `_tap_or_zero`'s 0
    long long col_offset[SIDE];
    bool col_ok[SIDE];
    _Pragma("unroll") for (int c = 0; c < side; ++c) {
        const long long col = (long long)col0 + c;
        col_ok[c] = col >= 0 && col < width;
        col_offset[c] = (col < 0 ? 0 : (col >= width ? width - 1 : col)) * tap_stride;
    }
    const bool any_col = (long long)col0 + side > 0 && col0 < width;
    // rows outside the level: 0; a window with every column outside: `outside` in its rows inside
    for (int q = q0; q < q1; ++q) {
        char* patch_p = patch_base + (long long)ord[q] * patch_pixel;
        for (int ty = 0; ty < side; ++ty) {
            const long long row = (long long)gj0[q] + ty;
            const bool row_in = row >= 0 && row < height;
            if (row_in && any_col)
                continue;
            T* out_row = reinterpret_cast<T*>(patch_p + (long long)ty * patch_row);
            _Pragma("unroll") for (int c = 0; c < side; ++c)
                out_row[c * col_step] = row_in ? outside : zero;
        }
    }
    if (!any_col || q0 >= q1)
        return;
    // a tap row's side 8-lane accumulators summed lane by lane, scaled and stored (`outside` where the column
    // is outside the level); taps 0..7: the 8x8 transpose of their accumulators, B[q][c] = acc[c][q], so the
    // lane sums ((acc[c][0] + acc[c][1]) + ...) + acc[c][7] run as 7 vector additions, the same additions in
    // the same order for every tap
    auto store_row = [&](const V* acc, T* out_row) {
        int c0 = 0;
        if (SIDE >= 8 && col_step == 1) {
            V P[8], Q[8], B[8];
            _Pragma("unroll") for (int i = 0; i < 4; ++i) {
                P[2 * i] = __builtin_shufflevector(acc[2 * i], acc[2 * i + 1], 0, 8, 2, 10, 4, 12, 6, 14);
                P[2 * i + 1] = __builtin_shufflevector(acc[2 * i], acc[2 * i + 1], 1, 9, 3, 11, 5, 13, 7, 15);
            }
            _Pragma("unroll") for (int j = 0; j < 2; ++j) {
                _Pragma("unroll") for (int e = 0; e < 2; ++e) {
                    const V a = P[4 * j + e];
                    const V b = P[4 * j + 2 + e];
                    Q[4 * j + e] = __builtin_shufflevector(a, b, 0, 1, 8, 9, 4, 5, 12, 13);
                    Q[4 * j + 2 + e] = __builtin_shufflevector(a, b, 2, 3, 10, 11, 6, 7, 14, 15);
                }
            }
            _Pragma("unroll") for (int m = 0; m < 4; ++m) {
                const int q = (m & 1) + 2 * (m >> 1);
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
        // the other taps one at a time (constant bounds, so the loop unrolls: c0 is 0 or 8)
        _Pragma("unroll") for (int c = 0; c < side; ++c) {
            if (c < c0)
                continue;
            T s = acc[c][0];
            _Pragma("unroll") for (int q = 1; q < 8; ++q)
                s = s + acc[c][q];
            const T tap = s * inv;
            out_row[c * col_step] = col_ok[c] ? tap : outside;
        }
    };
    // K pixels (sorted positions q .. q + K - 1; K = 1 here) against level row r: their tap rows r - j0,
    // half a row's taps at a time, each tap vector converted once for the K pixels
    auto block = [&](auto tag, int q, long long r) {
        constexpr int K = sizeof(*tag);
        const char* base = level + r * width * tap_stride;
        const XV* xs[K];
        _Pragma("unroll") for (int i = 0; i < K; ++i)
            xs[i] = reinterpret_cast<const XV*>(f1_base + (long long)ord[q + i] * f1_stride);
        V acc[K][SIDE];
        _Pragma("unroll") for (int h = 0; h < 2; ++h) {
            const SV* ys[SIDE / 2];
            _Pragma("unroll") for (int c = 0; c < half; ++c)
                ys[c] = reinterpret_cast<const SV*>(base + col_offset[h * half + c]);
            V a[K][SIDE / 2];
            {
                V y[SIDE / 2];
                _Pragma("unroll") for (int c = 0; c < half; ++c)
                    y[c] = __builtin_convertvector(ys[c][0], V);
                _Pragma("unroll") for (int i = 0; i < K; ++i) {
                    const V x = xs[i][0];
                    _Pragma("unroll") for (int c = 0; c < half; ++c)
                        a[i][c] = x * y[c];
                }
            }
            for (int k = 1; k < n_vec; ++k) {
                V y[SIDE / 2];
                _Pragma("unroll") for (int c = 0; c < half; ++c)
                    y[c] = __builtin_convertvector(ys[c][k], V);
                _Pragma("unroll") for (int i = 0; i < K; ++i) {
                    const V x = xs[i][k];
                    _Pragma("unroll") for (int c = 0; c < half; ++c) {
                        MULTIPLY_ADD
                    }
                }
            }
            _Pragma("unroll") for (int i = 0; i < K; ++i)
                _Pragma("unroll") for (int c = 0; c < half; ++c)
                    acc[i][h * half + c] = a[i][c];
        }
        _Pragma("unroll") for (int i = 0; i < K; ++i) {
            const long long ty = r - gj0[q + i];
            store_row(acc[i], reinterpret_cast<T*>(patch_base + (long long)ord[q + i] * patch_pixel + ty * patch_row));
        }
    };
    // 2P pixels as P pairs, a pair in the two halves of a 16-lane vector (lanes 0-7 the first pixel's, 8-15
    // the second's) against the tap vector in both halves: each lane the same operations as `block`'s
    typedef T W2 __attribute__((ext_vector_type(16)));
    auto pairs = [&](auto tag, int q, long long r) {
        constexpr int P = sizeof(*tag);
        const char* base = level + r * width * tap_stride;
        const XV* xs[2 * P];
        _Pragma("unroll") for (int i = 0; i < 2 * P; ++i)
            xs[i] = reinterpret_cast<const XV*>(f1_base + (long long)ord[q + i] * f1_stride);
        V acc[2 * P][SIDE];
        _Pragma("unroll") for (int h = 0; h < 2; ++h) {
            const SV* ys[SIDE / 2];
            _Pragma("unroll") for (int c = 0; c < half; ++c)
                ys[c] = reinterpret_cast<const SV*>(base + col_offset[h * half + c]);
            W2 a[P][SIDE / 2];
            {
                W2 y[SIDE / 2];
                _Pragma("unroll") for (int c = 0; c < half; ++c) {
                    const V y8 = __builtin_convertvector(ys[c][0], V);
                    y[c] = __builtin_shufflevector(y8, y8, 0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7);
                }
                _Pragma("unroll") for (int i = 0; i < P; ++i) {
                    const V x0 = xs[2 * i][0];
                    const V x1 = xs[2 * i + 1][0];
                    const W2 x = __builtin_shufflevector(x0, x1, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
                    _Pragma("unroll") for (int c = 0; c < half; ++c)
                        a[i][c] = x * y[c];
                }
            }
            for (int k = 1; k < n_vec; ++k) {
                W2 y[SIDE / 2];
                _Pragma("unroll") for (int c = 0; c < half; ++c) {
                    const V y8 = __builtin_convertvector(ys[c][k], V);
                    y[c] = __builtin_shufflevector(y8, y8, 0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7);
                }
                _Pragma("unroll") for (int i = 0; i < P; ++i) {
                    const V x0 = xs[2 * i][k];
                    const V x1 = xs[2 * i + 1][k];
                    const W2 x = __builtin_shufflevector(x0, x1, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
                    _Pragma("unroll") for (int c = 0; c < half; ++c) {
                        MULTIPLY_ADD2
                    }
                }
            }
            _Pragma("unroll") for (int i = 0; i < P; ++i)
                _Pragma("unroll") for (int c = 0; c < half; ++c) {
                    const W2 pair = a[i][c];
                    acc[2 * i][h * half + c] = __builtin_shufflevector(pair, pair, 0, 1, 2, 3, 4, 5, 6, 7);
                    acc[2 * i + 1][h * half + c] = __builtin_shufflevector(pair, pair, 8, 9, 10, 11, 12, 13, 14, 15);
                }
        }
        _Pragma("unroll") for (int i = 0; i < 2 * P; ++i) {
            const long long ty = r - gj0[q + i];
            store_row(acc[i], reinterpret_cast<T*>(patch_base + (long long)ord[q + i] * patch_pixel + ty * patch_row));
        }
    };
    // level rows in order; the pixels whose windows hold row r are q in [lo, hi) (sorted by j0)
    const long long r_first = (long long)gj0[q0] > 0 ? (long long)gj0[q0] : 0;
    const long long r_last_win = (long long)gj0[q1 - 1] + side - 1;
    const long long r_last = r_last_win < height - 1 ? r_last_win : height - 1;
    int lo = q0;
    int hi = q0;
    for (long long r = r_first; r <= r_last; ++r) {
        while (hi < q1 && (long long)gj0[hi] <= r)
            ++hi;
        while (lo < hi && (long long)gj0[lo] + side - 1 < r)
            ++lo;
        int q = lo;
        for (; q + 8 <= hi; q += 8)
            pairs((const char(*)[4])nullptr, q, r);
        if (q + 4 <= hi) {
            pairs((const char(*)[2])nullptr, q, r);
            q += 4;
        }
        if (q + 2 <= hi) {
            pairs((const char(*)[1])nullptr, q, r);
            q += 2;
        }
        if (q < hi)
            block((const char(*)[1])nullptr, q, r);
    }
"""
_STORE_CPP = {wp.float32: "float", wp.float64: "double", wp.float16: "_Float16"}
# a[i][c] + x * y[c], a product then a sum (8 lanes: V; a pair of pixels: W2); with float16 storage and
# float32 work the product is exact, so one fused multiply-add rounds the same sum (module docstring).
_SEPARATE = "const V prod = x * y[c];\n                        a[i][c] = a[i][c] + prod;"
_SEPARATE_PAIR = "const W2 prod = x * y[c];\n                        a[i][c] = a[i][c] + prod;"
_FUSED = "a[i][c] = __builtin_elementwise_fma(x, y[c], a[i][c]);"

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
    source = _GROUP_CPP.replace("SIDE", str(side + 1)).replace("STORE", _STORE_CPP[storage])
    source = source.replace("MULTIPLY_ADD2", _FUSED if fused else _SEPARATE_PAIR)
    group_func = wp.func_native(source.replace("MULTIPLY_ADD", _FUSED if fused else _SEPARATE))(group_func)
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
    `onthefly._patch_level`'s; thread = group, over W_l + 2r + 3 groups.
    """
    return built_once(_group_kernels, (radius, scalar, storage), lambda: _build_group(radius, scalar, storage))


# The counting sort of `group_pixels_cpu`: key (i0, j0), both clamped.
_GROUPS_CPP = r"""
    const int side = SIDE;
    const int n = i0s.shape[0];
    const int height = height_l;
    const int width = width_l;
    const int n_rows = height + side + 1;  // j0 clamped to [-side, height]
    const int n_buckets = width + side + 1;  // i0 clamped to [-side, width]
    const int* i0 = reinterpret_cast<const int*>(i0s.data);
    const int* j0 = reinterpret_cast<const int*>(j0s.data);
    int* ord = reinterpret_cast<int*>(order.data);
    int* sj0 = reinterpret_cast<int*>(sorted_j0.data);
    int* st = reinterpret_cast<int*>(starts.data);
    int* count = reinterpret_cast<int*>(counts.data);
    auto clamp = [](int v, int lo, int hi) { return v < lo ? lo : (v > hi ? hi : v); };
    auto key = [&](int p) {
        return (clamp(i0[p], -side, width) + side) * n_rows + clamp(j0[p], -side, height) + side;
    };
    for (int k = 0; k <= n_buckets * n_rows; ++k)
        count[k] = 0;
    for (int p = 0; p < n; ++p)
        ++count[key(p) + 1];
    for (int k = 0; k < n_buckets * n_rows; ++k)
        count[k + 1] += count[k];
    for (int b = 0; b < n_buckets; ++b)
        st[b] = count[b * n_rows];
    st[n_buckets] = n;
    for (int p = 0; p < n; ++p) {
        const int k = key(p);
        const int at = count[k]++;
        ord[at] = p;
        sj0[at] = clamp(j0[p], -side, height);
    }
"""

def _build_grouping(radius: int, scalar: Any) -> Any:
    array3 = wp.array3d(dtype=scalar)
    ints = wp.array(dtype=wp.int32)
    side = 2 * radius + 2

    def sort_func(i0s: ints, j0s: ints, order: ints, sorted_j0: ints, starts: ints, counts: ints, height_l: int,
                  width_l: int): ...

    sort_func.__name__ = sort_func.__qualname__ = f"onthefly_group_pixels_r{radius}"
    sort_func = wp.func_native(_GROUPS_CPP.replace("SIDE", str(side)))(sort_func)

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
