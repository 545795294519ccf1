"""The splat projection through a lens model (opencv, fisheye, orthographic; kernels/lens.py), and
its hand-written backward.

Per splat, as kernels.splat.projection states for the pinhole, except the EWA step:

    p = W mu + t;  culled if z < near, z > far, or p outside the lens's domain (kernels.lens.lens_valid)
    m, J_m = lens_project(p)  (the normalised image point and its Jacobian dm/dp, 2x3)
    mean2d = (fx m_x + cx, fy m_y + cy),   J = diag(fx, fy) J_m,   Sigma2d = J Sigma_c J^T

The covariance is carried through the local linearisation of the full projection at the mean
(the EWA splatting approximation, Zwicker et al. 2002; gsplat's fisheye projection makes the same
choice): exact for the mean, first order for the spread, so a splat that covers a region where the
distortion's Jacobian changes is drawn as the ellipse of its centre. There is no frustum clamp of
J (the pinhole path's 3DGS / gsplat clamp is a pinhole device); `mode` still selects the radius
floor, the culling rule and the antialiasing floor. The dilation, conic, radius, clamp, colour and
opacity are the pinhole path's functions (kernels.splat.ewa, projection_kernels), unchanged.

Backward: for the cotangent g_S of Sigma2d, g_J = 2 g_S J Sigma_c and g_Sigma_c = J^T g_S J;
then g_Jm = diag(fx, fy) g_J, g_m = (fx g_u, fy g_v), and dL/dp = lens_project_vjp(g_m, g_Jm)
(which holds the second derivatives of the lens model) + (0, 0, g_depth). Intrinsics:
dL/dfx = g_u m_x + sum_j g_J[0, j] J_m[0, j], dL/dcx = g_u (y alike). The distortion coefficients
get no gradient. The pose and the Gaussian's parameters follow as for the pinhole (ewa.pose_vjp,
transform_cov_vjp, quat_scale_to_covar_vjp, view_direction_vjp).

There is no float64 wide path here: in float32 a splat whose det overflows (2D standard
deviations past about 4e9 px) is culled.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.lens import lens_project, lens_project_vjp
from kernels.splat.ewa import (aa_compensation, aa_compensation_vjp, conic_inverse, conic_inverse_vjp, dilate_cov2d,
                               dilate_cov2d_vjp, pose_vjp, quat_scale_to_covar, quat_scale_to_covar_vjp, sigmoid,
                               transform_cov, transform_cov_vjp)
from kernels.splat.projection_kernels import (_camera_frame, _load_splat, _load_view, clear_grads, clear_outputs,
                                              screen_radius, store_pose_grad, store_splat_grads, store_visible)

wp.set_module_options({"enable_backward": False})


@wp.func
def lens_ewa(model: int, lens: wp.array(dtype=Any), p: Any, cov_c: Any, fx: Any, fy: Any, cx: Any, cy: Any):
    """(u, v, Sigma2d, J_m, m_x, m_y, valid) of the camera-frame mean p and covariance Sigma_c."""
    mx, my, Jm, valid = lens_project(model, p, lens)
    zero = type(fx)(0.0)
    F = wp.matrix(fx, zero, zero, fy, shape=(2, 2), dtype=type(fx))
    J = F * Jm
    return fx * mx + cx, fy * my + cy, J * cov_c * wp.transpose(J), Jm, mx, my, valid


@wp.kernel
def _lens_project_kernel(
    means: wp.array2d(dtype=Any), log_scales: wp.array2d(dtype=Any), quats: wp.array2d(dtype=Any),
    opacity_logits: wp.array(dtype=Any), sh: wp.array3d(dtype=Any), view: wp.array2d(dtype=Any),
    cam: wp.array(dtype=Any), model: int, lens: wp.array(dtype=Any), width: int, height: int, sh_degree: int,
    mode: int, dilation: wp.float64, antialiased: int,
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
    cov_c = transform_cov(Wr, quat_scale_to_covar(q, l))
    u, v, cov2d, Jm, mx, my, valid = lens_ewa(model, lens, p, cov_c, cam[0], cam[1], cam[2], cam[3])
    if not valid:
        return
    a, b, c, det0, a1, c1 = dilate_cov2d(cov2d, dilation)
    det, qa, qb, qc = conic_inverse(a1, b, c1)
    if not (det > zero) or wp.isinf(det):
        return
    comp = means.dtype(1.0)
    if antialiased != 0:
        comp = aa_compensation(det0, det, mode)
    store_visible(means2d, conics, depths, radii, colors, opacities, i, u, v, screen_radius(a1, c1, det, mode), qa, qb,
                  qc, tz, comp, antialiased, width, height, mode, sh, sh_degree, mu, Wr, tv, opacity_logits)


@wp.kernel
def _lens_project_backward_kernel(
    means: wp.array2d(dtype=Any), log_scales: wp.array2d(dtype=Any), quats: wp.array2d(dtype=Any),
    opacity_logits: wp.array(dtype=Any), sh: wp.array3d(dtype=Any), view: wp.array2d(dtype=Any),
    cam: wp.array(dtype=Any), model: int, lens: wp.array(dtype=Any), width: int, height: int, sh_degree: int,
    mode: int, dilation: wp.float64, antialiased: int,
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
    two = means.dtype(2.0)
    clear_grads(i, d_means, d_log_scales, d_quats, d_opacity_logits, d_sh, want_camera, d_camera)
    if radii[i] == 0:
        return

    # The forward recomputed, then its VJP in reverse.
    Wr, tv = _load_view(view)
    mu, q, l = _load_splat(means, log_scales, quats, i)
    fx = cam[0]
    fy = cam[1]
    p = Wr * mu + tv
    cov_c = transform_cov(Wr, quat_scale_to_covar(q, l))
    u, v, cov2d, Jm, mx, my, valid = lens_ewa(model, lens, p, cov_c, fx, fy, cam[2], cam[3])
    a, b, c, det0, a1, c1 = dilate_cov2d(cov2d, dilation)
    det, qa, qb, qc = conic_inverse(a1, b, c1)

    sig = sigmoid(opacity_logits[i])
    g_o = g_opacities[i]
    comp = one
    g_det0 = zero
    g_det = zero
    if antialiased != 0:
        comp = aa_compensation(det0, det, mode)
        g_det0, g_det = aa_compensation_vjp(det0, det, g_o * sig, mode)

    g_a1, g_b1, g_c1 = conic_inverse_vjp(a1, b, c1, g_conics[i, 0], g_conics[i, 1], g_conics[i, 2], g_det)
    g_cov2d = dilate_cov2d_vjp(a, b, c, g_a1, g_b1, g_c1, g_det0)

    # Sigma2d = J Sigma_c J^T with J = diag(fx, fy) J_m(p); mean2d = (fx m_x + cx, fy m_y + cy).
    F = wp.matrix(fx, zero, zero, fy, shape=(2, 2), dtype=means.dtype)
    J = F * Jm
    g_cov_c = wp.transpose(J) * g_cov2d * J
    g_J = two * g_cov2d * J * cov_c
    gu = g_means2d[i, 0]
    gv = g_means2d[i, 1]
    g_p = lens_project_vjp(model, p, lens, fx * gu, fy * gv, F * g_J)
    g_p = g_p + wp.vector(zero, zero, g_depths[i], length=3, dtype=means.dtype)

    g_q, g_l = quat_scale_to_covar_vjp(q, l, transform_cov_vjp(Wr, g_cov_c))
    g_view = store_splat_grads(i, g_o, comp, sig, wp.transpose(Wr) * g_p, g_q, g_l, sh, sh_degree, mu, Wr, tv,
                               g_colors, d_sh, d_means, d_log_scales, d_quats, d_opacity_logits)
    if want_camera != 0:
        g_rho, g_phi = pose_vjp(p, g_p, cov_c, g_cov_c)
        store_pose_grad(d_camera, i, g_rho, g_phi, Wr, g_view)
        d_camera[i, 6] = gu * mx + g_J[0, 0] * Jm[0, 0] + g_J[0, 1] * Jm[0, 1] + g_J[0, 2] * Jm[0, 2]
        d_camera[i, 7] = gv * my + g_J[1, 0] * Jm[1, 0] + g_J[1, 1] * Jm[1, 1] + g_J[1, 2] * Jm[1, 2]
        d_camera[i, 8] = gu
        d_camera[i, 9] = gv

for _k in (_lens_project_kernel, _lens_project_backward_kernel):
    A.declare_float_overloads(_k)
