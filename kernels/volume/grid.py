"""Dense voxel-grid radiance field: trilinear density and colour (RGB or spherical harmonics).

Follows Plenoxels (Fridovich-Keil et al. 2022) and DVGO (Sun et al. 2022). Values live on the
nx * ny * nz vertices of a regular grid spanning the box [lo, hi] (vertex v = ix + nx (iy + ny iz),
x fastest; NumPy shape (nz, ny, nx, ...)). A point p inside the box has grid coordinates
u_a = (p_a - lo_a) / (hi_a - lo_a) * (n_a - 1), cell i_a = min(floor(u_a), n_a - 2), fraction
f_a = u_a - i_a, and the trilinear weights of the cell's 8 corners (b in {0, 1}^3)

    w_b = prod_a (b_a f_a + (1 - b_a)(1 - f_a)),     V(p) = sum_b w_b V[i + b].

    sigma(p)  = density_scale * act(D(p) + density_bias)   act = softplus (DVGO) or exp (instant-ngp)
    rgb_c(p)  = sigmoid( sum_j Y_j(d) K_{c,j}(p) ),   c = 0, 1, 2

with K the colour coefficients: one per channel (sh_degree None: Y_0 = 1, plain RGB) or
(deg+1)^2 per channel for real spherical harmonics of degree deg <= 2 in the view direction d
(the basis and constants of Plenoxels/3DGS, kernels/sh.py).
Points outside the box get sigma = 0 and rgb = 0, and no gradient.

DVGO's choice is softplus with a large negative bias (the field starts transparent) and a scale of
1 / voxel size (densities "per voxel").

A total-variation regulariser (Plenoxels) sum_v sum_a (V[v + e_a] - V[v])^2 adds its gradient
2 sum_a (2 V[v] - V[v + e_a] - V[v - e_a]) (terms present only inside the grid) by a gather kernel.

Backward, for cotangents (g_s, g):  dL/dD[v] = sum_points w_b g_s scale act'(D + bias) and
dL/dK_{c,j}[v] = sum_points w_b g_c s_c (1 - s_c) Y_j(d), s_c = rgb_c. Many points hit the same
vertex, so the backward scatters with atomic adds in ONE launch (no Warp atomic is atomic between
concurrent CPU launches, docs/warp.md); the forward runs one thread per point through launch_split.
Points follow the array contract of kernels.volume.field.
"""

from __future__ import annotations

import typing
from typing import Any, Sequence

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.sh import sh_component
from kernels.volume import _act
from kernels.volume._act import density_act, density_act_grad, sigmoid, sigmoid_vjp
from kernels.volume._checks import check_bbox, check_dtype
from kernels.volume.field import Field, FieldOutput
from kernels.volume.workspace import Workspace

wp.set_module_options({"enable_backward": False})

@wp.func
def sh_basis(j: int, x: typing.Any, y: typing.Any, z: typing.Any, mode: int):
    """Y_j(x, y, z) of kernels/sh.py; mode -1 is plain RGB (Y_0 = 1)."""
    if mode < 0:
        return type(x)(1.0)
    return sh_component(j, x, y, z)


@wp.func
def grid_axis(p: typing.Any, lo: typing.Any, hi: typing.Any, n: int):
    """(cell index, fraction, inside flag) of coordinate p on an axis with n vertices over [lo, hi]."""
    u = (p - lo) / (hi - lo) * type(p)(n - 1)
    inside = int(1)
    if u < type(p)(0.0) or u > type(p)(n - 1):
        inside = 0
    i = wp.clamp(int(wp.floor(u)), 0, n - 2)
    return i, u - type(p)(i), inside


@wp.func
def corner_weight(b: int, f: typing.Any):
    if b == 1:
        return f
    return type(f)(1.0) - f


@wp.func
def corner_offsets(c: int):
    """The offsets (b_x, b_y, b_z) in {0, 1}^3 of corner c = b_x + 2 b_y + 4 b_z of a cell."""
    return c & 1, (c >> 1) & 1, (c >> 2) & 1


@wp.func
def trilinear_weight(c: int, fx: typing.Any, fy: typing.Any, fz: typing.Any):
    """w_b of corner c for the fractions (f_x, f_y, f_z)."""
    bx, by, bz = corner_offsets(c)
    return corner_weight(bx, fx) * corner_weight(by, fy) * corner_weight(bz, fz)


@wp.func
def grid_cell(points: wp.array2d(dtype=typing.Any), i: int, bbox: wp.array2d(dtype=typing.Any), res: wp.vec3i):
    """Cell (i_x, i_y, i_z), fractions (f_x, f_y, f_z) and inside flag of point i on the vertex grid."""
    ix, fx, inx = grid_axis(points[i, 0], bbox[0, 0], bbox[1, 0], res[0])
    iy, fy, iny = grid_axis(points[i, 1], bbox[0, 1], bbox[1, 1], res[1])
    iz, fz, inz = grid_axis(points[i, 2], bbox[0, 2], bbox[1, 2], res[2])
    return ix, iy, iz, fx, fy, fz, inx * iny * inz


@wp.func
def corner_vertex(c: int, ix: int, iy: int, iz: int, res: wp.vec3i) -> int:
    """Flat index of corner c of cell (i_x, i_y, i_z)."""
    bx, by, bz = corner_offsets(c)
    return (ix + bx) + res[0] * ((iy + by) + res[1] * (iz + bz))


@wp.func
def flat_coords(v: int, res: wp.vec3i) -> wp.vec3i:
    """(i_x, i_y, i_z) of flat index v = i_x + res_x (i_y + res_y i_z), x fastest."""
    return wp.vec3i(v % res[0], (v / res[0]) % res[1], v / (res[0] * res[1]))


@wp.func
def trilinear_density(density: wp.array(dtype=typing.Any), ix: int, iy: int, iz: int, fx: typing.Any,
                      fy: typing.Any, fz: typing.Any, res: wp.vec3i):
    """sum_c w_c density[corner c] over the 8 corners of cell (i_x, i_y, i_z)."""
    raw_d = type(fx)(0.0)
    for c in range(8):
        raw_d += trilinear_weight(c, fx, fy, fz) * density[corner_vertex(c, ix, iy, iz, res)]
    return raw_d


@wp.func
def view_dir(dirs: wp.array2d(dtype=typing.Any), i: int, sh_mode: int):
    """Direction of point i, or zeros for plain RGB (sh_mode -1, where dirs is a placeholder)."""
    zero = dirs.dtype(0.0)
    if sh_mode >= 0:
        return dirs[i, 0], dirs[i, 1], dirs[i, 2]
    return zero, zero, zero


@wp.func
def grid_raw_cotangents(density: wp.array(dtype=typing.Any), ix: int, iy: int, iz: int, fx: typing.Any,
                        fy: typing.Any, fz: typing.Any, res: wp.vec3i, density_bias: typing.Any,
                        density_scale: typing.Any, act_kind: int, rgb: wp.array2d(dtype=typing.Any),
                        grad_sigma: wp.array(dtype=typing.Any), grad_rgb: wp.array2d(dtype=typing.Any), i: int):
    """(g_D, g_K0, g_K1, g_K2) of point i: the cotangents of its raw (pre-activation) density and colour."""
    raw_d = trilinear_density(density, ix, iy, iz, fx, fy, fz, res)
    g_raw_d = grad_sigma[i] * density_scale * density_act_grad(raw_d + density_bias, act_kind)
    return (g_raw_d, sigmoid_vjp(grad_rgb[i, 0], rgb[i, 0]), sigmoid_vjp(grad_rgb[i, 1], rgb[i, 1]),
            sigmoid_vjp(grad_rgb[i, 2], rgb[i, 2]))


@wp.kernel
def _grid_forward_kernel(
    points: wp.array2d(dtype=typing.Any), dirs: wp.array2d(dtype=typing.Any), bbox: wp.array2d(dtype=typing.Any),
    res: wp.vec3i, density: wp.array(dtype=typing.Any), color: wp.array2d(dtype=typing.Any),
    n_coef: int, sh_mode: int, density_bias: typing.Any, density_scale: typing.Any, act_kind: int,
    out_sigma: wp.array(dtype=typing.Any), out_rgb: wp.array2d(dtype=typing.Any), offset: int,
):
    i = wp.tid() + offset
    zero = points.dtype(0.0)
    ix, iy, iz, fx, fy, fz, inside = grid_cell(points, i, bbox, res)
    if inside == 0:
        out_sigma[i] = zero
        out_rgb[i, 0] = zero
        out_rgb[i, 1] = zero
        out_rgb[i, 2] = zero
        return
    dx, dy, dz = view_dir(dirs, i, sh_mode)
    raw_d = trilinear_density(density, ix, iy, iz, fx, fy, fz, res)
    r0 = zero
    r1 = zero
    r2 = zero
    for c in range(8):
        w = trilinear_weight(c, fx, fy, fz)
        v = corner_vertex(c, ix, iy, iz, res)
        for j in range(n_coef):
            wy = w * sh_basis(j, dx, dy, dz, sh_mode)
            r0 += wy * color[v, j]
            r1 += wy * color[v, n_coef + j]
            r2 += wy * color[v, 2 * n_coef + j]
    out_sigma[i] = density_scale * density_act(raw_d + density_bias, act_kind)
    out_rgb[i, 0] = sigmoid(r0)
    out_rgb[i, 1] = sigmoid(r1)
    out_rgb[i, 2] = sigmoid(r2)


@wp.kernel
def _grid_backward_kernel(
    points: wp.array2d(dtype=typing.Any), dirs: wp.array2d(dtype=typing.Any), bbox: wp.array2d(dtype=typing.Any),
    res: wp.vec3i, density: wp.array(dtype=typing.Any),
    n_coef: int, sh_mode: int, density_bias: typing.Any, density_scale: typing.Any, act_kind: int,
    rgb: wp.array2d(dtype=typing.Any), grad_sigma: wp.array(dtype=typing.Any), grad_rgb: wp.array2d(dtype=typing.Any),
    grad_density: wp.array(dtype=typing.Any), grad_color: wp.array2d(dtype=typing.Any),
):
    i = wp.tid()
    ix, iy, iz, fx, fy, fz, inside = grid_cell(points, i, bbox, res)
    if inside == 0:
        return
    dx, dy, dz = view_dir(dirs, i, sh_mode)
    g_raw_d, g0, g1, g2 = grid_raw_cotangents(density, ix, iy, iz, fx, fy, fz, res, density_bias, density_scale,
                                              act_kind, rgb, grad_sigma, grad_rgb, i)
    for c in range(8):
        w = trilinear_weight(c, fx, fy, fz)
        v = corner_vertex(c, ix, iy, iz, res)
        wp.atomic_add(grad_density, v, w * g_raw_d)
        for j in range(n_coef):
            wy = w * sh_basis(j, dx, dy, dz, sh_mode)
            wp.atomic_add(grad_color, v, j, wy * g0)
            wp.atomic_add(grad_color, v, n_coef + j, wy * g1)
            wp.atomic_add(grad_color, v, 2 * n_coef + j, wy * g2)


@wp.kernel
def _tv_grad_kernel(
    values: wp.array2d(dtype=typing.Any), res: wp.vec3i, weight: typing.Any,
    grad: wp.array2d(dtype=typing.Any), offset: int,
):
    v = wp.tid() + offset
    ijk = flat_coords(v, res)
    stride = wp.vec3i(1, res[0], res[0] * res[1])
    for c in range(values.shape[1]):
        g = values.dtype(0.0)
        x = values[v, c]
        for a in range(3):
            if ijk[a] + 1 < res[a]:
                g += x - values[v + stride[a], c]
            if ijk[a] > 0:
                g += x - values[v - stride[a], c]
        grad[v, c] = grad[v, c] + values.dtype(2.0) * weight * g


def add_tv_grad(values: wp.array, resolution: Sequence[int], weight: float, grad: wp.array) -> None:
    """grad += weight * d TV(values) / d values for values (V,) or (V, C) wp.arrays on the grid's vertices.

    TV is the total variation of Plenoxels with squared differences (module docstring;
    kernels.reference.volume.total_variation computes it).

    A gather (each vertex reads its 6 neighbours and writes its own gradient): launch_split is safe.
    """
    if len(resolution) != 3:
        raise ValueError(f"resolution: expected three vertex counts (nx, ny, nz), got {resolution!r}")
    nv = int(np.prod([A.check_int("resolution", r, minimum=1) for r in resolution]))
    if not isinstance(values, wp.array) or values.ndim not in (1, 2) or values.shape[0] != nv:
        raise ValueError(f"values: expected a wp.array of shape ({nv},) or ({nv}, C)")
    a = A.Inputs(values.device, values)
    a.floats("values", values, finite=False)
    A.check_out("grad", grad, values.shape, values.dtype, values.device)
    weight = A.check_float("weight", weight)
    a.launch(_tv_grad_kernel, nv, [values.reshape((nv, -1)), wp.vec3i(*resolution), a.s(weight),
                                   grad.reshape((nv, -1))])


def n_sh_coefficients(sh_degree: int | None) -> int:
    if sh_degree is None:
        return 1
    if sh_degree not in (0, 1, 2):
        raise ValueError(f"sh_degree: expected None (plain RGB) or 0, 1, 2, got {sh_degree!r}")
    return (sh_degree + 1) ** 2


class GridField(Field):
    """Dense voxel grid (module docstring). Parameters: density (V,) and color (V, 3 * n_coef)."""

    name = "grid"

    def __init__(
        self,
        bbox: Any,
        resolution: Sequence[int],
        sh_degree: int | None = None,
        density_bias: float = 0.0,
        density_scale: float = 1.0,
        density_activation: str = "softplus",
        init_density: float = 0.0,
        init_color_std: float = 0.0,
        seed: int = 0,
        dtype: Any = wp.float32,
        device: str | wp.Device | None = None,
    ) -> None:
        check_dtype("dtype", dtype)
        self.bbox = check_bbox("bbox", bbox)
        if len(resolution) != 3:
            raise ValueError(f"resolution: expected three vertex counts (nx, ny, nz), got {resolution!r}")
        self.resolution = tuple(A.check_int("resolution", r, minimum=1) for r in resolution)
        if min(self.resolution) < 2:
            raise ValueError(f"resolution: expected at least 2 vertices per axis, got {self.resolution}")
        self.sh_degree = sh_degree
        self.n_coef = n_sh_coefficients(sh_degree)
        self.act_code = _act.density_code("density_activation", density_activation)
        self.density_activation = density_activation
        self.density_bias = A.check_float("density_bias", density_bias)
        self.density_scale = A.check_float("density_scale", density_scale, positive=True)
        self.needs_dirs = sh_degree is not None
        device = A.get_device(device)
        nv = int(np.prod(self.resolution))
        rng = np.random.default_rng(seed)
        np_t = A.NP_OF_WP[dtype]
        params = {
            "density": wp.array(np.full(nv, init_density, dtype=np_t), dtype=dtype, device=device),
            "color": wp.array((rng.standard_normal((nv, 3 * self.n_coef)) * init_color_std).astype(np_t),
                              dtype=dtype, device=device),
        }
        super().__init__(params, dtype, device)

    def _grid_args(self, a: A.Inputs, d: wp.array | None) -> tuple[list, list]:
        """The kernels' arguments before and after the colour: (points' dirs, box, resolution,
        density) and (n_coef, SH mode, bias, scale, activation). Plain RGB gets a placeholder for dirs."""
        dirs = d if d is not None else a.zeros((1, 3))
        sh_mode = -1 if self.sh_degree is None else self.sh_degree
        return ([dirs, wp.array(self.bbox, dtype=self.dtype, device=self.device), wp.vec3i(*self.resolution),
                 self.params["density"]],
                [self.n_coef, sh_mode, a.s(self.density_bias), a.s(self.density_scale), self.act_code])

    def forward(self, points: A.ArrayLike, dirs: A.ArrayLike | None = None) -> FieldOutput:
        a, p, d = self._inputs(points, dirs)
        n = p.shape[0]
        sigma, rgb = a.empty(n), a.empty((n, 3))
        before, after = self._grid_args(a, d)
        a.launch(_grid_forward_kernel, n, [p, *before, self.params["color"], *after, sigma, rgb])
        return self._result(a, sigma, rgb)

    def backward(self, points: A.ArrayLike, dirs: A.ArrayLike | None, out: FieldOutput,
                 grad_sigma: A.ArrayLike | None, grad_rgb: A.ArrayLike | None,
                 workspace: Workspace | None = None) -> dict[str, wp.array]:
        a, p, d, _, rgb, gs, gr = self._backward_inputs(points, dirs, out, grad_sigma, grad_rgb)
        before, after = self._grid_args(a, d)
        return self._scatter_grads(_grid_backward_kernel, p.shape[0], [p, *before, *after, rgb, gs, gr], workspace)


A.declare_float_overloads(_grid_forward_kernel)
A.declare_float_overloads(_grid_backward_kernel)
A.declare_float_overloads(_tv_grad_kernel)
