"""Pinhole camera rays and the volume renderer's gradients with respect to the camera.

Camera (OpenCV axes, research/cameras.py): world-to-camera T_cw = [[R, t], [0, 1]], intrinsics
(fx, fy, cx, cy); pixel coordinates (u, v) are continuous (the centre of pixel (i, j) is
(i + 1/2, j + 1/2)). Ray generation, per pixel:

    c = ((u - cx)/fx, (v - cy)/fy, 1),   n = |c|,   e = c / n          (camera frame)
    o = -R^T t   (camera centre),   d = R^T e   (unit, world),   z_scale = 1/n

so that the sample o + s d has z-depth s z_scale (the renderer's depth z_k = s_k z_scale).

Pose convention (shared with kernels/splat and research/poses/se3.py): a LEFT-multiplied se(3)
perturbation of world-to-camera, T_cw <- exp(xi^) T_cw, xi = (rho, phi) translation first. Then
camera-to-world becomes T_wc exp(-xi^), and to first order at xi = 0

    o(xi) = o - R^T rho,        d(xi) = R^T (e + e x phi),

so for cotangents (g_o, g_d, g_z) of (o, d, z_scale), with g_e = R g_d (the camera frame):

    dL/drho = -R sum_pixels g_o,        dL/dphi = sum_pixels g_e x e,
    dL/dc   = (g_e - e (e . g_e))/n - g_z e / n^2,
    dL/dfx  = -dL/dc_x c_x / fx,  dL/dcx = -dL/dc_x / fx,  dL/dfy = -dL/dc_y c_y / fy,  dL/dcy = -dL/dc_y / fy.

The gradients are with respect to xi at xi = 0: an optimiser steps xi and folds it into the pose
(T_cw <- exp(xi^) T_cw), which is the standard re-linearisation of pose refinement.

Renderer (kernels.volume.render). Samples x_k = o + s_k d, z_k = s_k z_scale, colour c(x_k, d). The
sample distances s_k and interval lengths delta_k are HELD FIXED: in render_rays they come from the
ray-box intersection, near/far and the occupancy grid, all of which depend on o and d, but they
move the quadrature nodes, not the integrand (the standard choice of BARF-style pose refinement).
With the compositing backward's dL/dsigma_k, dL/dc_k (kernels.volume.composite), the weights
w_k = T_k (1 - exp(-sigma_k delta_k)), and the field's point gradient (kernels.volume.field_points):

    dL/dz_k = g_D w_k,     dL/do = sum_k dL/dx_k,
    dL/dd   = sum_k (s_k dL/dx_k + dL/ddir_k),     dL/dz_scale = sum_k s_k dL/dz_k,

summed over ray r's samples, k < n_used (samples after early termination have zero gradient).

Normalised device coordinates (NeRF's forward-facing parametrisation, Mildenhall et al. 2020,
appendix C; its `ndc_rays`). For a scene whose cameras look down -z of the world frame (LLFF after
NeRF's recentring, research.datasets.llff), a near plane z = -n and a reference pinhole of focal
lengths (fx, fy) and size (W, H), with a_x = 2 fx / W, a_y = 2 fy / H, a world ray o + s d first has
its origin moved onto the near plane and is then mapped by the projective map of the camera frustum:

    s_n = -(n + o_z) / d_z,   p = o + s_n d   (so p_z = -n),   r = d / d_z,
    o' = (-a_x p_x / p_z,  -a_y p_y / p_z,  1 + 2 n / p_z)
    d' = (-a_x (r_x - p_x / p_z),  -a_y (r_y - p_y / p_z),  -2 n / p_z)

(o' + t d', t in [0, 1], runs from the near plane to z = -infinity; t is linear in disparity 1/z).
With p_z = -n exactly, o' = (a_x p_x / n, a_y p_y / n, -1) and d' = (-a_x (r_x + p_x / n), -a_y (r_y +
p_y / n), 2): the third components are constant, so their gradient is zero, and with
p_x = o_x - (n + o_z) r_x the VJP of cotangents (g_o', g_d') is, per axis x (y alike, a_y):

    g_p = a_x (g_o'_x - g_d'_x) / n,   g_r = -a_x g_d'_x - (n + o_z) g_p,
    dL/do_x = g_p,   dL/do_z += -r_x g_p,   dL/dd_x = g_r / d_z,   dL/dd_z += -g_r r_x / d_z.

`normalize=True` returns u' = d' / |d'| instead of d' (the renderer's unit directions: sample
intervals are then NDC lengths, as NeRF's `dists * |rays_d|`), whose VJP is g_d' = (g_u - u' (u' . g_u))
/ |d'|. Every ray must point into the scene, d_z < 0 (a value check). The kernel is NeRF's formula
term by term (its p_z is computed, equal to -n up to rounding); the NumPy reference is
kernels.reference.volume.ndc_rays. Chained after `camera_rays`, `ndc_rays_backward` carries a
render's ray gradients (render_backward_rays) back to the world rays and so to the camera.

Lens models (opencv, fisheye, orthographic; kernels/lens.py): `camera_rays(..., lens=)` and its
backward hand over to kernels.volume.lens_rays, which states their rays and gradients.

Kernels: one thread per pixel or ray, each writing its own rows (launch_split); the per-pixel
pose and intrinsics terms are summed on the host. Inputs follow the array contract
(kernels._arrays): origins, dirs, z_scale come back in the kind of `pixels`; the per-ray
gradients in the kind of the RenderResult's arrays (wp.arrays); the camera gradients are NumPy.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.lens import check_lens
from kernels.rotation import checked_rigid
from kernels.volume.composite import check_backpropagatable, composite_backward
from kernels.volume.field import Field
from kernels.volume.field_points import check_point_field, field_point_backward
from kernels.volume.render import RenderResult

wp.set_module_options({"enable_backward": False})


@wp.func
def pixel_ray(pixels: wp.array2d(dtype=typing.Any), i: int, intr: wp.array(dtype=typing.Any)):
    """((u - cx)/fx, (v - cy)/fy, n): pixel i's camera-frame ray (x, y, 1) and its length n."""
    cx_ = (pixels[i, 0] - intr[2]) / intr[0]
    cy_ = (pixels[i, 1] - intr[3]) / intr[1]
    return cx_, cy_, wp.sqrt(cx_ * cx_ + cy_ * cy_ + pixels.dtype(1.0))


@wp.func
def pixel_dir(pixels: wp.array2d(dtype=typing.Any), i: int, intr: wp.array(dtype=typing.Any)):
    """pixel_ray's (x, y, n) and the unit camera-frame direction e = (x, y, 1) / n."""
    cx_, cy_, n = pixel_ray(pixels, i, intr)
    return cx_, cy_, n, cx_ / n, cy_ / n, pixels.dtype(1.0) / n


@wp.func
def rotate_row(rot: wp.array2d(dtype=typing.Any), g: wp.array2d(dtype=typing.Any), i: int):
    """R g_i: row i of g (a world-frame cotangent) in the camera frame."""
    return wp.vector(rot[0, 0] * g[i, 0] + rot[0, 1] * g[i, 1] + rot[0, 2] * g[i, 2],
                     rot[1, 0] * g[i, 0] + rot[1, 1] * g[i, 1] + rot[1, 2] * g[i, 2],
                     rot[2, 0] * g[i, 0] + rot[2, 1] * g[i, 1] + rot[2, 2] * g[i, 2], length=3, dtype=g.dtype)


@wp.func
def store_camera_row(out: wp.array2d(dtype=typing.Any), i: int, g_cam: typing.Any, g_phi: typing.Any,
                     g_mx: typing.Any, g_my: typing.Any, mx: typing.Any, my: typing.Any,
                     intr: wp.array(dtype=typing.Any)):
    """Row i of the camera gradient: (the camera-frame origin cotangent (3), dL/dphi (3),
    dL/d(fx, fy, cx, cy) from dL/dm of m = ((u - cx)/fx, (v - cy)/fy))."""
    for a in range(3):
        out[i, a] = g_cam[a]
        out[i, 3 + a] = g_phi[a]
    out[i, 6] = -g_mx * mx / intr[0]
    out[i, 7] = -g_my * my / intr[1]
    out[i, 8] = -g_mx / intr[0]
    out[i, 9] = -g_my / intr[1]


@wp.kernel
def _rays_kernel(
    pixels: wp.array2d(dtype=typing.Any), rot: wp.array2d(dtype=typing.Any), trans: wp.array(dtype=typing.Any),
    intr: wp.array(dtype=typing.Any), out_o: wp.array2d(dtype=typing.Any), out_d: wp.array2d(dtype=typing.Any),
    out_z: wp.array(dtype=typing.Any), offset: int,
):
    i = wp.tid() + offset
    one = pixels.dtype(1.0)
    cx_, cy_, n, ex, ey, ez = pixel_dir(pixels, i, intr)
    for a in range(3):
        out_o[i, a] = -(rot[0, a] * trans[0] + rot[1, a] * trans[1] + rot[2, a] * trans[2])
        out_d[i, a] = rot[0, a] * ex + rot[1, a] * ey + rot[2, a] * ez
    out_z[i] = one / n


@wp.kernel
def _rays_backward_kernel(
    pixels: wp.array2d(dtype=typing.Any), rot: wp.array2d(dtype=typing.Any), intr: wp.array(dtype=typing.Any),
    g_o: wp.array2d(dtype=typing.Any), g_d: wp.array2d(dtype=typing.Any), g_z: wp.array(dtype=typing.Any),
    out: wp.array2d(dtype=typing.Any), offset: int,
):
    # Row i of `out`: (g_o in the camera frame R g_o (3), dL/dphi (3), dL/d(fx, fy, cx, cy) (4)).
    i = wp.tid() + offset
    cx_, cy_, n, ex, ey, ez = pixel_dir(pixels, i, intr)
    e = wp.vector(ex, ey, ez, length=3, dtype=pixels.dtype)
    go = rotate_row(rot, g_o, i)
    ge = rotate_row(rot, g_d, i)
    gphi = wp.cross(ge, e)
    ee = wp.dot(e, ge)
    gcx = (ge[0] - e[0] * ee) / n - g_z[i] * e[0] / (n * n)
    gcy = (ge[1] - e[1] * ee) / n - g_z[i] * e[1] / (n * n)
    store_camera_row(out, i, go, gphi, gcx, gcy, cx_, cy_, intr)


@wp.kernel
def _depth_grad_kernel(
    factor: wp.array(dtype=typing.Any), ray_offsets: wp.array(dtype=wp.int32), n_used: wp.array(dtype=wp.int32),
    grad_depth: wp.array(dtype=typing.Any), out: wp.array(dtype=typing.Any), offset: int,
):
    # dL/dz_k = g_D w_k, w_k = T_k (1 - factor_k) rebuilt front to back as the compositing does.
    r = wp.tid() + offset
    start = ray_offsets[r]
    end = ray_offsets[r + 1]
    T = factor.dtype(1.0)
    g = grad_depth[r]
    for k in range(start, end):
        if k - start < n_used[r]:
            out[k] = g * T * (factor.dtype(1.0) - factor[k])
            T = T * factor[k]
        else:
            out[k] = factor.dtype(0.0)


@wp.kernel
def _gather_rays_kernel(
    ray_offsets: wp.array(dtype=wp.int32), t: wp.array(dtype=typing.Any), g_points: wp.array2d(dtype=typing.Any),
    g_dirs: wp.array2d(dtype=typing.Any), g_z: wp.array(dtype=typing.Any),
    out_o: wp.array2d(dtype=typing.Any), out_d: wp.array2d(dtype=typing.Any), out_zs: wp.array(dtype=typing.Any),
    offset: int,
):
    r = wp.tid() + offset
    zero = t.dtype(0.0)
    for a in range(3):
        out_o[r, a] = zero
        out_d[r, a] = zero
    zs = zero
    for k in range(ray_offsets[r], ray_offsets[r + 1]):
        s = t[k]
        for a in range(3):
            out_o[r, a] = out_o[r, a] + g_points[k, a]
            out_d[r, a] = out_d[r, a] + s * g_points[k, a] + g_dirs[k, a]
        zs += s * g_z[k]
    out_zs[r] = zs


@wp.func
def _ndc_terms(origins: wp.array2d(dtype=typing.Any), dirs: wp.array2d(dtype=typing.Any), i: int, near: typing.Any):
    """(p_x, p_y, p_z, r_x, r_y) of ray i: its origin moved onto the plane z = -near, r = d / d_z."""
    s = -(near + origins[i, 2]) / dirs[i, 2]
    return (origins[i, 0] + s * dirs[i, 0], origins[i, 1] + s * dirs[i, 1], origins[i, 2] + s * dirs[i, 2],
            dirs[i, 0] / dirs[i, 2], dirs[i, 1] / dirs[i, 2])


@wp.kernel
def _ndc_kernel(
    origins: wp.array2d(dtype=typing.Any), dirs: wp.array2d(dtype=typing.Any), near: typing.Any, ax: typing.Any,
    ay: typing.Any, normalize: int, out_o: wp.array2d(dtype=typing.Any), out_d: wp.array2d(dtype=typing.Any),
    offset: int,
):
    i = wp.tid() + offset
    one = origins.dtype(1.0)
    two = origins.dtype(2.0)
    px, py, pz, rx, ry = _ndc_terms(origins, dirs, i, near)
    out_o[i, 0] = -ax * px / pz
    out_o[i, 1] = -ay * py / pz
    out_o[i, 2] = one + two * near / pz
    dx = -ax * (rx - px / pz)
    dy = -ay * (ry - py / pz)
    dz = -two * near / pz
    if normalize != 0:
        inv = one / wp.sqrt(dx * dx + dy * dy + dz * dz)
        dx = dx * inv
        dy = dy * inv
        dz = dz * inv
    out_d[i, 0] = dx
    out_d[i, 1] = dy
    out_d[i, 2] = dz


@wp.kernel
def _ndc_backward_kernel(
    origins: wp.array2d(dtype=typing.Any), dirs: wp.array2d(dtype=typing.Any), near: typing.Any, ax: typing.Any,
    ay: typing.Any, normalize: int, g_on: wp.array2d(dtype=typing.Any), g_dn: wp.array2d(dtype=typing.Any),
    out_go: wp.array2d(dtype=typing.Any), out_gd: wp.array2d(dtype=typing.Any), offset: int,
):
    # The module docstring's VJP; p_z = -near exactly, so o'_z and d'_z are constants.
    i = wp.tid() + offset
    two = origins.dtype(2.0)
    px, py, pz, rx, ry = _ndc_terms(origins, dirs, i, near)
    gdx = g_dn[i, 0]
    gdy = g_dn[i, 1]
    gdz = g_dn[i, 2]
    if normalize != 0:  # d' -> d' / |d'|
        dx = -ax * (rx + px / near)
        dy = -ay * (ry + py / near)
        dz = two
        n = wp.sqrt(dx * dx + dy * dy + dz * dz)
        ux = dx / n
        uy = dy / n
        uz = dz / n
        ug = ux * gdx + uy * gdy + uz * gdz
        gdx = (gdx - ux * ug) / n
        gdy = (gdy - uy * ug) / n
    gpx = ax * (g_on[i, 0] - gdx) / near
    gpy = ay * (g_on[i, 1] - gdy) / near
    shift = near + origins[i, 2]
    grx = -ax * gdx - shift * gpx
    gry = -ay * gdy - shift * gpy
    dz_ = dirs[i, 2]
    out_go[i, 0] = gpx
    out_go[i, 1] = gpy
    out_go[i, 2] = -rx * gpx - ry * gpy
    out_gd[i, 0] = grx / dz_
    out_gd[i, 1] = gry / dz_
    out_gd[i, 2] = -(grx * rx + gry * ry) / dz_


# =========================================================================== camera


def check_camera(w2c: Any, intrinsics: Any) -> tuple[np.ndarray, np.ndarray]:
    """(w2c (4, 4), intrinsics (4,)) as float64 NumPy; ValueError naming the argument for a matrix that is
    not a rigid transform (kernels/rotation.py's one check: rotation part orthonormal to 1e-5, det > 0,
    last row 0 0 0 1; the rotation is returned re-orthonormalised) or intrinsics that are not
    (fx > 0, fy > 0, cx, cy)."""
    M = np.asarray(w2c.numpy() if isinstance(w2c, wp.array) else w2c, dtype=np.float64)
    if M.shape != (4, 4):
        raise ValueError(f"w2c: expected a 4x4 world-to-camera matrix, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError("w2c: contains non-finite values")
    M = checked_rigid("w2c", M)
    K = np.asarray(intrinsics.numpy() if isinstance(intrinsics, wp.array) else intrinsics, dtype=np.float64)
    if K.shape != (4,):
        raise ValueError(f"intrinsics: expected (fx, fy, cx, cy), got shape {K.shape}")
    if not np.all(np.isfinite(K)) or K[0] <= 0 or K[1] <= 0:
        raise ValueError(f"intrinsics: expected finite (fx, fy, cx, cy) with fx, fy > 0, got {K.tolist()}")
    return M, K


def _camera_arrays(a: A.Inputs, M: np.ndarray, K: np.ndarray) -> tuple[wp.array, wp.array, wp.array]:
    arr = lambda x: wp.array(np.ascontiguousarray(x, dtype=a.np_dtype), dtype=a.scalar, device=a.device)  # noqa: E731
    return arr(M[:3, :3]), arr(M[:3, 3]), arr(K)


def pixel_centers(width: int, height: int, dtype: Any = np.float64) -> np.ndarray:
    """(H*W, 2) continuous coordinates (i + 1/2, j + 1/2) of every pixel, row by row."""
    width = A.check_int("width", width, minimum=1)
    height = A.check_int("height", height, minimum=1)
    j, i = np.mgrid[0:height, 0:width]
    return np.stack([i.ravel() + 0.5, j.ravel() + 0.5], axis=1).astype(dtype)


def camera_rays(w2c: Any, intrinsics: Any, pixels: A.ArrayLike, device: str | wp.Device | None = None,
                lens: Any = None) -> tuple[A.ArrayLike, A.ArrayLike, A.ArrayLike]:
    """(origins (P, 3), unit dirs (P, 3), z_scale (P,)) of pixels (P, 2) (module docstring), in the
    kind and dtype of `pixels`. w2c is the 4x4 world-to-camera matrix, intrinsics (fx, fy, cx, cy).
    `lens`: None (the pinhole) or a kernels.lens.Lens, whose rays kernels.volume.lens_rays makes
    (pixels outside its domain get the optical axis; lens_rays also returns their mask)."""
    if check_lens("lens", lens) is not None:
        from kernels.volume.lens_rays import lens_rays  # it imports this module's helpers

        return lens_rays(w2c, intrinsics, lens, pixels, device)[:3]
    M, K = check_camera(w2c, intrinsics)
    a = A.Inputs(device, pixels)
    px = a.floats("pixels", pixels, (None, 2))
    n = px.shape[0]
    o, d, z = a.empty((n, 3)), a.empty((n, 3)), a.empty(n)
    rot, trans, intr = _camera_arrays(a, M, K)
    a.launch(_rays_kernel, n, [px, rot, trans, intr, o, d, z])
    return a.out(o), a.out(d), a.out(z)


@dataclass
class CameraGrad:
    """d L / d camera: `xi` (6,) the left se(3) perturbation of world-to-camera at 0 (rho, phi), and
    `intrinsics` (4,) = d L / d (fx, fy, cx, cy). NumPy float64 (one row per pixel with `per_pixel`)."""

    xi: np.ndarray
    intrinsics: np.ndarray


def _ray_cotangents(a: A.Inputs, n: int, grad_origins: A.ArrayLike | None, grad_dirs: A.ArrayLike | None,
                   grad_z_scale: A.ArrayLike | None) -> tuple[wp.array, wp.array, wp.array]:
    """(g_o (n, 3), g_d (n, 3), g_z (n,)) of n rays for a camera backward, each checked, or zeros where missing."""
    return (a.floats_or_zeros("grad_origins", grad_origins, (n, 3)), a.floats_or_zeros("grad_dirs", grad_dirs, (n, 3)),
            a.floats_or_zeros("grad_z_scale", grad_z_scale, (n,)))


def _camera_grad(rows: wp.array, per_pixel: bool) -> CameraGrad:
    """The CameraGrad of a camera backward kernel's rows (store_camera_row: the camera-frame origin
    cotangent, whose negative is dL/drho, then dL/dphi and the intrinsics' four), summed over the pixels
    in float64 unless `per_pixel`."""
    rows_np = rows.numpy().astype(np.float64)
    if per_pixel:
        return CameraGrad(np.concatenate([-rows_np[:, :3], rows_np[:, 3:6]], axis=1), rows_np[:, 6:10])
    total = rows_np.sum(axis=0)
    return CameraGrad(np.concatenate([-total[:3], total[3:6]]), total[6:10])


def camera_rays_backward(w2c: Any, intrinsics: Any, pixels: A.ArrayLike, grad_origins: A.ArrayLike | None = None,
                         grad_dirs: A.ArrayLike | None = None, grad_z_scale: A.ArrayLike | None = None,
                         device: str | wp.Device | None = None, per_pixel: bool = False,
                         lens: Any = None) -> CameraGrad:
    """Gradient of <g_o, origins> + <g_d, dirs> + <g_z, z_scale> of camera_rays (module docstring)
    with respect to the pose perturbation xi and the intrinsics; missing cotangents count as zero.

    `per_pixel`: return each pixel's term instead of the sum (xi (P, 6), intrinsics (P, 4)). Pixel p's
    ray depends only on p, so with the cotangent of one residual per pixel these rows are the rows of
    the residuals' Jacobian (what a Gauss-Newton step needs). `lens` as in camera_rays
    (kernels.volume.lens_rays.lens_rays_backward)."""
    if check_lens("lens", lens) is not None:
        from kernels.volume.lens_rays import lens_rays_backward  # it imports this module's helpers

        return lens_rays_backward(w2c, intrinsics, lens, pixels, grad_origins, grad_dirs, grad_z_scale, device,
                                  per_pixel)
    M, K = check_camera(w2c, intrinsics)
    a = A.Inputs(device, pixels, grad_origins, grad_dirs, grad_z_scale)
    px = a.floats("pixels", pixels, (None, 2))
    n = px.shape[0]
    go, gd, gz = _ray_cotangents(a, n, grad_origins, grad_dirs, grad_z_scale)
    rot, _, intr = _camera_arrays(a, M, K)
    rows = a.empty((n, 10))
    a.launch(_rays_backward_kernel, n, [px, rot, intr, go, gd, gz, rows])
    return _camera_grad(rows, per_pixel)


# =========================================================================== NDC


def _ndc_params(near: float, focal: Any, size: Any) -> tuple[float, float, float]:
    near = A.check_float("near", near, positive=True)
    f = np.asarray(focal, dtype=np.float64).reshape(-1)
    if f.shape not in ((1,), (2,)) or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError(f"focal: expected fx or (fx, fy), finite and > 0, got {np.asarray(focal).tolist()}")
    wh = np.asarray(size, dtype=np.float64).reshape(-1)
    if wh.shape != (2,) or not np.all(np.isfinite(wh)) or np.any(wh <= 0):
        raise ValueError(f"size: expected the reference image's (width, height) > 0, got {np.asarray(size).tolist()}")
    fx, fy = (f[0], f[0]) if f.shape == (1,) else (f[0], f[1])
    return near, 2.0 * fx / wh[0], 2.0 * fy / wh[1]


def _ndc_inputs(a: A.Inputs, origins: A.ArrayLike, dirs: A.ArrayLike) -> tuple[wp.array, wp.array]:
    o = a.floats("origins", origins, (None, 3))
    d = a.floats("dirs", dirs, (o.shape[0], 3))
    if A.values_checked() and d.shape[0]:
        h = A.host_view(d)
        dz = h[:, 2] if h is not None else d.numpy()[:, 2]
        if np.any(dz >= 0):
            raise ValueError(f"dirs: NDC needs every ray to point into the scene (d_z < 0 in the world frame, "
                             f"which looks down -z); {int(np.sum(dz >= 0))} of {dz.size} do not")
    return o, d


def ndc_rays(origins: A.ArrayLike, dirs: A.ArrayLike, near: float, focal: Any, size: Any, normalize: bool = False,
             device: str | wp.Device | None = None) -> tuple[A.ArrayLike, A.ArrayLike]:
    """(origins', dirs') (R, 3) in NDC of world rays (R, 3) (module docstring; NeRF's `ndc_rays`), in the
    kind and dtype of `origins`. `near`: the near plane z = -near; `focal`: fx or (fx, fy) and `size`:
    (width, height) of the reference pinhole; `normalize`: unit dirs' (else NeRF's d', d'_z = 2)."""
    near, ax, ay = _ndc_params(near, focal, size)
    a = A.Inputs(device, origins, dirs)
    o, d = _ndc_inputs(a, origins, dirs)
    n = o.shape[0]
    on, dn = a.empty((n, 3)), a.empty((n, 3))
    if n:
        a.launch(_ndc_kernel, n, [o, d, a.s(near), a.s(ax), a.s(ay), int(bool(normalize)), on, dn])
    return a.out(on), a.out(dn)


def ndc_rays_backward(origins: A.ArrayLike, dirs: A.ArrayLike, near: float, focal: Any, size: Any,
                      grad_origins: A.ArrayLike | None = None, grad_dirs: A.ArrayLike | None = None,
                      normalize: bool = False, device: str | wp.Device | None = None
                      ) -> tuple[A.ArrayLike, A.ArrayLike]:
    """(dL/dorigins, dL/ddirs) (R, 3) of L = <g_o', origins'> + <g_d', dirs'> of `ndc_rays` (module
    docstring), in the kind of `origins`; a missing cotangent counts as zero."""
    near, ax, ay = _ndc_params(near, focal, size)
    a = A.Inputs(device, origins, dirs, grad_origins, grad_dirs)
    o, d = _ndc_inputs(a, origins, dirs)
    n = o.shape[0]
    go, gd = a.floats_or_zeros("grad_origins", grad_origins, (n, 3)), a.floats_or_zeros("grad_dirs", grad_dirs, (n, 3))
    out_o, out_d = a.empty((n, 3)), a.empty((n, 3))
    if n:
        a.launch(_ndc_backward_kernel, n, [o, d, a.s(near), a.s(ax), a.s(ay), int(bool(normalize)), go, gd,
                                           out_o, out_d])
    return a.out(out_o), a.out(out_d)


# =========================================================================== renderer


def render_backward_rays(field: Field, result: RenderResult, grad_rgb: A.ArrayLike | None = None,
                         grad_depth: A.ArrayLike | None = None, grad_opacity: A.ArrayLike | None = None
                         ) -> tuple[wp.array, wp.array, wp.array]:
    """(dL/dorigins (R, 3), dL/ddirs (R, 3), dL/dz_scale (R,)) as wp.arrays on the field's device, for
    L = <grad_rgb, C> + <grad_depth, D> + <grad_opacity, A> of a render (kernels.volume.render_rays or
    render_samples), with the sample distances and intervals held fixed (module docstring).

    Needs a field with a point gradient (kernels.volume.field_points: spheres, grid).
    """
    check_point_field(field)
    if not isinstance(result, RenderResult):
        raise ValueError(f"result: expected the RenderResult of render_rays, got {type(result).__name__}")
    check_backpropagatable("result", result.composite)
    s, out, comp = result.samples, result.field_out, result.composite
    a = A.Inputs(field.device, s.points)
    a.scalar = field.dtype
    n_rays, n = s.n_rays, s.n_samples
    g_sigma, g_rgb = composite_backward(out.sigma, out.rgb, s.delta, s.z, s.ray_offsets, comp, grad_rgb, grad_depth,
                                        grad_opacity, result.background, field.device)
    gdep = a.floats_or_zeros("grad_depth", grad_depth, (n_rays,))
    g_z = a.empty(n)
    o, d, zs = a.empty((n_rays, 3)), a.empty((n_rays, 3)), a.empty(n_rays)
    if n_rays:
        a.launch(_depth_grad_kernel, n_rays, [comp.factor, s.ray_offsets, comp.n_used, gdep, g_z])
    g_p, g_d = field_point_backward(field, s.points, s.dirs, out, g_sigma, g_rgb)
    if n_rays:
        a.launch(_gather_rays_kernel, n_rays, [s.ray_offsets, s.t, g_p, g_d, g_z, o, d, zs])
    return o, d, zs


def render_backward_camera(field: Field, result: RenderResult, w2c: Any, intrinsics: Any, pixels: A.ArrayLike,
                           grad_rgb: A.ArrayLike | None = None, grad_depth: A.ArrayLike | None = None,
                           grad_opacity: A.ArrayLike | None = None, lens: Any = None) -> CameraGrad:
    """d L / d (xi, fx, fy, cx, cy) of a render of `camera_rays(w2c, intrinsics, pixels, lens=lens)`: the
    chain of render_backward_rays and camera_rays_backward (module docstring)."""
    go, gd, gz = render_backward_rays(field, result, grad_rgb, grad_depth, grad_opacity)
    return camera_rays_backward(w2c, intrinsics, pixels, go, gd, gz, device=field.device, lens=lens)


for _k in (_rays_kernel, _rays_backward_kernel, _depth_grad_kernel, _gather_rays_kernel, _ndc_kernel,
           _ndc_backward_kernel):
    A.declare_float_overloads(_k)
