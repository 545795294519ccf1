"""The soft spheres' plain Warp kernels: the field, its adjoint, and the fused dense render.

Sphere k has centre c_k, radius r_k, colour col_k and sharpness s_k. At a point p, with
m_k = max(0, |p - c_k| - r_k),

    d_k(p)   = s_k exp(-s_k m_k)                    density of sphere k (s_k inside the sphere)
    sigma(p) = sum_k d_k
    rgb(p)   = sum_k d_k col_k / sigma   if sigma > 1e-6, else sum_k d_k col_k

(spheres_at, and spheres_at_packed with the parameters packed per sphere as two vec4s (c_k, r_k)
and (col_k, s_k): the same operations in the same order). Backward, for cotangents (g_s, g):

    dL/dd_k   = g_s + g . (col_k - rgb) / sigma      (g_s + g . col_k below the threshold)
    dL/dcol_k = g d_k / sigma                         (g d_k below the threshold)
    dL/ds_k   = dL/dd_k exp(-s_k m_k) (1 - s_k m_k)
    dL/dr_k   = dL/dd_k s_k d_k,   dL/dc_k = dL/dd_k s_k d_k (p - c_k) / |p - c_k|   (outside, m_k > 0)

The gradient is one-sided where a point lies on a sphere's surface (m_k's kink at |p - c_k| = r_k:
the kernel takes the inside branch there) and at the colour normalisation's switch sigma = 1e-6.
The forward runs one thread per point; the backward (_spheres_backward_kernel) scatters every
point's contribution into the few sphere parameters with atomic adds in ONE launch (no Warp
atomic is atomic between concurrent CPU launches, docs/warp.md).

The dense render (_spheres_render_dense_kernel, one thread per ray) is the forward of
kernels.volume.render_samples(field, dense_samples(o, d, t, delta)) fused: x_j = o + t_j d
(rounded as dense_samples rounds it), the field at x_j, then front to back

    e_j = exp(-sigma_j delta_j),  w_j = T_j (1 - e_j),  T_{j+1} = T_j e_j,  T_0 = 1,
    C = sum_j w_j rgb_j + T b,  D = sum_j w_j t_j,  A = 1 - T,

stopping before a sample whose T_j is below the termination threshold (as kernels.volume.composite
does). It evaluates exp with Warp's exp; it is the CUDA path and the CPU's with the fast paths
off. The CPU passes of kernels.volume.spheres_passes compute the same sums around NumPy's exp.
"""

from __future__ import annotations

import typing

import warp as wp

from kernels import _arrays as A
from kernels.volume.composite_kernels import blend_step, ray_start

wp.set_module_options({"enable_backward": False})

_VEC3 = {wp.float32: wp.vec3f, wp.float64: wp.vec3d}
_VEC4 = {wp.float32: wp.vec4f, wp.float64: wp.vec4d}



@wp.func
def offset_from(px: typing.Any, py: typing.Any, pz: typing.Any, cx: typing.Any, cy: typing.Any, cz: typing.Any):
    """(p - c, |p - c|): the offset of the point p from the centre c, and its length."""
    dx = px - cx
    dy = py - cy
    dz = pz - cz
    return dx, dy, dz, wp.sqrt(dx * dx + dy * dy + dz * dz)


@wp.func
def center_offset(points: wp.array2d(dtype=typing.Any), i: int, centers: wp.array2d(dtype=typing.Any), k: int):
    """(p_i - c_k, |p_i - c_k|): point i's offset from the centre of sphere k, and its length."""
    return offset_from(points[i, 0], points[i, 1], points[i, 2], centers[k, 0], centers[k, 1], centers[k, 2])


@wp.func
def no_spheres(like: typing.Any):
    """The field's sums (sigma, unnormalised colour) before any sphere: zeros of like's type."""
    zero = type(like)(0.0)
    return zero, zero, zero, zero


@wp.func
def add_sphere(sig: typing.Any, nr: typing.Any, ng: typing.Any, nb: typing.Any, d: typing.Any, cr: typing.Any,
               cg: typing.Any, cb: typing.Any):
    """The field's sums with one sphere added: (sigma + d_k, n + d_k col_k), n the unnormalised colour."""
    return sig + d, nr + d * cr, ng + d * cg, nb + d * cb


@wp.func
def normalised_colour(sig: typing.Any, nr: typing.Any, ng: typing.Any, nb: typing.Any):
    """(sigma, rgb): the colour sums divided by sigma where sigma > 1e-6, as they are below."""
    if sig > type(sig)(1e-6):
        return sig, nr / sig, ng / sig, nb / sig
    return sig, nr, ng, nb


@wp.func
def sphere_density_cotangent(gs: typing.Any, g0: typing.Any, g1: typing.Any, g2: typing.Any,
                             colors: wp.array2d(dtype=typing.Any), k: int, rgb: wp.array2d(dtype=typing.Any),
                             i: int, inv: typing.Any, normalized: bool):
    """dL/dd_k of point i: g_s + g . (col_k - rgb)/sigma, or g_s + g . col_k below the normalisation switch."""
    if normalized:
        return gs + (g0 * (colors[k, 0] - rgb[i, 0]) + g1 * (colors[k, 1] - rgb[i, 1])
                     + g2 * (colors[k, 2] - rgb[i, 2])) * inv
    return gs + g0 * colors[k, 0] + g1 * colors[k, 1] + g2 * colors[k, 2]


@wp.func
def point_cotangents(sigma: wp.array(dtype=typing.Any), grad_sigma: wp.array(dtype=typing.Any),
                     grad_rgb: wp.array2d(dtype=typing.Any), i: int):
    """Point i's (normalized, 1/sigma (1 unless normalized), g_s, g): whether its colour was divided
    by sigma (sigma > 1e-6), and the cotangents of its sigma and colour."""
    one = sigma.dtype(1.0)
    sig = sigma[i]
    normalized = sig > sigma.dtype(1e-6)
    inv = one
    if normalized:
        inv = one / sig
    return normalized, inv, grad_sigma[i], grad_rgb[i, 0], grad_rgb[i, 1], grad_rgb[i, 2]


@wp.func
def spheres_at(px: typing.Any, py: typing.Any, pz: typing.Any, centers: wp.array2d(dtype=typing.Any),
               radii: wp.array(dtype=typing.Any), colors: wp.array2d(dtype=typing.Any),
               sharpness: wp.array(dtype=typing.Any)):
    """(sigma, r, g, b) of the spheres at the point (px, py, pz) (module docstring)."""
    zero = type(px)(0.0)
    sig, nr, ng, nb = no_spheres(px)
    for k in range(radii.shape[0]):
        dx, dy, dz, dist = offset_from(px, py, pz, centers[k, 0], centers[k, 1], centers[k, 2])
        m = wp.max(zero, dist - radii[k])
        d = sharpness[k] * wp.exp(-sharpness[k] * m)
        sig, nr, ng, nb = add_sphere(sig, nr, ng, nb, d, colors[k, 0], colors[k, 1], colors[k, 2])
    return normalised_colour(sig, nr, ng, nb)


@wp.func
def spheres_at_packed(px: typing.Any, py: typing.Any, pz: typing.Any, geometry: wp.array(dtype=typing.Any),
                      appearance: wp.array(dtype=typing.Any)):
    """spheres_at with the parameters packed per sphere: geometry[k] = (c_k, r_k) and
    appearance[k] = (col_k, s_k) as vec4s, two loads a sphere instead of eight indexed ones (Warp's
    CPU code computes and wraps every index). The same operations in the same order: bit for bit
    spheres_at."""
    zero = type(px)(0.0)
    sig, nr, ng, nb = no_spheres(px)
    for k in range(geometry.shape[0]):
        g = geometry[k]
        a = appearance[k]
        dx, dy, dz, dist = offset_from(px, py, pz, g[0], g[1], g[2])
        m = wp.max(zero, dist - g[3])
        d = a[3] * wp.exp(-a[3] * m)
        sig, nr, ng, nb = add_sphere(sig, nr, ng, nb, d, a[0], a[1], a[2])
    return normalised_colour(sig, nr, ng, nb)


@wp.kernel
def _spheres_forward_kernel(
    points: wp.array2d(dtype=typing.Any), centers: wp.array2d(dtype=typing.Any), radii: wp.array(dtype=typing.Any),
    colors: wp.array2d(dtype=typing.Any), sharpness: wp.array(dtype=typing.Any),
    out_sigma: wp.array(dtype=typing.Any), out_rgb: wp.array2d(dtype=typing.Any), offset: int,
):
    i = wp.tid() + offset
    sig, nr, ng, nb = spheres_at(points[i, 0], points[i, 1], points[i, 2], centers, radii, colors, sharpness)
    out_sigma[i] = sig
    out_rgb[i, 0] = nr
    out_rgb[i, 1] = ng
    out_rgb[i, 2] = nb


@wp.func
def _blend_sample(T: typing.Any, cr: typing.Any, cg: typing.Any, cb: typing.Any, dep: typing.Any, sig: typing.Any,
                  nr: typing.Any, ng: typing.Any, nb: typing.Any, tk: typing.Any, dk: typing.Any):
    """One front-to-back step of the dense renders: alpha = 1 - exp(-sigma delta), weight T alpha."""
    return blend_step(T, cr, cg, cb, dep, wp.exp(-sig * dk), nr, ng, nb, tk)


@wp.func
def _write_pixel(out_rgb: wp.array(dtype=typing.Any), out_depth: wp.array(dtype=typing.Any),
                 out_opacity: wp.array(dtype=typing.Any), r: int, background: wp.array(dtype=typing.Any),
                 T: typing.Any, cr: typing.Any, cg: typing.Any, cb: typing.Any, dep: typing.Any):
    bg = background[0]
    out_rgb[r] = type(bg)(cr + T * bg[0], cg + T * bg[1], cb + T * bg[2])
    out_depth[r] = dep
    out_opacity[r] = type(T)(1.0) - T


@wp.kernel
def _spheres_render_dense_kernel(
    origins: wp.array(dtype=typing.Any), dirs: wp.array(dtype=typing.Any), t: wp.array2d(dtype=typing.Any),
    delta: wp.array2d(dtype=typing.Any), geometry: wp.array(dtype=typing.Any), appearance: wp.array(dtype=typing.Any),
    background: wp.array(dtype=typing.Any), t_threshold: typing.Any,
    out_rgb: wp.array(dtype=typing.Any), out_depth: wp.array(dtype=typing.Any),
    out_opacity: wp.array(dtype=typing.Any), offset: int,
):
    # origins, dirs, out_rgb: (R, 3) arrays viewed as R vec3; background one vec3; geometry and
    # appearance: the packed sphere parameters (spheres_at_packed).
    r = wp.tid() + offset
    T, cr, cg, cb, dep = ray_start(t_threshold)
    o = origins[r]
    dr = dirs[r]
    for j in range(t.shape[1]):
        if T < t_threshold:
            break
        tk = t[r, j]
        # x = o + (t d), rounded as kernels.volume.sampling.dense_samples rounds it
        sx = tk * dr[0]
        sy = tk * dr[1]
        sz = tk * dr[2]
        sig, nr, ng, nb = spheres_at_packed(o[0] + sx, o[1] + sy, o[2] + sz, geometry, appearance)
        T, cr, cg, cb, dep = _blend_sample(T, cr, cg, cb, dep, sig, nr, ng, nb, tk, delta[r, j])
    _write_pixel(out_rgb, out_depth, out_opacity, r, background, T, cr, cg, cb, dep)


@wp.kernel
def _spheres_backward_kernel(
    points: wp.array2d(dtype=typing.Any), centers: wp.array2d(dtype=typing.Any), radii: wp.array(dtype=typing.Any),
    colors: wp.array2d(dtype=typing.Any), sharpness: wp.array(dtype=typing.Any), sigma: wp.array(dtype=typing.Any),
    rgb: wp.array2d(dtype=typing.Any), grad_sigma: wp.array(dtype=typing.Any), grad_rgb: wp.array2d(dtype=typing.Any),
    grad_centers: wp.array2d(dtype=typing.Any), grad_radii: wp.array(dtype=typing.Any),
    grad_colors: wp.array2d(dtype=typing.Any), grad_sharpness: wp.array(dtype=typing.Any),
):
    i = wp.tid()
    zero = points.dtype(0.0)
    one = points.dtype(1.0)
    normalized, inv, gs, g0, g1, g2 = point_cotangents(sigma, grad_sigma, grad_rgb, i)
    for k in range(radii.shape[0]):
        dx, dy, dz, dist = center_offset(points, i, centers, k)
        m = wp.max(zero, dist - radii[k])
        s = sharpness[k]
        e = wp.exp(-s * m)
        d = s * e
        gd = sphere_density_cotangent(gs, g0, g1, g2, colors, k, rgb, i, inv, normalized)
        wp.atomic_add(grad_colors, k, 0, g0 * d * inv)
        wp.atomic_add(grad_colors, k, 1, g1 * d * inv)
        wp.atomic_add(grad_colors, k, 2, g2 * d * inv)
        wp.atomic_add(grad_sharpness, k, gd * e * (one - s * m))
        if dist - radii[k] > zero:
            gm = gd * s * d  # = -dL/dm
            wp.atomic_add(grad_radii, k, gm)
            wp.atomic_add(grad_centers, k, 0, gm * dx / dist)
            wp.atomic_add(grad_centers, k, 1, gm * dy / dist)
            wp.atomic_add(grad_centers, k, 2, gm * dz / dist)



@wp.kernel
def _pack_spheres_kernel(centers: wp.array2d(dtype=typing.Any), radii: wp.array(dtype=typing.Any),
                         colors: wp.array2d(dtype=typing.Any), sharpness: wp.array(dtype=typing.Any),
                         geometry: wp.array(dtype=typing.Any), appearance: wp.array(dtype=typing.Any)):
    k = wp.tid()
    geometry[k] = type(geometry[k])(centers[k, 0], centers[k, 1], centers[k, 2], radii[k])
    appearance[k] = type(appearance[k])(colors[k, 0], colors[k, 1], colors[k, 2], sharpness[k])



A.declare_float_overloads(_spheres_forward_kernel)
A.declare_float_overloads(_spheres_backward_kernel)
for _s in A.FLOATS:
    _v4 = _VEC4[_s]
    wp.overload(_pack_spheres_kernel, {
        "centers": wp.array2d(dtype=_s), "radii": wp.array(dtype=_s), "colors": wp.array2d(dtype=_s),
        "sharpness": wp.array(dtype=_s), "geometry": wp.array(dtype=_v4), "appearance": wp.array(dtype=_v4)})
