"""Camera rays through a lens model (opencv, fisheye, orthographic; kernels/lens.py), and their
gradient with respect to the camera pose and intrinsics.

Per pixel (u, v), with world-to-camera T_cw = [[R, t], [0, 1]] and intrinsics (fx, fy, cx, cy):

    m = ((u - cx)/fx, (v - cy)/fy)                  the normalised image point
    (q, e, valid) = lens_unproject(m)               camera-frame origin and unit direction
    o = R^T (q - t),   d = R^T e,   z_scale = e_z

(central models: q = 0, so o is the camera centre; orthographic: q = (m_x, m_y, 0), e = (0, 0, 1)).
The sample o + s d has z-depth s z_scale, as for kernels.volume.rays' pinhole rays. A pixel outside
the model's domain (kernels/lens.py: Newton not converged, past the polynomial's turning point,
fisheye theta >= pi/2) gets valid = 0, o = the camera centre, d = the optical axis, z_scale 1,
and a zero gradient.

Gradients (the pose convention of kernels.volume.rays: T_cw <- exp(xi^) T_cw, xi = (rho, phi),
translation first). A camera-frame point q maps to the world point R^T (q - rho + q x phi - t) to
first order, so for the cotangents (g_o, g_d, g_z), with g_q = R g_o and g_e = R g_d,

    dL/drho = -R sum g_o,     dL/dphi = sum (g_e x e + g_q x q),
    (dL/dm_x, dL/dm_y) = lens_unproject_vjp(g_q, g_e + g_z (0, 0, 1)),
    dL/dfx = -dL/dm_x m_x / fx,  dL/dcx = -dL/dm_x / fx,  (y alike).

Kernels: one thread per pixel, each writing its own rows (launch_split); the per-pixel rows are
summed on the host. The pinhole keeps its own kernels (kernels.volume.rays), which are unchanged.
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.lens import Lens, check_lens, lens_unproject, lens_unproject_vjp
from kernels.volume.rays import (_camera_arrays, _camera_grad, _ray_cotangents, check_camera, rotate_row,
                                 store_camera_row)

wp.set_module_options({"enable_backward": False})


@wp.func
def _pixel_point(pixels: wp.array2d(dtype=typing.Any), i: int, intr: wp.array(dtype=typing.Any)):
    """m = ((u - cx)/fx, (v - cy)/fy) of pixel i."""
    return (pixels[i, 0] - intr[2]) / intr[0], (pixels[i, 1] - intr[3]) / intr[1]


@wp.kernel
def _lens_rays_kernel(
    pixels: wp.array2d(dtype=typing.Any), rot: wp.array2d(dtype=typing.Any), trans: wp.array(dtype=typing.Any),
    intr: wp.array(dtype=typing.Any), model: int, lens: wp.array(dtype=typing.Any),
    out_o: wp.array2d(dtype=typing.Any), out_d: wp.array2d(dtype=typing.Any), out_z: wp.array(dtype=typing.Any),
    out_valid: wp.array(dtype=wp.uint8), offset: int,
):
    i = wp.tid() + offset
    mx, my = _pixel_point(pixels, i, intr)
    q, e, valid = lens_unproject(model, mx, my, lens)
    zero = pixels.dtype(0.0)
    if not valid:
        q = wp.vector(zero, zero, zero, length=3, dtype=pixels.dtype)
    for a in range(3):
        out_o[i, a] = (rot[0, a] * (q[0] - trans[0]) + rot[1, a] * (q[1] - trans[1])
                       + rot[2, a] * (q[2] - trans[2]))
        out_d[i, a] = rot[0, a] * e[0] + rot[1, a] * e[1] + rot[2, a] * e[2]
    out_z[i] = e[2]
    out_valid[i] = wp.uint8(0)
    if valid:
        out_valid[i] = wp.uint8(1)


@wp.kernel
def _lens_rays_backward_kernel(
    pixels: wp.array2d(dtype=typing.Any), rot: wp.array2d(dtype=typing.Any), intr: wp.array(dtype=typing.Any),
    model: int, lens: wp.array(dtype=typing.Any), g_o: wp.array2d(dtype=typing.Any),
    g_d: wp.array2d(dtype=typing.Any), g_z: wp.array(dtype=typing.Any), out: wp.array2d(dtype=typing.Any),
    offset: int,
):
    # Row i of `out`: (g_q = R g_o (3), dL/dphi (3), dL/d(fx, fy, cx, cy) (4)); zeros where invalid.
    i = wp.tid() + offset
    zero = pixels.dtype(0.0)
    for a in range(10):
        out[i, a] = zero
    mx, my = _pixel_point(pixels, i, intr)
    q, e, valid = lens_unproject(model, mx, my, lens)
    if not valid:
        return
    gq = rotate_row(rot, g_o, i)
    ge = rotate_row(rot, g_d, i)
    gphi = wp.cross(ge, e) + wp.cross(gq, q)
    ge[2] = ge[2] + g_z[i]
    gmx, gmy = lens_unproject_vjp(model, e, lens, gq, ge)
    store_camera_row(out, i, gq, gphi, gmx, gmy, mx, my, intr)


for _k in (_lens_rays_kernel, _lens_rays_backward_kernel):
    A.declare_float_overloads(_k)


def _lens_inputs(a: A.Inputs, lens: Any) -> tuple[int, wp.array]:
    checked = check_lens("lens", lens)
    if checked is None:
        checked = Lens("opencv")  # a plain pinhole through the lens route: zero coefficients
    arr = wp.array(checked.params().astype(a.np_dtype), dtype=a.scalar, device=a.device)
    return checked.model_id, arr


def lens_rays(w2c: Any, intrinsics: Any, lens: Any, pixels: A.ArrayLike, device: str | wp.Device | None = None
              ) -> tuple[A.ArrayLike, A.ArrayLike, A.ArrayLike, A.ArrayLike]:
    """(origins (P, 3), unit dirs (P, 3), z_scale (P,), valid (P,) uint8) of pixels (P, 2) through
    `lens` (a kernels.lens.Lens; module docstring), in the kind and dtype of `pixels`. w2c is the 4x4
    world-to-camera matrix, intrinsics (fx, fy, cx, cy)."""
    M, K = check_camera(w2c, intrinsics)
    a = A.Inputs(device, pixels)
    px = a.floats("pixels", pixels, (None, 2))
    model, lens_arr = _lens_inputs(a, lens)
    n = px.shape[0]
    o, d, z = a.empty((n, 3)), a.empty((n, 3)), a.empty(n)
    valid = wp.empty(n, dtype=wp.uint8, device=a.device)
    rot, trans, intr = _camera_arrays(a, M, K)
    if n:
        a.launch(_lens_rays_kernel, n, [px, rot, trans, intr, model, lens_arr, o, d, z, valid])
    return a.out(o), a.out(d), a.out(z), a.out_mask(valid)


def lens_rays_backward(w2c: Any, intrinsics: Any, lens: Any, pixels: A.ArrayLike,
                       grad_origins: A.ArrayLike | None = None, grad_dirs: A.ArrayLike | None = None,
                       grad_z_scale: A.ArrayLike | None = None, device: str | wp.Device | None = None,
                       per_pixel: bool = False):
    """Gradient of <g_o, origins> + <g_d, dirs> + <g_z, z_scale> of `lens_rays` with respect to the
    pose perturbation xi and the intrinsics (module docstring), as kernels.volume.rays.CameraGrad;
    missing cotangents count as zero; invalid pixels contribute nothing. `per_pixel` as in
    kernels.volume.rays.camera_rays_backward."""
    M, K = check_camera(w2c, intrinsics)
    a = A.Inputs(device, pixels, grad_origins, grad_dirs, grad_z_scale)
    px = a.floats("pixels", pixels, (None, 2))
    model, lens_arr = _lens_inputs(a, lens)
    n = px.shape[0]
    go, gd, gz = _ray_cotangents(a, n, grad_origins, grad_dirs, grad_z_scale)
    rot, _, intr = _camera_arrays(a, M, K)
    rows = a.zeros((n, 10))
    if n:
        a.launch(_lens_rays_backward_kernel, n, [px, rot, intr, model, lens_arr, go, gd, gz, rows])
    return _camera_grad(rows, per_pixel)
