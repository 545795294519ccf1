"""The soft spheres' CPU passes in Warp: the field and the dense render around NumPy's exp.

The same maths as kernels.volume.spheres_kernels (d_k = s_k exp(-s_k m_k), m_k = max(0, |p - c_k|
- r_k); sigma = sum_k d_k; rgb = sum_k d_k col_k / sigma above 1e-6; the dense render's
e_j = exp(-sigma_j delta_j), w_j = T_j (1 - e_j), T_{j+1} = T_j e_j), cut where the exponentials
are, so that NumPy's vectorised exp can take them (SphereField._two_passes runs the passes over
blocks of points or rays, kernels.volume.spheres):

    pass 1  (sphere_exponents)         writes x_jk = -s_k m_k for every sample j and sphere k;
            NumPy's exp turns them into the falloffs f_jk = exp(-s_k m_k) in place;
    factor  (render_dense only)        writes -(sigma_j delta_j), sigma_j = sum_k s_k f_jk
            (sigma_from_falloff); NumPy's exp turns them into the factors e_j in place, as
            kernels.volume.composite's CPU factor pass does;
    last    (spheres_from_falloff)     d_k = s_k f_jk, the sums and the normalisation of
            spheres_at in the same order; render_dense then blends each ray with the e_j.

Warp's scalar expf is a library call per sphere and point (every live float register saved
around it); the one-kernel versions spent most of their time there. Every sample, field value,
factor and sum is formed as dense_samples, SphereField.forward and composite_forward form it, in
the same order with the same exponentials, so render_dense's image, depth and opacity are those
of render_samples on dense_samples bit for bit (tested). Against the one-kernel kernels the only
change is the exponentials' rounding: NumPy's float32 exp is within 2.4 ulp (Warp's 0.5).

Quads. The *4 kernels take four samples at a time as the lanes of vec4s: the field's quads are
points 4q .. 4q+3 (the last quad repeats the last point in its missing lanes and writes only the
real ones), render_dense's are samples 4j .. 4j+3 of a ray when S % 4 == 0, with a block's
exponents stored sphere by sphere for each quad. Every lane does the operations of one sample in
the same order (the squares and sums, the square root lane by lane, the colour divided where
sigma > 1e-6), so the results are bit for bit those of one sample at a time; the compiler turns
the lane-wise arithmetic into SIMD instructions and the loop and index arithmetic is paid once
per four samples. render_dense's last quad pass takes a quad's four factors and, unless the ray
terminates inside the quad, runs its four blend steps as straight-line code (the transmittances
it checks are the products the steps form); else one step at a time.
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.volume.composite_kernels import blend_step, ray_start
from kernels.volume.spheres_kernels import (_VEC3, _VEC4, _spheres_render_dense_kernel,
                                            _write_pixel, add_sphere, no_spheres, normalised_colour,
                                            offset_from)

wp.set_module_options({"enable_backward": False})

@wp.func
def falloff_sums(falloff: wp.array(dtype=typing.Any), i: int, stride: int, appearance: wp.array(dtype=typing.Any)):
    """spheres_at's sums (sigma, unnormalised colour) from falloff[i + k stride] = exp(-s_k m_k) given
    (the CPU passes): d_k = s_k falloff_k added sphere by sphere in spheres_at's order; scalars, or
    vec4s of four samples lane by lane (the quads)."""
    sig, nr, ng, nb = no_spheres(falloff[i])
    for k in range(appearance.shape[0]):
        a = appearance[k]
        sig, nr, ng, nb = add_sphere(sig, nr, ng, nb, a[3] * falloff[i + k * stride], a[0], a[1], a[2])
    return sig, nr, ng, nb


@wp.func
def sigma_from_falloff(falloff: wp.array(dtype=typing.Any), i: int, stride: int,
                       appearance: wp.array(dtype=typing.Any)):
    """The sigma of falloff_sums alone: the same products and sums in the same order."""
    sig = type(falloff[i])(0.0)
    for k in range(appearance.shape[0]):
        d = appearance[k][3] * falloff[i + k * stride]
        sig = sig + d
    return sig


@wp.func
def spheres_from_falloff(falloff: wp.array(dtype=typing.Any), i: int, appearance: wp.array(dtype=typing.Any)):
    """spheres_at's (sigma, r, g, b) from falloff[i + k] = exp(-s_k m_k) given (the CPU passes):
    falloff_sums, then spheres_at's normalisation."""
    sig, nr, ng, nb = falloff_sums(falloff, i, 1, appearance)
    return normalised_colour(sig, nr, ng, nb)


@wp.func
def sphere_exponents(px: typing.Any, py: typing.Any, pz: typing.Any, geometry: wp.array(dtype=typing.Any),
                     appearance: wp.array(dtype=typing.Any), out: wp.array(dtype=typing.Any), i: int):
    """out[i + k] = -s_k m_k at the point (px, py, pz) for every sphere k (the CPU passes' first half)."""
    zero = type(px)(0.0)
    for k in range(geometry.shape[0]):
        g = geometry[k]
        dx, dy, dz, dist = offset_from(px, py, pz, g[0], g[1], g[2])
        out[i + k] = -appearance[k][3] * wp.max(zero, dist - g[3])


@wp.kernel
def _spheres_dense_exponent_kernel(
    origins: wp.array(dtype=typing.Any), dirs: wp.array(dtype=typing.Any), t: wp.array2d(dtype=typing.Any),
    geometry: wp.array(dtype=typing.Any), appearance: wp.array(dtype=typing.Any),
    out_exponent: wp.array(dtype=typing.Any), base: int, offset: int,
):
    # CPU render_dense, pass 1 over the block of rays from `base`: the exponents at x = o_r + t_rj d_r,
    # sample (r, j) at ((r - base) S + j) K.
    q = wp.tid() + offset
    r = base + q
    o = origins[r]
    dr = dirs[r]
    n_s = t.shape[1]
    for j in range(n_s):
        tk = t[r, j]
        # rounded as kernels.volume.sampling.dense_samples rounds it
        sphere_exponents(o[0] + tk * dr[0], o[1] + tk * dr[1], o[2] + tk * dr[2], geometry, appearance,
                         out_exponent, (q * n_s + j) * geometry.shape[0])


@wp.kernel
def _spheres_dense_factor_kernel(
    falloff: wp.array(dtype=typing.Any), delta: wp.array2d(dtype=typing.Any), appearance: wp.array(dtype=typing.Any),
    out_exponent: wp.array(dtype=typing.Any), base: int, offset: int,
):
    # CPU render_dense, pass 2 over the block from `base`: the compositing exponents -(sigma delta) of
    # every sample (NumPy's exp turns them into the factors, as kernels.volume.composite does).
    q = wp.tid() + offset
    r = base + q
    n_s = delta.shape[1]
    for j in range(n_s):
        sig = sigma_from_falloff(falloff, (q * n_s + j) * appearance.shape[0], 1, appearance)
        out_exponent[q * n_s + j] = -(sig * delta[r, j])


@wp.kernel
def _spheres_dense_composite_kernel(
    falloff: wp.array(dtype=typing.Any), factor: wp.array(dtype=typing.Any), t: wp.array2d(dtype=typing.Any),
    appearance: wp.array(dtype=typing.Any), background: wp.array(dtype=typing.Any), t_threshold: typing.Any,
    out_rgb: wp.array(dtype=typing.Any), out_depth: wp.array(dtype=typing.Any),
    out_opacity: wp.array(dtype=typing.Any), base: int, offset: int,
):
    # CPU render_dense, pass 3 over the block from `base`: the spheres from the falloffs, composited
    # as the fused kernel does with the factors exp(-sigma delta) of pass 2 (sample (r, j) at
    # (r - base) S + j).
    q = wp.tid() + offset
    r = base + q
    T, cr, cg, cb, dep = ray_start(t_threshold)
    n_s = t.shape[1]
    for j in range(n_s):
        if T < t_threshold:
            break
        sig, nr, ng, nb = spheres_from_falloff(falloff, (q * n_s + j) * appearance.shape[0], appearance)
        T, cr, cg, cb, dep = blend_step(T, cr, cg, cb, dep, factor[q * n_s + j], nr, ng, nb, t[r, j])
    _write_pixel(out_rgb, out_depth, out_opacity, r, background, T, cr, cg, cb, dep)


# ---- The CPU passes four samples (or points) at a time (module docstring, "Quads").


@wp.func
def _splat4(like: typing.Any, v: typing.Any):
    """A vector of like's type (4 lanes) holding v in every lane."""
    return type(like)(v, v, v, v)


@wp.func
def _sphere_exponents4(px: typing.Any, py: typing.Any, pz: typing.Any, geometry: wp.array(dtype=typing.Any),
                       appearance: wp.array(dtype=typing.Any), out4: wp.array(dtype=typing.Any), i: int,
                       stride: int):
    """sphere_exponents for four points given lane-wise (px, py, pz vec4s): out4[i + k stride] =
    -s_k m_k of the four, lane by lane the same operations in the same order."""
    zero4 = type(px)()
    for k in range(geometry.shape[0]):
        g = geometry[k]
        dx = px - _splat4(px, g[0])
        dy = py - _splat4(px, g[1])
        dz = pz - _splat4(px, g[2])
        q = wp.cw_mul(dx, dx) + wp.cw_mul(dy, dy) + wp.cw_mul(dz, dz)
        dist = type(q)(wp.sqrt(q[0]), wp.sqrt(q[1]), wp.sqrt(q[2]), wp.sqrt(q[3]))
        out4[i + k * stride] = -appearance[k][3] * wp.max(zero4, dist - _splat4(px, g[3]))


@wp.func
def _spheres_from_falloff4(f4: wp.array(dtype=typing.Any), i: int, stride: int,
                           appearance: wp.array(dtype=typing.Any)):
    """spheres_from_falloff for four samples, the falloffs of sphere k at f4[i + k stride]:
    (sigma, r, g, b) as vec4s; the same sums in the same order, lane by lane, then the colour
    normalised in the lanes where sigma > 1e-6."""
    sig, nr, ng, nb = falloff_sums(f4, i, stride, appearance)
    for l in range(4):
        if sig[l] > type(sig[l])(1e-6):
            nr[l] = nr[l] / sig[l]
            ng[l] = ng[l] / sig[l]
            nb[l] = nb[l] / sig[l]
    return sig, nr, ng, nb


@wp.kernel
def _spheres_dense_exponent4_kernel(
    origins: wp.array(dtype=typing.Any), dirs: wp.array(dtype=typing.Any), t4: wp.array2d(dtype=typing.Any),
    geometry: wp.array(dtype=typing.Any), appearance: wp.array(dtype=typing.Any),
    out4: wp.array(dtype=typing.Any), base: int, offset: int,
):
    # CPU render_dense, pass 1 with S % 4 == 0 (t4: t viewed as (R, S/4) vec4s): the exponents of
    # ray r = base + q, sphere k and samples 4 jq .. 4 jq + 3 at out4[(q K + k) S/4 + jq].
    q = wp.tid() + offset
    r = base + q
    o = origins[r]
    dr = dirs[r]
    n_q = t4.shape[1]
    for jq in range(n_q):
        tq = t4[r, jq]
        # x = o + (t d) lane by lane, rounded as kernels.volume.sampling.dense_samples rounds it
        _sphere_exponents4(_splat4(tq, o[0]) + tq * dr[0], _splat4(tq, o[1]) + tq * dr[1],
                           _splat4(tq, o[2]) + tq * dr[2], geometry, appearance, out4,
                           q * geometry.shape[0] * n_q + jq, n_q)


@wp.kernel
def _spheres_dense_factor4_kernel(
    f4: wp.array(dtype=typing.Any), delta4: wp.array2d(dtype=typing.Any), appearance: wp.array(dtype=typing.Any),
    out4: wp.array(dtype=typing.Any), base: int, offset: int,
):
    # CPU render_dense, pass 2 with S % 4 == 0: the compositing exponents -(sigma delta) of samples
    # 4 jq .. 4 jq + 3 of ray r = base + q at out4[q S/4 + jq], lane by lane.
    q = wp.tid() + offset
    r = base + q
    n_q = delta4.shape[1]
    for jq in range(n_q):
        sig = sigma_from_falloff(f4, q * appearance.shape[0] * n_q + jq, n_q, appearance)
        out4[q * n_q + jq] = -wp.cw_mul(sig, delta4[r, jq])


@wp.kernel
def _spheres_dense_composite4_kernel(
    f4: wp.array(dtype=typing.Any), e4: wp.array(dtype=typing.Any), t4: wp.array2d(dtype=typing.Any),
    appearance: wp.array(dtype=typing.Any), background: wp.array(dtype=typing.Any), t_threshold: typing.Any,
    out_rgb: wp.array(dtype=typing.Any), out_depth: wp.array(dtype=typing.Any),
    out_opacity: wp.array(dtype=typing.Any), base: int, offset: int,
):
    # CPU render_dense, pass 3 with S % 4 == 0: the spheres of four samples at a time from the
    # falloffs, their four factors exp(-sigma delta) from pass 2 (e4[q S/4 + jq]), then the four
    # blend steps one after the other (early termination as the fused kernel: the steps after it
    # are not taken).
    q = wp.tid() + offset
    r = base + q
    T, cr, cg, cb, dep = ray_start(t_threshold)
    n_q = t4.shape[1]
    done = int(0)
    for jq in range(n_q):
        if done != 0:
            break
        sig, nr, ng, nb = _spheres_from_falloff4(f4, q * appearance.shape[0] * n_q + jq, n_q, appearance)
        tq = t4[r, jq]
        e = e4[q * n_q + jq]
        # The transmittances before the four steps (each the product the step itself forms): when
        # none is below the threshold the four steps run straight, else one at a time up to it.
        T1 = T * e[0]
        T2 = T1 * e[1]
        T3 = T2 * e[2]
        if T < t_threshold or T1 < t_threshold or T2 < t_threshold or T3 < t_threshold:
            for l in range(4):
                if T < t_threshold:
                    done = 1
                    break
                T, cr, cg, cb, dep = blend_step(T, cr, cg, cb, dep, e[l], nr[l], ng[l], nb[l], tq[l])
        else:
            T, cr, cg, cb, dep = blend_step(T, cr, cg, cb, dep, e[0], nr[0], ng[0], nb[0], tq[0])
            T, cr, cg, cb, dep = blend_step(T, cr, cg, cb, dep, e[1], nr[1], ng[1], nb[1], tq[1])
            T, cr, cg, cb, dep = blend_step(T, cr, cg, cb, dep, e[2], nr[2], ng[2], nb[2], tq[2])
            T, cr, cg, cb, dep = blend_step(T, cr, cg, cb, dep, e[3], nr[3], ng[3], nb[3], tq[3])
    _write_pixel(out_rgb, out_depth, out_opacity, r, background, T, cr, cg, cb, dep)


@wp.kernel
def _spheres_exponent4_kernel(points: wp.array(dtype=typing.Any), n: int, geometry: wp.array(dtype=typing.Any),
                              appearance: wp.array(dtype=typing.Any), out4: wp.array(dtype=typing.Any),
                              base: int, offset: int):
    # CPU field forward, pass 1 over quads of points: quad base + q holds points 4 (base + q) + l,
    # l = 0..3 (the last quad repeats point n - 1 in its missing lanes); sphere k's exponents at
    # out4[q K + k].
    q = wp.tid() + offset
    i = 4 * (base + q)
    p0 = points[wp.min(i, n - 1)]
    p1 = points[wp.min(i + 1, n - 1)]
    p2 = points[wp.min(i + 2, n - 1)]
    p3 = points[wp.min(i + 3, n - 1)]
    _sphere_exponents4(type(out4[0])(p0[0], p1[0], p2[0], p3[0]), type(out4[0])(p0[1], p1[1], p2[1], p3[1]),
                       type(out4[0])(p0[2], p1[2], p2[2], p3[2]), geometry, appearance, out4,
                       q * geometry.shape[0], 1)


@wp.kernel
def _spheres_from_falloff4_kernel(f4: wp.array(dtype=typing.Any), appearance: wp.array(dtype=typing.Any), n: int,
                                  out_sigma: wp.array(dtype=typing.Any), out_rgb: wp.array(dtype=typing.Any),
                                  out_sigma4: wp.array(dtype=typing.Any), out_rgb4: wp.array(dtype=typing.Any),
                                  base: int, offset: int):
    # CPU field forward, pass 2 over quads of points (out_rgb (N, 3) viewed as N vec3; out_sigma4 and
    # out_rgb4 view the whole quads' sigma and rgb as vec4s: one store of sigma and three of rgb).
    q = wp.tid() + offset
    i = 4 * (base + q)
    sig, nr, ng, nb = _spheres_from_falloff4(f4, q * appearance.shape[0], 1, appearance)
    if i + 4 <= n:
        out_sigma4[base + q] = sig
        b = 3 * (base + q)
        out_rgb4[b] = type(sig)(nr[0], ng[0], nb[0], nr[1])
        out_rgb4[b + 1] = type(sig)(ng[1], nb[1], nr[2], ng[2])
        out_rgb4[b + 2] = type(sig)(nb[2], nr[3], ng[3], nb[3])
    else:
        for l in range(4):
            if i + l < n:
                out_sigma[i + l] = sig[l]
                out_rgb[i + l] = type(out_rgb[0])(nr[l], ng[l], nb[l])



def _render_dense_overloads() -> dict[Any, tuple[Any, Any, Any, Any]]:
    """{scalar: concrete overloads of (the fused kernel, CPU pass 1, CPU pass 2 (factors), CPU pass 3)}
    (launching a concrete overload spares Warp inferring the argument types on every launch)."""
    out = {}
    for s in A.FLOATS:
        v3, v4 = _VEC3[s], _VEC4[s]
        rays = {"origins": wp.array(dtype=v3), "dirs": wp.array(dtype=v3), "t": wp.array2d(dtype=s)}
        params = {"geometry": wp.array(dtype=v4), "appearance": wp.array(dtype=v4)}
        outputs = {"background": wp.array(dtype=v3), "t_threshold": s, "out_rgb": wp.array(dtype=v3),
                   "out_depth": wp.array(dtype=s), "out_opacity": wp.array(dtype=s)}
        out[s] = (
            wp.overload(_spheres_render_dense_kernel,
                        {**rays, "delta": wp.array2d(dtype=s), **params, **outputs}),
            wp.overload(_spheres_dense_exponent_kernel, {**rays, **params, "out_exponent": wp.array(dtype=s)}),
            wp.overload(_spheres_dense_factor_kernel,
                        {"falloff": wp.array(dtype=s), "delta": wp.array2d(dtype=s), "appearance": wp.array(dtype=v4),
                         "out_exponent": wp.array(dtype=s)}),
            wp.overload(_spheres_dense_composite_kernel,
                        {"falloff": wp.array(dtype=s), "factor": wp.array(dtype=s), "t": wp.array2d(dtype=s),
                         "appearance": wp.array(dtype=v4), **outputs}))
    return out


_RENDER_DENSE = _render_dense_overloads()
_FIELD_PASSES = {s: (wp.overload(_spheres_exponent4_kernel, {
    "points": wp.array(dtype=_VEC3[s]), "geometry": wp.array(dtype=_VEC4[s]), "appearance": wp.array(dtype=_VEC4[s]),
    "out4": wp.array(dtype=_VEC4[s])}), wp.overload(_spheres_from_falloff4_kernel, {
        "f4": wp.array(dtype=_VEC4[s]), "appearance": wp.array(dtype=_VEC4[s]), "out_sigma": wp.array(dtype=s),
        "out_rgb": wp.array(dtype=_VEC3[s]), "out_sigma4": wp.array(dtype=_VEC4[s]),
        "out_rgb4": wp.array(dtype=_VEC4[s])})) for s in A.FLOATS}
_RENDER_DENSE4 = {s: (wp.overload(_spheres_dense_exponent4_kernel, {
    "origins": wp.array(dtype=_VEC3[s]), "dirs": wp.array(dtype=_VEC3[s]), "t4": wp.array2d(dtype=_VEC4[s]),
    "geometry": wp.array(dtype=_VEC4[s]), "appearance": wp.array(dtype=_VEC4[s]), "out4": wp.array(dtype=_VEC4[s])}),
    wp.overload(_spheres_dense_factor4_kernel, {
        "f4": wp.array(dtype=_VEC4[s]), "delta4": wp.array2d(dtype=_VEC4[s]), "appearance": wp.array(dtype=_VEC4[s]),
        "out4": wp.array(dtype=_VEC4[s])}),
    wp.overload(_spheres_dense_composite4_kernel, {
        "f4": wp.array(dtype=_VEC4[s]), "e4": wp.array(dtype=_VEC4[s]), "t4": wp.array2d(dtype=_VEC4[s]),
        "appearance": wp.array(dtype=_VEC4[s]), "background": wp.array(dtype=_VEC3[s]), "t_threshold": s,
        "out_rgb": wp.array(dtype=_VEC3[s]), "out_depth": wp.array(dtype=s), "out_opacity": wp.array(dtype=s)}))
    for s in A.FLOATS}

