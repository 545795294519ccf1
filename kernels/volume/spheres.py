"""Analytic soft spheres: the Video and 3D Vision textbook chapter's volume-rendering scene, with gradients.

Sphere k has centre c_k, radius r_k, colour col_k and sharpness s_k (the chapter's per-sphere
"sigma"). At a point p, with m_k = max(0, |p - c_k| - r_k),

    d_k(p)   = s_k exp(-s_k m_k)                    density of sphere k (s_k inside the sphere)
    sigma(p) = sum_k d_k
    rgb(p)   = sum_k d_k col_k / sigma   if sigma > 1e-6, else sum_k d_k col_k

(the chapter's `jnp.where(density > 1e-6, colour / density, colour)`). Colour does not depend
on the view direction. Backward, for cotangents (g_s, g):

    dL/dd_k   = g_s + g . (col_k - rgb) / sigma      (g_s + g . col_k below the threshold)
    dL/dcol_k = g d_k / sigma                         (g d_k below the threshold)
    dL/ds_k   = dL/dd_k exp(-s_k m_k) (1 - s_k m_k)
    dL/dr_k   = dL/dd_k s_k d_k,   dL/dc_k = dL/dd_k s_k d_k (p - c_k) / |p - c_k|   (outside, m_k > 0)

The forward runs one thread per point (launch_split); the backward scatters every point's
contribution into the (few) sphere parameters with atomic adds in ONE launch (no Warp atomic is
atomic between concurrent CPU launches, docs/warp.md). Points follow the array contract of
kernels.volume.field.

`SphereField.render_dense` is the forward of kernels.volume.render_samples(field,
dense_samples(o, d, t, delta)) fused into one kernel, one thread per ray: x_k = o + t_k d, the
field at x_k, and the compositing of kernels.volume.composite (z_k = t_k, early termination as
there), without the packed sample, field-output and factor arrays of the general path (their
allocation, first-touch page faults and memory traffic were most of the textbook task's time,
docs/performance.md). Forward only. The one kernel evaluates exp(-sigma_k delta_k) with Warp's
exp (on the CPU the passes below run instead, equal to the general path bit for bit). Its sphere loop
reads the parameters packed per sphere as two vec4s (spheres_at_packed; the same arithmetic as
spheres_at) and the rays' origins, directions and colours as vec3s: fewer indexed loads, whose
address arithmetic Warp's CPU code repeats for every one.

On the CPU forward and render_dense run in passes around NumPy instead, over blocks of points
(or rays) of at most _FALLOFF_BLOCK values: pass 1 writes the exponents -s_k m_k of every point
(or sample) and sphere of the block, NumPy's vectorised exp turns them into the falloffs
exp(-s_k m_k) in place (split over the launch threads), and the last pass does the rest of
spheres_at (spheres_from_falloff). render_dense has a pass between them: it writes the
compositing exponents -(sigma_k delta_k) of the block's samples (sigma from the falloffs, the
same sums), NumPy's exp turns them into the factors exp(-(sigma_k delta_k)) in place, as
kernels.volume.composite's CPU factor pass does, and the last pass composites each ray with them.
Warp's scalar expf is a library call per sphere and point (every live float register saved
around it); the one-kernel versions spent most of their time there. So on the CPU render_dense
forms every sample, field value, factor and sum as dense_samples, SphereField.forward and
composite_forward do, in the same order with the same exponentials: its image, depth and opacity
are those of render_samples on dense_samples bit for bit (tested), without the packed sample,
field-output and factor arrays. Against the one-kernel versions the only change is the
exponentials' rounding: NumPy's float32 exp is within 2.4 ulp (Warp's 0.5), so on the textbook
scene float32 images differ from the fused kernel's by about 1e-6 (depth 4e-6), float64 by
about 1e-15. The backward evaluates its own exponentials, as before. On CUDA the one-kernel
versions run.

Quads. The CPU passes take four samples at a time as the lanes of vec4s: the forward's quads are
points 4q .. 4q+3 (the last quad repeats the last point in its missing lanes and writes only the
real ones), render_dense's are samples 4j .. 4j+3 of a ray when S % 4 == 0 (one sample at a time
otherwise), with a block's exponents stored sphere by sphere for each quad. Every lane does the
operations of one sample in the same order (the squares and sums, the square root lane by lane,
the colour divided where sigma > 1e-6), so the results are bit for bit those of one sample at a
time; the compiler turns the lane-wise arithmetic into SIMD instructions and the loop and index
arithmetic is paid once per four samples. render_dense's last pass takes a quad's four factors
and, unless the ray terminates inside the quad, runs its four blend steps as straight-line code
(the transmittances it checks are the products the steps form); else one step at a time.

C++ on the CPU (float32, CPUs with AVX2): render_dense's three passes run in
kernels.volume.spheres_cpu instead, eight rays in the lanes of a vector (sample j of eight rays at
once, each lane the operations above in the same order, the blends of eight rays side by side), and
where kernels._npexp's copy of NumPy's float32 exp gives np.exp's bits (checked once a process), in one
launch a chunk that applies it between the passes on each group's values. The same
outputs bit for bit (tested); float64, CUDA and CPUs without AVX2 keep the Warp passes.
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels import _npexp, fast_paths
from kernels.volume import spheres_cpu
from kernels.volume._checks import check_dtype
from kernels.volume.composite import DEFAULT_T_THRESHOLD
from kernels.volume.field import Field, FieldOutput
from kernels.launch import default_threads, guided_bounds, parallel_items
from kernels.volume.workspace import Workspace

wp.set_module_options({"enable_backward": False})

COLOR_NORMALIZE_EPS = 1e-6
# forward and render_dense on the CPU run the two-pass paths (NumPy's exp between Warp passes, and C++);
# True, or the CPU fast paths off (kernels.fast_paths), runs the one-kernel paths there too (CUDA's).
_FUSED_ON_CPU = False
# render_dense's CPU passes take four samples at a time when S % 4 == 0; False runs the one-at-a-time
# passes there too (for tests: the same results bit for bit).
_QUADS_ON_CPU = True
# Falloff values per block of the CPU passes (8 MB in float32): their memory stays bounded at any size.
_FALLOFF_BLOCK = 1 << 21
# The CPU passes' chunks (SphereField._two_passes, and render_dense's three-launch C++ route): no chunk of
# fewer items than hold this many falloff values (~0.1-0.2 ms of kernel a pass, against 20-40 us of Python
# a launch; a 64x64 x 64 render_dense on the Warp passes is cut into 6 chunks at 2 threads).
_CHUNK_VALUES = 1 << 17
# render_dense's C++ passes (float32 on CPUs with AVX2, kernels.volume.spheres_cpu); False runs the Warp
# passes there too (for tests: the same results bit for bit).
_NATIVE_ON_CPU = True
# Those passes run in one launch a chunk, calling NumPy's float32 exp loop themselves, where it was found
# (kernels._npexp.numpy_agrees); False runs three launches a chunk with np.exp between them (for tests).
_FUSED_EXP_ON_CPU = True
# ... with chunks of at least this many falloff values (~0.8 ms of one core; nothing is stored between the
# passes, so no cache size bounds them): the textbook image (786432 values) runs as 2/3 and 1/3 on 2
# threads, which on the loaded 2-core host was as fast as one chunk or faster, where 6 guided chunks
# of 2^17 or two halves lost 0.5-1.5 ms of median wall time waiting for the other thread (fifth round).
_CHUNK_VALUES_ONE_LAUNCH = 1 << 19

# The chapter's scene: (centre, radius, colour, sharpness).
TEXTBOOK_SPHERES = (
    ((0.0, 0.0, 4.0), 0.8, (1.0, 0.2, 0.2), 5.0),
    ((1.5, 0.5, 5.0), 0.6, (0.2, 1.0, 0.2), 5.0),
    ((-1.0, -0.5, 3.5), 0.5, (0.2, 0.2, 1.0), 5.0),
)


@wp.func
def center_offset(points: wp.array2d(dtype=typing.Any), i: int, centers: wp.array2d(dtype=typing.Any), k: int):
    """(p_i - c_k, |p_i - c_k|): point i's offset from the centre of sphere k, and its length."""
    dx = points[i, 0] - centers[k, 0]
    dy = points[i, 1] - centers[k, 1]
    dz = points[i, 2] - centers[k, 2]
    return dx, dy, dz, wp.sqrt(dx * dx + dy * dy + dz * dz)


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
def spheres_at(px: typing.Any, py: typing.Any, pz: typing.Any, centers: wp.array2d(dtype=typing.Any),
               radii: wp.array(dtype=typing.Any), colors: wp.array2d(dtype=typing.Any),
               sharpness: wp.array(dtype=typing.Any)):
    """(sigma, r, g, b) of the spheres at the point (px, py, pz) (module docstring)."""
    zero = type(px)(0.0)
    sig = zero
    nr = zero
    ng = zero
    nb = zero
    for k in range(radii.shape[0]):
        dx = px - centers[k, 0]
        dy = py - centers[k, 1]
        dz = pz - centers[k, 2]
        dist = wp.sqrt(dx * dx + dy * dy + dz * dz)
        m = wp.max(zero, dist - radii[k])
        d = sharpness[k] * wp.exp(-sharpness[k] * m)
        sig += d
        nr += d * colors[k, 0]
        ng += d * colors[k, 1]
        nb += d * colors[k, 2]
    if sig > type(px)(1e-6):
        nr = nr / sig
        ng = ng / sig
        nb = nb / sig
    return sig, nr, ng, nb


@wp.func
def spheres_at_packed(px: typing.Any, py: typing.Any, pz: typing.Any, geometry: wp.array(dtype=typing.Any),
                      appearance: wp.array(dtype=typing.Any)):
    """spheres_at with the parameters packed per sphere: geometry[k] = (c_k, r_k) and
    appearance[k] = (col_k, s_k) as vec4s, two loads a sphere instead of eight indexed ones (Warp's
    CPU code computes and wraps every index). The same operations in the same order: bit for bit
    spheres_at."""
    zero = type(px)(0.0)
    sig = zero
    nr = zero
    ng = zero
    nb = zero
    for k in range(geometry.shape[0]):
        g = geometry[k]
        a = appearance[k]
        dx = px - g[0]
        dy = py - g[1]
        dz = pz - g[2]
        dist = wp.sqrt(dx * dx + dy * dy + dz * dz)
        m = wp.max(zero, dist - g[3])
        d = a[3] * wp.exp(-a[3] * m)
        sig += d
        nr += d * a[0]
        ng += d * a[1]
        nb += d * a[2]
    if sig > type(px)(1e-6):
        nr = nr / sig
        ng = ng / sig
        nb = nb / sig
    return sig, nr, ng, nb


@wp.func
def spheres_from_falloff(falloff: wp.array(dtype=typing.Any), i: int, appearance: wp.array(dtype=typing.Any)):
    """spheres_at's (sigma, r, g, b) from falloff[i + k] = exp(-s_k m_k) given (the CPU passes):
    d_k = s_k falloff_k, then the same sums and normalisation in the same order."""
    zero = falloff.dtype(0.0)
    sig = zero
    nr = zero
    ng = zero
    nb = zero
    for k in range(appearance.shape[0]):
        a = appearance[k]
        d = a[3] * falloff[i + k]
        sig += d
        nr += d * a[0]
        ng += d * a[1]
        nb += d * a[2]
    if sig > falloff.dtype(1e-6):
        nr = nr / sig
        ng = ng / sig
        nb = nb / sig
    return sig, nr, ng, nb


@wp.func
def sphere_exponents(px: typing.Any, py: typing.Any, pz: typing.Any, geometry: wp.array(dtype=typing.Any),
                     appearance: wp.array(dtype=typing.Any), out: wp.array(dtype=typing.Any), i: int):
    """out[i + k] = -s_k m_k at the point (px, py, pz) for every sphere k (the CPU passes' first half)."""
    zero = type(px)(0.0)
    for k in range(geometry.shape[0]):
        g = geometry[k]
        dx = px - g[0]
        dy = py - g[1]
        dz = pz - g[2]
        dist = wp.sqrt(dx * dx + dy * dy + dz * dz)
        out[i + k] = -appearance[k][3] * wp.max(zero, dist - g[3])


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
def _blend_factor(T: typing.Any, cr: typing.Any, cg: typing.Any, cb: typing.Any, dep: typing.Any, e: typing.Any,
                  nr: typing.Any, ng: typing.Any, nb: typing.Any, tk: typing.Any):
    """One front-to-back step of the dense renders given e = exp(-sigma delta) = 1 - alpha: weight T alpha."""
    w = T * (type(T)(1.0) - e)
    return T * e, cr + w * nr, cg + w * ng, cb + w * nb, dep + w * tk


@wp.func
def _blend_sample(T: typing.Any, cr: typing.Any, cg: typing.Any, cb: typing.Any, dep: typing.Any, sig: typing.Any,
                  nr: typing.Any, ng: typing.Any, nb: typing.Any, tk: typing.Any, dk: typing.Any):
    """One front-to-back step of the dense renders: alpha = 1 - exp(-sigma delta), weight T alpha."""
    return _blend_factor(T, cr, cg, cb, dep, wp.exp(-sig * dk), nr, ng, nb, tk)


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
    one = t.dtype(1.0)
    T = one
    cr = t.dtype(0.0)
    cg = t.dtype(0.0)
    cb = t.dtype(0.0)
    dep = t.dtype(0.0)
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


@wp.func
def sigma_from_falloff(falloff: wp.array(dtype=typing.Any), i: int, appearance: wp.array(dtype=typing.Any)):
    """The sigma of spheres_from_falloff alone: the same products and sums in the same order."""
    sig = falloff.dtype(0.0)
    for k in range(appearance.shape[0]):
        d = appearance[k][3] * falloff[i + k]
        sig += d
    return sig


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
        sig = sigma_from_falloff(falloff, (q * n_s + j) * appearance.shape[0], appearance)
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
    one = t.dtype(1.0)
    T = one
    cr = t.dtype(0.0)
    cg = t.dtype(0.0)
    cb = t.dtype(0.0)
    dep = t.dtype(0.0)
    n_s = t.shape[1]
    for j in range(n_s):
        if T < t_threshold:
            break
        sig, nr, ng, nb = spheres_from_falloff(falloff, (q * n_s + j) * appearance.shape[0], appearance)
        T, cr, cg, cb, dep = _blend_factor(T, cr, cg, cb, dep, factor[q * n_s + j], nr, ng, nb, t[r, j])
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
    zero4 = type(f4[i])()
    sig = zero4
    nr = zero4
    ng = zero4
    nb = zero4
    for k in range(appearance.shape[0]):
        a = appearance[k]
        d = a[3] * f4[i + k * stride]
        sig = sig + d
        nr = nr + d * a[0]
        ng = ng + d * a[1]
        nb = nb + d * a[2]
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


@wp.func
def _sigma_from_falloff4(f4: wp.array(dtype=typing.Any), i: int, stride: int, appearance: wp.array(dtype=typing.Any)):
    """The sigma of _spheres_from_falloff4 alone (vec4): the same products and sums in the same order."""
    sig = type(f4[i])()
    for k in range(appearance.shape[0]):
        d = appearance[k][3] * f4[i + k * stride]
        sig = sig + d
    return sig


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
        sig = _sigma_from_falloff4(f4, q * appearance.shape[0] * n_q + jq, n_q, appearance)
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
    T = type(t_threshold)(1.0)
    cr = type(t_threshold)(0.0)
    cg = type(t_threshold)(0.0)
    cb = type(t_threshold)(0.0)
    dep = type(t_threshold)(0.0)
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
                T, cr, cg, cb, dep = _blend_factor(T, cr, cg, cb, dep, e[l], nr[l], ng[l], nb[l], tq[l])
        else:
            T, cr, cg, cb, dep = _blend_factor(T, cr, cg, cb, dep, e[0], nr[0], ng[0], nb[0], tq[0])
            T, cr, cg, cb, dep = _blend_factor(T, cr, cg, cb, dep, e[1], nr[1], ng[1], nb[1], tq[1])
            T, cr, cg, cb, dep = _blend_factor(T, cr, cg, cb, dep, e[2], nr[2], ng[2], nb[2], tq[2])
            T, cr, cg, cb, dep = _blend_factor(T, cr, cg, cb, dep, e[3], nr[3], ng[3], nb[3], tq[3])
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
    sig = sigma[i]
    normalized = sig > points.dtype(1e-6)
    inv = one
    if normalized:
        inv = one / sig
    gs = grad_sigma[i]
    g0 = grad_rgb[i, 0]
    g1 = grad_rgb[i, 1]
    g2 = grad_rgb[i, 2]
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


class SphereField(Field):
    """Soft spheres (module docstring). Parameters: centers (K, 3), radii (K,), colors (K, 3), sharpness (K,)."""

    name = "spheres"

    def __init__(self, centers: Any, radii: Any, colors: Any, sharpness: Any,
                 dtype: Any = wp.float32, device: str | wp.Device | None = None) -> None:
        check_dtype("dtype", dtype)
        vals = {"centers": centers, "radii": radii, "colors": colors, "sharpness": sharpness}
        vals = {k: np.asarray(v.numpy() if isinstance(v, wp.array) else v, dtype=np.float64) for k, v in vals.items()}
        c = vals["centers"]
        if c.ndim != 2 or c.shape[1] != 3 or c.shape[0] < 1:
            raise ValueError(f"centers: expected shape (K, 3) with K >= 1, got {c.shape}")
        k = c.shape[0]
        for name, shape in (("radii", (k,)), ("colors", (k, 3)), ("sharpness", (k,))):
            A.check_shape(name, vals[name], shape)
        for name, v in vals.items():
            A.check_finite(name, v)
        A.check_at_least("radii", vals["radii"], 0.0)
        A.check_at_least("sharpness", vals["sharpness"], 0.0)
        np_t = A.NP_OF_WP[dtype]
        device = A.get_device(device)
        super().__init__({n: wp.array(v.astype(np_t), dtype=dtype, device=device) for n, v in vals.items()},
                         dtype, device)

    @classmethod
    def textbook(cls, dtype: Any = wp.float32, device: str | wp.Device | None = None) -> "SphereField":
        c, r, col, s = zip(*TEXTBOOK_SPHERES)
        return cls(c, r, col, s, dtype=dtype, device=device)

    def _param_args(self) -> list[wp.array]:
        P = self.params
        return [P["centers"], P["radii"], P["colors"], P["sharpness"]]

    # (the parameters' bytes, geometry, appearance) of the last CPU packing (_packed)
    _packed_host: tuple[bytes, wp.array, wp.array] | None = None

    def _packed(self) -> tuple[wp.array, wp.array]:
        """(geometry, appearance): the parameters as K vec4s (c_k, r_k) and (col_k, s_k)."""
        v4 = _VEC4[self.dtype]
        if self.device.is_cpu:  # K rows packed on the host from zero-copy views
            P = {k: v.numpy() for k, v in self.params.items()}
            # Packed again only when a parameter's value changed (an optimiser updates them in place):
            # the K rows' bytes are compared, a few microseconds against two new arrays a call.
            key = b"".join(P[k].tobytes() for k in ("centers", "radii", "colors", "sharpness"))
            cached = self._packed_host
            if cached is not None and cached[0] == key:
                return cached[1], cached[2]
            geometry = wp.array(np.concatenate([P["centers"], P["radii"][:, None]], axis=1), dtype=v4)
            appearance = wp.array(np.concatenate([P["colors"], P["sharpness"][:, None]], axis=1), dtype=v4)
            self._packed_host = (key, geometry, appearance)
            return geometry, appearance
        k = self.params["radii"].shape[0]
        geometry = wp.empty(k, dtype=v4, device=self.device)
        appearance = wp.empty(k, dtype=v4, device=self.device)
        wp.launch(_pack_spheres_kernel, k, [*self._param_args(), geometry, appearance], device=self.device)
        return geometry, appearance

    def _two_passes(self, a: A.Inputs, n_items: int, samples_per_item: int, pass1: Any, pass1_inputs: list[Any],
                    pass2: Any, pass2_inputs: list[Any], geometry: wp.array, appearance: wp.array,
                    quads: bool = False, factor_pass: tuple[Any, list[Any]] | None = None) -> None:
        """The CPU passes (module docstring) over n_items points, rays or quads of samples_per_item
        samples, in blocks of at most _FALLOFF_BLOCK falloff values (bounded memory): `pass1` writes
        the exponents -s_k m_k, NumPy's exp turns them into falloffs in place, `pass2` consumes
        them. With `quads` the kernels see the values as vec4s.

        `factor_pass` (kernel, inputs), for render_dense: between the two, that kernel writes the
        compositing exponents -(sigma delta) of the samples, NumPy's exp turns them into the
        factors in place, and `pass2` takes them as its second argument.

        A block is cut into chunks of items (guided, kernels.launch.guided_bounds, none smaller than
        _CHUNK_VALUES falloff values; one chunk on one thread) and the launch threads take the
        chunks one at a time, each running every pass and exp over its chunk in turn: the items are
        independent, so the outputs are those of pass after pass over the whole block, with one
        hand-off between threads a block instead of one a pass and a chunk's values still in the
        core's cache for the next pass."""
        per_item = samples_per_item * geometry.shape[0]
        block = max(1, min(n_items, _FALLOFF_BLOCK // max(per_item, 1)))
        falloff = a.empty(block * per_item)
        f = falloff.numpy()
        values = _vec_view(falloff, _VEC4, (block * per_item // 4,)) if quads else falloff
        if factor_pass is not None:
            factor = a.empty(block * samples_per_item)
            e = factor.numpy()
            factors = [_vec_view(factor, _VEC4, (block * samples_per_item // 4,)) if quads else factor]
        else:
            factors = []
        min_chunk = max(1, _CHUNK_VALUES // max(per_item, 1))
        threads = default_threads()
        lanes = 4 if quads else 1
        dev = a.device
        for base in range(0, n_items, block):
            nb = min(block, n_items - base)
            bounds = guided_bounds(nb, threads, min_chunk) if threads > 1 and nb >= 2 * min_chunk else [(0, nb)]

            def chunk(j: int, base: int = base, bounds: list[tuple[int, int]] = bounds) -> None:
                # every pass over the chunk's items [lo, lo + n) of the block, one after the other on this
                # thread; the kernels see the chunk's falloffs (and factors) from their start
                lo, n = bounds[j]
                v0, v1 = lo * per_item, (lo + n) * per_item
                fv = _view(falloff.ptr + v0 * f.itemsize, values.dtype, ((v1 - v0) // lanes,), dev)
                wp.launch(pass1, dim=n, inputs=[*pass1_inputs, geometry, appearance, fv, base + lo, 0], device=dev)
                np.exp(f[v0:v1], out=f[v0:v1])
                ev = []
                if factor_pass is not None:
                    e0, e1 = lo * samples_per_item, (lo + n) * samples_per_item
                    ev = [_view(factor.ptr + e0 * e.itemsize, factors[0].dtype, ((e1 - e0) // lanes,), dev)]
                    wp.launch(factor_pass[0], dim=n, inputs=[fv, *factor_pass[1], *ev, base + lo, 0], device=dev)
                    np.exp(e[e0:e1], out=e[e0:e1])
                wp.launch(pass2, dim=n, inputs=[fv, *ev, *pass2_inputs, base + lo, 0], device=dev)

            parallel_items(chunk, len(bounds), threads=threads)

    def _native_passes(self, a: A.Inputs, o: wp.array, d: wp.array, tt: wp.array, dl: wp.array,
                       geometry: wp.array, appearance: wp.array, bg_v: wp.array, t_threshold: float,
                       rgb: wp.array, depth: wp.array, opacity: wp.array) -> None:
        """render_dense's CPU passes in C++ (float32, kernels.volume.spheres_cpu) over groups of eight
        rays, cut into guided chunks of groups, each chunk on one launch thread. Where kernels._npexp's
        exp has np.exp's bits (numpy_agrees), one launch a chunk (chunks of at least
        _CHUNK_VALUES_ONE_LAUNCH falloff values) runs pass 1, the exp, pass 2, the exp and pass 3
        group by group in the chunk's scratch; else, in blocks of at most _FALLOFF_BLOCK falloff
        values, three launches a chunk (chunks of at least _CHUNK_VALUES) with np.exp between them."""
        k1, k2, k3, fused = spheres_cpu.kernels()
        n_rays, n_s = tt.shape
        n_k = geometry.shape[0]
        dev = a.device
        lanes = spheres_cpu.LANES
        n_groups = -(-n_rays // lanes)
        per_group = lanes * n_s * n_k
        fused_exp = _FUSED_EXP_ON_CPU and _npexp.numpy_agrees()
        block = n_groups if fused_exp else max(1, min(n_groups, _FALLOFF_BLOCK // per_group))
        g4 = _view(geometry.ptr, wp.float32, (n_k, 4), dev)
        p4 = _view(appearance.ptr, wp.float32, (n_k, 4), dev)
        bg3 = _view(bg_v.ptr, wp.float32, (3,), dev)
        thr = wp.float32(t_threshold)
        min_chunk = max(1, _CHUNK_VALUES // per_group)
        threads = default_threads()
        if fused_exp:
            min_chunk = max(1, _CHUNK_VALUES_ONE_LAUNCH // per_group)
            # (split as soon as there is more than one chunk's work: the last chunk may be smaller)
            bounds = (guided_bounds(n_groups, threads, min_chunk) if threads > 1 and n_groups > min_chunk
                      else [(0, n_groups)])
            falloff = a.empty(len(bounds) * per_group)
            factor = a.empty(len(bounds) * lanes * n_s)

            def chunk(j: int) -> None:
                lo, n = bounds[j]
                fv = _view(falloff.ptr + j * per_group * 4, wp.float32, (per_group,), dev)
                ev = _view(factor.ptr + j * lanes * n_s * 4, wp.float32, (lanes * n_s,), dev)
                wp.launch(fused, dim=n, inputs=[o, d, tt, dl, g4, p4, bg3, thr, rgb, depth, opacity, fv, ev,
                                                n_rays, lo], device=dev)

            parallel_items(chunk, len(bounds), threads=threads)
            return
        falloff = a.empty(block * per_group)
        factor = a.empty(block * lanes * n_s)
        f, e = falloff.numpy(), factor.numpy()
        for base in range(0, n_groups, block):
            nb = min(block, n_groups - base)
            bounds = guided_bounds(nb, threads, min_chunk) if threads > 1 and nb >= 2 * min_chunk else [(0, nb)]

            def chunk(j: int, base: int = base, bounds: list[tuple[int, int]] = bounds) -> None:
                lo, n = bounds[j]
                g_lo = base + lo
                v0, v1 = lo * per_group, (lo + n) * per_group
                u0, u1 = lo * lanes * n_s, (lo + n) * lanes * n_s
                fv = _view(falloff.ptr + v0 * 4, wp.float32, (v1 - v0,), dev)
                ev = _view(factor.ptr + u0 * 4, wp.float32, (u1 - u0,), dev)
                wp.launch(k1, dim=n, inputs=[o, d, tt, g4, p4, fv, n_rays, g_lo], device=dev)
                np.exp(f[v0:v1], out=f[v0:v1])
                wp.launch(k2, dim=n, inputs=[fv, tt, dl, g4, p4, ev, n_rays, g_lo], device=dev)
                np.exp(e[u0:u1], out=e[u0:u1])
                wp.launch(k3, dim=n, inputs=[fv, ev, tt, g4, p4, bg3, thr, rgb, depth, opacity, n_rays, g_lo],
                          device=dev)

            parallel_items(chunk, len(bounds), threads=threads)

    def forward(self, points: A.ArrayLike, dirs: A.ArrayLike | None = None) -> FieldOutput:
        a, p, _ = self._inputs(points, dirs)
        n = p.shape[0]
        sigma, rgb = a.empty(n), a.empty((n, 3))
        if not self.device.is_cpu or _FUSED_ON_CPU or not fast_paths.enabled():
            a.launch(_spheres_forward_kernel, n, [p, *self._param_args(), sigma, rgb])
            return self._result(a, sigma, rgb)
        # CPU: the falloffs by NumPy's exp between two passes over quads of points (module docstring).
        if n:
            k1, k2 = _FIELD_PASSES[self.dtype]
            geometry, appearance = self._packed()
            sigma4, rgb4 = _vec_view(sigma, _VEC4, (n // 4,)), _vec_view(rgb, _VEC4, (3 * (n // 4),))
            self._two_passes(a, (n + 3) // 4, 4, k1, [_vec_view3(p), n], k2,
                             [appearance, n, sigma, _vec_view3(rgb), sigma4, rgb4], geometry, appearance, quads=True)
        return self._result(a, sigma, rgb)

    def render_dense(self, origins: A.ArrayLike, dirs: A.ArrayLike, t: A.ArrayLike, delta: A.ArrayLike,
                     background: Any = (0.0, 0.0, 0.0), t_threshold: float = DEFAULT_T_THRESHOLD
                     ) -> tuple[A.ArrayLike, A.ArrayLike, A.ArrayLike]:
        """(rgb (R, 3), depth (R,), opacity (R,)) of rays o + t d with explicit samples t (R, S) and
        interval lengths delta (R, S) >= 0 (module docstring: the fused forward of render_samples on
        dense_samples; depth is sum_k w_k t_k). Arrays in the field's dtype; outputs in the kind of
        `origins`. On the CPU, NumPy t and delta whose rows are one row broadcast
        (np.broadcast_to(row, (R, S)), the same samples on every ray) are read as that row, without
        a copy."""
        a = A.Inputs(self.device, origins, dirs, t, delta)
        keep: list[np.ndarray] = []  # NumPy inputs the kernels read in place (_floats_in_place)
        o = _floats_in_place(a, keep, "origins", origins, (None, 3))
        if a.scalar != self.dtype:
            raise ValueError(f"origins: expected dtype {A.type_name(self.dtype)} (the field's), "
                             f"got {A.type_name(a.scalar)}")
        n_rays = o.shape[0]
        d = _floats_in_place(a, keep, "dirs", dirs, (n_rays, 3))
        tt = _floats_in_place(a, keep, "t", t, (n_rays, None))
        dl = _floats_in_place(a, keep, "delta", delta, tuple(tt.shape), finite=False)
        A.check_at_least("delta", delta[0] if _broadcast_rows(delta, a) else dl, 0.0)
        t_threshold = A.check_float("t_threshold", t_threshold, nonnegative=True)
        if not t_threshold < 1.0:
            raise ValueError(f"t_threshold: expected a value in [0, 1), got {t_threshold}")
        bg = np.asarray(background.numpy() if isinstance(background, wp.array) else background, dtype=a.np_dtype)
        if bg.shape != (3,):
            raise ValueError(f"background: expected shape (3,), got {bg.shape}")
        A.check_finite("background", bg)
        rgb, depth, opacity = a.empty((n_rays, 3)), a.empty(n_rays), a.empty(n_rays)
        geometry, appearance = self._packed()
        bg_v = _background_vec3(bg, self.dtype, self.device)
        o3, d3, rgb3 = _vec_view3(o), _vec_view3(d), _vec_view3(rgb)
        fused, k1, kf, k2 = _RENDER_DENSE[self.dtype]
        if not self.device.is_cpu or _FUSED_ON_CPU or not fast_paths.enabled():
            a.launch(fused, n_rays, [o3, d3, tt, dl, geometry, appearance, bg_v, a.s(t_threshold), rgb3, depth,
                                     opacity], min_chunk=16)
            return a.out(rgb), a.out(depth), a.out(opacity)
        # CPU: the sphere falloffs and then the compositing factors by NumPy's exp between three
        # split launches (module docstring), four samples at a time where the samples of a ray come
        # in fours.
        n_s = tt.shape[1]
        if self.dtype == wp.float32 and _NATIVE_ON_CPU and n_rays and n_s and spheres_cpu.available():
            self._native_passes(a, o, d, tt, dl, geometry, appearance, bg_v, t_threshold, rgb, depth, opacity)
            return a.out(rgb), a.out(depth), a.out(opacity)
        if n_s % 4 == 0 and _QUADS_ON_CPU:  # (t and delta: rows contiguous, _floats_in_place)
            k1, kf, k2 = _RENDER_DENSE4[self.dtype]
            t4, dl4 = (_vec_view(x, _VEC4, (n_rays, n_s // 4)) for x in (tt, dl))
            self._two_passes(a, n_rays, n_s, k1, [o3, d3, t4], k2,
                             [t4, appearance, bg_v, a.s(t_threshold), rgb3, depth, opacity], geometry, appearance,
                             quads=True, factor_pass=(kf, [dl4, appearance]))
        else:
            self._two_passes(a, n_rays, n_s, k1, [o3, d3, tt], k2,
                             [tt, appearance, bg_v, a.s(t_threshold), rgb3, depth, opacity], geometry, appearance,
                             factor_pass=(kf, [dl, appearance]))
        return a.out(rgb), a.out(depth), a.out(opacity)

    def backward(self, points: A.ArrayLike, dirs: A.ArrayLike | None, out: FieldOutput,
                 grad_sigma: A.ArrayLike | None, grad_rgb: A.ArrayLike | None,
                 workspace: Workspace | None = None) -> dict[str, wp.array]:
        a, p, _, sigma, rgb, gs, gr = self._backward_inputs(points, dirs, out, grad_sigma, grad_rgb)
        return self._scatter_grads(_spheres_backward_kernel, p.shape[0], [p, *self._param_args(), sigma, rgb, gs, gr],
                                   workspace)


A.declare_float_overloads(_spheres_forward_kernel)
A.declare_float_overloads(_spheres_backward_kernel)
_VEC3 = {wp.float32: wp.vec3f, wp.float64: wp.vec3d}
_VEC4 = {wp.float32: wp.vec4f, wp.float64: wp.vec4d}


@wp.kernel
def _pack_spheres_kernel(centers: wp.array2d(dtype=typing.Any), radii: wp.array(dtype=typing.Any),
                         colors: wp.array2d(dtype=typing.Any), sharpness: wp.array(dtype=typing.Any),
                         geometry: wp.array(dtype=typing.Any), appearance: wp.array(dtype=typing.Any)):
    k = wp.tid()
    g = geometry[k]
    g[0] = centers[k, 0]
    g[1] = centers[k, 1]
    g[2] = centers[k, 2]
    g[3] = radii[k]
    geometry[k] = g
    a = appearance[k]
    a[0] = colors[k, 0]
    a[1] = colors[k, 1]
    a[2] = colors[k, 2]
    a[3] = sharpness[k]
    appearance[k] = a


def _render_dense_overloads() -> dict[Any, tuple[Any, Any, Any, Any]]:
    """{scalar: concrete overloads of (the fused kernel, CPU pass 1, CPU pass 2 (factors), CPU pass 3)}
    (launching a concrete overload spares Warp inferring the argument types on every launch); also
    declares _pack_spheres_kernel's."""
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
        wp.overload(_pack_spheres_kernel, {
            "centers": wp.array2d(dtype=s), "radii": wp.array(dtype=s), "colors": wp.array2d(dtype=s),
            "sharpness": wp.array(dtype=s), "geometry": wp.array(dtype=v4), "appearance": wp.array(dtype=v4)})
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


def _floats_in_place(a: A.Inputs, keep: list[np.ndarray], name: str, x: Any, shape: tuple[Any, ...],
                     finite: bool = True) -> wp.array:
    """a.floats(name, x, shape, finite=finite) (the same checks and errors), except that a non-empty
    NumPy argument of a CPU call is not copied: the result is a non-owning wp.array over its
    contiguous data (the copies and their first-touch page faults were ~0.9 ms of a 64x64 x 64
    render_dense, docs/performance.md). `keep` holds the NumPy array; the caller keeps `keep` alive
    while the kernels run."""
    if not (isinstance(x, np.ndarray) and a.device.is_cpu and x.size):
        return a.floats(name, x, shape, finite=finite)
    dtype = A.float_dtype(name, x)
    if a.scalar is None:
        a.scalar = dtype
    elif dtype != a.scalar:
        raise ValueError(f"{name}: expected dtype {A.type_name(a.scalar)} like the other inputs, "
                         f"got {A.type_name(dtype)}")
    A.check_shape(name, x, shape)
    if _broadcast_rows(x, a):
        # every row is row 0: checked once, and read through a zero row stride
        if finite:
            A.check_finite(name, x[0])
        keep.append(x)
        return _view(x.ctypes.data, dtype, x.shape, a.device, (0, x.strides[1]))
    if finite:
        A.check_finite(name, x)
    h = np.ascontiguousarray(x)
    keep.append(h)
    return _view(h.ctypes.data, dtype, h.shape, a.device)


def _broadcast_rows(x: Any, a: A.Inputs) -> bool:
    """Whether x is a 2-D NumPy array of a CPU call whose rows are all its first row (row stride 0,
    np.broadcast_to) with contiguous entries."""
    return (isinstance(x, np.ndarray) and a.device.is_cpu and x.ndim == 2 and x.size > 0 and x.strides[0] == 0
            and x.strides[1] == x.itemsize)


_BACKGROUNDS: dict[tuple, wp.array] = {}  # (bytes, dtype, device) -> the checked background as one vec3


def _background_vec3(bg: np.ndarray, dtype: Any, device: wp.Device) -> wp.array:
    """The checked background colour bg (3,) as a one-vec3 array, kept for the next call with the same colour."""
    key = (bg.tobytes(), dtype, device.alias)
    arr = _BACKGROUNDS.get(key)
    if arr is None:
        if len(_BACKGROUNDS) >= 64:
            _BACKGROUNDS.clear()
        arr = _BACKGROUNDS[key] = wp.array(bg[None], dtype=_VEC3[dtype], device=device)
    return arr


# Non-owning views kept by (address, dtype, shape, device). A view is nothing but those four, so a
# kept one is the same as a new one; a call's arrays come from the host pool (or NumPy's allocator)
# at the same addresses call after call, and a new wp.array costs ~10 us of Python (about a dozen a
# render_dense call). Bounded: cleared when full.
_VIEWS: dict[tuple, wp.array] = {}
_VIEWS_MAX = 256


def _view(ptr: int, dtype: Any, shape: tuple[int, ...], device: wp.Device,
          strides: tuple[int, ...] | None = None) -> wp.array:
    """wp.array(ptr=ptr, dtype=dtype, shape=shape, strides=strides, device=device), kept in _VIEWS."""
    key = (ptr, dtype, tuple(shape), strides, device.alias)
    v = _VIEWS.get(key)
    if v is None:
        if len(_VIEWS) >= _VIEWS_MAX:
            _VIEWS.clear()
        v = _VIEWS[key] = wp.array(ptr=ptr, dtype=dtype, shape=shape, strides=strides, device=device)
    return v


def _vec_view3(x: wp.array) -> wp.array:
    """A contiguous (N, 3) float array seen as N vec3s (zero-copy)."""
    return _view(x.ptr, _VEC3[x.dtype], (x.shape[0],), x.device)


def _vec_view(x: wp.array, vec: dict[Any, Any], shape: tuple[int, ...]) -> wp.array:
    """A contiguous float array seen as an array of `shape` of vec[x.dtype] vectors (zero-copy; x
    must stay alive while the view is used). A 2-D x whose rows are one row (row stride 0) gives
    rows that are that row's vectors."""
    v = vec[x.dtype]
    if x.ndim == 2 and x.strides[0] == 0:
        return _view(x.ptr, v, shape, x.device, (0, wp.types.type_size_in_bytes(v)))
    return _view(x.ptr, v, shape, x.device)
