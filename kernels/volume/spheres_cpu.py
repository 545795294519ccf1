"""render_dense's three CPU passes in C++, eight rays at once in vector lanes (float32).

The same passes as `spheres._spheres_dense_exponent_kernel`, `_spheres_dense_factor_kernel` and
`_spheres_dense_composite_kernel` (and their quad versions; the module docstring of
kernels/volume/spheres.py), with NumPy's exp between them as there, and for every sample the same
float32 operations in the same order, so the same exponents, factors and outputs bit for bit. A
group is eight rays r = 8 g + l, lane l (the rays past the last one repeat the last ray in their
lanes and nothing of them is written); at step j every lane takes sample j of its ray:

    pass 1  x = o + (t_j d) (each coordinate: the product, then the sum)
            for sphere k: q = ((x - c_k)_x^2 + (x - c_k)_y^2) + (x - c_k)_z^2, m = max(0, sqrt(q) - r_k)
            (Warp's max(0, v): 0 if 0 > v, else v), exponent -s_k m          -> E1[g][j][k][l]
    (NumPy: F = exp(E1) in place, the falloffs)
    pass 2  sigma = ((0 + s_0 F_0) + s_1 F_1) + ...;  -(sigma delta_j)        -> E2[g][j][l]
    (NumPy: e = exp(E2) in place, the compositing factors)
    pass 3  d_k = s_k F_k; sigma, and the colour sums n += d_k col_k, from 0 in sphere order; the
            colour divided by sigma where sigma > 1e-6; early termination before the sample
            (T < t_threshold: the lane stops, its values kept by a select); w = T (1 - e),
            T' = T e, C' = C + w n (each channel), D' = D + w t_j; the pixel C + T b, D, 1 - T.

Each product and each sum is its own statement, with floating-point contraction off, so no fused
multiply-add appears (none does in Warp's generated code), and the square root and division are
the IEEE ones of Warp's code. Only the order of the values in the buffers differs from the Warp
passes (a group's eight rays interleaved, so that every lane's loads are one vector load): NumPy's
exp is elementwise, so its bits do not depend on it.

One launch a chunk (`kernels()[3]`, where `kernels._npexp.numpy_agrees()`): each thread takes its
groups one after the other, and for each runs pass 1 into the chunk's scratch, NumPy's float32 exp on
the group's exponents in place, pass 2, the exp on the factors, and pass 3. The exp is
kernels._npexp's 16-lane copy of the loop np.exp runs (the same bits for all 2^32 float32 inputs on
this repository's host; `numpy_agrees` checks a fixed set against np.exp in each process, and where
anything differs the three-launch route below runs). The group's values (8 S K + 8 S floats, 8 KB at
S = 64, K = 3) stay in the core's L1/L2 cache, and a chunk costs one launch instead of three launches
and two np.exp calls. Otherwise (`kernels()[:3]`) the three passes are three launches a chunk over
the chunk's falloff and factor buffers, with np.exp between them.

Why. The Warp passes take at most four samples of one ray as the lanes of a vec4 (SSE width),
repeat Warp's index arithmetic for every array access, and pass 3 blends the samples of one ray one
after the other: its loop-carried products bound it (docs/performance.md, Textbook spheres). Here
eight rays fill the lanes, the blends of eight rays run side by side, and the buffers are read and
written as whole vectors.

Built only where the CPU has AVX2 (`#if`: CUDA and other CPUs compile a body that does nothing, and
`available()` is False there, so render_dense keeps the Warp passes); float64 keeps them too.
"""

from typing import Any

import numpy as np
import warp as wp

from kernels._native import SELECT_CPP, built_once
from kernels._npexp import NPEXP16, NPEXP_TYPES
from kernels.volume.composite_cpu import BLEND8_CPP

LANES = 8  # rays per group (one thread of each kernel)

_GUARD = r"""
#if defined(__CUDA_ARCH__) || !defined(__AVX2__)
    return;
#else
"""

_COMMON = r"""
#pragma clang fp contract(off)
    typedef float v8f __attribute__((ext_vector_type(8)));
    typedef int v8i __attribute__((ext_vector_type(8)));
""" + SELECT_CPP + BLEND8_CPP + r"""    const int n_s = t.shape[1];
    const long long ts0 = t.strides[0];
    const long long ts1 = t.strides[1];
    const char* tb = (const char*)t.data;
    const int n_k = geometry.shape[0];
    const int g = g_lo + tid;
    int rl[8];
    for (int l = 0; l < 8; ++l) {
        const int r = 8 * g + l;
        rl[l] = r < n_rays ? r : n_rays - 1;
    }
    // column j of a (R, S) float32 array (base, strides s0, s1) for every lane's ray: one load when its rows are
    // one row (s0 = 0)
    auto lanes_at = [&](const char* base, const long long s0, const long long s1, const int j) -> v8f {
        v8f v;
        if (s0 == 0) {
            v = *(const float*)(base + (long long)j * s1);
        } else {
            for (int l = 0; l < 8; ++l)
                v[l] = *(const float*)(base + (long long)rl[l] * s0 + (long long)j * s1);
        }
        return v;
    };
"""

# the sample t_j of every lane's ray
_LOAD_T = r"""
        const v8f tk = lanes_at(tb, ts0, ts1, j);
"""

# pass 1: the exponents of the group's samples to out1[j K + k] (eight lanes each)
_BODY1 = r"""
  {
    const char* ob = (const char*)origins.data;
    const char* db = (const char*)dirs.data;
    const long long os0 = origins.strides[0], os1 = origins.strides[1];
    const long long ds0 = dirs.strides[0], ds1 = dirs.strides[1];
    v8f ox, oy, oz, dx, dy, dz;
    for (int l = 0; l < 8; ++l) {
        const char* o = ob + (long long)rl[l] * os0;
        const char* d = db + (long long)rl[l] * ds0;
        ox[l] = *(const float*)o;
        oy[l] = *(const float*)(o + os1);
        oz[l] = *(const float*)(o + 2 * os1);
        dx[l] = *(const float*)d;
        dy[l] = *(const float*)(d + ds1);
        dz[l] = *(const float*)(d + 2 * ds1);
    }
    const v8f zero = 0.0f;
    for (int j = 0; j < n_s; ++j) {
""" + _LOAD_T + r"""
        const v8f sx = tk * dx;
        const v8f sy = tk * dy;
        const v8f sz = tk * dz;
        const v8f px = ox + sx;
        const v8f py = oy + sy;
        const v8f pz = oz + sz;
        for (int k = 0; k < n_k; ++k) {
            const v8f ex = px - G[4 * k];
            const v8f ey = py - G[4 * k + 1];
            const v8f ez = pz - G[4 * k + 2];
            const v8f qx = ex * ex;
            const v8f qy = ey * ey;
            const v8f qz = ez * ez;
            const v8f qxy = qx + qy;
            const v8f q = qxy + qz;
            const v8f dist = __builtin_elementwise_sqrt(q);
            const v8f v = dist - G[4 * k + 3];
            const v8i pos = zero > v;
            const v8f m = sel(pos, zero, v);
            const float neg_s = -P[4 * k + 3];
            out1[j * n_k + k] = neg_s * m;
        }
    }
  }
"""

# pass 2: from the falloffs F[j K + k], the compositing exponents to out2[j]
_BODY2 = r"""
  {
    const char* lb = (const char*)delta.data;
    const long long ls0 = delta.strides[0];
    const long long ls1 = delta.strides[1];
    for (int j = 0; j < n_s; ++j) {
        const v8f dk = lanes_at(lb, ls0, ls1, j);
        v8f sig = 0.0f;
        for (int k = 0; k < n_k; ++k) {
            const v8f d = P[4 * k + 3] * F[j * n_k + k];
            sig = sig + d;
        }
        const v8f x = sig * dk;
        out2[j] = -x;
    }
  }
"""

# pass 3: from the falloffs F and the factors E[j], the colours, the compositing and the pixels
_BODY3 = r"""
  {
    const v8f thr = t_threshold;
    const v8f one = 1.0f;
    const v8f eps = 1e-6f;
    v8f T = one;
    v8f cr = 0.0f;
    v8f cg = 0.0f;
    v8f cb = 0.0f;
    v8f dep = 0.0f;
    for (int j = 0; j < n_s; ++j) {
        const v8i run = ~(T < thr);
        if (!__builtin_reduce_or(run))
            break;
""" + _LOAD_T + r"""
        v8f sig = 0.0f;
        v8f nr = 0.0f;
        v8f ng = 0.0f;
        v8f nb = 0.0f;
        for (int k = 0; k < n_k; ++k) {
            const v8f d = P[4 * k + 3] * F[j * n_k + k];
            sig = sig + d;
            const v8f d0 = d * P[4 * k];
            nr = nr + d0;
            const v8f d1 = d * P[4 * k + 1];
            ng = ng + d1;
            const v8f d2 = d * P[4 * k + 2];
            nb = nb + d2;
        }
        const v8i norm = sig > eps;
        const v8f qr = nr / sig;
        const v8f qg = ng / sig;
        const v8f qb = nb / sig;
        nr = sel(norm, qr, nr);
        ng = sel(norm, qg, ng);
        nb = sel(norm, qb, nb);
        blend8(run, E[j], nr, ng, nb, tk, T, cr, cg, cb, dep);
    }
    const float* bg = (const float*)background.data;
    const float b0 = bg[0];
    const float b1 = bg[1];
    const float b2 = bg[2];
    char* rb = (char*)out_rgb.data;
    const long long rs0 = out_rgb.strides[0], rs1 = out_rgb.strides[1];
    for (int l = 0; l < 8; ++l) {
        const int r = 8 * g + l;
        if (r >= n_rays)
            break;
        const float Tl = T[l];
        const float tb0 = Tl * b0;
        const float tb1 = Tl * b1;
        const float tb2 = Tl * b2;
        char* o = rb + (long long)r * rs0;
        *(float*)o = cr[l] + tb0;
        *(float*)(o + rs1) = cg[l] + tb1;
        *(float*)(o + 2 * rs1) = cb[l] + tb2;
        *(float*)((char*)out_depth.data + (long long)r * out_depth.strides[0]) = dep[l];
        *(float*)((char*)out_opacity.data + (long long)r * out_opacity.strides[0]) = 1.0f - Tl;
    }
  }
"""

_PARAMS = r"""
    const float* G = (const float*)geometry.data;  // (K, 4) contiguous: c_k, r_k
    const float* P = (const float*)appearance.data;  // (K, 4) contiguous: col_k, s_k
"""

_PASS1_CPP = _GUARD + _COMMON + _PARAMS + r"""
    v8f* out1 = (v8f*)((float*)out_exponent.data + (long long)tid * n_s * n_k * 8);
""" + _BODY1 + "#endif\n"

_PASS2_CPP = _GUARD + _COMMON + _PARAMS + r"""
    const v8f* F = (const v8f*)((const float*)falloff.data + (long long)tid * n_s * n_k * 8);
    v8f* out2 = (v8f*)((float*)out_exponent.data + (long long)tid * n_s * 8);
""" + _BODY2 + "#endif\n"

_PASS3_CPP = _GUARD + _COMMON + _PARAMS + r"""
    const v8f* F = (const v8f*)((const float*)falloff.data + (long long)tid * n_s * n_k * 8);
    const v8f* E = (const v8f*)((const float*)factor.data + (long long)tid * n_s * 8);
""" + _BODY3 + "#endif\n"

# All three passes on one group, with NumPy's float32 exp in between on the group's values, in place
# in the chunk's scratch (reused group after group: in the core's L1/L2 cache): kernels._npexp's
# 16-lane copy of NumPy's exp loop, the last 8 values (the scratch holds a multiple of 8) in a padded
# vector.
_FUSED_CPP = _GUARD + _COMMON + _PARAMS + NPEXP_TYPES + r"""
    auto exp_in_place = [](float* p, const long long n) {
        long long i = 0;
        for (; i + 16 <= n; i += 16) {
            v16f nx;
            __builtin_memcpy(&nx, p + i, sizeof(nx));
""" + NPEXP16 + r"""
            __builtin_memcpy(p + i, &ne, sizeof(ne));
        }
        if (i < n) {
            float tail[16] = {0.0f};
            __builtin_memcpy(tail, p + i, (n - i) * sizeof(float));
            v16f nx;
            __builtin_memcpy(&nx, tail, sizeof(nx));
""" + NPEXP16 + r"""
            __builtin_memcpy(tail, &ne, sizeof(ne));
            __builtin_memcpy(p + i, tail, (n - i) * sizeof(float));
        }
    };
    v8f* out1 = (v8f*)scratch_falloff.data;
    v8f* out2 = (v8f*)scratch_factor.data;
""" + _BODY1 + r"""
    exp_in_place((float*)out1, (long long)n_s * n_k * 8);
    const v8f* F = out1;
""" + _BODY2 + r"""
    exp_in_place((float*)out2, (long long)n_s * 8);
    const v8f* E = out2;
""" + _BODY3 + "#endif\n"

_AVAILABLE_CPP = r"""
#if defined(__CUDA_ARCH__) || !defined(__AVX2__)
    return 0;
#else
    return 1;
#endif
"""

_kernels: dict = {}


def kernels() -> tuple[Any, Any, Any, Any]:
    """(pass 1, pass 2, pass 3, all three in one): the C++ kernels (float32; module docstring), built
    once. Thread tid of a launch with g_lo takes group g_lo + tid; the passes' buffers (falloff,
    factor, out_exponent) are views starting at group g_lo's values; the one-launch kernel's scratch
    holds one group's values (8 S K and 8 S floats) and is reused group after group."""
    return built_once(_kernels, "passes", _build)


def available() -> bool:
    """Whether the C++ passes were compiled to do their work (a CPU with AVX2), checked once."""
    return built_once(_kernels, "available", _check_available) == 1


@wp.func_native(_AVAILABLE_CPP)
def _spheres_cpu_available() -> int: ...


@wp.kernel(enable_backward=False)
def _available_kernel(out: wp.array(dtype=wp.int32)):
    out[0] = _spheres_cpu_available()


def _check_available() -> int:
    out = wp.zeros(1, dtype=wp.int32, device="cpu")
    wp.launch(_available_kernel, 1, [out], device="cpu")
    return int(out.numpy()[0])


def _build() -> tuple[Any, Any, Any, Any]:
    f32 = wp.array(dtype=wp.float32)
    f32_2 = wp.array2d(dtype=wp.float32)

    def spheres_exponents8(origins: f32_2, dirs: f32_2, t: f32_2, geometry: f32_2, appearance: f32_2,
                           out_exponent: f32, n_rays: int, g_lo: int, tid: int): ...

    def spheres_factors8(falloff: f32, t: f32_2, delta: f32_2, geometry: f32_2, appearance: f32_2,
                         out_exponent: f32, n_rays: int, g_lo: int, tid: int): ...

    def spheres_composite8(falloff: f32, factor: f32, t: f32_2, geometry: f32_2, appearance: f32_2,
                           background: f32, t_threshold: wp.float32, out_rgb: f32_2, out_depth: f32,
                           out_opacity: f32, n_rays: int, g_lo: int, tid: int): ...

    def spheres_render8(origins: f32_2, dirs: f32_2, t: f32_2, delta: f32_2, geometry: f32_2, appearance: f32_2,
                        background: f32, t_threshold: wp.float32, out_rgb: f32_2, out_depth: f32, out_opacity: f32,
                        scratch_falloff: f32, scratch_factor: f32, n_rays: int, g_lo: int, tid: int): ...

    n1 = wp.func_native(_PASS1_CPP)(spheres_exponents8)
    n2 = wp.func_native(_PASS2_CPP)(spheres_factors8)
    n3 = wp.func_native(_PASS3_CPP)(spheres_composite8)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def spheres_dense_exponent8_cpu(origins: f32_2, dirs: f32_2, t: f32_2, geometry: f32_2, appearance: f32_2,
                                    out_exponent: f32, n_rays: int, g_lo: int):
        n1(origins, dirs, t, geometry, appearance, out_exponent, n_rays, g_lo, wp.tid())

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def spheres_dense_factor8_cpu(falloff: f32, t: f32_2, delta: f32_2, geometry: f32_2, appearance: f32_2,
                                  out_exponent: f32, n_rays: int, g_lo: int):
        n2(falloff, t, delta, geometry, appearance, out_exponent, n_rays, g_lo, wp.tid())

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def spheres_dense_composite8_cpu(falloff: f32, factor: f32, t: f32_2, geometry: f32_2, appearance: f32_2,
                                     background: f32, t_threshold: wp.float32, out_rgb: f32_2, out_depth: f32,
                                     out_opacity: f32, n_rays: int, g_lo: int):
        n3(falloff, factor, t, geometry, appearance, background, t_threshold, out_rgb, out_depth, out_opacity,
           n_rays, g_lo, wp.tid())

    nf = wp.func_native(_FUSED_CPP)(spheres_render8)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def spheres_render_dense8_cpu(origins: f32_2, dirs: f32_2, t: f32_2, delta: f32_2, geometry: f32_2,
                                  appearance: f32_2, background: f32, t_threshold: wp.float32, out_rgb: f32_2,
                                  out_depth: f32, out_opacity: f32, scratch_falloff: f32, scratch_factor: f32,
                                  n_rays: int, g_lo: int):
        nf(origins, dirs, t, delta, geometry, appearance, background, t_threshold, out_rgb, out_depth, out_opacity,
           scratch_falloff, scratch_factor, n_rays, g_lo, wp.tid())

    return (spheres_dense_exponent8_cpu, spheres_dense_factor8_cpu, spheres_dense_composite8_cpu,
            spheres_render_dense8_cpu)
