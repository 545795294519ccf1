"""3D Gaussian splatting: projection, tile binning, rasterisation and their adjoints.

Follows Kerbl et al., "3D Gaussian Splatting for Real-Time Radiance Field
Rendering" (SIGGRAPH 2023), with the EWA splatting of Zwicker et al. (2002) and,
optionally, the antialiasing compensation of Yu et al., "Mip-Splatting" (CVPR
2024) as gsplat's ``rasterize_mode="antialiased"`` has it.

Parameters of Gaussian i: mean mu (3), log-scales l (3), quaternion q = (w, x, y, z)
(normalised here), opacity logit a, SH coefficients f (K = (L+1)^2, 3), L <= 3.
Camera: world-to-camera [W | t] (OpenCV: x right, y down, z forward),
intrinsics fx, fy, cx, cy, image W_img x H_img; pixel (i, j) has its centre at
(i + 0.5, j + 0.5).

Projection (per Gaussian, per camera)
    R = R(q / |q|),  S = diag(exp l),  Sigma = R S S^T R^T
    p = W mu + t = (x, y, z);  culled if z < near or z > far
    mean2d = (fx x/z + cx, fy y/z + cy),  depth = z
    J = [[fx/z, 0, -fx x'/z^2], [0, fy/z, -fy y'/z^2]], where x' = z clamp(x/z, -lx-, lx+)
        with lx- = cx/fx + 0.3 W_img/fx and lx+ = (W_img - cx)/fx + 0.3 W_img/fx
        (y' likewise), as the 3DGS/gsplat code clamps the Jacobian outside the frustum
    Sigma2d = J W Sigma W^T J^T + 0.3 I      (0.3 px^2 dilation, a low-pass filter)
    conic Q = Sigma2d^-1, stored as (Q00, Q01, Q11); culled if det Sigma2d <= 0
    radius = ceil(3 sqrt(lambda_max)),  lambda_max = b + sqrt(max(0.01, b^2 - det)), b = tr/2
    culled if the square mean2d +- radius misses the image (radius 0 marks a culled splat)
    colour = max(0, sum_k f_k Y_k(d) + 1/2),  d = (mu - camera centre) / |mu - camera centre|
        (real SH basis Y_k with the constants of the 3DGS code)
    opacity o = sigmoid(a) * c, with c = 1 (classic) or, antialiased,
        c = sqrt(max(0, det(Sigma2d - 0.3 I) / det Sigma2d))   (Mip-Splatting's 2D filter)

Tile binning: 16 x 16 pixel tiles. As in 3DGS, a visible splat belongs to the
tiles its square mean2d +- radius meets; of these it is listed only in those that
also meet the bounding box of the ellipse d^T Q d <= 2 ln(255 o), outside which
alpha < 1/255 and the rasteriser skips it anyway (so the image is the same, and
splats with 255 o < 1 are never listed). Splats are ranked by depth (stable radix
sort), and each (tile, splat) pair gets the key tile * 2^b + rank; one radix sort
of these keys (wp.utils.radix_sort_pairs) lists every tile's splats front to
back, and per-tile ranges [start, end) index the sorted list.

Rasterisation (per pixel p, front to back over its tile's list)
    G_i = exp(-1/2 d^T Q_i d),  d = mean2d_i - p
    alpha_i = min(0.99, o_i G_i); a splat with alpha_i < 1/255 is skipped;
    T_1 = 1,  T_{i+1} = T_i (1 - alpha_i); the loop stops before the splat that
        would bring T below 1e-4 (that splat is not blended)
    rgb = sum_i colour_i alpha_i T_i + T_final * background
    alpha = 1 - T_final
    depth = sum_i z_i alpha_i T_i   (background depth 0: the expected z-depth is depth / alpha)

Backward, written by hand (Warp's tape is wrong through the compositing loop,
notes/warp.md). Per pixel, back to front, T_i is recovered as T_{i+1} / (1 - alpha_i)
from the stored T_final, and with S_i the colour composited behind splat i
(S <- alpha_j c_j + (1 - alpha_j) S over j > i),
    drgb/dalpha_i = T_i (c_i - S_i) - T_final background / (1 - alpha_i),
    dalpha_out/dalpha_i = T_final / (1 - alpha_i),
depth like a colour channel with background 0. Through alpha = o G (zero where
the 0.99 clamp is active) the gradients reach o, Q and mean2d. Every tile's
backward runs on one thread and writes one gradient row per (tile, splat) pair,
which a second kernel sums per splat: no float atomics are shared between
concurrent launches (notes/warp.md), so tiles run in parallel through
kernels.launch.launch_split, and the result does not depend on the thread count.
The projection backward (also by hand) carries these gradients to mu, l, q, a
and f, through the matrix chain rule above (conic inverse, compensation factor,
EWA product, Sigma = M M^T, quaternion normalisation, SH basis gradients).

Non-smooth points, where gradients are one-sided: the 1/255 skip, the 0.99
clamp, the T < 1e-4 stop, the colour clamp at 0, the Jacobian clamp, the ceil of
the radius and a change of tile set or depth order. The gradient here is the
one of the smooth piece the inputs lie on.

Entry points: `gaussian_inputs` validates the parameters, `render` / `render_backward`
run the whole chain for one camera (several views are several calls), and the stages
(`project`, `bin_tiles`, `rasterize` and their backwards) are exposed for testing.
Inputs are NumPy arrays or wp.arrays on the named device; bad input raises ValueError
naming the argument before any launch. All kernels are generic over float32 and
float64 (dtype=typing.Any).
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels.launch import launch_split

# Every backward here is written by hand; the generated adjoints would only cost compile time.
wp.set_module_options({"enable_backward": False})

TILE = 16
TILE_PIXELS = TILE * TILE
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
DILATION = 0.3
DEFAULT_NEAR = 0.01
DEFAULT_FAR = 1e10
# Columns of the per-(tile, splat) gradient rows: mean2d (2), conic (3), opacity, colour (3), depth.
_GRAD_COLS = 10

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2_0 = 1.0925484305920792
SH_C2_1 = -1.0925484305920792
SH_C2_2 = 0.31539156525252005
SH_C2_3 = -1.0925484305920792
SH_C2_4 = 0.5462742152960396
SH_C3_0 = -0.5900435899266435
SH_C3_1 = 2.890611442640554
SH_C3_2 = -0.4570457994644658
SH_C3_3 = 0.3731763325901154
SH_C3_4 = -0.4570457994644658
SH_C3_5 = 1.445305721320277
SH_C3_6 = -0.5900435899266435


# ============================================================================ SH basis


@wp.func
def sh_basis(x: Any, y: Any, z: Any):
    """The 16 real SH basis values Y_k(x, y, z) of degree <= 3 (3DGS constants and signs)."""
    xx = x * x
    yy = y * y
    zz = z * z
    return wp.vector(
        type(x)(SH_C0),
        -type(x)(SH_C1) * y, type(x)(SH_C1) * z, -type(x)(SH_C1) * x,
        type(x)(SH_C2_0) * x * y, type(x)(SH_C2_1) * y * z, type(x)(SH_C2_2) * (type(x)(2.0) * zz - xx - yy),
        type(x)(SH_C2_3) * x * z, type(x)(SH_C2_4) * (xx - yy),
        type(x)(SH_C3_0) * y * (type(x)(3.0) * xx - yy), type(x)(SH_C3_1) * x * y * z,
        type(x)(SH_C3_2) * y * (type(x)(4.0) * zz - xx - yy),
        type(x)(SH_C3_3) * z * (type(x)(2.0) * zz - type(x)(3.0) * xx - type(x)(3.0) * yy),
        type(x)(SH_C3_4) * x * (type(x)(4.0) * zz - xx - yy), type(x)(SH_C3_5) * z * (xx - yy),
        type(x)(SH_C3_6) * x * (xx - type(x)(3.0) * yy),
        length=16, dtype=type(x))


@wp.func
def sh_basis_dx(x: Any, y: Any, z: Any):
    """d Y_k / d x for the 16 basis functions of `sh_basis`."""
    xx = x * x
    yy = y * y
    zz = z * z
    zero = type(x)(0.0)
    return wp.vector(
        zero,
        zero, zero, -type(x)(SH_C1),
        type(x)(SH_C2_0) * y,
        zero,
        -type(x)(2.0) * type(x)(SH_C2_2) * x,
        type(x)(SH_C2_3) * z,
        type(x)(2.0) * type(x)(SH_C2_4) * x,
        type(x)(6.0) * type(x)(SH_C3_0) * x * y,
        type(x)(SH_C3_1) * y * z,
        -type(x)(2.0) * type(x)(SH_C3_2) * x * y,
        -type(x)(6.0) * type(x)(SH_C3_3) * x * z,
        type(x)(SH_C3_4) * (type(x)(4.0) * zz - type(x)(3.0) * xx - yy),
        type(x)(2.0) * type(x)(SH_C3_5) * x * z, type(x)(3.0) * type(x)(SH_C3_6) * (xx - yy),
        length=16, dtype=type(x))


@wp.func
def sh_basis_dy(x: Any, y: Any, z: Any):
    """d Y_k / d y for the 16 basis functions of `sh_basis`."""
    xx = x * x
    yy = y * y
    zz = z * z
    zero = type(x)(0.0)
    return wp.vector(
        zero,
        -type(x)(SH_C1), zero, zero,
        type(x)(SH_C2_0) * x,
        type(x)(SH_C2_1) * z,
        -type(x)(2.0) * type(x)(SH_C2_2) * y,
        zero,
        -type(x)(2.0) * type(x)(SH_C2_4) * y,
        type(x)(3.0) * type(x)(SH_C3_0) * (xx - yy),
        type(x)(SH_C3_1) * x * z,
        type(x)(SH_C3_2) * (type(x)(4.0) * zz - xx - type(x)(3.0) * yy),
        -type(x)(6.0) * type(x)(SH_C3_3) * y * z,
        -type(x)(2.0) * type(x)(SH_C3_4) * x * y,
        -type(x)(2.0) * type(x)(SH_C3_5) * y * z,
        -type(x)(6.0) * type(x)(SH_C3_6) * x * y,
        length=16, dtype=type(x))


@wp.func
def sh_basis_dz(x: Any, y: Any, z: Any):
    """d Y_k / d z for the 16 basis functions of `sh_basis`."""
    xx = x * x
    yy = y * y
    zz = z * z
    zero = type(x)(0.0)
    return wp.vector(
        zero,
        zero, type(x)(SH_C1), zero,
        zero, type(x)(SH_C2_1) * y, type(x)(4.0) * type(x)(SH_C2_2) * z, type(x)(SH_C2_3) * x, zero,
        zero, type(x)(SH_C3_1) * x * y, type(x)(8.0) * type(x)(SH_C3_2) * y * z,
        type(x)(SH_C3_3) * (type(x)(6.0) * zz - type(x)(3.0) * xx - type(x)(3.0) * yy),
        type(x)(8.0) * type(x)(SH_C3_4) * x * z,
        type(x)(SH_C3_5) * (xx - yy), zero,
        length=16, dtype=type(x))


# ============================================================================ shared math


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
def clamp_ratio(r: Any, lo: Any, hi: Any):
    return wp.min(wp.max(r, lo), hi)


@wp.func
def sigmoid(a: Any):
    one = type(a)(1.0)
    return one / (one + wp.exp(-a))


# ============================================================================ projection kernels


@wp.kernel
def _project_kernel(
    means: wp.array2d(dtype=Any),
    log_scales: wp.array2d(dtype=Any),
    quats: wp.array2d(dtype=Any),
    opacity_logits: wp.array(dtype=Any),
    sh: wp.array3d(dtype=Any),
    view: wp.array2d(dtype=Any),
    cam: wp.array(dtype=Any),
    width: int,
    height: int,
    sh_degree: int,
    antialiased: int,
    means2d: wp.array2d(dtype=Any),
    conics: wp.array2d(dtype=Any),
    depths: wp.array(dtype=Any),
    radii: wp.array(dtype=wp.int32),
    colors: wp.array2d(dtype=Any),
    opacities: wp.array(dtype=Any),
    offset: int,
):
    i = wp.tid() + offset
    zero = means.dtype(0.0)
    radii[i] = 0
    means2d[i, 0] = zero
    means2d[i, 1] = zero
    conics[i, 0] = zero
    conics[i, 1] = zero
    conics[i, 2] = zero
    depths[i] = zero
    colors[i, 0] = zero
    colors[i, 1] = zero
    colors[i, 2] = zero
    opacities[i] = zero

    fx = cam[0]
    fy = cam[1]
    cx = cam[2]
    cy = cam[3]
    mu = wp.vector(means[i, 0], means[i, 1], means[i, 2], length=3, dtype=means.dtype)
    Wr = wp.matrix(view[0, 0], view[0, 1], view[0, 2], view[1, 0], view[1, 1], view[1, 2],
                   view[2, 0], view[2, 1], view[2, 2], shape=(3, 3), dtype=means.dtype)
    p = Wr * mu + wp.vector(view[0, 3], view[1, 3], view[2, 3], length=3, dtype=means.dtype)
    tz = p[2]
    if tz < cam[4] or tz > cam[5]:
        return

    qw = quats[i, 0]
    qx = quats[i, 1]
    qy = quats[i, 2]
    qz = quats[i, 3]
    qn = wp.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    R = quat_to_rotation(qw / qn, qx / qn, qy / qn, qz / qn)
    s = wp.vector(wp.exp(log_scales[i, 0]), wp.exp(log_scales[i, 1]), wp.exp(log_scales[i, 2]), length=3,
                  dtype=means.dtype)
    M = wp.matrix(R[0, 0] * s[0], R[0, 1] * s[1], R[0, 2] * s[2],
                  R[1, 0] * s[0], R[1, 1] * s[1], R[1, 2] * s[2],
                  R[2, 0] * s[0], R[2, 1] * s[1], R[2, 2] * s[2], shape=(3, 3), dtype=means.dtype)
    Sc = Wr * (M * wp.transpose(M)) * wp.transpose(Wr)

    w_img = means.dtype(float(width))
    limx_pos = (w_img - cx) / fx + means.dtype(DILATION) * w_img / fx
    limx_neg = cx / fx + means.dtype(DILATION) * w_img / fx
    h_img = means.dtype(float(height))
    limy_pos = (h_img - cy) / fy + means.dtype(DILATION) * h_img / fy
    limy_neg = cy / fy + means.dtype(DILATION) * h_img / fy
    xr = clamp_ratio(p[0] / tz, -limx_neg, limx_pos)
    yr = clamp_ratio(p[1] / tz, -limy_neg, limy_pos)
    J = wp.matrix(fx / tz, zero, -fx * xr / tz, zero, fy / tz, -fy * yr / tz, shape=(2, 3), dtype=means.dtype)
    C2 = J * Sc * wp.transpose(J)
    a = C2[0, 0]
    b = C2[0, 1]
    c = C2[1, 1]
    det0 = a * c - b * b
    a1 = a + means.dtype(DILATION)
    c1 = c + means.dtype(DILATION)
    det = a1 * c1 - b * b
    if det <= zero:
        return
    half = means.dtype(0.5)
    bb = half * (a1 + c1)
    lam = bb + wp.sqrt(wp.max(means.dtype(0.01), bb * bb - det))
    r = wp.ceil(means.dtype(3.0) * wp.sqrt(lam))
    u = fx * p[0] / tz + cx
    v = fy * p[1] / tz + cy
    if u + r <= zero or u - r >= w_img or v + r <= zero or v - r >= h_img:
        return

    radii[i] = int(r)
    means2d[i, 0] = u
    means2d[i, 1] = v
    conics[i, 0] = c1 / det
    conics[i, 1] = -b / det
    conics[i, 2] = a1 / det
    depths[i] = tz

    # Camera centre: -Wr^T t.
    tv = wp.vector(view[0, 3], view[1, 3], view[2, 3], length=3, dtype=means.dtype)
    d = mu + wp.transpose(Wr) * tv
    d = d / wp.length(d)
    basis = sh_basis(d[0], d[1], d[2])
    n_coeffs = (sh_degree + 1) * (sh_degree + 1)
    for ch in range(3):
        acc = means.dtype(0.5)
        for k in range(n_coeffs):
            acc += basis[k] * sh[i, k, ch]
        colors[i, ch] = wp.max(acc, zero)

    o = sigmoid(opacity_logits[i])
    if antialiased != 0:
        o = o * wp.sqrt(wp.max(zero, det0 / det))
    opacities[i] = o


@wp.kernel
def _project_backward_kernel(
    means: wp.array2d(dtype=Any),
    log_scales: wp.array2d(dtype=Any),
    quats: wp.array2d(dtype=Any),
    opacity_logits: wp.array(dtype=Any),
    sh: wp.array3d(dtype=Any),
    view: wp.array2d(dtype=Any),
    cam: wp.array(dtype=Any),
    width: int,
    height: int,
    sh_degree: int,
    antialiased: int,
    radii: wp.array(dtype=wp.int32),
    g_means2d: wp.array2d(dtype=Any),
    g_conics: wp.array2d(dtype=Any),
    g_depths: wp.array(dtype=Any),
    g_colors: wp.array2d(dtype=Any),
    g_opacities: wp.array(dtype=Any),
    d_means: wp.array2d(dtype=Any),
    d_log_scales: wp.array2d(dtype=Any),
    d_quats: wp.array2d(dtype=Any),
    d_opacity_logits: wp.array(dtype=Any),
    d_sh: wp.array3d(dtype=Any),
    offset: int,
):
    i = wp.tid() + offset
    zero = means.dtype(0.0)
    one = means.dtype(1.0)
    two = means.dtype(2.0)
    half = means.dtype(0.5)
    n_all = sh.shape[1]
    for k in range(n_all):
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

    # ---- forward recomputation (same as _project_kernel)
    fx = cam[0]
    fy = cam[1]
    cx = cam[2]
    cy = cam[3]
    mu = wp.vector(means[i, 0], means[i, 1], means[i, 2], length=3, dtype=means.dtype)
    Wr = wp.matrix(view[0, 0], view[0, 1], view[0, 2], view[1, 0], view[1, 1], view[1, 2],
                   view[2, 0], view[2, 1], view[2, 2], shape=(3, 3), dtype=means.dtype)
    tv = wp.vector(view[0, 3], view[1, 3], view[2, 3], length=3, dtype=means.dtype)
    p = Wr * mu + tv
    tx = p[0]
    ty = p[1]
    tz = p[2]
    qw = quats[i, 0]
    qx = quats[i, 1]
    qy = quats[i, 2]
    qz = quats[i, 3]
    qn = wp.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w = qw / qn
    x = qx / qn
    y = qy / qn
    z = qz / qn
    R = quat_to_rotation(w, x, y, z)
    s = wp.vector(wp.exp(log_scales[i, 0]), wp.exp(log_scales[i, 1]), wp.exp(log_scales[i, 2]), length=3,
                  dtype=means.dtype)
    M = wp.matrix(R[0, 0] * s[0], R[0, 1] * s[1], R[0, 2] * s[2],
                  R[1, 0] * s[0], R[1, 1] * s[1], R[1, 2] * s[2],
                  R[2, 0] * s[0], R[2, 1] * s[1], R[2, 2] * s[2], shape=(3, 3), dtype=means.dtype)
    Sc = Wr * (M * wp.transpose(M)) * wp.transpose(Wr)
    w_img = means.dtype(float(width))
    h_img = means.dtype(float(height))
    limx_pos = (w_img - cx) / fx + means.dtype(DILATION) * w_img / fx
    limx_neg = cx / fx + means.dtype(DILATION) * w_img / fx
    limy_pos = (h_img - cy) / fy + means.dtype(DILATION) * h_img / fy
    limy_neg = cy / fy + means.dtype(DILATION) * h_img / fy
    xr_raw = tx / tz
    yr_raw = ty / tz
    xr = clamp_ratio(xr_raw, -limx_neg, limx_pos)
    yr = clamp_ratio(yr_raw, -limy_neg, limy_pos)
    J = wp.matrix(fx / tz, zero, -fx * xr / tz, zero, fy / tz, -fy * yr / tz, shape=(2, 3), dtype=means.dtype)
    C2 = J * Sc * wp.transpose(J)
    a = C2[0, 0]
    b = C2[0, 1]
    c = C2[1, 1]
    det0 = a * c - b * b
    a1 = a + means.dtype(DILATION)
    c1 = c + means.dtype(DILATION)
    det = a1 * c1 - b * b
    sig = sigmoid(opacity_logits[i])

    # ---- opacity: o = sigmoid(a) * comp
    g_o = g_opacities[i]
    g_det0 = zero
    g_det = zero
    comp = one
    if antialiased != 0:
        ratio = det0 / det
        if ratio > zero:
            comp = wp.sqrt(ratio)
            g_comp = g_o * sig
            # comp = sqrt(det0 / det): dcomp = comp/2 (ddet0/det0 - ddet/det)
            g_det0 = g_comp * comp / (two * det0)
            g_det = -g_comp * comp / (two * det)
        else:
            comp = zero
    d_opacity_logits[i] = g_o * comp * sig * (one - sig)

    # ---- conic (A, B, C) = (c1, -b, a1) / det
    gA = g_conics[i, 0]
    gB = g_conics[i, 1]
    gC = g_conics[i, 2]
    g_det = g_det - (gA * c1 - gB * b + gC * a1) / (det * det)
    g_a = gC / det + g_det * c1 + g_det0 * c
    g_c = gA / det + g_det * a1 + g_det0 * a
    g_b = -gB / det - two * b * g_det - two * b * g_det0
    # symmetric matrix gradient of C2 (b appears in both off-diagonal entries)
    G2 = wp.matrix(g_a, half * g_b, half * g_b, g_c, shape=(2, 2), dtype=means.dtype)
    g_Sc = wp.transpose(J) * G2 * J
    g_J = two * G2 * J * Sc

    # ---- J -> p
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

    # ---- mean2d and depth -> p
    gu = g_means2d[i, 0]
    gv = g_means2d[i, 1]
    g_tx += gu * fx / tz
    g_ty += gv * fy / tz
    g_tz += -gu * fx * tx / tz2 - gv * fy * ty / tz2 + g_depths[i]
    g_mu = wp.transpose(Wr) * wp.vector(g_tx, g_ty, g_tz, length=3, dtype=means.dtype)

    # ---- Sc = Wr Sigma Wr^T, Sigma = M M^T, M = R diag(s)
    g_Sigma = wp.transpose(Wr) * g_Sc * Wr
    g_M = two * g_Sigma * M
    for j in range(3):
        gs = g_M[0, j] * R[0, j] + g_M[1, j] * R[1, j] + g_M[2, j] * R[2, j]
        d_log_scales[i, j] = gs * s[j]
    g00 = g_M[0, 0] * s[0]
    g01 = g_M[0, 1] * s[1]
    g02 = g_M[0, 2] * s[2]
    g10 = g_M[1, 0] * s[0]
    g11 = g_M[1, 1] * s[1]
    g12 = g_M[1, 2] * s[2]
    g20 = g_M[2, 0] * s[0]
    g21 = g_M[2, 1] * s[1]
    g22 = g_M[2, 2] * s[2]
    gw = two * (-z * g01 + y * g02 + z * g10 - x * g12 - y * g20 + x * g21)
    gx = two * (y * g01 + z * g02 + y * g10 - two * x * g11 - w * g12 + z * g20 + w * g21 - two * x * g22)
    gy = two * (-two * y * g00 + x * g01 + w * g02 + x * g10 + z * g12 - w * g20 + z * g21 - two * y * g22)
    gz = two * (-two * z * g00 - w * g01 + x * g02 + w * g10 - two * z * g11 + y * g12 + x * g20 + y * g21)
    dot = w * gw + x * gx + y * gy + z * gz
    d_quats[i, 0] = (gw - w * dot) / qn
    d_quats[i, 1] = (gx - x * dot) / qn
    d_quats[i, 2] = (gy - y * dot) / qn
    d_quats[i, 3] = (gz - z * dot) / qn

    # ---- colour = max(0, sum_k f_k Y_k(d) + 1/2), d = normalize(mu - centre)
    dv = mu + wp.transpose(Wr) * tv
    dn = wp.length(dv)
    d = dv / dn
    basis = sh_basis(d[0], d[1], d[2])
    bdx = sh_basis_dx(d[0], d[1], d[2])
    bdy = sh_basis_dy(d[0], d[1], d[2])
    bdz = sh_basis_dz(d[0], d[1], d[2])
    n_coeffs = (sh_degree + 1) * (sh_degree + 1)
    g_d = wp.vector(zero, zero, zero, length=3, dtype=means.dtype)
    for ch in range(3):
        acc = means.dtype(0.5)
        for k in range(n_coeffs):
            acc += basis[k] * sh[i, k, ch]
        if acc > zero:
            gcol = g_colors[i, ch]
            for k in range(n_coeffs):
                d_sh[i, k, ch] = basis[k] * gcol
                f = sh[i, k, ch] * gcol
                g_d = g_d + wp.vector(bdx[k] * f, bdy[k] * f, bdz[k] * f, length=3, dtype=means.dtype)
    g_mu = g_mu + (g_d - d * wp.dot(d, g_d)) / dn

    d_means[i, 0] = g_mu[0]
    d_means[i, 1] = g_mu[1]
    d_means[i, 2] = g_mu[2]


# ============================================================================ tile binning kernels


@wp.kernel
def _tile_counts_kernel(
    means2d: wp.array2d(dtype=Any),
    conics: wp.array2d(dtype=Any),
    opacities: wp.array(dtype=Any),
    depths: wp.array(dtype=Any),
    radii: wp.array(dtype=wp.int32),
    tiles_x: int,
    tiles_y: int,
    rects: wp.array2d(dtype=wp.int32),
    counts: wp.array(dtype=wp.int32),
    packed: wp.array2d(dtype=Any),
    offset: int,
):
    i = wp.tid() + offset
    r = radii[i]
    counts[i] = 0
    for j in range(4):
        rects[i, j] = 0
    o = opacities[i]
    # The splat's alpha reaches 1/255 only inside the ellipse d^T Q d <= k2 (and never if 255 o < 1).
    if r <= 0 or o * means2d.dtype(255.0) < means2d.dtype(1.0):
        return
    qa = conics[i, 0]
    qb = conics[i, 1]
    qc = conics[i, 2]
    k2 = means2d.dtype(2.0) * wp.log(o * means2d.dtype(255.0))
    det = qa * qc - qb * qb
    rf = means2d.dtype(float(r))
    ext_x = wp.min(rf, wp.sqrt(k2 * qc / det))
    ext_y = wp.min(rf, wp.sqrt(k2 * qa / det))
    t = means2d.dtype(float(TILE))
    u = means2d[i, 0]
    v = means2d[i, 1]
    x0 = wp.clamp(int(wp.floor((u - ext_x) / t)), 0, tiles_x)
    x1 = wp.clamp(int(wp.ceil((u + ext_x) / t)), 0, tiles_x)
    y0 = wp.clamp(int(wp.floor((v - ext_y) / t)), 0, tiles_y)
    y1 = wp.clamp(int(wp.ceil((v + ext_y) / t)), 0, tiles_y)
    rects[i, 0] = x0
    rects[i, 1] = x1
    rects[i, 2] = y0
    rects[i, 3] = y1
    counts[i] = (x1 - x0) * (y1 - y0)
    packed[i, 0] = u
    packed[i, 1] = v
    packed[i, 2] = qa
    packed[i, 3] = qb
    packed[i, 4] = qc
    packed[i, 5] = o
    packed[i, 6] = -means2d.dtype(0.5) * k2
    packed[i, 7] = depths[i]


@wp.kernel
def _depth_keys_kernel(
    depths: wp.array(dtype=Any),
    radii: wp.array(dtype=wp.int32),
    keys: wp.array(dtype=Any),
    values: wp.array(dtype=wp.int32),
    offset: int,
):
    i = wp.tid() + offset
    # Culled splats sort last; their rank is never used.
    keys[i] = depths[i]
    if radii[i] <= 0:
        keys[i] = depths.dtype(1e30)
    values[i] = i


@wp.kernel
def _rank_kernel(order: wp.array(dtype=wp.int32), rank: wp.array(dtype=wp.int32), offset: int):
    j = wp.tid() + offset
    rank[order[j]] = j


@wp.kernel
def _emit_kernel(
    rects: wp.array2d(dtype=wp.int32),
    starts: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.int32),
    rank: wp.array(dtype=wp.int32),
    tiles_x: int,
    rank_stride: wp.int64,
    keys: wp.array(dtype=wp.int64),
    values: wp.array(dtype=wp.int32),
    entry_gid: wp.array(dtype=wp.int32),
    offset: int,
):
    i = wp.tid() + offset
    if counts[i] == 0:
        return
    e = starts[i]
    for ty in range(rects[i, 2], rects[i, 3]):
        for tx in range(rects[i, 0], rects[i, 1]):
            keys[e] = wp.int64(ty * tiles_x + tx) * rank_stride + wp.int64(rank[i])
            values[e] = e
            entry_gid[e] = i
            e += 1


@wp.kernel
def _ranges_kernel(
    keys: wp.array(dtype=wp.int64),
    values: wp.array(dtype=wp.int32),
    entry_gid: wp.array(dtype=wp.int32),
    n: int,
    rank_stride: wp.int64,
    sorted_gid: wp.array(dtype=wp.int32),
    ranges: wp.array2d(dtype=wp.int32),
    offset: int,
):
    s = wp.tid() + offset
    sorted_gid[s] = entry_gid[values[s]]
    tile = int(keys[s] / rank_stride)
    if s == 0:
        ranges[tile, 0] = s
    elif int(keys[s - 1] / rank_stride) != tile:
        ranges[tile, 0] = s
    if s == n - 1:
        ranges[tile, 1] = s + 1
    elif int(keys[s + 1] / rank_stride) != tile:
        ranges[tile, 1] = s + 1


# ============================================================================ rasterisation kernels


@wp.kernel
def _raster_forward_kernel(
    packed: wp.array2d(dtype=Any),
    colors: wp.array2d(dtype=Any),
    background: wp.array(dtype=Any),
    sorted_gid: wp.array(dtype=wp.int32),
    ranges: wp.array2d(dtype=wp.int32),
    width: int,
    height: int,
    tiles_x: int,
    out_rgb: wp.array3d(dtype=Any),
    out_alpha: wp.array2d(dtype=Any),
    out_depth: wp.array2d(dtype=Any),
    final_T: wp.array2d(dtype=Any),
    n_contrib: wp.array2d(dtype=wp.int32),
    offset: int,
):
    t = wp.tid() + offset
    tile = t / TILE_PIXELS
    local = t - tile * TILE_PIXELS
    tile_y = tile / tiles_x
    px = (tile - tile_y * tiles_x) * TILE + local % TILE
    py = tile_y * TILE + local / TILE
    if px >= width or py >= height:
        return
    zero = packed.dtype(0.0)
    one = packed.dtype(1.0)
    half = packed.dtype(0.5)
    pxf = packed.dtype(float(px)) + half
    pyf = packed.dtype(float(py)) + half
    start = ranges[tile, 0]
    end = ranges[tile, 1]
    tr = one
    cr = zero
    cg = zero
    cb = zero
    cd = zero
    last = start
    for s in range(start, end):
        g = sorted_gid[s]
        dx = packed[g, 0] - pxf
        dy = packed[g, 1] - pyf
        power = -half * (packed[g, 2] * dx * dx + packed[g, 4] * dy * dy) - packed[g, 3] * dx * dy
        # packed[g, 6] = -ln(255 o): below it alpha < 1/255, so exp() is skipped.
        if power > zero or power < packed[g, 6]:
            continue
        alpha = wp.min(packed.dtype(ALPHA_MAX), packed[g, 5] * wp.exp(power))
        if alpha < packed.dtype(ALPHA_MIN):
            continue
        next_t = tr * (one - alpha)
        if next_t < packed.dtype(T_MIN):
            break
        wgt = alpha * tr
        cr += wgt * colors[g, 0]
        cg += wgt * colors[g, 1]
        cb += wgt * colors[g, 2]
        cd += wgt * packed[g, 7]
        tr = next_t
        last = s + 1
    out_rgb[py, px, 0] = cr + tr * background[0]
    out_rgb[py, px, 1] = cg + tr * background[1]
    out_rgb[py, px, 2] = cb + tr * background[2]
    out_alpha[py, px] = one - tr
    out_depth[py, px] = cd
    final_T[py, px] = tr
    n_contrib[py, px] = last


@wp.kernel
def _raster_backward_tile_kernel(
    packed: wp.array2d(dtype=Any),
    colors: wp.array2d(dtype=Any),
    background: wp.array(dtype=Any),
    sorted_gid: wp.array(dtype=wp.int32),
    sorted_entry: wp.array(dtype=wp.int32),
    ranges: wp.array2d(dtype=wp.int32),
    width: int,
    height: int,
    tiles_x: int,
    final_T: wp.array2d(dtype=Any),
    n_contrib: wp.array2d(dtype=wp.int32),
    g_rgb: wp.array3d(dtype=Any),
    g_alpha: wp.array2d(dtype=Any),
    g_depth: wp.array2d(dtype=Any),
    entry_grads: wp.array2d(dtype=Any),
    tile_bg_grads: wp.array2d(dtype=Any),
    offset: int,
):
    # One thread per tile: it alone writes the rows of its (tile, splat) entries and its background row.
    tile = wp.tid() + offset
    zero = packed.dtype(0.0)
    one = packed.dtype(1.0)
    half = packed.dtype(0.5)
    start = ranges[tile, 0]
    tile_y = tile / tiles_x
    tile_x = tile - tile_y * tiles_x
    bg0 = background[0]
    bg1 = background[1]
    bg2 = background[2]
    gbg0 = zero
    gbg1 = zero
    gbg2 = zero
    for local in range(TILE_PIXELS):
        px = tile_x * TILE + local % TILE
        py = tile_y * TILE + local / TILE
        if px >= width or py >= height:
            continue
        pxf = packed.dtype(float(px)) + half
        pyf = packed.dtype(float(py)) + half
        tf = final_T[py, px]
        gr = g_rgb[py, px, 0]
        gg = g_rgb[py, px, 1]
        gb = g_rgb[py, px, 2]
        ga = g_alpha[py, px]
        gd = g_depth[py, px]
        gbg0 += tf * gr
        gbg1 += tf * gg
        gbg2 += tf * gb
        bg_dot = bg0 * gr + bg1 * gg + bg2 * gb
        tr = tf
        sr = zero
        sg = zero
        sb = zero
        sd = zero
        s = n_contrib[py, px] - 1
        while s >= start:
            g = sorted_gid[s]
            dx = packed[g, 0] - pxf
            dy = packed[g, 1] - pyf
            qa = packed[g, 2]
            qb = packed[g, 3]
            qc = packed[g, 4]
            power = -half * (qa * dx * dx + qc * dy * dy) - qb * dx * dy
            if power <= zero and power >= packed[g, 6]:
                gauss = wp.exp(power)
                raw = packed[g, 5] * gauss
                alpha = wp.min(packed.dtype(ALPHA_MAX), raw)
                if alpha >= packed.dtype(ALPHA_MIN):
                    tr = tr / (one - alpha)
                    wgt = alpha * tr
                    c0 = colors[g, 0]
                    c1 = colors[g, 1]
                    c2 = colors[g, 2]
                    z = packed[g, 7]
                    row = sorted_entry[s]
                    entry_grads[row, 6] += wgt * gr
                    entry_grads[row, 7] += wgt * gg
                    entry_grads[row, 8] += wgt * gb
                    entry_grads[row, 9] += wgt * gd
                    g_a = tr * ((c0 - sr) * gr + (c1 - sg) * gg + (c2 - sb) * gb + (z - sd) * gd)
                    g_a += (ga - bg_dot) * tf / (one - alpha)
                    sr = alpha * c0 + (one - alpha) * sr
                    sg = alpha * c1 + (one - alpha) * sg
                    sb = alpha * c2 + (one - alpha) * sb
                    sd = alpha * z + (one - alpha) * sd
                    if raw <= packed.dtype(ALPHA_MAX):
                        entry_grads[row, 5] += gauss * g_a
                        g_p = alpha * g_a
                        entry_grads[row, 0] += -(qa * dx + qb * dy) * g_p
                        entry_grads[row, 1] += -(qb * dx + qc * dy) * g_p
                        entry_grads[row, 2] += -half * dx * dx * g_p
                        entry_grads[row, 3] += -dx * dy * g_p
                        entry_grads[row, 4] += -half * dy * dy * g_p
            s -= 1
    tile_bg_grads[tile, 0] = gbg0
    tile_bg_grads[tile, 1] = gbg1
    tile_bg_grads[tile, 2] = gbg2


@wp.kernel
def _gather_entry_grads_kernel(
    starts: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.int32),
    entry_grads: wp.array2d(dtype=Any),
    g_means2d: wp.array2d(dtype=Any),
    g_conics: wp.array2d(dtype=Any),
    g_opacities: wp.array(dtype=Any),
    g_colors: wp.array2d(dtype=Any),
    g_depths: wp.array(dtype=Any),
    offset: int,
):
    i = wp.tid() + offset
    acc = wp.vector(length=10, dtype=entry_grads.dtype)
    e0 = starts[i]
    for e in range(e0, e0 + counts[i]):
        for j in range(_GRAD_COLS):
            acc[j] += entry_grads[e, j]
    g_means2d[i, 0] = acc[0]
    g_means2d[i, 1] = acc[1]
    g_conics[i, 0] = acc[2]
    g_conics[i, 1] = acc[3]
    g_conics[i, 2] = acc[4]
    g_opacities[i] = acc[5]
    g_colors[i, 0] = acc[6]
    g_colors[i, 1] = acc[7]
    g_colors[i, 2] = acc[8]
    g_depths[i] = acc[9]


def _declare_float_overloads(kernel: Any) -> None:
    """Instantiate a generic kernel for float32 and float64 up front.

    Warp rebuilds a module each time a launch adds an overload; declaring both
    at import makes the first launch build the module once, for both dtypes.
    """
    for dt in (wp.float32, wp.float64):
        types = {}
        for arg in kernel.adj.args:
            if wp.types.is_array(arg.type) and arg.type.dtype is Any:
                types[arg.label] = wp.array(dtype=dt, ndim=arg.type.ndim)
            elif arg.type is Any:
                types[arg.label] = dt
        wp.overload(kernel, types)


for _k in (_project_kernel, _project_backward_kernel, _tile_counts_kernel, _depth_keys_kernel,
           _raster_forward_kernel, _raster_backward_tile_kernel, _gather_entry_grads_kernel):
    _declare_float_overloads(_k)


# ============================================================================ Python entry points


@dataclass(frozen=True)
class SplatCamera:
    """A pinhole camera for the splatting kernels (OpenCV axes).

    viewmat: 4x4 world-to-camera; K: 3x3 intrinsics [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    (no skew); splats with z-depth outside [near, far] are culled.
    """

    viewmat: np.ndarray
    K: np.ndarray
    width: int
    height: int
    near: float = DEFAULT_NEAR
    far: float = DEFAULT_FAR

    def __post_init__(self) -> None:
        view = np.asarray(self.viewmat, dtype=np.float64)
        K = np.asarray(self.K, dtype=np.float64)
        if view.shape != (4, 4) or not np.all(np.isfinite(view)):
            raise ValueError(f"viewmat: expected a finite 4x4 matrix, got shape {view.shape}")
        R = view[:3, :3]
        if not np.allclose(view[3], [0, 0, 0, 1]) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) \
                or np.linalg.det(R) <= 0:
            raise ValueError("viewmat: expected a rigid world-to-camera transform [[R, t], [0, 0, 0, 1]]")
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError(f"K: expected a finite 3x3 matrix, got shape {K.shape}")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or K[0, 1] != 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise ValueError("K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0 and no skew")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise ValueError(f"{name}: expected a positive integer, got {v!r}")
        if not (0 < self.near < self.far):
            raise ValueError(f"near, far: expected 0 < near < far, got {self.near}, {self.far}")
        object.__setattr__(self, "viewmat", view)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    def params(self) -> np.ndarray:
        """(fx, fy, cx, cy, near, far)."""
        K = self.K
        return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], self.near, self.far])

    @property
    def tiles(self) -> tuple[int, int]:
        return (self.width + TILE - 1) // TILE, (self.height + TILE - 1) // TILE


@dataclass
class Projection:
    """Per-splat screen-space quantities (radius 0 = culled; its other outputs are 0)."""

    means2d: wp.array  # (N, 2) pixels
    conics: wp.array  # (N, 3) (Q00, Q01, Q11)
    depths: wp.array  # (N,)
    radii: wp.array  # (N,) int32
    colors: wp.array  # (N, 3)
    opacities: wp.array  # (N,)


@dataclass
class Tiles:
    """Depth-sorted (tile, splat) lists: entries ranges[t, 0]:ranges[t, 1] of sorted_gid belong to tile t."""

    tiles_x: int
    tiles_y: int
    n_entries: int
    starts: wp.array  # (N,) first emitted entry of each splat
    counts: wp.array  # (N,) tiles each splat covers
    sorted_gid: wp.array  # (E,) splat of each sorted entry
    sorted_entry: wp.array  # (E,) emitted index of each sorted entry
    ranges: wp.array  # (n_tiles, 2)
    packed: wp.array  # (N, 8): u, v, Q00, Q01, Q11, opacity, -ln(255 opacity), depth (rows of binned splats)


@dataclass
class Raster:
    rgb: wp.array  # (H, W, 3)
    alpha: wp.array  # (H, W)
    depth: wp.array  # (H, W) sum of alpha-weighted z-depths
    final_T: wp.array  # (H, W)
    n_contrib: wp.array  # (H, W) int32: sorted entries up to and including the last one blended


_FLOATS = (np.float32, np.float64)


def _np_dtype(x: Any) -> np.dtype:
    if isinstance(x, wp.array):
        try:
            return np.dtype(wp.dtype_to_numpy(x.dtype))
        except (TypeError, KeyError):
            return np.dtype(object)
    return np.asarray(x).dtype


def _dtype_of(name: str, x: Any) -> np.dtype:
    dt = _np_dtype(x)
    if dt not in _FLOATS:
        raise ValueError(f"{name}: expected float32 or float64, got {dt}")
    return dt


def _to_wp(name: str, x: Any, shape: tuple, dtype: np.dtype, device: wp.Device, finite: bool = True) -> wp.array:
    """Validate shape, dtype, device and finiteness of one input; return it as a wp.array."""
    if isinstance(x, wp.array):
        if x.device != device:
            raise ValueError(f"{name}: expected an array on device {device}, got {x.device}")
        shp = tuple(x.shape)
    else:
        x = np.asarray(x)
        shp = x.shape
    if shp != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got {shp}")
    got = _np_dtype(x)
    if got != dtype:
        raise ValueError(f"{name}: expected dtype {np.dtype(dtype)}, got {got}")
    arr_np = x.numpy() if isinstance(x, wp.array) else x
    if finite and arr_np.size and not np.all(np.isfinite(arr_np)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    if isinstance(x, wp.array):
        return x
    return wp.array(np.ascontiguousarray(arr_np), dtype=wp.dtype_from_numpy(dtype), device=device)


def _wp_dtype(dtype: np.dtype):
    return wp.float64 if np.dtype(dtype) == np.float64 else wp.float32


def _sh_degree(sh_shape: tuple, sh_degree: int | None) -> int:
    k = sh_shape[1]
    full = int(round(math.sqrt(k))) - 1
    if (full + 1) ** 2 != k or not 0 <= full <= 3:
        raise ValueError(f"sh: expected (N, K, 3) with K in (1, 4, 9, 16), got {sh_shape}")
    if sh_degree is None:
        return full
    if isinstance(sh_degree, bool) or not isinstance(sh_degree, (int, np.integer)) or not 0 <= sh_degree <= full:
        raise ValueError(f"sh_degree: expected an integer in [0, {full}] for K={k}, got {sh_degree!r}")
    return int(sh_degree)


@dataclass
class GaussianInputs:
    """Validated splat parameters on one device and dtype."""

    means: wp.array
    log_scales: wp.array
    quats: wp.array
    opacity_logits: wp.array
    sh: wp.array
    dtype: np.dtype
    device: wp.Device

    @property
    def n(self) -> int:
        return self.means.shape[0]


def gaussian_inputs(means: Any, log_scales: Any, quats: Any, opacity_logits: Any, sh: Any,
                    device: str | wp.Device = "cpu") -> GaussianInputs:
    """Check the parameter arrays (shapes, one float dtype, device, finite, non-zero quaternions)."""
    device = wp.get_device(device)
    dtype = _dtype_of("means", means)
    m_shape = tuple(means.shape) if isinstance(means, wp.array) else np.shape(means)
    if len(m_shape) != 2 or m_shape[1] != 3:
        raise ValueError(f"means: expected shape (N, 3), got {m_shape}")
    n = m_shape[0]
    sh_shape = tuple(sh.shape) if isinstance(sh, wp.array) else np.shape(sh)
    if len(sh_shape) != 3 or sh_shape[0] != n or sh_shape[2] != 3:
        raise ValueError(f"sh: expected shape (N={n}, K, 3), got {sh_shape}")
    _sh_degree(sh_shape, None)
    g = GaussianInputs(
        _to_wp("means", means, (n, 3), dtype, device),
        _to_wp("log_scales", log_scales, (n, 3), dtype, device),
        _to_wp("quats", quats, (n, 4), dtype, device),
        _to_wp("opacity_logits", opacity_logits, (n,), dtype, device),
        _to_wp("sh", sh, sh_shape, dtype, device),
        dtype, device)
    if n:
        qn = np.linalg.norm(g.quats.numpy().astype(np.float64), axis=1)
        if np.any(qn < 1e-12):
            raise ValueError(f"quats: quaternion {int(np.argmin(qn))} has zero norm; expected non-zero quaternions")
        big = np.abs(g.log_scales.numpy()).max()
        if big > 80:
            raise ValueError(f"log_scales: |log-scale| up to {big:.3g}; expected values in [-80, 80] "
                             "(scales are exp(log_scales), and must stay finite and non-zero)")
    return g


def _launch(kernel, dim: int, inputs: list, device: wp.Device, min_chunk: int = 1024, threads: int | None = None):
    if dim > 0:
        launch_split(kernel, dim, inputs, device=device, min_chunk=min_chunk, threads=threads)


def project(g: GaussianInputs, camera: SplatCamera, *, sh_degree: int | None = None,
            antialiased: bool = False) -> Projection:
    """Project every splat into `camera` (see the module docstring)."""
    deg = _sh_degree(tuple(g.sh.shape), sh_degree)
    n, dev, wdt = g.n, g.device, _wp_dtype(g.dtype)
    view = wp.array(camera.viewmat.astype(g.dtype), dtype=wdt, device=dev)
    cam = wp.array(camera.params().astype(g.dtype), dtype=wdt, device=dev)
    out = Projection(wp.zeros((n, 2), dtype=wdt, device=dev), wp.zeros((n, 3), dtype=wdt, device=dev),
                     wp.zeros(n, dtype=wdt, device=dev), wp.zeros(n, dtype=wp.int32, device=dev),
                     wp.zeros((n, 3), dtype=wdt, device=dev), wp.zeros(n, dtype=wdt, device=dev))
    _launch(_project_kernel, n,
            [g.means, g.log_scales, g.quats, g.opacity_logits, g.sh, view, cam, camera.width, camera.height,
             deg, int(bool(antialiased)), out.means2d, out.conics, out.depths, out.radii, out.colors,
             out.opacities], dev)
    return out


def project_backward(g: GaussianInputs, camera: SplatCamera, radii: wp.array, grad_means2d: Any, grad_conics: Any,
                     grad_depths: Any, grad_colors: Any, grad_opacities: Any, *, sh_degree: int | None = None,
                     antialiased: bool = False) -> dict[str, wp.array]:
    """Vector-Jacobian product of `project`: gradients of means, log_scales, quats, opacity_logits, sh."""
    deg = _sh_degree(tuple(g.sh.shape), sh_degree)
    n, dev, wdt, dt = g.n, g.device, _wp_dtype(g.dtype), g.dtype
    radii = _to_wp("radii", radii, (n,), np.dtype(np.int32), dev, finite=False)
    if tuple(radii.shape) != (n,) or radii.dtype != wp.int32:
        raise ValueError(f"radii: expected int32 shape ({n},)")
    gm = _to_wp("grad_means2d", grad_means2d, (n, 2), dt, dev)
    gc = _to_wp("grad_conics", grad_conics, (n, 3), dt, dev)
    gd = _to_wp("grad_depths", grad_depths, (n,), dt, dev)
    gcol = _to_wp("grad_colors", grad_colors, (n, 3), dt, dev)
    go = _to_wp("grad_opacities", grad_opacities, (n,), dt, dev)
    view = wp.array(camera.viewmat.astype(dt), dtype=wdt, device=dev)
    cam = wp.array(camera.params().astype(dt), dtype=wdt, device=dev)
    out = {"means": wp.zeros((n, 3), dtype=wdt, device=dev), "log_scales": wp.zeros((n, 3), dtype=wdt, device=dev),
           "quats": wp.zeros((n, 4), dtype=wdt, device=dev), "opacity_logits": wp.zeros(n, dtype=wdt, device=dev),
           "sh": wp.zeros(tuple(g.sh.shape), dtype=wdt, device=dev)}
    _launch(_project_backward_kernel, n,
            [g.means, g.log_scales, g.quats, g.opacity_logits, g.sh, view, cam, camera.width, camera.height, deg,
             int(bool(antialiased)), radii, gm, gc, gd, gcol, go, out["means"], out["log_scales"], out["quats"],
             out["opacity_logits"], out["sh"]], dev)
    return out


@dataclass
class Splats2D:
    """Screen-space splats, the input of the rasteriser."""

    means2d: wp.array
    conics: wp.array
    colors: wp.array
    opacities: wp.array
    depths: wp.array
    radii: wp.array
    dtype: np.dtype
    device: wp.Device

    @property
    def n(self) -> int:
        return self.means2d.shape[0]


def splats_2d(means2d: Any, conics: Any, colors: Any, opacities: Any, depths: Any, radii: Any,
              device: str | wp.Device = "cpu") -> Splats2D:
    """Validate screen-space splats (conics must be positive definite where radius > 0)."""
    device = wp.get_device(device)
    dt = _dtype_of("means2d", means2d)
    shp = tuple(means2d.shape) if isinstance(means2d, wp.array) else np.shape(means2d)
    if len(shp) != 2 or shp[1] != 2:
        raise ValueError(f"means2d: expected shape (N, 2), got {shp}")
    n = shp[0]
    r = radii.numpy() if isinstance(radii, wp.array) else np.asarray(radii)
    if r.shape != (n,) or not np.issubdtype(r.dtype, np.integer) or (n and r.min() < 0):
        raise ValueError(f"radii: expected non-negative integers of shape ({n},), got {r.dtype} {r.shape}")
    out = Splats2D(_to_wp("means2d", means2d, (n, 2), dt, device), _to_wp("conics", conics, (n, 3), dt, device),
                   _to_wp("colors", colors, (n, 3), dt, device), _to_wp("opacities", opacities, (n,), dt, device),
                   _to_wp("depths", depths, (n,), dt, device),
                   wp.array(r.astype(np.int32), dtype=wp.int32, device=device), dt, device)
    if n:
        q = out.conics.numpy()[r > 0]
        if np.any(q[:, 0] <= 0) or np.any(q[:, 0] * q[:, 2] - q[:, 1] ** 2 <= 0):
            raise ValueError("conics: expected positive definite (Q00, Q01, Q11) for every splat with radius > 0")
        o = out.opacities.numpy()
        if np.any(o < 0) or np.any(o > 1):
            raise ValueError("opacities: expected values in [0, 1]")
    return out


def bin_tiles(s: Splats2D, width: int, height: int) -> Tiles:
    """Sort (tile, splat) pairs by tile, then depth; per-tile ranges (see the module docstring).

    A splat is listed in the tiles that meet the square mean2d +- radius AND the
    bounding box of its ellipse d^T Q d <= 2 ln(255 o), outside which its alpha is
    below 1/255: the second bound only drops pixels the rasteriser would skip.
    """
    dev = s.device
    n = s.n
    tiles_x, tiles_y = (width + TILE - 1) // TILE, (height + TILE - 1) // TILE
    n_tiles = tiles_x * tiles_y
    rects = wp.zeros((n, 4), dtype=wp.int32, device=dev)
    counts = wp.zeros(n, dtype=wp.int32, device=dev)
    packed = wp.zeros((n, 8), dtype=_wp_dtype(s.dtype), device=dev)
    _launch(_tile_counts_kernel, n, [s.means2d, s.conics, s.opacities, s.depths, s.radii, tiles_x, tiles_y, rects,
                                     counts, packed], dev)
    starts = wp.zeros(n, dtype=wp.int32, device=dev)
    n_entries = 0
    if n:
        wp.utils.array_scan(counts, starts, inclusive=False)
        n_entries = int(starts[n - 1:n].numpy()[0]) + int(counts[n - 1:n].numpy()[0])
    ranges = wp.zeros((n_tiles, 2), dtype=wp.int32, device=dev)
    sorted_gid = wp.zeros(max(n_entries, 1), dtype=wp.int32, device=dev)
    sorted_entry = wp.zeros(max(n_entries, 1), dtype=wp.int32, device=dev)
    if n_entries == 0:
        return Tiles(tiles_x, tiles_y, 0, starts, counts, sorted_gid, sorted_entry, ranges, packed)
    means2d, radii, depths = s.means2d, s.radii, s.depths

    # Depth ranks by a stable sort of the depths (culled splats last).
    dkeys = wp.zeros(2 * n, dtype=means2d.dtype, device=dev)
    order = wp.zeros(2 * n, dtype=wp.int32, device=dev)
    _launch(_depth_keys_kernel, n, [depths, radii, dkeys, order], dev)
    wp.utils.radix_sort_pairs(dkeys, order, n)
    rank = wp.zeros(n, dtype=wp.int32, device=dev)
    _launch(_rank_kernel, n, [order, rank], dev)

    rank_bits = max(1, (n - 1).bit_length())
    tile_bits = max(1, (n_tiles - 1).bit_length())
    stride = 1 << rank_bits
    keys = wp.zeros(2 * n_entries, dtype=wp.int64, device=dev)
    values = wp.zeros(2 * n_entries, dtype=wp.int32, device=dev)
    entry_gid = wp.zeros(n_entries, dtype=wp.int32, device=dev)
    # The emit kernel writes the disjoint slice [starts[i], starts[i] + counts[i]) of splat i.
    _launch(_emit_kernel, n, [rects, starts, counts, rank, tiles_x, wp.int64(stride), keys, values, entry_gid], dev)
    wp.utils.radix_sort_pairs(keys, values, n_entries, 0, rank_bits + tile_bits)
    _launch(_ranges_kernel, n_entries, [keys, values, entry_gid, n_entries, wp.int64(stride), sorted_gid, ranges], dev)
    wp.copy(sorted_entry, values, count=n_entries)
    return Tiles(tiles_x, tiles_y, n_entries, starts, counts, sorted_gid, sorted_entry, ranges, packed)


def _image_grads(name_rgb: str, grad_rgb: Any, grad_alpha: Any, grad_depth: Any, h: int, w: int, dt: np.dtype,
                 dev: wp.Device) -> tuple[wp.array, wp.array, wp.array]:
    wdt = _wp_dtype(dt)
    g_rgb = _to_wp(name_rgb, grad_rgb, (h, w, 3), dt, dev)
    g_a = wp.zeros((h, w), dtype=wdt, device=dev) if grad_alpha is None else \
        _to_wp("grad_alpha", grad_alpha, (h, w), dt, dev)
    g_d = wp.zeros((h, w), dtype=wdt, device=dev) if grad_depth is None else \
        _to_wp("grad_depth", grad_depth, (h, w), dt, dev)
    return g_rgb, g_a, g_d


def _background(background: Any, dt: np.dtype, dev: wp.Device) -> wp.array:
    if background is None:
        background = np.zeros(3, dtype=dt)
    return _to_wp("background", background, (3,), dt, dev)


def rasterize(s: Splats2D, width: int, height: int, background: Any = None,
              tiles: Tiles | None = None) -> tuple[Raster, Tiles]:
    """Bin (unless `tiles` is given) and alpha-composite the splats front to back (module docstring)."""
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise ValueError(f"{name}: expected a positive integer, got {v!r}")
    bg = _background(background, s.dtype, s.device)
    dev, wdt = s.device, _wp_dtype(s.dtype)
    if tiles is None:
        tiles = bin_tiles(s, width, height)
    out = Raster(wp.zeros((height, width, 3), dtype=wdt, device=dev), wp.zeros((height, width), dtype=wdt, device=dev),
                 wp.zeros((height, width), dtype=wdt, device=dev), wp.zeros((height, width), dtype=wdt, device=dev),
                 wp.zeros((height, width), dtype=wp.int32, device=dev))
    n_tiles = tiles.tiles_x * tiles.tiles_y
    _launch(_raster_forward_kernel, n_tiles * TILE_PIXELS,
            [tiles.packed, s.colors, bg, tiles.sorted_gid, tiles.ranges, width, height,
             tiles.tiles_x, out.rgb, out.alpha, out.depth, out.final_T, out.n_contrib], dev, min_chunk=TILE_PIXELS)
    return out, tiles


def rasterize_backward(s: Splats2D, width: int, height: int, background: Any, tiles: Tiles, raster: Raster,
                       grad_rgb: Any, grad_alpha: Any = None, grad_depth: Any = None) -> dict[str, wp.array]:
    """VJP of `rasterize`: gradients of means2d, conics, colors, opacities, depths and background."""
    dev, dt, wdt, n = s.device, s.dtype, _wp_dtype(s.dtype), s.n
    bg = _background(background, dt, dev)
    g_rgb, g_a, g_d = _image_grads("grad_rgb", grad_rgb, grad_alpha, grad_depth, height, width, dt, dev)
    n_tiles = tiles.tiles_x * tiles.tiles_y
    entry_grads = wp.zeros((max(tiles.n_entries, 1), _GRAD_COLS), dtype=wdt, device=dev)
    tile_bg = wp.zeros((n_tiles, 3), dtype=wdt, device=dev)
    _launch(_raster_backward_tile_kernel, n_tiles,
            [tiles.packed, s.colors, bg, tiles.sorted_gid, tiles.sorted_entry, tiles.ranges, width, height,
             tiles.tiles_x, raster.final_T, raster.n_contrib, g_rgb, g_a, g_d, entry_grads, tile_bg], dev,
            min_chunk=1)
    out = {"means2d": wp.zeros((n, 2), dtype=wdt, device=dev), "conics": wp.zeros((n, 3), dtype=wdt, device=dev),
           "opacities": wp.zeros(n, dtype=wdt, device=dev), "colors": wp.zeros((n, 3), dtype=wdt, device=dev),
           "depths": wp.zeros(n, dtype=wdt, device=dev)}
    _launch(_gather_entry_grads_kernel, n,
            [tiles.starts, tiles.counts, entry_grads, out["means2d"], out["conics"], out["opacities"], out["colors"],
             out["depths"]], dev)
    out["background"] = wp.array(tile_bg.numpy().sum(axis=0), dtype=wdt, device=dev)
    return out


@dataclass
class Render:
    """Everything `render` computed; `render_backward` needs it."""

    rgb: wp.array  # (H, W, 3)
    alpha: wp.array  # (H, W)
    depth: wp.array  # (H, W)
    projection: Projection
    tiles: Tiles
    raster: Raster
    camera: SplatCamera
    background: wp.array
    sh_degree: int
    antialiased: bool


def render(g: GaussianInputs, camera: SplatCamera, background: Any = None, *, sh_degree: int | None = None,
           antialiased: bool = False) -> Render:
    """Project, bin, sort and rasterise: rgb (H, W, 3), alpha (H, W), depth (H, W)."""
    if not isinstance(camera, SplatCamera):
        raise ValueError(f"camera: expected a SplatCamera, got {type(camera).__name__}")
    deg = _sh_degree(tuple(g.sh.shape), sh_degree)
    bg = _background(background, g.dtype, g.device)
    proj = project(g, camera, sh_degree=deg, antialiased=antialiased)
    s2 = Splats2D(proj.means2d, proj.conics, proj.colors, proj.opacities, proj.depths, proj.radii, g.dtype, g.device)
    raster, tiles = rasterize(s2, camera.width, camera.height, bg)
    return Render(raster.rgb, raster.alpha, raster.depth, proj, tiles, raster, camera, bg, deg, bool(antialiased))


def render_backward(g: GaussianInputs, result: Render, grad_rgb: Any, grad_alpha: Any = None,
                    grad_depth: Any = None) -> dict[str, wp.array]:
    """VJP of `render`: gradients of means, log_scales, quats, opacity_logits, sh and background.

    Also returns "means2d", the screen-space (pixel) gradient of every splat's 2D mean,
    which densification uses.
    """
    cam, proj = result.camera, result.projection
    s2 = Splats2D(proj.means2d, proj.conics, proj.colors, proj.opacities, proj.depths, proj.radii, g.dtype, g.device)
    g2 = rasterize_backward(s2, cam.width, cam.height, result.background, result.tiles, result.raster, grad_rgb,
                            grad_alpha, grad_depth)
    g3 = project_backward(g, cam, proj.radii, g2["means2d"], g2["conics"], g2["depths"], g2["colors"],
                          g2["opacities"], sh_degree=result.sh_degree, antialiased=result.antialiased)
    g3["background"] = g2["background"]
    g3["means2d"] = g2["means2d"]
    return g3
