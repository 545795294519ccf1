"""Per-splat projection math, forward and vector-Jacobian product side by side (Warp functions).

The projection kernels (kernels/splat/projection_kernels.py) call these: the forward kernel the forward
functions, the backward kernel the same forward functions where it needs intermediate values and
then the VJPs, so the forward is written once (as gsplat's `quat_scale_to_covar_vjp` and
`persp_proj_vjp` serve both directions). With q = (w, x, y, z) and log-scales l:

Covariance (`quat_scale_to_covar`)
    R = R(q / |q|),  S = diag(exp l),  M = R S,  Sigma = M M^T
    VJP for G = dL/dSigma (symmetric):  dL/dM = 2 G M,  dL/dl_j = (R^T dL/dM)_jj s_j,
    dL/dR = dL/dM S, chained through the entries of R(q) and the normalisation
    dL/dq = (g_u - u (u . g_u)) / |q| for the unit quaternion u = q / |q|.

World to camera (`transform_cov`):  Sigma_c = W Sigma W^T;  VJP dL/dSigma = W^T G W.

Perspective EWA projection of Zwicker et al., "EWA Splatting" (2002) (`persp_proj`), for the
camera-space mean p = (x, y, z), intrinsics fx, fy, cx, cy and image size W_img x H_img:
    mean2d = (fx x/z + cx, fy y/z + cy),  depth = z,  Sigma2d = J Sigma_c J^T,
    J = [[fx/z, 0, -fx x'/z^2], [0, fy/z, -fy y'/z^2]],  x' = z clamp(x/z, -lx-, lx+)  (y' likewise).
The frustum clamp of the Jacobian depends on the mode (kernels/splat/modes.py):
    "3dgs"    lx- = lx+ = 1.3 tan_fovx,  tan_fovx = W_img / (2 fx): the original 3DGS code
              (computeCov2D clamps t.x / t.z to [-limx, limx], limx = 1.3 tan_fovx, and 3DGS's
              cameras have tan_fovx = tan(FoVx / 2) = W / (2 fx)). The window is symmetric about the
              optical axis, i.e. about the principal point cx: for cx = W/2 it reaches 0.15 W past each
              image edge; for cx != W/2 it is NOT centred on the image (3DGS itself only has cx = W/2;
              its limit sees only tan_fovx, so this is what its formula gives for any cx).
    "gsplat"  lx+ = (W_img - cx)/fx + 0.3 tan_fovx,  lx- = cx/fx + 0.3 tan_fovx (gsplat's persp_proj):
              0.15 W past each image edge whatever cx; equal to "3dgs" when cx = W/2.
VJP for G2 = dL/dSigma2d: dL/dSigma_c = J^T G2 J, dL/dJ = 2 G2 J Sigma_c, then through J and mean2d to
p; where the clamp is active, x' does not move with x (the gradient of the clamped piece).

Intrinsics (`persp_intrinsics_vjp`), from the same G2 and dL/dmean2d = (gu, gv):
    dL/dfx = gu x/z + dL/dJ00 / z + dL/dJ02 dJ02/dfx,   dL/dcx = gu + dL/dJ02 dJ02/dcx,
    J02 = -fx x'/z^2 = -(fx r)/z with r = clamp(x/z): unclamped dJ02/dfx = -r/z, dJ02/dcx = 0;
    clamped, fx r is fx times the limit: "3dgs" +-0.65 W (neither fx nor cx), "gsplat"
    W - cx + 0.15 W or -(cx + 0.15 W), so dJ02/dfx = 0 and dJ02/dcx = 1/z in "gsplat", 0 in "3dgs"
    (fy, cy, J11, J12 likewise).

Camera pose (`pose_vjp`), for a left perturbation [W | t] <- exp(xi^) [W | t], xi = (rho, phi):
    to first order p <- p + phi x p + rho and Sigma_c <- Sigma_c + [phi]x Sigma_c + Sigma_c [phi]x^T, so
    dL/drho = dL/dp,  dL/dphi = p x dL/dp + (M21 - M12, M02 - M20, M10 - M01),
    M = (G + G^T) Sigma_c for G = dL/dSigma_c (from dL = <G, A Sigma_c + Sigma_c A^T> = <M, A>, A = [phi]x);
    the camera centre -W^T t moves by -W^T rho (and not with phi), which the caller adds for the
    view direction (kernels/splat/projection.py).

Dilation (`dilate_cov2d`): (a1, b, c1) = (a + s, b, c + s) and det0 = a c - b^2 for
Sigma2d = [[a, b], [b, c]] and the low-pass dilation s >= 0 in px^2 (0.3 in both modes, DILATION;
the entry points' `dilation`, kernels/splat/modes.py), a constant without a gradient;
VJP dL/da = dL/da1 + dL/ddet0 c, dL/dc = dL/dc1 + dL/ddet0 a, dL/db = dL/db' - 2 b dL/ddet0, split half
and half over Sigma2d's two off-diagonal entries.

Conic (`conic_inverse`): the dilated covariance (a1, b, c1) = Sigma2d + s I has
    det = a1 c1 - b^2,  Q = (c1, -b, a1) / det,
    VJP for dL/dQ = (gA, gB, gC) and an extra dL/ddet from other users of det:
    g_det' = g_det - (gA c1 - gB b + gC a1) / det^2,
    dL/da1 = gC / det + g_det' c1,  dL/dc1 = gA / det + g_det' a1,  dL/db = -gB / det - 2 b g_det'.

Antialiasing compensation of Yu et al., "Mip-Splatting" (2024) (`aa_compensation`):
    c = sqrt(max(f, det0 / det)) with det0 = a c - b^2 undilated and the floor f of the mode:
    f = 0 in "gsplat" (rasterize_mode="antialiased"), f = 2.5e-5 in "3dgs" (the 3DGS code's
    `antialiasing` option, "max for numerical stability");
    VJP dL/ddet0 = dL/dc c / (2 det0), dL/ddet = -dL/dc c / (2 det) (zero where det0 / det <= f).

View direction (`view_direction`): d = v / |v|, v = mu - camera centre; VJP (g - d (d . g)) / |v|.

All functions are generic over float32 and float64 (the type of their scalar arguments).
"""

from __future__ import annotations

from typing import Any

import warp as wp

# The low-pass dilation s (px^2) of both reference codes: the entry points' default (kernels/splat/modes.py).
DILATION = 0.3
# The floor of the antialiasing compensation's ratio in the 3DGS code (module docstring).
AA_FLOOR_3DGS = 2.5e-5


@wp.func
def sigmoid(a: Any):
    one = type(a)(1.0)
    return one / (one + wp.exp(-a))


@wp.func
def clamp_ratio(r: Any, lo: Any, hi: Any):
    return wp.min(wp.max(r, lo), hi)


@wp.func
def quat_to_rotation(w: Any, x: Any, y: Any, z: Any):
    """Rotation matrix of a UNIT quaternion (w, x, y, z)."""
    one = type(w)(1.0)
    two = type(w)(2.0)
    return wp.matrix(
        one - two * (y * y + z * z), two * (x * y - w * z), two * (x * z + w * y),
        two * (x * y + w * z), one - two * (x * x + z * z), two * (y * z - w * x),
        two * (x * z - w * y), two * (y * z + w * x), one - two * (x * x + y * y),
        shape=(3, 3), dtype=type(w))


@wp.func
def rotation_scale(q: Any, log_scale: Any):
    """(|q|, R(q / |q|), s = exp(log_scale), M = R diag(s)) of one splat."""
    qn = wp.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    R = quat_to_rotation(q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn)
    s = wp.vector(wp.exp(log_scale[0]), wp.exp(log_scale[1]), wp.exp(log_scale[2]), length=3, dtype=type(qn))
    M = wp.matrix(R[0, 0] * s[0], R[0, 1] * s[1], R[0, 2] * s[2],
                  R[1, 0] * s[0], R[1, 1] * s[1], R[1, 2] * s[2],
                  R[2, 0] * s[0], R[2, 1] * s[1], R[2, 2] * s[2], shape=(3, 3), dtype=type(qn))
    return qn, R, s, M


@wp.func
def quat_scale_to_covar(q: Any, log_scale: Any):
    """Sigma = M M^T, M = R(q / |q|) diag(exp log_scale)."""
    qn, R, s, M = rotation_scale(q, log_scale)
    return M * wp.transpose(M)


@wp.func
def rotation_vjp(q: Any, g_R: Any):
    """dL/dq of R(q / |q|) for dL/dR = g_R (module docstring: through R's entries and the normalisation)."""
    qn = wp.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    two = type(qn)(2.0)
    w = q[0] / qn
    x = q[1] / qn
    y = q[2] / qn
    z = q[3] / qn
    g00 = g_R[0, 0]
    g01 = g_R[0, 1]
    g02 = g_R[0, 2]
    g10 = g_R[1, 0]
    g11 = g_R[1, 1]
    g12 = g_R[1, 2]
    g20 = g_R[2, 0]
    g21 = g_R[2, 1]
    g22 = g_R[2, 2]
    gw = two * (-z * g01 + y * g02 + z * g10 - x * g12 - y * g20 + x * g21)
    gx = two * (y * g01 + z * g02 + y * g10 - two * x * g11 - w * g12 + z * g20 + w * g21 - two * x * g22)
    gy = two * (-two * y * g00 + x * g01 + w * g02 + x * g10 + z * g12 - w * g20 + z * g21 - two * y * g22)
    gz = two * (-two * z * g00 - w * g01 + x * g02 + w * g10 - two * z * g11 + y * g12 + x * g20 + y * g21)
    dot = w * gw + x * gx + y * gy + z * gz
    return wp.vector((gw - w * dot) / qn, (gx - x * dot) / qn, (gy - y * dot) / qn, (gz - z * dot) / qn,
                     length=4, dtype=type(qn))


@wp.func
def quat_scale_to_covar_vjp(q: Any, log_scale: Any, g_sigma: Any):
    """(dL/dq, dL/dlog_scale) for dL/dSigma = g_sigma (module docstring)."""
    qn, R, s, M = rotation_scale(q, log_scale)
    g_M = type(qn)(2.0) * g_sigma * M
    g_l = wp.vector(length=3, dtype=type(qn))
    for j in range(3):
        gs = g_M[0, j] * R[0, j] + g_M[1, j] * R[1, j] + g_M[2, j] * R[2, j]
        g_l[j] = gs * s[j]
    g_R = wp.matrix(g_M[0, 0] * s[0], g_M[0, 1] * s[1], g_M[0, 2] * s[2],
                    g_M[1, 0] * s[0], g_M[1, 1] * s[1], g_M[1, 2] * s[2],
                    g_M[2, 0] * s[0], g_M[2, 1] * s[1], g_M[2, 2] * s[2], shape=(3, 3), dtype=type(qn))
    return rotation_vjp(q, g_R), g_l


@wp.func
def transform_cov(Wr: Any, sigma: Any):
    """W Sigma W^T."""
    return Wr * sigma * wp.transpose(Wr)


@wp.func
def transform_cov_vjp(Wr: Any, g_cov: Any):
    """dL/dSigma = W^T G W for G = dL/d(W Sigma W^T)."""
    return wp.transpose(Wr) * g_cov * Wr


@wp.func
def frustum_ratio(r: Any, focal: Any, centre: Any, size: int, mode: int):
    """clamp(r, -lim-, lim+) for the ratio r = x/z along one image axis of `size` pixels, with the
    limits of `mode` (0 = "3dgs", 1 = "gsplat"; module docstring)."""
    tan_fov = type(r)(0.5) * type(r)(float(size)) / focal
    if mode == 0:
        lim = type(r)(1.3) * tan_fov
        return clamp_ratio(r, -lim, lim)
    lim_pos = (type(r)(float(size)) - centre) / focal + type(r)(0.3) * tan_fov
    lim_neg = centre / focal + type(r)(0.3) * tan_fov
    return clamp_ratio(r, -lim_neg, lim_pos)


@wp.func
def persp_jacobian(p: Any, fx: Any, fy: Any, cx: Any, cy: Any, width: int, height: int, mode: int):
    """The EWA Jacobian J at the camera-space mean p, with the frustum clamp of `mode`."""
    tz = p[2]
    zero = type(tz)(0.0)
    xr = frustum_ratio(p[0] / tz, fx, cx, width, mode)
    yr = frustum_ratio(p[1] / tz, fy, cy, height, mode)
    return wp.matrix(fx / tz, zero, -fx * xr / tz, zero, fy / tz, -fy * yr / tz, shape=(2, 3), dtype=type(tz))


@wp.func
def persp_proj(p: Any, cov_c: Any, fx: Any, fy: Any, cx: Any, cy: Any, width: int, height: int, mode: int):
    """(u, v, Sigma2d): the pixel position of the camera-space mean p and its 2D covariance J Sigma_c J^T."""
    tz = p[2]
    J = persp_jacobian(p, fx, fy, cx, cy, width, height, mode)
    cov2d = J * cov_c * wp.transpose(J)
    u = fx * p[0] / tz + cx
    v = fy * p[1] / tz + cy
    return u, v, cov2d


@wp.func
def persp_proj_vjp(p: Any, cov_c: Any, fx: Any, fy: Any, cx: Any, cy: Any, width: int, height: int, mode: int,
                   g_cov2d: Any, gu: Any, gv: Any, g_depth: Any):
    """(dL/dp, dL/dSigma_c) for the cotangents of (Sigma2d, u, v) and of the depth z (module docstring)."""
    tx = p[0]
    ty = p[1]
    tz = p[2]
    zero = type(tz)(0.0)
    two = type(tz)(2.0)
    xr_raw = tx / tz
    yr_raw = ty / tz
    xr = frustum_ratio(xr_raw, fx, cx, width, mode)
    yr = frustum_ratio(yr_raw, fy, cy, height, mode)
    J = persp_jacobian(p, fx, fy, cx, cy, width, height, mode)
    g_cov_c = wp.transpose(J) * g_cov2d * J
    g_J = two * g_cov2d * J * cov_c
    tz2 = tz * tz
    g_tx = zero
    g_ty = zero
    g_tz = -fx / tz2 * g_J[0, 0] - fy / tz2 * g_J[1, 1]
    if xr_raw == xr:
        g_tx += -fx / tz2 * g_J[0, 2]
        g_tz += two * fx * tx / (tz2 * tz) * g_J[0, 2]
    else:
        g_tz += fx * xr / tz2 * g_J[0, 2]
    if yr_raw == yr:
        g_ty += -fy / tz2 * g_J[1, 2]
        g_tz += two * fy * ty / (tz2 * tz) * g_J[1, 2]
    else:
        g_tz += fy * yr / tz2 * g_J[1, 2]
    g_tx += gu * fx / tz
    g_ty += gv * fy / tz
    g_tz += -gu * fx * tx / tz2 - gv * fy * ty / tz2 + g_depth
    return wp.vector(g_tx, g_ty, g_tz, length=3, dtype=type(tz)), g_cov_c


@wp.func
def persp_intrinsics_vjp(p: Any, cov_c: Any, fx: Any, fy: Any, cx: Any, cy: Any, width: int, height: int, mode: int,
                         g_cov2d: Any, gu: Any, gv: Any):
    """(dL/dfx, dL/dfy, dL/dcx, dL/dcy) of `persp_proj` for the cotangents of (Sigma2d, u, v) (module docstring)."""
    tz = p[2]
    two = type(tz)(2.0)
    J = persp_jacobian(p, fx, fy, cx, cy, width, height, mode)
    g_J = two * g_cov2d * J * cov_c
    xr_raw = p[0] / tz
    yr_raw = p[1] / tz
    xr = frustum_ratio(xr_raw, fx, cx, width, mode)
    yr = frustum_ratio(yr_raw, fy, cy, height, mode)
    g_fx = gu * xr_raw + g_J[0, 0] / tz
    g_fy = gv * yr_raw + g_J[1, 1] / tz
    g_cx = gu
    g_cy = gv
    if xr_raw == xr:
        g_fx += -xr / tz * g_J[0, 2]
    elif mode == 1:
        g_cx += g_J[0, 2] / tz
    if yr_raw == yr:
        g_fy += -yr / tz * g_J[1, 2]
    elif mode == 1:
        g_cy += g_J[1, 2] / tz
    return wp.vector(g_fx, g_fy, g_cx, g_cy, length=4, dtype=type(tz))


@wp.func
def pose_vjp(p: Any, g_p: Any, cov_c: Any, g_cov_c: Any):
    """(dL/drho, dL/dphi) of one splat's camera-frame mean and covariance for the left se(3)
    perturbation of world-to-camera (module docstring); the view direction's share is the caller's."""
    M = (g_cov_c + wp.transpose(g_cov_c)) * cov_c
    phi = wp.cross(p, g_p) + wp.vector(M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1], length=3,
                                       dtype=type(p[0]))
    return g_p, phi


@wp.func
def dilate_cov2d(cov2d: Any, dilation: wp.float64):
    """(a, b, c, det0, a1, c1): Sigma2d = [[a, b], [b, c]], its determinant det0 = a c - b^2, and the
    diagonal a1 = a + s, c1 = c + s of the dilated Sigma2d + s I, s = `dilation` (px^2)."""
    a = cov2d[0, 0]
    b = cov2d[0, 1]
    c = cov2d[1, 1]
    det0 = a * c - b * b
    s = type(a)(dilation)
    return a, b, c, det0, a + s, c + s


@wp.func
def dilate_cov2d_vjp(a: Any, b: Any, c: Any, g_a1: Any, g_b: Any, g_c1: Any, g_det0: Any):
    """dL/dSigma2d (symmetric, b in both off-diagonal entries) from the cotangents of a1, b, c1 and det0."""
    two = type(a)(2.0)
    half = type(a)(0.5)
    ga = g_a1 + g_det0 * c
    gc = g_c1 + g_det0 * a
    gb = g_b - two * b * g_det0
    return wp.matrix(ga, half * gb, half * gb, gc, shape=(2, 2), dtype=type(a))


@wp.func
def conic_inverse(a1: Any, b: Any, c1: Any):
    """(det, Q00, Q01, Q11) of the dilated 2D covariance [[a1, b], [b, c1]]."""
    det = a1 * c1 - b * b
    return det, c1 / det, -b / det, a1 / det


@wp.func
def conic_inverse_vjp(a1: Any, b: Any, c1: Any, gA: Any, gB: Any, gC: Any, g_det: Any):
    """(dL/da1, dL/db, dL/dc1) for dL/dQ = (gA, gB, gC) and an extra dL/ddet = g_det."""
    two = type(a1)(2.0)
    det = a1 * c1 - b * b
    g_det = g_det - (gA * c1 - gB * b + gC * a1) / (det * det)
    return gC / det + g_det * c1, -gB / det - two * b * g_det, gA / det + g_det * a1


@wp.func
def aa_floor(mode: int, det: Any):
    """The floor f of the compensation's ratio: 2.5e-5 in "3dgs" (mode 0), 0 in "gsplat"."""
    if mode == 0:
        return type(det)(AA_FLOOR_3DGS)
    return type(det)(0.0)


@wp.func
def aa_compensation(det0: Any, det: Any, mode: int):
    """Mip-Splatting's opacity factor sqrt(max(f, det0 / det)), f = aa_floor(mode)."""
    return wp.sqrt(wp.max(aa_floor(mode, det), det0 / det))


@wp.func
def aa_compensation_vjp(det0: Any, det: Any, g_comp: Any, mode: int):
    """(dL/ddet0, dL/ddet) for dL/dc = g_comp; zero where det0 / det <= f (the floor is active)."""
    zero = type(det)(0.0)
    two = type(det)(2.0)
    ratio = det0 / det
    if ratio > aa_floor(mode, det):
        comp = wp.sqrt(ratio)
        return g_comp * comp / (two * det0), -g_comp * comp / (two * det)
    return zero, zero


@wp.func
def view_direction(mu: Any, Wr: Any, t: Any):
    """(d, |v|): the unit direction d = v / |v| from the camera centre -W^T t to the mean mu."""
    v = mu + wp.transpose(Wr) * t
    n = wp.length(v)
    return v / n, n


@wp.func
def view_direction_vjp(d: Any, n: Any, g_d: Any):
    """dL/dmu = (g - d (d . g)) / |v| for dL/dd = g."""
    return (g_d - d * wp.dot(d, g_d)) / n
