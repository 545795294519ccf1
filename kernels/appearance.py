"""Per-image appearance: a bilateral grid of 3x4 affine colour transforms, sliced and applied, and its adjoint.

Wang et al., "Bilateral Guided Radiance Field Processing" (SIGGRAPH 2024), as gsplat's bilateral grid
(its examples' `lib_bilagrid.py`): each training image has a grid G of shape (L, GH, GW, 12) whose
entry e = 4 c + k holds row c, column k of a 3x4 affine colour transform (row-major). A rendered
pixel (i, j) of an H x W image with linear colour p = (r, g, b) is looked up at the grid coordinates

    x = (j + 1/2) / W (GW - 1),   y = (i + 1/2) / H (GH - 1),   z = clamp(lum(p), 0, 1) (L - 1),
    lum(p) = 0.299 r + 0.587 g + 0.114 b   (BT.601 luma, gsplat's guidance),

which is PyTorch's grid_sample with align_corners=True and border padding on the pixel centres in
[0, 1] and the guidance 2 lum - 1 in [-1, 1]. Trilinear interpolation gives the pixel's transform

    A_e = sum over the 8 corners n of w_n G[n, e],   w_n = prod over the axes of (1 - f) or f,

with t0 = floor(t) (kept <= size - 2 so that the upper node exists), t1 = t0 + 1, f = t - t0 on each
axis (an axis of size 1 has the one node, weight 1). The output colour is

    out_c = sum_{k<3} A_{4c+k} p_k + A_{4c+3}.

A grid of size 1 x 1 x 1 is one affine transform per image, A = G[0, 0, 0]: the simpler baseline
(per-image affine colour correction) is the same operation.

Adjoint, for the cotangent g = dL/dout, with q_e = dL/dA_e = g_c p_k (k < 3) and g_c (k = 3):

    dL/dG[n, e] = sum over the pixels of w_n q_e,
    dL/dp_k = sum_c g_c A_{4c+k} + lum_k (dz/dlum) sum_e q_e dA_e/dz,
    dA_e/dz = sum_n (dw_n/df_z) G[n, e],  dw_n/df_z = -+ w_n^(x) w_n^(y)  (lower / upper z node),

dz/dlum = L - 1 where 0 < lum < 1 and 0 outside (the clamp, as grid_sample's border padding).
The gradient is one-sided where z crosses an integer (a kink of the trilinear interpolation) and at
lum = 0 or 1; x and y are constants of the pixel. The forward is one thread per pixel (split across
CPU threads); the backward scatters into the grid, so it runs as one launch (kernels/launch.py: CPU
atomics are plain read-modify-writes). Generic over float32 and float64. research/splats/appearance.py
trains these grids with the splats; kernels/reference/appearance.py is the NumPy forward.
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A

wp.set_module_options({"enable_backward": False})

ENTRIES = 12  # a 3x4 affine transform, row-major
LUMA = (0.299, 0.587, 0.114)  # BT.601, the guidance of gsplat's bilateral grid


@wp.func
def _axis(t: Any, n: int):
    """(t0, t1, f): the grid nodes around coordinate t (clamped to [0, n - 1]) and the weight of t1."""
    tc = wp.clamp(t, type(t)(0.0), type(t)(float(n - 1)))
    t0 = wp.max(wp.min(int(wp.floor(tc)), n - 2), 0)
    t1 = wp.min(t0 + 1, n - 1)
    return t0, t1, tc - type(t)(float(t0))


@wp.func
def _corner(upper: int, t0: int, t1: int, f: Any):
    """(node, weight, dweight/df) of the lower (upper = 0) or upper (1) node on one axis."""
    if upper == 1:
        return t1, f, type(f)(1.0)
    return t0, type(f)(1.0) - f, type(f)(-1.0)


@wp.func
def _luma(r: Any, g: Any, b: Any):
    return type(r)(0.299) * r + type(r)(0.587) * g + type(r)(0.114) * b


@wp.func
def _pixel_nodes(rgb: wp.array3d(dtype=Any), p: int, gl: int, gh: int, gw: int):
    """Pixel p's row i and column j (row-major), its luma and the grid nodes around it on each axis
    (t0, t1, f for x and y from the pixel centre, z from the luma: module docstring)."""
    h = rgb.shape[0]
    w = rgb.shape[1]
    i = p // w
    j = p - i * w
    r = rgb[i, j, 0]
    half = type(r)(0.5)
    lum = _luma(r, rgb[i, j, 1], rgb[i, j, 2])
    x0, x1, fx = _axis((type(r)(float(j)) + half) / type(r)(float(w)) * type(r)(float(gw - 1)), gw)
    y0, y1, fy = _axis((type(r)(float(i)) + half) / type(r)(float(h)) * type(r)(float(gh - 1)), gh)
    z0, z1, fz = _axis(lum * type(r)(float(gl - 1)), gl)
    return i, j, lum, x0, x1, fx, y0, y1, fy, z0, z1, fz


@wp.kernel
def _slice_kernel(grid: wp.array2d(dtype=typing.Any), rgb: wp.array3d(dtype=typing.Any),
                  out: wp.array3d(dtype=typing.Any), gl: int, gh: int, gw: int, offset: int):
    i, j, _lum, x0, x1, fx, y0, y1, fy, z0, z1, fz = _pixel_nodes(rgb, wp.tid() + offset, gl, gh, gw)
    for c in range(3):
        acc = type(fx)(0.0)
        for k in range(4):
            e = 4 * c + k
            a = type(fx)(0.0)
            for corner in range(8):
                zi, wz, _sz = _corner(corner // 4, z0, z1, fz)
                yi, wy, _sy = _corner((corner // 2) % 2, y0, y1, fy)
                xi, wx, _sx = _corner(corner % 2, x0, x1, fx)
                a += wz * wy * wx * grid[(zi * gh + yi) * gw + xi, e]
            if k < 3:
                acc += a * rgb[i, j, k]
            else:
                acc += a
        out[i, j, c] = acc


@wp.kernel
def _slice_backward_kernel(grid: wp.array2d(dtype=typing.Any), rgb: wp.array3d(dtype=typing.Any),
                           g_out: wp.array3d(dtype=typing.Any), d_grid: wp.array2d(dtype=typing.Any),
                           d_rgb: wp.array3d(dtype=typing.Any), gl: int, gh: int, gw: int, offset: int):
    # one launch (never split): the grid gradient is a scatter over the pixels
    i, j, lum, x0, x1, fx, y0, y1, fy, z0, z1, fz = _pixel_nodes(rgb, wp.tid() + offset, gl, gh, gw)
    zero = type(lum)(0.0)
    one = type(lum)(1.0)
    dz = zero  # dL/dz = sum_e q_e dA_e/dz
    d0 = zero
    d1 = zero
    d2 = zero
    for c in range(3):
        gc = g_out[i, j, c]
        for k in range(4):
            e = 4 * c + k
            q = gc
            if k < 3:
                q = gc * rgb[i, j, k]
            a = zero
            dadz = zero
            for corner in range(8):
                zi, wz, sz = _corner(corner // 4, z0, z1, fz)
                yi, wy, _sy = _corner((corner // 2) % 2, y0, y1, fy)
                xi, wx, _sx = _corner(corner % 2, x0, x1, fx)
                node = (zi * gh + yi) * gw + xi
                v = grid[node, e]
                a += wz * wy * wx * v
                dadz += sz * wy * wx * v
                wp.atomic_add(d_grid, node, e, wz * wy * wx * q)
            dz += q * dadz
            if k == 0:
                d0 += gc * a
            elif k == 1:
                d1 += gc * a
            elif k == 2:
                d2 += gc * a
    dlum = zero
    if gl > 1 and lum > zero and lum < one:
        dlum = dz * type(lum)(float(gl - 1))
    d_rgb[i, j, 0] = d0 + type(lum)(0.299) * dlum
    d_rgb[i, j, 1] = d1 + type(lum)(0.587) * dlum
    d_rgb[i, j, 2] = d2 + type(lum)(0.114) * dlum


A.declare_float_overloads(_slice_kernel)
A.declare_float_overloads(_slice_backward_kernel)


def _inputs(grid: Any, rgb: Any, device: Any) -> tuple[A.Inputs, wp.array, wp.array, tuple[int, int, int]]:
    a = A.Inputs(device, grid, rgb)
    gr = a.floats("grid", grid, ndim=4, nonempty=True)
    if int(grid.shape[3]) != ENTRIES:
        raise ValueError(f"grid: expected (L, GH, GW, {ENTRIES}) (a 3x4 affine transform per node), "
                         f"got shape {tuple(grid.shape)}")
    rg = a.floats("rgb", rgb, ndim=3, nonempty=True)
    if int(rgb.shape[2]) != 3:
        raise ValueError(f"rgb: expected an (H, W, 3) image, got shape {tuple(rgb.shape)}")
    dims = tuple(int(s) for s in grid.shape[:3])
    return a, gr.reshape((dims[0] * dims[1] * dims[2], ENTRIES)), rg, dims


def bilateral_slice(grid: Any, rgb: Any, *, device: Any = None) -> Any:
    """out (H, W, 3): the image `rgb` (H, W, 3) through the bilateral grid `grid` (L, GH, GW, 12) (module
    docstring); a (1, 1, 1, 12) grid is one affine colour transform. In the inputs' kind."""
    a, gr, rg, (gl, gh, gw) = _inputs(grid, rgb, device)
    h, w = int(rgb.shape[0]), int(rgb.shape[1])
    out = a.empty((h, w, 3))
    a.launch(_slice_kernel, h * w, [gr, rg, out, gl, gh, gw])
    return a.out(out)


def bilateral_slice_backward(grid: Any, rgb: Any, grad_out: Any, *, device: Any = None) -> dict[str, Any]:
    """{"grid": dL/dgrid (L, GH, GW, 12), "rgb": dL/drgb (H, W, 3)} from dL/dout (H, W, 3) of
    `bilateral_slice` at the same inputs; in the inputs' kind."""
    a, gr, rg, (gl, gh, gw) = _inputs(grid, rgb, device)
    h, w = int(rgb.shape[0]), int(rgb.shape[1])
    go = a.floats("grad_out", grad_out, (h, w, 3))
    d_grid = a.zeros((gl * gh * gw, ENTRIES))
    d_rgb = a.empty((h, w, 3))
    a.launch(_slice_backward_kernel, h * w, [gr, rg, go, d_grid, d_rgb, gl, gh, gw], threads=1)
    d_grid = d_grid.reshape((gl, gh, gw, ENTRIES))
    return {"grid": a.out(d_grid), "rgb": a.out(d_rgb)}


def identity_grid(shape: tuple[int, int, int], dtype: Any = np.float32) -> np.ndarray:
    """A (L, GH, GW, 12) grid holding the identity transform at every node (gsplat's initialisation)."""
    if len(shape) != 3 or any(int(s) < 1 for s in shape):
        raise ValueError(f"shape: expected three grid sizes (L, GH, GW) >= 1, got {tuple(shape)}")
    eye = np.eye(3, 4, dtype=dtype).reshape(ENTRIES)
    return np.ascontiguousarray(np.broadcast_to(eye, (*(int(s) for s in shape), ENTRIES)))
