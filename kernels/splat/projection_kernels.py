"""The splat projection's Warp kernels: each 3D Gaussian to a screen-space conic, and the reverse pass.

Per splat i (kernels.splat.projection states the conventions, the modes and the radius clamp):

    Sigma = R(q/|q|) S S^T R^T,  S = diag(exp l)                      (ewa.quat_scale_to_covar)
    p = W mu + t = (x, y, z);  culled if z < near or z > far
    mean2d, Sigma2d = EWA projection of (p, W Sigma W^T)               (ewa.persp_proj)
    (a1, b, c1) = Sigma2d + s I;  culled if det <= 0                   (ewa.dilate_cov2d)
    conic Q = (a1, b, c1)^-1 stored as (Q00, Q01, Q11)                 (ewa.conic_inverse)
    radius = ceil(3 sqrt(lambda_max)), lambda_max = h + sqrt(max(f, h^2 - det)), h = (a1 + c1)/2,
        culled by the mode's rule (culled); stored as min(radius, reach) (clamp_radius)
    colour = sum_k f_k Y_k(d) + 1/2, d = (mu - camera centre) / |.|   (sh_color, sh.sh_basis)
    opacity = sigmoid(a), times the antialiasing compensation where asked  (ewa.aa_compensation)

`_project_kernel` runs one thread per splat. `_project_backward_kernel` recomputes that forward
through the same functions of kernels/splat/ewa.py (`_screen_conic`) and chains their VJPs in
reverse (`_projection_vjp`): colour and SH (sh.sh_basis_grad, view_direction_vjp), opacity and
compensation, conic inverse and dilation, EWA projection, covariance, and with the camera
gradients the pose and intrinsics. One thread per splat writes only that splat's gradients, so
both kernels run split over CPU threads. In float32 a splat whose det is not finite takes the
wide path: its geometry redone in float64 (the *_f64 loaders), the results rounded to float32.
The gradient is one-sided at the culling tests and the Jacobian's frustum clamp (ewa.persp_proj).
"""

from __future__ import annotations

from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.sh import sh_basis, sh_basis_grad
from kernels.splat.modes import RADIUS_FLOOR_OF
from kernels.splat.ewa import (aa_compensation, aa_compensation_vjp, conic_inverse, conic_inverse_vjp, dilate_cov2d,
                               dilate_cov2d_vjp, persp_intrinsics_vjp, persp_proj, persp_proj_vjp, pose_vjp,
                               quat_scale_to_covar,
                               quat_scale_to_covar_vjp, sigmoid, transform_cov, transform_cov_vjp, view_direction,
                               view_direction_vjp)
from kernels.splat.tiles import TILE

wp.set_module_options({"enable_backward": False})

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
    return u, v, det0, det, qa, qb, qc, screen_radius(a1, c1, det, mode)


@wp.func
def screen_radius(a1: Any, c1: Any, det: Any, mode: int):
    """ceil(3 sqrt(lambda_max)) of the dilated 2D covariance (a1, b, c1) with determinant det,
    lambda_max = h + sqrt(max(f, h^2 - det)), h = (a1 + c1)/2, f the mode's floor (module docstring)."""
    bb = type(det)(0.5) * (a1 + c1)
    floor = type(det)(RADIUS_FLOOR_GSPLAT)
    if mode == 0:
        floor = type(det)(RADIUS_FLOOR_3DGS)
    lam = bb + wp.sqrt(wp.max(floor, bb * bb - det))
    return wp.ceil(type(det)(3.0) * wp.sqrt(lam))


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


@wp.func
def clear_outputs(means2d: wp.array2d(dtype=Any), conics: wp.array2d(dtype=Any), depths: wp.array(dtype=Any),
                  radii: wp.array(dtype=wp.int32), colors: wp.array2d(dtype=Any), opacities: wp.array(dtype=Any),
                  i: int):
    """Splat i's outputs as for a culled splat: radius 0 and every value 0."""
    zero = means2d.dtype(0.0)
    radii[i] = 0
    _store_screen(means2d, conics, depths, i, zero, zero, zero, zero, zero, zero)
    colors[i, 0] = zero
    colors[i, 1] = zero
    colors[i, 2] = zero
    opacities[i] = zero


@wp.func
def store_colors(sh: wp.array3d(dtype=Any), i: int, sh_degree: int, mu: Any, Wr: Any, tv: Any,
                 colors: wp.array2d(dtype=Any)):
    """colour = max(0, sum_k f_k Y_k(d) + 1/2) of splat i, seen along d = (mu - camera centre) / |.|."""
    d, dn = view_direction(mu, Wr, tv)
    basis = sh_basis(d[0], d[1], d[2])
    n_coeffs = (sh_degree + 1) * (sh_degree + 1)
    for ch in range(3):
        colors[i, ch] = wp.max(sh_color(sh, i, ch, basis, n_coeffs), sh.dtype(0.0))


@wp.func
def clear_grads(i: int, d_means: wp.array2d(dtype=Any), d_log_scales: wp.array2d(dtype=Any),
                d_quats: wp.array2d(dtype=Any), d_opacity_logits: wp.array(dtype=Any), d_sh: wp.array3d(dtype=Any),
                want_camera: int, d_camera: wp.array2d(dtype=Any)):
    """Splat i's gradient rows set to 0 (what a culled splat keeps)."""
    zero = d_means.dtype(0.0)
    if want_camera != 0:
        for j in range(10):
            d_camera[i, j] = zero
    for k in range(d_sh.shape[1]):
        for ch in range(3):
            d_sh[i, k, ch] = zero
    for j in range(3):
        d_means[i, j] = zero
        d_log_scales[i, j] = zero
    for j in range(4):
        d_quats[i, j] = zero
    d_opacity_logits[i] = zero


@wp.func
def color_vjp(sh: wp.array3d(dtype=Any), i: int, sh_degree: int, mu: Any, Wr: Any, tv: Any,
              g_colors: wp.array2d(dtype=Any), d_sh: wp.array3d(dtype=Any)):
    """The VJP of `store_colors`: writes dL/df (d_sh) of splat i and returns dL/dmu through the view
    direction (sh.sh_basis_grad, view_direction_vjp); a channel clamped at 0 passes nothing."""
    zero = sh.dtype(0.0)
    d, dn = view_direction(mu, Wr, tv)
    basis = sh_basis(d[0], d[1], d[2])
    bdx, bdy, bdz = sh_basis_grad(d[0], d[1], d[2])
    n_coeffs = (sh_degree + 1) * (sh_degree + 1)
    g_d = wp.vector(zero, zero, zero, length=3, dtype=sh.dtype)
    for ch in range(3):
        acc = sh_color(sh, i, ch, basis, n_coeffs)
        if acc > zero:
            gcol = g_colors[i, ch]
            for k in range(n_coeffs):
                d_sh[i, k, ch] = basis[k] * gcol
                f = sh[i, k, ch] * gcol
                g_d = g_d + wp.vector(bdx[k] * f, bdy[k] * f, bdz[k] * f, length=3, dtype=sh.dtype)
    return view_direction_vjp(d, dn, g_d)


@wp.func
def store_pose_grad(d_camera: wp.array2d(dtype=Any), i: int, g_rho: Any, g_phi: Any, Wr: Any, g_view: Any):
    """Splat i's row of dL/d(rho, phi). The camera centre -W^T t moves by -W^T rho, so the view
    direction's share of dL/drho is W g_view."""
    g_r = g_rho + Wr * g_view
    for j in range(3):
        d_camera[i, j] = g_r[j]
        d_camera[i, 3 + j] = g_phi[j]


@wp.func
def store_vec3(out: wp.array2d(dtype=Any), i: int, x: Any):
    out[i, 0] = x[0]
    out[i, 1] = x[1]
    out[i, 2] = x[2]


@wp.func
def store_visible(means2d: wp.array2d(dtype=Any), conics: wp.array2d(dtype=Any), depths: wp.array(dtype=Any),
                  radii: wp.array(dtype=wp.int32), colors: wp.array2d(dtype=Any), opacities: wp.array(dtype=Any),
                  i: int, u: Any, v: Any, r: Any, qa: Any, qb: Any, qc: Any, tz: Any, comp: Any, antialiased: int,
                  width: int, height: int, mode: int, sh: wp.array3d(dtype=Any), sh_degree: int, mu: Any, Wr: Any,
                  tv: Any, opacity_logits: wp.array(dtype=Any)):
    """Splat i's outputs once its conic is valid: none (it stays culled) when `culled` or its clamped
    radius is 0, else the radius, mean2d, conic, depth, colour and opacity sigmoid(a) (times the
    compensation `comp` when antialiased)."""
    if culled(u, v, r, width, height, mode):
        return
    rc = clamp_radius(r, u, v, width, height)
    if rc <= type(r)(0.0):
        return
    radii[i] = int(rc)
    _store_screen(means2d, conics, depths, i, u, v, qa, qb, qc, tz)
    store_colors(sh, i, sh_degree, mu, Wr, tv, colors)
    o = sigmoid(opacity_logits[i])
    if antialiased != 0:
        o = o * comp
    opacities[i] = o


@wp.func
def store_splat_grads(i: int, g_o: Any, comp: Any, sig: Any, g_mu: Any, g_q: Any, g_l: Any, sh: wp.array3d(dtype=Any),
                      sh_degree: int, mu: Any, Wr: Any, tv: Any, g_colors: wp.array2d(dtype=Any),
                      d_sh: wp.array3d(dtype=Any), d_means: wp.array2d(dtype=Any), d_log_scales: wp.array2d(dtype=Any),
                      d_quats: wp.array2d(dtype=Any), d_opacity_logits: wp.array(dtype=Any)):
    """Splat i's gradient rows from the geometry's VJP (g_mu, g_q, g_l) and the opacity's
    (dL/da = g_o comp sig (1 - sig)), with the colour's VJP (d_sh, and its dL/dmu added to d_means);
    returns that view-direction dL/dmu (the pose gradient's share, store_pose_grad)."""
    d_opacity_logits[i] = g_o * comp * sig * (type(sig)(1.0) - sig)
    for j in range(3):
        d_log_scales[i, j] = g_l[j]
    for j in range(4):
        d_quats[i, j] = g_q[j]
    g_view = color_vjp(sh, i, sh_degree, mu, Wr, tv, g_colors, d_sh)
    store_vec3(d_means, i, g_mu + g_view)
    return g_view


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
    clear_outputs(means2d, conics, depths, radii, colors, opacities, i)

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
    store_visible(means2d, conics, depths, radii, colors, opacities, i, u, v, r, qa, qb, qc, tz, comp, antialiased,
                  width, height, mode, sh, sh_degree, mu, Wr, tv, opacity_logits)


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
    clear_grads(i, d_means, d_log_scales, d_quats, d_opacity_logits, d_sh, want_camera, d_camera)
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
    g_view = store_splat_grads(i, g_o, comp, sig, g_mu, g_q, g_l, sh, sh_degree, mu, Wr, tv, g_colors, d_sh, d_means,
                               d_log_scales, d_quats, d_opacity_logits)
    if want_camera != 0:
        store_pose_grad(d_camera, i, g_rho, g_phi, Wr, g_view)
        for j in range(4):
            d_camera[i, 6 + j] = g_intr[j]


for _k in (_project_kernel, _project_backward_kernel):
    A.declare_float_overloads(_k)
