"""render_dense's three CPU passes in C++, eight rays at once in vector lanes (float32).

The C++ is in kernels/native/spheres_*.cpp (one file a native function; the passes' bodies in
spheres_pass1.h, spheres_pass2.h and spheres_pass3.h, their set-up in spheres_common.h, with the
shared lanes.h, blend8.h and npexp16.h), loaded by `kernels.native.source`.

The same passes as `spheres_passes._spheres_dense_exponent_kernel`, `_spheres_dense_factor_kernel` and
`_spheres_dense_composite_kernel` (and their quad versions; the module docstring of
kernels/volume/spheres_passes.py), with NumPy's exp between them as there, and for every sample the same
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
after the other: its loop-carried products bound it (docs/performance.md, "CPU fast paths", has
what the lanes gain). Here eight rays fill the lanes, the blends of eight rays run side by side,
and the buffers are read and written as whole vectors.

Built only where the CPU has AVX2 (`#if`: CUDA and other CPUs compile a body that does nothing, and
`available()` is False there, so render_dense keeps the Warp passes); float64 keeps them too.
"""

from typing import Any

import warp as wp

from kernels.native import built_once, native_flag, source

LANES = 8  # rays per group (one thread of each kernel)

_kernels: dict = {}


def kernels() -> tuple[Any, Any, Any, Any]:
    """(pass 1, pass 2, pass 3, all three in one): the C++ kernels (float32; module docstring), built
    once. Thread tid of a launch with g_lo takes group g_lo + tid; the passes' buffers (falloff,
    factor, out_exponent) are views starting at group g_lo's values; the one-launch kernel's scratch
    holds one group's values (8 S K and 8 S floats) and is reused group after group."""
    return built_once(_kernels, "passes", _build)


def available() -> bool:
    """Whether the C++ passes were compiled to do their work (a CPU with AVX2), checked once."""
    return built_once(_kernels, "available", lambda: native_flag(_spheres_cpu_available)) == 1


@wp.func_native(source("spheres_available.cpp"))
def _spheres_cpu_available() -> int: ...


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

    n1 = wp.func_native(source("spheres_exponents.cpp"))(spheres_exponents8)
    n2 = wp.func_native(source("spheres_factors.cpp"))(spheres_factors8)
    n3 = wp.func_native(source("spheres_composite.cpp"))(spheres_composite8)

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

    nf = wp.func_native(source("spheres_render.cpp"))(spheres_render8)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def spheres_render_dense8_cpu(origins: f32_2, dirs: f32_2, t: f32_2, delta: f32_2, geometry: f32_2,
                                  appearance: f32_2, background: f32, t_threshold: wp.float32, out_rgb: f32_2,
                                  out_depth: f32, out_opacity: f32, scratch_falloff: f32, scratch_factor: f32,
                                  n_rays: int, g_lo: int):
        nf(origins, dirs, t, delta, geometry, appearance, background, t_threshold, out_rgb, out_depth, out_opacity,
           scratch_falloff, scratch_factor, n_rays, g_lo, wp.tid())

    return (spheres_dense_exponent8_cpu, spheres_dense_factor8_cpu, spheres_dense_composite8_cpu,
            spheres_render_dense8_cpu)
