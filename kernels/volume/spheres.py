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
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.volume._checks import check_dtype
from kernels.volume.field import Field, FieldOutput
from kernels.volume.workspace import Workspace

wp.set_module_options({"enable_backward": False})

COLOR_NORMALIZE_EPS = 1e-6

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


@wp.kernel
def _spheres_forward_kernel(
    points: wp.array2d(dtype=typing.Any), centers: wp.array2d(dtype=typing.Any), radii: wp.array(dtype=typing.Any),
    colors: wp.array2d(dtype=typing.Any), sharpness: wp.array(dtype=typing.Any),
    out_sigma: wp.array(dtype=typing.Any), out_rgb: wp.array2d(dtype=typing.Any), offset: int,
):
    i = wp.tid() + offset
    zero = points.dtype(0.0)
    sig = zero
    nr = zero
    ng = zero
    nb = zero
    for k in range(radii.shape[0]):
        dx, dy, dz, dist = center_offset(points, i, centers, k)
        m = wp.max(zero, dist - radii[k])
        d = sharpness[k] * wp.exp(-sharpness[k] * m)
        sig += d
        nr += d * colors[k, 0]
        ng += d * colors[k, 1]
        nb += d * colors[k, 2]
    out_sigma[i] = sig
    if sig > points.dtype(1e-6):
        nr = nr / sig
        ng = ng / sig
        nb = nb / sig
    out_rgb[i, 0] = nr
    out_rgb[i, 1] = ng
    out_rgb[i, 2] = nb


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
        if normalized:
            gd = gs + (g0 * (colors[k, 0] - rgb[i, 0]) + g1 * (colors[k, 1] - rgb[i, 1])
                       + g2 * (colors[k, 2] - rgb[i, 2])) * inv
        else:
            gd = gs + g0 * colors[k, 0] + g1 * colors[k, 1] + g2 * colors[k, 2]
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

    def forward(self, points: A.ArrayLike, dirs: A.ArrayLike | None = None) -> FieldOutput:
        a, p, _ = self._inputs(points, dirs)
        n = p.shape[0]
        sigma, rgb = a.empty(n), a.empty((n, 3))
        a.launch(_spheres_forward_kernel, n, [p, *self._param_args(), sigma, rgb])
        return self._result(a, sigma, rgb)

    def backward(self, points: A.ArrayLike, dirs: A.ArrayLike | None, out: FieldOutput,
                 grad_sigma: A.ArrayLike | None, grad_rgb: A.ArrayLike | None,
                 workspace: Workspace | None = None) -> dict[str, wp.array]:
        a, p, _, sigma, rgb, gs, gr = self._backward_inputs(points, dirs, out, grad_sigma, grad_rgb)
        return self._scatter_grads(_spheres_backward_kernel, p.shape[0], [p, *self._param_args(), sigma, rgb, gs, gr],
                                   workspace)


A.declare_float_overloads(_spheres_forward_kernel)
A.declare_float_overloads(_spheres_backward_kernel)
