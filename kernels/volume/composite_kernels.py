"""The compositing kernels: the volume-rendering quadrature along each ray and its hand-written reverse pass.

Ray r owns the packed samples k = o_r .. o_{r+1}-1 in front-to-back order, each with density
sigma_k >= 0, colour c_k, interval length delta_k >= 0 and depth z_k (kernels.volume.composite
states the conventions). With the factor e_k = exp(-sigma_k delta_k) = 1 - alpha_k,

    w_k = T_k (1 - e_k),   T_{k+1} = T_k e_k,   T_0 = 1          (_composite_step)
    C = sum_k w_k c_k + T_N b,   D = sum_k w_k z_k,   A = 1 - T_N,

stopping before sample k as soon as T_k < t_threshold (n_used counts the samples processed).
The factor is read from `factor` where the CPU filled it first, else evaluated and stored
(_sample_factor). Backward, for cotangents (g_C, g_D, g_A) and f_k = g_C . c_k + g_D z_k:

    dL/dc_k     = g_C w_k
    dL/dsigma_k = delta_k [ T_{k+1} f_k - S_k + T_N (g_A - g_C . b) ],   S_k = sum_{j>k} w_j f_j

(_backward_step), a second pass over the ray from the forward's final values: the total
sum_j w_j f_j = g_C . (C - T_N b) + g_D D, S_k = total - (the running prefix), and T_k rebuilt
front to back from the stored factors (the forward's products, so bit for bit its T_k and w_k).
Samples after the termination point get zero gradient. At the termination threshold the outputs
jump (a sample's inclusion switches there); the gradient is that of the samples processed.

One thread per ray, writing only its ray's outputs and its samples' gradients. The loops take
the samples four at a time where four consecutive ones start at a multiple of 4 (vec4 loads of
the factors and depths, vec3 loads of the colours) and none of the four terminates the ray, one
at a time elsewhere: the same operations in the same order, so the outputs are bit for bit those
of a one-at-a-time loop. `_FORWARD` and `_BACKWARD` hold the concrete float32 and float64
overloads with those vector types.
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels import _arrays as A

wp.set_module_options({"enable_backward": False})


@wp.func
def _sample_factor(sigma: wp.array(dtype=typing.Any), delta: wp.array(dtype=typing.Any),
                   factor: wp.array(dtype=typing.Any), k: int, factor_given: int):
    """exp(-sigma_k delta_k): read from `factor` (filled before the launch), or evaluated and stored."""
    if factor_given != 0:
        return factor[k]
    e = wp.exp(-sigma[k] * delta[k])
    factor[k] = e
    return e


@wp.func
def ray_start(like: typing.Any):
    """(T, C, D) before a ray's first sample: T = 1, C = (0, 0, 0), D = 0, in like's type."""
    zero = type(like)(0.0)
    return type(like)(1.0), zero, zero, zero, zero


@wp.func
def blend_step(T: typing.Any, cr: typing.Any, cg: typing.Any, cb: typing.Any, d: typing.Any, e: typing.Any,
               nr: typing.Any, ng: typing.Any, nb: typing.Any, zk: typing.Any):
    """One sample of the quadrature given e = exp(-sigma delta) = 1 - alpha and the sample's colour
    and depth: w = T (1 - e); (T e, C + w c, D + w z)."""
    w = T * (type(T)(1.0) - e)
    return T * e, cr + w * nr, cg + w * ng, cb + w * nb, d + w * zk


@wp.func
def _composite_step(T: typing.Any, cr: typing.Any, cg: typing.Any, cb: typing.Any, d: typing.Any, e: typing.Any,
                    c: typing.Any, zk: typing.Any):
    """blend_step with the colour as a vec3."""
    return blend_step(T, cr, cg, cb, d, e, c[0], c[1], c[2], zk)


@wp.func
def _steps_one_at_a_time(sigma: wp.array(dtype=typing.Any), rgb: wp.array(dtype=typing.Any),
                         delta: wp.array(dtype=typing.Any), z: wp.array(dtype=typing.Any),
                         factor: wp.array(dtype=typing.Any), factor_given: int, t_threshold: typing.Any,
                         T: typing.Any, cr: typing.Any, cg: typing.Any, cb: typing.Any, d: typing.Any, k: int,
                         stop: int, to_quad: int):
    """The forward's samples k, k + 1, ... one at a time while k < stop (and, with to_quad, while k is
    not a multiple of 4); early termination ends the ray (stop = k). Returns (T, C, D, k, stop)."""
    while k < stop and (to_quad == 0 or k % 4 != 0):
        if T < t_threshold:
            stop = k
        else:
            e = _sample_factor(sigma, delta, factor, k, factor_given)
            T, cr, cg, cb, d = _composite_step(T, cr, cg, cb, d, e, rgb[k], z[k])
            k += 1
    return T, cr, cg, cb, d, k, stop


@wp.kernel
def _composite_forward_kernel(
    sigma: wp.array(dtype=typing.Any), rgb: wp.array(dtype=typing.Any), delta: wp.array(dtype=typing.Any),
    z: wp.array(dtype=typing.Any), ray_offsets: wp.array(dtype=wp.int32), background: wp.array2d(dtype=typing.Any),
    background_per_ray: int, t_threshold: typing.Any,
    out_rgb: wp.array2d(dtype=typing.Any), out_depth: wp.array(dtype=typing.Any),
    out_opacity: wp.array(dtype=typing.Any), out_transmittance: wp.array(dtype=typing.Any),
    out_n_used: wp.array(dtype=wp.int32), out_factor: wp.array(dtype=typing.Any), factor_given: int,
    factor4: wp.array(dtype=typing.Any), z4: wp.array(dtype=typing.Any), check_values: int,
    out_bad: wp.array(dtype=wp.int32), offset: int,
):
    # rgb is the (N, 3) colours viewed as N vec3; factor4 and z4 view out_factor and z as vec4 (samples 4q..4q+3).
    # check_values != 0: out_bad[r] = 1 if a colour or depth of the ray may be NaN or infinite (see below).
    r = wp.tid() + offset
    one = sigma.dtype(1.0)
    T, cr, cg, cb, d = ray_start(one)
    start = ray_offsets[r]
    k = start
    # Single samples up to a multiple of 4 (stop = k ends the ray: early termination) ...
    T, cr, cg, cb, d, k, stop = _steps_one_at_a_time(sigma, rgb, delta, z, out_factor, factor_given, t_threshold,
                                                     T, cr, cg, cb, d, k, ray_offsets[r + 1], 1)
    # ... then four at a time while none of the four terminates (the same operations in the same
    # order as one at a time, so bit for bit the same sums; fewer loop and index computations) ...
    while k + 4 <= stop:
        q = k // 4
        e4 = factor4[q]
        if factor_given == 0:
            e4 = wp.vector(wp.exp(-sigma[k] * delta[k]), wp.exp(-sigma[k + 1] * delta[k + 1]),
                           wp.exp(-sigma[k + 2] * delta[k + 2]), wp.exp(-sigma[k + 3] * delta[k + 3]))
            factor4[q] = e4
        T1 = T * e4[0]
        T2 = T1 * e4[1]
        T3 = T2 * e4[2]
        if T < t_threshold or T1 < t_threshold or T2 < t_threshold or T3 < t_threshold:
            break
        z_q = z4[q]
        T, cr, cg, cb, d = _composite_step(T, cr, cg, cb, d, e4[0], rgb[k], z_q[0])
        T, cr, cg, cb, d = _composite_step(T, cr, cg, cb, d, e4[1], rgb[k + 1], z_q[1])
        T, cr, cg, cb, d = _composite_step(T, cr, cg, cb, d, e4[2], rgb[k + 2], z_q[2])
        T, cr, cg, cb, d = _composite_step(T, cr, cg, cb, d, e4[3], rgb[k + 3], z_q[3])
        k += 4
    # ... and single samples for the rest (the tail, or the quad in which the ray terminates).
    T, cr, cg, cb, d, k, stop = _steps_one_at_a_time(sigma, rgb, delta, z, out_factor, factor_given, t_threshold,
                                                     T, cr, cg, cb, d, k, stop, 0)
    if check_values != 0:
        # The sums C and D are NaN or infinite if a processed colour or depth is (w_k is finite:
        # sigma and delta were checked), so only the samples after early termination are added
        # up here. Infinite sums of finite values are a false alarm that the exact check clears.
        rest = sigma.dtype(0.0)
        for j in range(k, ray_offsets[r + 1]):
            c = rgb[j]
            rest += c[0] + c[1] + c[2] + z[j]
        bad = int(1)
        if wp.isfinite(cr) and wp.isfinite(cg) and wp.isfinite(cb) and wp.isfinite(d) and wp.isfinite(rest):
            bad = 0
        out_bad[r] = bad
    b = r * background_per_ray
    out_rgb[r, 0] = cr + T * background[b, 0]
    out_rgb[r, 1] = cg + T * background[b, 1]
    out_rgb[r, 2] = cb + T * background[b, 2]
    out_depth[r] = d
    out_opacity[r] = one - T
    out_transmittance[r] = T
    out_n_used[r] = k - start


@wp.func
def _backward_step(T: typing.Any, prefix: typing.Any, e: typing.Any, c: typing.Any, zk: typing.Any, dk: typing.Any,
                   gr: typing.Any, gg: typing.Any, gb: typing.Any, gd: typing.Any, total: typing.Any,
                   tail: typing.Any):
    """One sample of the backward: (T_{k+1}, prefix through k, dL/dsigma_k, w_k)."""
    w = T * (type(T)(1.0) - e)
    f = gr * c[0] + gg * c[1] + gb * c[2] + gd * zk
    prefix = prefix + w * f
    T = T * e
    return T, prefix, dk * (T * f - (total - prefix) + tail), w


@wp.kernel
def _composite_backward_kernel(
    factor: wp.array(dtype=typing.Any), rgb: wp.array(dtype=typing.Any), delta: wp.array(dtype=typing.Any),
    z: wp.array(dtype=typing.Any), ray_offsets: wp.array(dtype=wp.int32), background: wp.array2d(dtype=typing.Any),
    background_per_ray: int, out_rgb: wp.array2d(dtype=typing.Any), out_depth: wp.array(dtype=typing.Any),
    out_transmittance: wp.array(dtype=typing.Any), out_n_used: wp.array(dtype=wp.int32),
    grad_rgb: wp.array2d(dtype=typing.Any), grad_depth: wp.array(dtype=typing.Any),
    grad_opacity: wp.array(dtype=typing.Any), grad_sigma: wp.array(dtype=typing.Any),
    grad_sample_rgb: wp.array(dtype=typing.Any), factor4: wp.array(dtype=typing.Any), z4: wp.array(dtype=typing.Any),
    delta4: wp.array(dtype=typing.Any), grad_sigma4: wp.array(dtype=typing.Any), offset: int,
):
    # rgb and grad_sample_rgb are (N, 3) arrays viewed as N vec3; the *4 arrays view their namesakes
    # as vec4 (samples 4q..4q+3). Quads where aligned, as in the forward kernel: the same operations.
    r = wp.tid() + offset
    zero = factor.dtype(0.0)
    one = factor.dtype(1.0)
    b = r * background_per_ray
    gr = grad_rgb[r, 0]
    gg = grad_rgb[r, 1]
    gb = grad_rgb[r, 2]
    gd = grad_depth[r]
    g3 = wp.vector(gr, gg, gb)
    T_final = out_transmittance[r]
    g_bg = gr * background[b, 0] + gg * background[b, 1] + gb * background[b, 2]
    total = (gr * (out_rgb[r, 0] - T_final * background[b, 0]) + gg * (out_rgb[r, 1] - T_final * background[b, 1])
             + gb * (out_rgb[r, 2] - T_final * background[b, 2]) + gd * out_depth[r])
    tail = T_final * (grad_opacity[r] - g_bg)
    start = ray_offsets[r]
    stop = start + out_n_used[r]
    T = one
    prefix = zero
    k = start
    while k < stop and k % 4 != 0:
        # factor: exp(-sigma_k delta_k), stored by the forward: bit for bit its T_k and w_k
        T, prefix, gs, w = _backward_step(T, prefix, factor[k], rgb[k], z[k], delta[k], gr, gg, gb, gd, total, tail)
        grad_sigma[k] = gs
        grad_sample_rgb[k] = g3 * w
        k += 1
    while k + 4 <= stop:
        q = k // 4
        e4 = factor4[q]
        z_q = z4[q]
        d_q = delta4[q]
        T, prefix, gs0, w0 = _backward_step(T, prefix, e4[0], rgb[k], z_q[0], d_q[0], gr, gg, gb, gd, total, tail)
        T, prefix, gs1, w1 = _backward_step(T, prefix, e4[1], rgb[k + 1], z_q[1], d_q[1], gr, gg, gb, gd, total, tail)
        T, prefix, gs2, w2 = _backward_step(T, prefix, e4[2], rgb[k + 2], z_q[2], d_q[2], gr, gg, gb, gd, total, tail)
        T, prefix, gs3, w3 = _backward_step(T, prefix, e4[3], rgb[k + 3], z_q[3], d_q[3], gr, gg, gb, gd, total, tail)
        grad_sigma4[q] = wp.vector(gs0, gs1, gs2, gs3)
        grad_sample_rgb[k] = g3 * w0
        grad_sample_rgb[k + 1] = g3 * w1
        grad_sample_rgb[k + 2] = g3 * w2
        grad_sample_rgb[k + 3] = g3 * w3
        k += 4
    while k < stop:
        T, prefix, gs, w = _backward_step(T, prefix, factor[k], rgb[k], z[k], delta[k], gr, gg, gb, gd, total, tail)
        grad_sigma[k] = gs
        grad_sample_rgb[k] = g3 * w
        k += 1
    zero3 = wp.vector(zero, zero, zero)
    for j in range(stop, ray_offsets[r + 1]):
        grad_sigma[j] = zero
        grad_sample_rgb[j] = zero3


_VEC3 = {wp.float32: wp.vec3f, wp.float64: wp.vec3d}
_VEC4 = {wp.float32: wp.vec4f, wp.float64: wp.vec4d}


def _declare_overloads(kernel: Any, vec3: tuple[str, ...], vec4: tuple[str, ...]) -> dict[Any, Any]:
    """Both float overloads of a generic kernel whose arrays named in `vec3`/`vec4` hold vectors,
    as {scalar type: overload}. Launching an overload rather than the generic kernel spares Warp
    inferring and normalising the argument types on every launch (~50 us of Python a launch,
    each chunk of a split launch paying it)."""
    overloads = {}
    for scalar in A.FLOATS:
        types: dict[str, Any] = {}
        for arg in kernel.adj.args:
            if wp.types.is_array(arg.type) and arg.type.dtype is typing.Any:
                dt = _VEC3[scalar] if arg.label in vec3 else _VEC4[scalar] if arg.label in vec4 else scalar
                types[arg.label] = wp.array(dtype=dt, ndim=arg.type.ndim)
            elif arg.type is typing.Any:
                types[arg.label] = scalar
        overloads[scalar] = wp.overload(kernel, types)
    return overloads


_FORWARD = _declare_overloads(_composite_forward_kernel, vec3=("rgb",), vec4=("factor4", "z4"))
_BACKWARD = _declare_overloads(_composite_backward_kernel, vec3=("rgb", "grad_sample_rgb"),
                               vec4=("factor4", "z4", "delta4", "grad_sigma4"))
