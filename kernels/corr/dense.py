"""Dense lookups: the windowed bilinear lookup (4) in a stored volume pyramid, and its adjoint.

For each pixel p of frame 1, level l and window offsets a, b in {0, ..., 2r},

    out[l (2r+1)^2 + a (2r+1) + b, p] = V^l[p](x_p / 2^l + a - r, y_p / 2^l + b - r),   (4)

with V^l[p] the level's (H_l, W_l) slice for p sampled by (3), taps outside the
slice counting as 0. All samples of a level share the fractions (fx, fy), so
they read the (2r + 2) x (2r + 2) tap patch from (i0, j0) (`pixel_window`); one
thread computes one column a of the window, and sample b's lower taps are
sample b + 1's upper taps.

Adjoint, with g = d loss / d out, one thread per pixel:
  * to the pyramid: d V^l[p, tap] += (weight of tap in (3)) g, scattered into row
    p only, so threads never collide;
  * to the coordinates: d x_p += 2^-l sum_{a,b} g dS/du, d y_p += 2^-l sum_{a,b} g dS/dv,
    with the slopes of (3) (`bilinear_slopes`); (3) is piecewise bilinear, so its
    derivative jumps where u or v crosses an integer.
"""

from __future__ import annotations

import typing
from typing import Sequence

import warp as wp

from kernels._arrays import Inputs, declare_float_overloads
from kernels.corr._common import (Array, add_coords_grad, bilinear_slopes, check_levels, check_list,
                                  check_radius, coords_in, levels_in, pixel_window, volume_in)

wp.set_module_options({"enable_backward": False, "optimization_level": 3})


# --------------------------------------------------------------------------- kernels


@wp.func
def _tap(s: wp.array3d(dtype=typing.Any), p: int, row: int, col: int):
    """S[p, row, col], or 0 outside the level's image."""
    if row < 0 or col < 0 or row >= s.shape[1] or col >= s.shape[2]:
        return s.dtype(0.0)
    return s[p, row, col]


@wp.func
def _scatter_tap(g: wp.array3d(dtype=typing.Any), p: int, row: int, col: int, value: typing.Any):
    if row >= 0 and col >= 0 and row < g.shape[1] and col < g.shape[2]:
        g[p, row, col] = g[p, row, col] + value


@wp.kernel
def _lookup_level(
    vol: wp.array3d(dtype=typing.Any),
    coords: wp.array3d(dtype=typing.Any),
    out: wp.array3d(dtype=typing.Any),
    scale: typing.Any,
    radius: int,
    channel0: int,
    offset: int,
):
    """Equation (4) for one level and one x offset a; thread = pixel * (2r+1) + a."""
    t = wp.tid() + offset
    side = 2 * radius + 1
    p = t // side
    a = t % side
    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
    one = coords.dtype(1.0)
    col = i0 + a
    # Sample b's lower taps are sample b + 1's upper taps: each row of taps is read once.
    top = (one - fx) * _tap(vol, p, j0, col) + fx * _tap(vol, p, j0, col + 1)
    for b in range(side):
        row = j0 + b + 1
        bottom = (one - fx) * _tap(vol, p, row, col) + fx * _tap(vol, p, row, col + 1)
        out[channel0 + a * side + b, h, w] = (one - fy) * top + fy * bottom
        top = bottom


@wp.kernel
def _lookup_level_adjoint(
    vol: wp.array3d(dtype=typing.Any),
    coords: wp.array3d(dtype=typing.Any),
    grad_out: wp.array3d(dtype=typing.Any),
    grad_vol: wp.array3d(dtype=typing.Any),
    grad_coords: wp.array3d(dtype=typing.Any),
    scale: typing.Any,
    radius: int,
    channel0: int,
    offset: int,
):
    """Adjoint of (4) for one level; thread = pixel. Writes row p of grad_vol and pixel p of grad_coords only."""
    p = wp.tid() + offset
    side = 2 * radius + 1
    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
    one = coords.dtype(1.0)
    gx = coords.dtype(0.0)
    gy = coords.dtype(0.0)
    for a in range(side):
        col = i0 + a
        for b in range(side):
            row = j0 + b
            g = grad_out[channel0 + a * side + b, h, w]
            dx, dy = bilinear_slopes(_tap(vol, p, row, col), _tap(vol, p, row, col + 1), _tap(vol, p, row + 1, col),
                                     _tap(vol, p, row + 1, col + 1), fx, fy, one)
            gx += g * dx
            gy += g * dy
            _scatter_tap(grad_vol, p, row, col, (one - fx) * (one - fy) * g)
            _scatter_tap(grad_vol, p, row, col + 1, fx * (one - fy) * g)
            _scatter_tap(grad_vol, p, row + 1, col, (one - fx) * fy * g)
            _scatter_tap(grad_vol, p, row + 1, col + 1, fx * fy * g)
    add_coords_grad(grad_coords, h, w, gx, gy, scale)


for _k in (_lookup_level, _lookup_level_adjoint):
    declare_float_overloads(_k)


# --------------------------------------------------------------------------- entry points


def _volume_pyramid(a: Inputs, pyramid: Sequence[Array]) -> tuple[list[wp.array], int, int]:
    """The pyramid's levels as (H W, H_l, W_l) wp.arrays, and (H, W)."""
    v0 = volume_in(a, "pyramid[0]", pyramid[0])
    height, width = v0.shape[:2]
    check_levels(len(pyramid), height, width)
    return levels_in(a, "pyramid", pyramid, v0, (height, width), height, width), height, width


def lookup(pyramid: Sequence[Array], coords: Array, radius: int, *, device: str | None = None) -> Array:
    """Windowed lookup (4) in a volume pyramid: (L (2r+1)^2, H, W) in RAFT's channel order."""
    radius = check_radius(radius)
    check_list("pyramid", pyramid, "(H, W, H_l, W_l)")
    a = Inputs(device, *pyramid, coords)
    levels, height, width = _volume_pyramid(a, pyramid)
    xy = coords_in(a, coords, height, width)
    side = 2 * radius + 1
    n = height * width
    out = a.zeros((len(levels) * side * side, height, width))
    for lvl, v in enumerate(levels):
        a.launch(_lookup_level, n * side, [v, xy, out, a.s(0.5 ** lvl), radius, lvl * side * side])
    return a.out(out)


def lookup_backward(pyramid: Sequence[Array], coords: Array, radius: int, grad_out: Array, *,
                    device: str | None = None) -> dict[str, Array | list[Array]]:
    """Adjoint of (4). Returns a dict {"pyramid": [gradient (H, W, H_l, W_l) of every level],
    "coords": gradient (2, H, W)}, in pyramid[0]'s kind."""
    radius = check_radius(radius)
    check_list("pyramid", pyramid, "(H, W, H_l, W_l)")
    a = Inputs(device, *pyramid, coords, grad_out)
    levels, height, width = _volume_pyramid(a, pyramid)
    xy = coords_in(a, coords, height, width)
    side = 2 * radius + 1
    n = height * width
    g = a.floats("grad_out", grad_out, (len(levels) * side * side, height, width))
    grad_coords = a.zeros((2, height, width))
    grads = []
    for lvl, v in enumerate(levels):
        gv = a.zeros(v.shape)
        a.launch(_lookup_level_adjoint, n, [v, xy, g, gv, grad_coords, a.s(0.5 ** lvl), radius, lvl * side * side])
        grads.append(a.out(gv.reshape((height, width, v.shape[1], v.shape[2]))))
    return {"pyramid": grads, "coords": a.out(grad_coords)}
