"""Projection of 3D Gaussians into a camera, and its hand-written backward.

Per splat i with mean mu, log-scales l, quaternion q (normalised here), opacity logit a and SH
coefficients f (K = (L+1)^2, 3), for the world-to-camera [W | t] and intrinsics fx, fy, cx, cy:

    Sigma = R(q/|q|) S S^T R^T,  S = diag(exp l)                      (ewa.quat_scale_to_covar)
    p = W mu + t = (x, y, z);  culled if z < near or z > far
    mean2d, Sigma2d = EWA projection of (p, W Sigma W^T)               (ewa.persp_proj)
    (a1, b, c1) = Sigma2d + s I  (the low-pass dilation s, 0.3 px^2 by default); culled if det <= 0
    conic Q = (a1, b, c1)^-1 stored as (Q00, Q01, Q11)                 (ewa.conic_inverse)
    radius = ceil(3 sqrt(lambda_max)),  lambda_max = h + sqrt(max(f, h^2 - det)), h = (a1 + c1)/2,
        f = 0.1 ("3dgs") or 0.01 ("gsplat"); culled when the mode's tile rectangle of the square
        mean2d +- radius is empty ("3dgs") or the square misses the image ("gsplat") (radius 0
        marks a culled splat, whose other outputs are 0)
    stored radius = min(radius, reach),  reach = 2 max(|u|, |u - W|, |v|, |v - H|) + 16 for
        mean2d = (u, v) and a W x H image                                (clamp_radius)

`mode` ("3dgs", the default, or "gsplat") selects the reference code followed: the Jacobian's
frustum clamp, the radius floor f, the culling rule and the antialiasing floor
(kernels/splat/modes.py has the table, kernels/splat/ewa.py the clamp's formulas).

The radius clamp. The radius is only a culling flag (> 0) and the half-size of the square a splat
is binned with (kernels/splat/tiles.py clamps that square to the image's tiles); the rasteriser
reads the conic, never the radius. Any square mean2d +- r with r >= reach contains the whole
image, so clamping to reach changes neither the culling nor the tiles nor any pixel or gradient:
a splat larger than the image still covers it all, and its gradients stay finite and non-zero
(about 1e-24 through the conic of a log-scale-30 splat seen from 4 units). Splats whose radius is
below reach are untouched, bit for bit. Without the clamp the float-to-int32 conversion overflowed
from about log-scale 20 (radius > 2^31) to -2^31, and the splat vanished with a zero gradient.

The wide path. In float32, det = a1 c1 - b^2 overflows once the 2D standard deviations pass about
4e9 px ((4e9)^4 > 3.4e38: log-scale 20 where fx / z = 10 px per unit). For such a splat (det not
finite) both kernels redo its geometry in float64: the forward its conic, radius and compensation,
the backward the VJP of its opacity factor, conic, dilation, projection and covariance, and round
the results to float32. No other splat takes this path, so float32 results are otherwise unchanged.

Largest scale that renders exactly: in float64, no limit within the |log-scale| <= 80 that
gaussian_inputs accepts (the backward's det^2 stays finite while fx / z < about 5e3 px per
unit), with one exception: a splat whose clamped radius would still exceed RADIUS_CAP = 2^30 (its
mean2d over 2^29 px off the image, its radius larger still) is culled, so the tile arithmetic stays
in int32. In float32 the limit is the conic's magnitude, about (fx / z)^-2 exp(-2 log-scale): it
leaves float32's normal range (1.2e-38) near log-scale 41 where fx / z = 10; beyond, it rounds to
a subnormal and then to 0. The splat still covers the image with alpha = its opacity, as the math
gives to float32 precision (its tile box is then the clamped radius, kernels/splat/tiles.py), and
its opacity and colour gradients stay exact, but the gradients that flow through the conic
(log-scales, quaternion, mean) fall below float32's range and read 0.

The backward kernel recomputes the forward through the same functions of kernels/splat/ewa.py and
chains their VJPs in reverse: colour and SH (sh.sh_basis_grad, view_direction_vjp), opacity
and compensation, conic inverse and dilation, EWA projection, covariance. One thread per splat
writes only that splat's gradients, so both kernels run split over CPU threads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.sh import sh_basis, sh_basis_grad
from kernels.splat.camera import SplatCamera
from kernels.splat.modes import DEFAULT_MODE, RADIUS_FLOOR_OF, dilation_of, mode_id
from kernels.splat.ewa import (aa_compensation, aa_compensation_vjp, conic_inverse, conic_inverse_vjp, dilate_cov2d,
                               dilate_cov2d_vjp, persp_intrinsics_vjp, persp_proj, persp_proj_vjp, pose_vjp,
                               quat_scale_to_covar,
                               quat_scale_to_covar_vjp, sigmoid, transform_cov, transform_cov_vjp, view_direction,
                               view_direction_vjp)
from kernels.splat.tiles import TILE

wp.set_module_options({"enable_backward": False})

MIN_CHUNK = 1024
RADIUS_FLOOR_3DGS = RADIUS_FLOOR_OF["3dgs"]
RADIUS_FLOOR_GSPLAT = RADIUS_FLOOR_OF["gsplat"]
# Largest radius stored (2^30: exact in float32, and u +- radius stays inside int32 in the tile binning).
RADIUS_CAP = float(2**30)


@wp.func
def _load_view(view: wp.array2d(dtype=Any)):
    """(W, t) of a 4x4 world-to-camera matrix."""
    Wr = wp.matrix(view[0, 0], view[0, 1], view[0, 2], view[1, 0], view[1, 1], view[1, 2],
                   view[2, 0], view[2, 1], view[2, 2], shape=(3, 3), dtype=view.dtype)
    t = wp.vector(view[0, 3], view[1, 3], view[2, 3], length=3, dtype=view.dtype)
    return Wr, t


@wp.func
def _load_splat(means: wp.array2d(dtype=Any), log_scales: wp.array2d(dtype=Any), quats: wp.array2d(dtype=Any),
                i: int):
    """(mu, q, l) of splat i."""
    mu = wp.vector(means[i, 0], means[i, 1], means[i, 2], length=3, dtype=means.dtype)
    q = wp.vector(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3], length=4, dtype=means.dtype)
    l = wp.vector(log_scales[i, 0], log_scales[i, 1], log_scales[i, 2], length=3, dtype=means.dtype)
    return mu, q, l


@wp.func
def _camera_frame(view: wp.array2d(dtype=Any), means: wp.array2d(dtype=Any), log_scales: wp.array2d(dtype=Any),
                  quats: wp.array2d(dtype=Any), i: int):
    """(W, t, mu, q, l, p = W mu + t) of splat i: the view, its parameters and its camera-frame mean."""
    Wr, tv = _load_view(view)
    mu, q, l = _load_splat(means, log_scales, quats, i)
    return Wr, tv, mu, q, l, Wr * mu + tv


@wp.func
def _conic_chain(Wr: Any, q: Any, l: Any, p: Any, fx: Any, fy: Any, cx: Any, cy: Any, width: int, height: int,
                 mode: int, dilation: wp.float64):
    """The forward from the camera-frame mean p to the conic (module docstring): (cov_c, u, v, the
    undilated a, b, c and det0, the dilated a1, c1, and det, qa, qb, qc of the conic inverse)."""
    cov_c = transform_cov(Wr, quat_scale_to_covar(q, l))
    u, v, cov2d = persp_proj(p, cov_c, fx, fy, cx, cy, width, height, mode)
    a, b, c, det0, a1, c1 = dilate_cov2d(cov2d, dilation)
    det, qa, qb, qc = conic_inverse(a1, b, c1)
    return cov_c, u, v, a, b, c, det0, a1, c1, det, qa, qb, qc


@wp.func
def _store_screen(means2d: wp.array2d(dtype=Any), conics: wp.array2d(dtype=Any), depths: wp.array(dtype=Any), i: int,
                  u: Any, v: Any, qa: Any, qb: Any, qc: Any, tz: Any):
    """Write splat i's screen-space mean (u, v), conic (qa, qb, qc) and depth tz."""
    means2d[i, 0] = u
    means2d[i, 1] = v
    conics[i, 0] = qa
    conics[i, 1] = qb
    conics[i, 2] = qc
    depths[i] = tz


@wp.func
def _load_view_f64(view: wp.array2d(dtype=Any)):
    """(W, t) of `view` in float64 (the float32 kernels' wide path)."""
    Wr = wp.matrix(wp.float64(view[0, 0]), wp.float64(view[0, 1]), wp.float64(view[0, 2]),
                   wp.float64(view[1, 0]), wp.float64(view[1, 1]), wp.float64(view[1, 2]),
                   wp.float64(view[2, 0]), wp.float64(view[2, 1]), wp.float64(view[2, 2]),
                   shape=(3, 3), dtype=wp.float64)
    t = wp.vector(wp.float64(view[0, 3]), wp.float64(view[1, 3]), wp.float64(view[2, 3]), length=3,
                  dtype=wp.float64)
    return Wr, t


@wp.func
def _load_splat_f64(means: wp.array2d(dtype=Any), log_scales: wp.array2d(dtype=Any),
                    quats: wp.array2d(dtype=Any), i: int):
    """(mu, q, l) of splat i in float64 (the float32 kernels' wide path)."""
    mu = wp.vector(wp.float64(means[i, 0]), wp.float64(means[i, 1]), wp.float64(means[i, 2]), length=3,
                   dtype=wp.float64)
    q = wp.vector(wp.float64(quats[i, 0]), wp.float64(quats[i, 1]), wp.float64(quats[i, 2]),
                  wp.float64(quats[i, 3]), length=4, dtype=wp.float64)
    l = wp.vector(wp.float64(log_scales[i, 0]), wp.float64(log_scales[i, 1]), wp.float64(log_scales[i, 2]),
                  length=3, dtype=wp.float64)
    return mu, q, l


@wp.func
def _screen_conic(mu: Any, q: Any, l: Any, Wr: Any, tv: Any, fx: Any, fy: Any, cx: Any, cy: Any, width: int,
                  height: int, mode: int, dilation: wp.float64):
    """(u, v, det0, det, Q00, Q01, Q11, unclamped radius) of one splat (module docstring)."""
    cov_c, u, v, a, b, c, det0, a1, c1, det, qa, qb, qc = _conic_chain(Wr, q, l, Wr * mu + tv, fx, fy, cx, cy,
                                                                       width, height, mode, dilation)
    half = type(det)(0.5)
    bb = half * (a1 + c1)
    floor = type(det)(RADIUS_FLOOR_GSPLAT)
    if mode == 0:
        floor = type(det)(RADIUS_FLOOR_3DGS)
    lam = bb + wp.sqrt(wp.max(floor, bb * bb - det))
    r = wp.ceil(type(det)(3.0) * wp.sqrt(lam))
    return u, v, det0, det, qa, qb, qc, r


@wp.func
def _projection_vjp(mu: Any, q: Any, l: Any, Wr: Any, tv: Any, fx: Any, fy: Any, cx: Any, cy: Any, width: int,
                    height: int, mode: int, dilation: wp.float64, antialiased: int, g_comp: Any, gQa: Any, gQb: Any,
                    gQc: Any, gu: Any, gv: Any,
                    g_depth: Any):
    """(dL/dmu, dL/dq, dL/dl, opacity factor c, det, dL/drho, dL/dphi, dL/d(fx, fy, cx, cy)) of the
    projection's geometry, for the cotangents of the conic, mean2d and depth and dL/dc = g_comp (c = 1
    unless antialiased); the pose terms leave out the view direction's share."""
    zero = type(g_comp)(0.0)
    p = Wr * mu + tv
    cov_c, u, v, a, b, c, det0, a1, c1, det, qa, qb, qc = _conic_chain(Wr, q, l, p, fx, fy, cx, cy, width, height,
                                                                       mode, dilation)

    # Opacity o = sigmoid(a) comp.
    g_det0 = zero
    g_det = zero
    comp = type(g_comp)(1.0)
    if antialiased != 0:
        comp = aa_compensation(det0, det, mode)
        g_det0, g_det = aa_compensation_vjp(det0, det, g_comp, mode)

    # Conic and dilation (det0 = a c - b^2 adds its share).
    g_a1, g_b1, g_c1 = conic_inverse_vjp(a1, b, c1, gQa, gQb, gQc, g_det)
    g_cov2d = dilate_cov2d_vjp(a, b, c, g_a1, g_b1, g_c1, g_det0)

    # EWA projection, then the world-to-camera transforms of the mean and the covariance.
    g_p, g_cov_c = persp_proj_vjp(p, cov_c, fx, fy, cx, cy, width, height, mode, g_cov2d, gu, gv, g_depth)
    g_mu = wp.transpose(Wr) * g_p
    g_q, g_l = quat_scale_to_covar_vjp(q, l, transform_cov_vjp(Wr, g_cov_c))
    g_rho, g_phi = pose_vjp(p, g_p, cov_c, g_cov_c)
    g_intr = persp_intrinsics_vjp(p, cov_c, fx, fy, cx, cy, width, height, mode, g_cov2d, gu, gv)
    return g_mu, g_q, g_l, comp, det, g_rho, g_phi, g_intr


@wp.func
def sh_color(sh: wp.array3d(dtype=Any), i: int, ch: int, basis: Any, n_coeffs: int):
    """sum_k f_k Y_k(d) + 1/2 for channel ch of splat i, before the clamp at 0."""
    acc = sh.dtype(0.5)
    for k in range(n_coeffs):
        acc += basis[k] * sh[i, k, ch]
    return acc


@wp.func
def culled(u: Any, v: Any, r: Any, width: int, height: int, mode: int):
    """Whether the square (u, v) +- r lists no tile: "3dgs" (mode 0) 3DGS's getRect rectangle is empty
    (kernels/splat/modes.py), "gsplat" the square misses the image."""
    zero = type(r)(0.0)
    w = type(r)(float(width))
    h = type(r)(float(height))
    if mode == 0:
        half = type(r)(0.5)
        t = type(r)(float(TILE))
        reach = type(r)(float(TILE - 1)) - half
        tw = type(r)(float(((width + TILE - 1) // TILE) * TILE))
        th = type(r)(float(((height + TILE - 1) // TILE) * TILE))
        return u + r + reach < t or u - half - r >= tw or v + r + reach < t or v - half - r >= th
    return u + r <= zero or u - r >= w or v + r <= zero or v - r >= h


@wp.func
def clamp_radius(r: Any, u: Any, v: Any, width: int, height: int):
    """min(r, reach), reach = 2 max(|u|, |u - W|, |v|, |v - H|) + TILE; 0 (culled) when both exceed
    RADIUS_CAP (module docstring)."""
    w = type(r)(float(width))
    h = type(r)(float(height))
    far = wp.max(wp.max(wp.abs(u), wp.abs(u - w)), wp.max(wp.abs(v), wp.abs(v - h)))
    reach = wp.ceil(type(r)(2.0) * far) + type(r)(float(TILE))
    out = wp.min(r, reach)
    if out > type(r)(RADIUS_CAP):
        out = type(r)(0.0)
    return out


@wp.kernel
def _project_kernel(
    means: wp.array2d(dtype=Any), log_scales: wp.array2d(dtype=Any), quats: wp.array2d(dtype=Any),
    opacity_logits: wp.array(dtype=Any), sh: wp.array3d(dtype=Any), view: wp.array2d(dtype=Any),
    cam: wp.array(dtype=Any), width: int, height: int, sh_degree: int, mode: int, dilation: wp.float64,
    antialiased: int,
    means2d: wp.array2d(dtype=Any), conics: wp.array2d(dtype=Any), depths: wp.array(dtype=Any),
    radii: wp.array(dtype=wp.int32), colors: wp.array2d(dtype=Any), opacities: wp.array(dtype=Any), offset: int,
):
    i = wp.tid() + offset
    zero = means.dtype(0.0)
    radii[i] = 0
    _store_screen(means2d, conics, depths, i, zero, zero, zero, zero, zero, zero)
    colors[i, 0] = zero
    colors[i, 1] = zero
    colors[i, 2] = zero
    opacities[i] = zero

    Wr, tv, mu, q, l, p = _camera_frame(view, means, log_scales, quats, i)
    tz = p[2]
    if tz < cam[4] or tz > cam[5]:
        return
    u, v, det0, det, qa, qb, qc, r = _screen_conic(mu, q, l, Wr, tv, cam[0], cam[1], cam[2], cam[3], width, height,
                                                   mode, dilation)
    comp = means.dtype(1.0)
    if wp.isnan(det) or wp.isinf(det):
        # Past float32's range (module docstring): the conic, radius and compensation in float64.
        W64, t64 = _load_view_f64(view)
        mu64, q64, l64 = _load_splat_f64(means, log_scales, quats, i)
        u64, v64, det0_64, det64, qa64, qb64, qc64, r64 = _screen_conic(
            mu64, q64, l64, W64, t64, wp.float64(cam[0]), wp.float64(cam[1]), wp.float64(cam[2]),
            wp.float64(cam[3]), width, height, mode, dilation)
        if det64 <= wp.float64(0.0) or wp.isnan(det64) or wp.isinf(det64):
            return
        qa = means.dtype(qa64)
        qb = means.dtype(qb64)
        qc = means.dtype(qc64)
        r = means.dtype(r64)
        det = means.dtype(1.0)  # only its sign is read below
        if antialiased != 0:
            comp = means.dtype(aa_compensation(det0_64, det64, mode))
    elif antialiased != 0:
        comp = aa_compensation(det0, det, mode)
    if det <= zero:
        return
    if culled(u, v, r, width, height, mode):
        return

    rc = clamp_radius(r, u, v, width, height)
    if rc <= zero:
        return
    radii[i] = int(rc)
    _store_screen(means2d, conics, depths, i, u, v, qa, qb, qc, tz)

    d, dn = view_direction(mu, Wr, tv)
    basis = sh_basis(d[0], d[1], d[2])
    n_coeffs = (sh_degree + 1) * (sh_degree + 1)
    for ch in range(3):
        acc = sh_color(sh, i, ch, basis, n_coeffs)
        colors[i, ch] = wp.max(acc, zero)

    o = sigmoid(opacity_logits[i])
    if antialiased != 0:
        o = o * comp
    opacities[i] = o


@wp.kernel
def _project_backward_kernel(
    means: wp.array2d(dtype=Any), log_scales: wp.array2d(dtype=Any), quats: wp.array2d(dtype=Any),
    opacity_logits: wp.array(dtype=Any), sh: wp.array3d(dtype=Any), view: wp.array2d(dtype=Any),
    cam: wp.array(dtype=Any), width: int, height: int, sh_degree: int, mode: int, dilation: wp.float64,
    antialiased: int,
    radii: wp.array(dtype=wp.int32),
    g_means2d: wp.array2d(dtype=Any), g_conics: wp.array2d(dtype=Any), g_depths: wp.array(dtype=Any),
    g_colors: wp.array2d(dtype=Any), g_opacities: wp.array(dtype=Any),
    d_means: wp.array2d(dtype=Any), d_log_scales: wp.array2d(dtype=Any), d_quats: wp.array2d(dtype=Any),
    d_opacity_logits: wp.array(dtype=Any), d_sh: wp.array3d(dtype=Any), want_camera: int,
    d_camera: wp.array2d(dtype=Any), offset: int,
):
    i = wp.tid() + offset
    zero = means.dtype(0.0)
    one = means.dtype(1.0)
    if want_camera != 0:
        for j in range(10):
            d_camera[i, j] = zero
    for k in range(sh.shape[1]):
        for ch in range(3):
            d_sh[i, k, ch] = zero
    for j in range(3):
        d_means[i, j] = zero
        d_log_scales[i, j] = zero
    for j in range(4):
        d_quats[i, j] = zero
    d_opacity_logits[i] = zero
    if radii[i] == 0:
        return

    # The forward recomputed by its own functions, and the geometry's VJP (opacity, conic and
    # dilation, EWA projection, world-to-camera transforms), in float64 where float32 overflowed
    # (the forward's wide path).
    Wr, tv = _load_view(view)
    mu, q, l = _load_splat(means, log_scales, quats, i)
    sig = sigmoid(opacity_logits[i])
    g_o = g_opacities[i]
    g_mu, g_q, g_l, comp, det, g_rho, g_phi, g_intr = _projection_vjp(
        mu, q, l, Wr, tv, cam[0], cam[1], cam[2], cam[3], width, height, mode, dilation, antialiased, g_o * sig,
        g_conics[i, 0], g_conics[i, 1],
                                                g_conics[i, 2], g_means2d[i, 0], g_means2d[i, 1], g_depths[i])
    if wp.isnan(det) or wp.isinf(det):
        W64, t64 = _load_view_f64(view)
        mu64, q64, l64 = _load_splat_f64(means, log_scales, quats, i)
        g_mu64, g_q64, g_l64, comp64, det64, g_rho64, g_phi64, g_intr64 = _projection_vjp(
            mu64, q64, l64, W64, t64, wp.float64(cam[0]), wp.float64(cam[1]), wp.float64(cam[2]),
            wp.float64(cam[3]), width, height, mode, dilation, antialiased, wp.float64(g_o * sig),
            wp.float64(g_conics[i, 0]), wp.float64(g_conics[i, 1]), wp.float64(g_conics[i, 2]),
            wp.float64(g_means2d[i, 0]), wp.float64(g_means2d[i, 1]), wp.float64(g_depths[i]))
        g_mu = wp.vector(means.dtype(g_mu64[0]), means.dtype(g_mu64[1]), means.dtype(g_mu64[2]), length=3,
                         dtype=means.dtype)
        g_l = wp.vector(means.dtype(g_l64[0]), means.dtype(g_l64[1]), means.dtype(g_l64[2]), length=3,
                        dtype=means.dtype)
        g_q = wp.vector(means.dtype(g_q64[0]), means.dtype(g_q64[1]), means.dtype(g_q64[2]), means.dtype(g_q64[3]),
                        length=4, dtype=means.dtype)
        comp = means.dtype(comp64)
        g_rho = wp.vector(means.dtype(g_rho64[0]), means.dtype(g_rho64[1]), means.dtype(g_rho64[2]), length=3,
                          dtype=means.dtype)
        g_phi = wp.vector(means.dtype(g_phi64[0]), means.dtype(g_phi64[1]), means.dtype(g_phi64[2]), length=3,
                          dtype=means.dtype)
        g_intr = wp.vector(means.dtype(g_intr64[0]), means.dtype(g_intr64[1]), means.dtype(g_intr64[2]),
                           means.dtype(g_intr64[3]), length=4, dtype=means.dtype)
    d_opacity_logits[i] = g_o * comp * sig * (one - sig)
    for j in range(3):
        d_log_scales[i, j] = g_l[j]
    for j in range(4):
        d_quats[i, j] = g_q[j]

    # Colour = max(0, sum_k f_k Y_k(d) + 1/2).
    d, dn = view_direction(mu, Wr, tv)
    basis = sh_basis(d[0], d[1], d[2])
    bdx, bdy, bdz = sh_basis_grad(d[0], d[1], d[2])
    n_coeffs = (sh_degree + 1) * (sh_degree + 1)
    g_d = wp.vector(zero, zero, zero, length=3, dtype=means.dtype)
    for ch in range(3):
        acc = sh_color(sh, i, ch, basis, n_coeffs)
        if acc > zero:
            gcol = g_colors[i, ch]
            for k in range(n_coeffs):
                d_sh[i, k, ch] = basis[k] * gcol
                f = sh[i, k, ch] * gcol
                g_d = g_d + wp.vector(bdx[k] * f, bdy[k] * f, bdz[k] * f, length=3, dtype=means.dtype)
    g_view = view_direction_vjp(d, dn, g_d)
    g_mu = g_mu + g_view

    if want_camera != 0:
        # The camera centre -W^T t moves by -W^T rho: the view direction's share of dL/drho is W g_view.
        g_rho = g_rho + Wr * g_view
        for j in range(3):
            d_camera[i, j] = g_rho[j]
            d_camera[i, 3 + j] = g_phi[j]
        for j in range(4):
            d_camera[i, 6 + j] = g_intr[j]

    d_means[i, 0] = g_mu[0]
    d_means[i, 1] = g_mu[1]
    d_means[i, 2] = g_mu[2]


@wp.kernel
def _count_bad_kernel(quats: wp.array2d(dtype=Any), log_scales: wp.array2d(dtype=Any), bound: float,
                      count: wp.array(dtype=wp.int32)):
    # Value checks on a CUDA device (one launch; the CPU reads a zero-copy view instead).
    i = wp.tid()
    qn = wp.float64(0.0)
    for j in range(4):
        qn += wp.float64(quats[i, j]) * wp.float64(quats[i, j])
    if wp.sqrt(qn) < wp.float64(1e-12):
        wp.atomic_add(count, 0, 1)
    for j in range(3):
        if wp.abs(wp.float64(log_scales[i, j])) > wp.float64(bound):
            wp.atomic_add(count, 1, 1)


for _k in (_project_kernel, _project_backward_kernel, _count_bad_kernel):
    A.declare_float_overloads(_k)

LOG_SCALE_BOUND = 80.0


# ============================================================================ entry points


@dataclass
class GaussianInputs:
    """Validated splat parameters: wp.arrays on one device, in one float dtype.

    `as_numpy` is the kind of the arrays the caller passed: every result computed from these
    inputs (projections, renders, gradients) comes back as NumPy arrays when it is True, and as
    wp.arrays on `device` otherwise.
    """

    means: wp.array
    log_scales: wp.array
    quats: wp.array
    opacity_logits: wp.array
    sh: wp.array
    scalar: Any  # wp.float32 or wp.float64
    device: wp.Device
    as_numpy: bool

    @property
    def n(self) -> int:
        return self.means.shape[0]

    @property
    def dtype(self) -> np.dtype:
        return A.NP_OF_WP[self.scalar]

    def inputs(self) -> A.Inputs:
        """An `Inputs` for a call on these parameters: their device, dtype and output kind."""
        return A.Inputs.like(self.device, self.scalar, self.as_numpy)


def sh_degree_of(sh_shape: tuple, sh_degree: int | None) -> int:
    """The SH degree to evaluate: `sh_degree`, or the full degree of the (N, K, 3) coefficients."""
    k = sh_shape[1]
    full = int(round(math.sqrt(k))) - 1
    if (full + 1) ** 2 != k or not 0 <= full <= 3:
        raise ValueError(f"sh: expected (N, K, 3) with K in (1, 4, 9, 16), got {tuple(sh_shape)}")
    if sh_degree is None:
        return full
    return A.check_int("sh_degree", sh_degree, 0, full)


def _check_values(quats: wp.array, log_scales: wp.array) -> None:
    if not A.values_checked() or quats.shape[0] == 0:
        return
    if quats.device.is_cpu:
        qn = np.linalg.norm(quats.numpy().astype(np.float64), axis=1)
        if np.any(qn < 1e-12):
            raise ValueError(f"quats: quaternion {int(np.argmin(qn))} has zero norm; expected non-zero quaternions")
        big = np.abs(log_scales.numpy()).max()
        if big > LOG_SCALE_BOUND:
            raise ValueError(f"log_scales: |log-scale| up to {big:.3g}; expected values in [-80, 80] "
                             "(scales are exp(log_scales), and must stay finite and non-zero)")
        return
    bad_q, bad_l = A.device_counts(_count_bad_kernel, quats.shape[0], [quats, log_scales, LOG_SCALE_BOUND],
                                   quats.device, slots=2)
    if bad_q:
        raise ValueError(f"quats: {bad_q} quaternions have zero norm; expected non-zero quaternions")
    if bad_l:
        raise ValueError("log_scales: expected values in [-80, 80] (scales are exp(log_scales), and must stay "
                         "finite and non-zero)")


def gaussian_inputs(means: Any, log_scales: Any, quats: Any, opacity_logits: Any, sh: Any,
                    device: Any = None) -> GaussianInputs:
    """Check the parameter arrays (shapes, one float dtype, device, finite, non-zero quaternions,
    |log_scales| <= 80) and hold them as wp.arrays; NumPy or wp.array inputs (kernels/_arrays.py)."""
    a = A.Inputs(device, means, log_scales, quats, opacity_logits, sh)
    m = a.floats("means", means, (None, 3))
    n = m.shape[0]
    ls = a.floats("log_scales", log_scales, (n, 3))
    q = a.floats("quats", quats, (n, 4))
    o = a.floats("opacity_logits", opacity_logits, (n,))
    s = a.floats("sh", sh, (n, None, 3))
    sh_degree_of(tuple(s.shape), None)
    _check_values(q, ls)
    return GaussianInputs(m, ls, q, o, s, a.scalar, a.device, a.as_numpy)


@dataclass
class Projection:
    """Per-splat screen-space quantities (radius 0 = culled; its other outputs are 0)."""

    means2d: Any  # (N, 2) pixels
    conics: Any  # (N, 3) (Q00, Q01, Q11)
    depths: Any  # (N,)
    radii: Any  # (N,) int32
    colors: Any  # (N, 3)
    opacities: Any  # (N,)

    def out(self, a: A.Inputs) -> "Projection":
        """This projection in the output kind of `a`."""
        return Projection(a.out(self.means2d), a.out(self.conics), a.out(self.depths), a.out(self.radii),
                          a.out(self.colors), a.out(self.opacities))


def _camera_arrays(a: A.Inputs, camera: SplatCamera) -> tuple[wp.array, wp.array]:
    if not isinstance(camera, SplatCamera):
        raise ValueError(f"camera: expected a SplatCamera, got {type(camera).__name__}")
    view = wp.array(camera.viewmat.astype(a.np_dtype), dtype=a.scalar, device=a.device)
    cam = wp.array(camera.params().astype(a.np_dtype), dtype=a.scalar, device=a.device)
    return view, cam


def project_wp(g: GaussianInputs, camera: SplatCamera, sh_degree: int, antialiased: bool,
               mode: str = DEFAULT_MODE, dilation: float | None = None) -> Projection:
    """`project` with wp.array results on g's device (the render chain's first stage)."""
    mid = mode_id(mode)
    s = dilation_of(mode, dilation, antialiased)
    a = g.inputs()
    view, cam = _camera_arrays(a, camera)
    n = g.n
    # Every row is written by its thread (zeros first, for a culled splat): no zero fill; on the CPU the
    # large arrays recycle freed blocks (kernels/_arrays.py, HostPool).
    out = Projection(a.empty((n, 2)), a.empty((n, 3)), a.empty(n), a.empty(n, wp.int32), a.empty((n, 3)),
                     a.empty(n))
    a.launch(_project_kernel, n,
             [g.means, g.log_scales, g.quats, g.opacity_logits, g.sh, view, cam, camera.width, camera.height,
              sh_degree, mid, wp.float64(s), int(bool(antialiased)), out.means2d, out.conics, out.depths, out.radii,
              out.colors, out.opacities], min_chunk=MIN_CHUNK)
    return out


def project(g: GaussianInputs, camera: SplatCamera, *, sh_degree: int | None = None,
            antialiased: bool = False, mode: str = DEFAULT_MODE, dilation: float | None = None) -> Projection:
    """Project every splat into `camera` (module docstring) following `mode` ("3dgs" or "gsplat",
    kernels/splat/modes.py), with the low-pass `dilation` (px^2; None: the mode's, 0.3); arrays in the
    kind of g's inputs."""
    mode_id(mode)
    dilation_of(mode, dilation, antialiased)
    deg = sh_degree_of(tuple(g.sh.shape), sh_degree)
    return project_wp(g, camera, deg, antialiased, mode, dilation).out(g.inputs())


def project_backward(g: GaussianInputs, camera: SplatCamera, radii: Any, grad_means2d: Any, grad_conics: Any,
                     grad_depths: Any, grad_colors: Any, grad_opacities: Any, *, sh_degree: int | None = None,
                     antialiased: bool = False, mode: str = DEFAULT_MODE, dilation: float | None = None,
                     want_camera: bool = False) -> dict[str, Any]:
    """Vector-Jacobian product of `project` (with the same `mode`, `antialiased` and `dilation`).

    Returns a dict with the gradients of "means", "log_scales", "quats", "opacity_logits" and
    "sh", each shaped like the parameter, in the kind of g's inputs (NumPy or wp.array). With
    `want_camera`, also "pose" (6,): dL/dxi for the left perturbation viewmat <- exp(xi^) viewmat,
    xi = (rho, phi) translation first, and "intrinsics" (4,): dL/d(fx, fy, cx, cy)
    (kernels/splat/ewa.py, `pose_vjp` and `persp_intrinsics_vjp`). Each splat's thread writes its
    own row of these, and the rows are summed afterwards, so the split launch stays race-free
    (docs/warp.md, section 2).
    """
    mid = mode_id(mode)
    s = dilation_of(mode, dilation, antialiased)
    deg = sh_degree_of(tuple(g.sh.shape), sh_degree)
    n = g.n
    a = g.inputs()
    r = a.ints("radii", radii, (n,), minimum=0)
    gm = a.floats("grad_means2d", grad_means2d, (n, 2))
    gc = a.floats("grad_conics", grad_conics, (n, 3))
    gd = a.floats("grad_depths", grad_depths, (n,))
    gcol = a.floats("grad_colors", grad_colors, (n, 3))
    go = a.floats("grad_opacities", grad_opacities, (n,))
    view, cam = _camera_arrays(a, camera)
    out = {"means": a.zeros((n, 3)), "log_scales": a.zeros((n, 3)), "quats": a.zeros((n, 4)),
           "opacity_logits": a.zeros(n), "sh": a.zeros(tuple(g.sh.shape))}
    rows = a.zeros((max(n, 1) if want_camera else 1, 10))
    a.launch(_project_backward_kernel, n,
             [g.means, g.log_scales, g.quats, g.opacity_logits, g.sh, view, cam, camera.width, camera.height, deg,
              mid, wp.float64(s), int(bool(antialiased)), r, gm, gc, gd, gcol, go, out["means"], out["log_scales"],
              out["quats"], out["opacity_logits"], out["sh"], int(bool(want_camera)), rows], min_chunk=MIN_CHUNK)
    result = {k: a.out(v) for k, v in out.items()}
    if want_camera:
        total = rows.numpy()[:n].sum(axis=0, dtype=np.float64).astype(a.np_dtype)
        result["pose"] = a.out(wp.array(total[:6], dtype=a.scalar, device=a.device))
        result["intrinsics"] = a.out(wp.array(total[6:], dtype=a.scalar, device=a.device))
    return result
