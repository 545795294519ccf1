"""Gradients of a radiance field with respect to its sample points and view directions.

Field.backward differentiates the parameters and treats points and directions as constants. The
camera gradients (kernels.volume.rays) need the other half: for cotangents (g_s, g) of
sigma (N,) and rgb (N, 3), the per-point vectors

    dL/dx_i = g_s,i dsigma/dx (x_i) + g_i . dc/dx (x_i, d_i),      dL/dd_i = g_i . dc/dd (x_i, d_i).

Soft spheres (kernels.volume.spheres; d_k = s_k exp(-s_k m_k), m_k = max(0, |x - c_k| - r_k)):

    dL/dx = sum_k dL/dd_k dd_k/dx,   dd_k/dx = -s_k d_k (x - c_k)/|x - c_k|  (outside, m_k > 0; else 0),
    dL/dd_k = g_s + g . (col_k - rgb)/sigma   (g_s + g . col_k below the 1e-6 normalisation switch),

and no direction dependence. Dense grid (kernels.volume.grid; u_a = (x_a - lo_a)/(hi_a - lo_a)(n_a - 1),
fractions f, corner weights w_b(f), raw density D = sum_b w_b D_b, raw colour
K_c = sum_b w_b sum_j Y_j(d) K_{c,j,b}):

    dL/dx_a = (n_a - 1)/(hi_a - lo_a) sum_b dw_b/df_a [ g_D D_b + sum_c g_K,c sum_j Y_j(d) K_{c,j,b} ],
    dL/dd   = sum_b w_b sum_c g_K,c sum_j K_{c,j,b} grad Y_j(d)      (SH colour only),

with g_D = g_s scale act'(D + bias), g_K,c = g_c s_c (1 - s_c), and dw_b/df_a = +-(product of the other
two axes' weights). grad Y_j is the gradient of the polynomial basis of kernels/sh.py in the raw
components of d (the callers pass unit directions and differentiate the normalisation themselves).
Trilinear interpolation is not differentiable on cell faces (the weights switch cells) and points
outside the box get zero: these are the kinks; the checks keep points away from them.

One thread per point writes only its own rows (launch_split). Inputs follow the array contract of
kernels.volume.field; results come back in the kind of `points`. Hash-grid and MLP fields have no
point gradient yet: `field_point_backward` raises ValueError naming the field for them.
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.sh import sh_basis_grad
from kernels.volume.field import Field, FieldOutput
from kernels.volume.grid import GridField, corner_offsets, corner_vertex, corner_weight, grid_cell, \
    grid_raw_cotangents, sh_basis, view_dir
from kernels.volume.spheres import SphereField, center_offset, point_cotangents, sphere_density_cotangent

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _spheres_points_kernel(
    points: wp.array2d(dtype=typing.Any), centers: wp.array2d(dtype=typing.Any), radii: wp.array(dtype=typing.Any),
    colors: wp.array2d(dtype=typing.Any), sharpness: wp.array(dtype=typing.Any), sigma: wp.array(dtype=typing.Any),
    rgb: wp.array2d(dtype=typing.Any), grad_sigma: wp.array(dtype=typing.Any), grad_rgb: wp.array2d(dtype=typing.Any),
    out_points: wp.array2d(dtype=typing.Any), out_dirs: wp.array2d(dtype=typing.Any), offset: int,
):
    i = wp.tid() + offset
    zero = points.dtype(0.0)
    normalized, inv, gs, g0, g1, g2 = point_cotangents(sigma, grad_sigma, grad_rgb, i)
    px = zero
    py = zero
    pz = zero
    for k in range(radii.shape[0]):
        dx, dy, dz, dist = center_offset(points, i, centers, k)
        m = dist - radii[k]
        if m > zero:
            s = sharpness[k]
            d = s * wp.exp(-s * m)
            gd = sphere_density_cotangent(gs, g0, g1, g2, colors, k, rgb, i, inv, normalized)
            c = -gd * s * d / dist
            px += c * dx
            py += c * dy
            pz += c * dz
    out_points[i, 0] = px
    out_points[i, 1] = py
    out_points[i, 2] = pz
    for a in range(3):
        out_dirs[i, a] = zero


@wp.func
def _corner_weight_grad(b: int) -> int:
    """dw/df of one axis' corner weight: +1 for the far corner (w = f), -1 for the near one (w = 1 - f)."""
    if b == 1:
        return 1
    return -1


@wp.kernel
def _grid_points_kernel(
    points: wp.array2d(dtype=typing.Any), dirs: wp.array2d(dtype=typing.Any), bbox: wp.array2d(dtype=typing.Any),
    res: wp.vec3i, density: wp.array(dtype=typing.Any), color: wp.array2d(dtype=typing.Any),
    n_coef: int, sh_mode: int, density_bias: typing.Any, density_scale: typing.Any, act_kind: int,
    rgb: wp.array2d(dtype=typing.Any), grad_sigma: wp.array(dtype=typing.Any), grad_rgb: wp.array2d(dtype=typing.Any),
    out_points: wp.array2d(dtype=typing.Any), out_dirs: wp.array2d(dtype=typing.Any), offset: int,
):
    i = wp.tid() + offset
    zero = points.dtype(0.0)
    for a in range(3):
        out_points[i, a] = zero
        out_dirs[i, a] = zero
    ix, iy, iz, fx, fy, fz, inside = grid_cell(points, i, bbox, res)
    if inside == 0:
        return
    dx, dy, dz = view_dir(dirs, i, sh_mode)
    g_raw_d, g0, g1, g2 = grid_raw_cotangents(density, ix, iy, iz, fx, fy, fz, res, density_bias, density_scale,
                                              act_kind, rgb, grad_sigma, grad_rgb, i)
    gradx, grady, gradz = sh_basis_grad(dx, dy, dz)
    gfx = zero
    gfy = zero
    gfz = zero
    gdx = zero
    gdy = zero
    gdz = zero
    for c in range(8):
        bx, by, bz = corner_offsets(c)
        wx = corner_weight(bx, fx)
        wy = corner_weight(by, fy)
        wz = corner_weight(bz, fz)
        v = corner_vertex(c, ix, iy, iz, res)
        val = g_raw_d * density[v]
        for j in range(n_coef):
            kc = g0 * color[v, j] + g1 * color[v, n_coef + j] + g2 * color[v, 2 * n_coef + j]
            val += kc * sh_basis(j, dx, dy, dz, sh_mode)
            if sh_mode >= 0:
                w = wx * wy * wz
                gdx += w * kc * gradx[j]
                gdy += w * kc * grady[j]
                gdz += w * kc * gradz[j]
        gfx += val * points.dtype(_corner_weight_grad(bx)) * wy * wz
        gfy += val * wx * points.dtype(_corner_weight_grad(by)) * wz
        gfz += val * wx * wy * points.dtype(_corner_weight_grad(bz))
    out_points[i, 0] = gfx * points.dtype(res[0] - 1) / (bbox[1, 0] - bbox[0, 0])
    out_points[i, 1] = gfy * points.dtype(res[1] - 1) / (bbox[1, 1] - bbox[0, 1])
    out_points[i, 2] = gfz * points.dtype(res[2] - 1) / (bbox[1, 2] - bbox[0, 2])
    out_dirs[i, 0] = gdx
    out_dirs[i, 1] = gdy
    out_dirs[i, 2] = gdz


SUPPORTED = (SphereField, GridField)


def check_point_field(field: Any) -> Field:
    """`field` if it has a point gradient here; ValueError naming it otherwise."""
    if not isinstance(field, SUPPORTED):
        raise ValueError(f"field: point and camera gradients exist for the spheres and grid fields, "
                         f"not for {type(field).__name__}")
    return field


def field_point_backward(field: Field, points: A.ArrayLike, dirs: A.ArrayLike | None, out: FieldOutput,
                         grad_sigma: A.ArrayLike | None, grad_rgb: A.ArrayLike | None
                         ) -> tuple[A.ArrayLike, A.ArrayLike]:
    """(dL/dpoints (N, 3), dL/ddirs (N, 3)) of L = <grad_sigma, sigma> + <grad_rgb, rgb> (module
    docstring), in the kind of `points`; dL/ddirs is zero for direction-independent colour."""
    check_point_field(field)
    a, p, d, sigma, rgb, gs, gr = field._backward_inputs(points, dirs, out, grad_sigma, grad_rgb)
    n = p.shape[0]
    g_p, g_d = a.empty((n, 3)), a.empty((n, 3))
    if isinstance(field, SphereField):
        a.launch(_spheres_points_kernel, n, [p, *field._param_args(), sigma, rgb, gs, gr, g_p, g_d])
    else:
        before, after = field._grid_args(a, d)
        a.launch(_grid_points_kernel, n, [p, *before, field.params["color"], *after, rgb, gs, gr, g_p, g_d])
    return a.out(g_p), a.out(g_d)


A.declare_float_overloads(_spheres_points_kernel)
A.declare_float_overloads(_grid_points_kernel)
