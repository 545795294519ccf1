"""What every stage of kernels.corr shares: 2x2 pooling (2) and its adjoint, the lookup window, checks.

Pooling (2) over the last two axes of an (N, H, W) array, odd trailing rows and
columns dropped (avg_pool2d with kernel 2, stride 2):

    out[n, h, w] = 1/4 sum_{a, b in {0, 1}} x[n, 2h + a, 2w + b],

and its adjoint adds g[n, h // 2, w // 2] / 4 into every fine pixel (h, w) that
has a coarse pixel. Given a gradient for every level of a pyramid, the total
gradient of level 0 runs that adjoint from the coarsest level down: level l's
total is its own gradient plus the adjoint applied to level l + 1's total.

Lookup window. For a pixel p = (h, w) of frame 1 at level l with radius r, the
(2r + 1)^2 samples of (4) share one fraction: with u0 = x_p / 2^l - 1/2 - r,
the window's taps start at column i0 = floor(u0) with fraction fx = u0 - i0
(and j0, fy from y_p the same way).

The family's argument checks live here too: the pyramid depth `levels` (frame 2
must hold the coarsest level's pixel), the window `radius`, the coordinates
(2, H, W), and lists of pyramid levels whose shapes follow `level_shapes`.
"""

from __future__ import annotations

import typing
from typing import Any, Sequence

import warp as wp

from kernels._arrays import Inputs, check_int, declare_float_overloads

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

VEC = 8  # SIMD width of the vector types below
vec8f = wp.types.vector(length=VEC, dtype=wp.float32)
vec8d = wp.types.vector(length=VEC, dtype=wp.float64)
VEC_OF = {wp.float32: vec8f, wp.float64: vec8d}

Array = Any  # np.ndarray or wp.array


# --------------------------------------------------------------------------- device functions


@wp.func
def _window_origin(coords: wp.array3d(dtype=typing.Any), axis: int, h: int, w: int, scale: typing.Any, radius: int):
    """Integer tap origin and fraction of the window's first sample: coords[axis, h, w] * scale - 1/2 - r split."""
    u0 = coords[axis, h, w] * scale - coords.dtype(0.5) - coords.dtype(radius)
    i0 = wp.floor(u0)
    return int(i0), u0 - i0


@wp.func
def pixel_window(coords: wp.array3d(dtype=typing.Any), p: int, scale: typing.Any, radius: int):
    """Pixel p's row h and column w, and its window's origin and fractions: (h, w, i0, fx, j0, fy)."""
    width = coords.shape[2]
    h = p // width
    w = p % width
    i0, fx = _window_origin(coords, 0, h, w, scale, radius)
    j0, fy = _window_origin(coords, 1, h, w, scale, radius)
    return h, w, i0, fx, j0, fy


@wp.func
def bilinear_slopes(s00: typing.Any, s01: typing.Any, s10: typing.Any, s11: typing.Any, fx: typing.Any,
                    fy: typing.Any, one: typing.Any):
    """d S / d u and d S / d v of the bilinear sample (3) from its four taps, in level pixels."""
    return (one - fy) * (s01 - s00) + fy * (s11 - s10), (one - fx) * (s10 - s00) + fx * (s11 - s01)


@wp.func
def add_coords_grad(grad_coords: wp.array3d(dtype=typing.Any), h: int, w: int, gx: typing.Any, gy: typing.Any,
                    scale: typing.Any):
    """grad_coords[:, h, w] += (gx, gy) * scale: the level's samples moved by coords / 2^l."""
    grad_coords[0, h, w] = grad_coords[0, h, w] + gx * scale
    grad_coords[1, h, w] = grad_coords[1, h, w] + gy * scale


# --------------------------------------------------------------------------- 2x2 average pooling


@wp.kernel
def _pool2x2(x: wp.array3d(dtype=typing.Any), out: wp.array3d(dtype=typing.Any), offset: int):
    """out[n, h, w] = mean of x[n, 2h : 2h + 2, 2w : 2w + 2]  (equation (2))."""
    t = wp.tid() + offset
    per = out.shape[1] * out.shape[2]
    n = t // per
    h = (t % per) // out.shape[2]
    w = t % out.shape[2]
    s = x[n, 2 * h, 2 * w] + x[n, 2 * h, 2 * w + 1] + x[n, 2 * h + 1, 2 * w] + x[n, 2 * h + 1, 2 * w + 1]
    out[n, h, w] = s * x.dtype(0.25)


@wp.kernel
def _pool2x2_adjoint_add(g_coarse: wp.array3d(dtype=typing.Any), g_fine: wp.array3d(dtype=typing.Any), offset: int):
    """g_fine[n, h, w] += g_coarse[n, h // 2, w // 2] / 4 where that coarse pixel exists (adjoint of (2))."""
    t = wp.tid() + offset
    per = g_fine.shape[1] * g_fine.shape[2]
    n = t // per
    h = (t % per) // g_fine.shape[2]
    w = t % g_fine.shape[2]
    hc = h // 2
    wc = w // 2
    if hc < g_coarse.shape[1] and wc < g_coarse.shape[2]:
        g_fine[n, h, w] = g_fine[n, h, w] + g_coarse[n, hc, wc] * g_fine.dtype(0.25)


for _k in (_pool2x2, _pool2x2_adjoint_add):
    declare_float_overloads(_k)


def pool_levels(x: wp.array, levels: int, a: Inputs) -> list[wp.array]:
    """[x, P(x), ..., P^{levels-1}(x)] for x (N, H, W), P the pooling (2)."""
    out = [x]
    for _ in range(1, levels):
        n, h, w = out[-1].shape
        coarse = a.empty((n, h // 2, w // 2))
        a.launch(_pool2x2, coarse.size, [out[-1], coarse])
        out.append(coarse)
    return out


def pool_levels_adjoint(grads: list[wp.array], a: Inputs) -> wp.array:
    """Total gradient of level 0 given each level's own gradient (3D views (N, H_l, W_l))."""
    acc = grads[-1]
    for lvl in range(len(grads) - 2, -1, -1):
        fine = wp.clone(grads[lvl])
        a.launch(_pool2x2_adjoint_add, fine.size, [acc, fine])
        acc = fine
    return acc


# --------------------------------------------------------------------------- shapes and checks


def level_shapes(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    """(H_l, W_l) of each pyramid level: halved and floored, as avg_pool2d(2, stride 2) does."""
    return [(height >> lvl, width >> lvl) for lvl in range(levels)]


def check_levels(levels: Any, height: int | None = None, width: int | None = None) -> int:
    """`levels` as an int >= 1; with a frame size, also that its coarsest level keeps a pixel."""
    levels = check_int("levels", levels, minimum=1)
    need = 2 ** (levels - 1)
    if height is not None and width is not None and (height < need or width < need):
        raise ValueError(f"levels: a pyramid of {levels} levels needs frame 2 at least {need}x{need} pixels "
                         f"(H, W >= 2**(levels-1)), got {height}x{width}; use at most "
                         f"{min(height, width).bit_length()} levels")
    return levels


def check_radius(radius: Any) -> int:
    return check_int("radius", radius, minimum=0)


def check_list(name: str, levels: Any, shape: str) -> None:
    if not isinstance(levels, (list, tuple)) or len(levels) < 1:
        raise ValueError(f"{name}: expected a non-empty list of levels, each {shape}")


def volume_in(a: Inputs, name: str, x: Array) -> wp.array:
    """An all-pairs volume (H, W, H, W) (or its gradient) as a wp.array."""
    v = a.floats(name, x, ndim=4, nonempty=True)
    if tuple(v.shape[:2]) != tuple(v.shape[2:]):
        raise ValueError(f"{name}: expected shape (H, W, H, W), got {tuple(v.shape)}")
    return v


def features_in(a: Inputs, name: str, x: Array) -> wp.array:
    """A (C, H, W) feature map (or its gradient) as a wp.array."""
    return a.floats(name, x, ndim=3, nonempty=True)


def levels_in(a: Inputs, name: str, arrays: Sequence[Array], first: wp.array, lead: tuple[int, ...],
              height: int, width: int) -> list[wp.array]:
    """Every level of a pyramid list: `first` (level 0, already checked), then level l of shape
    (*lead, H_l, W_l), as wp.arrays of shape (prod(lead), H_l, W_l)."""
    rows = 1
    for s in lead:
        rows *= s
    out = [first.reshape((rows, height, width))]
    for lvl, (hl, wl) in enumerate(level_shapes(height, width, len(arrays))):
        if lvl:
            out.append(a.floats(f"{name}[{lvl}]", arrays[lvl], (*lead, hl, wl)).reshape((rows, hl, wl)))
    return out


def coords_in(a: Inputs, coords: Array, height: int, width: int) -> wp.array:
    """Lookup positions (2, H, W): (x, y) in frame 2 for each pixel of frame 1."""
    return a.floats("coords", coords, (2, height, width))
