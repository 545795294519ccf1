"""Median and expected depth of the rasterised splats, and their backward.

Per pixel p, over the splats the rasteriser blended there (kernels/splat/raster.py), front to back,
with T_i the transmittance in front of splat i (T_1 = 1, T_{i+1} = T_i (1 - alpha_i)) and z_i its
camera-space z-depth:

Median depth (2DGS, Huang et al., "2D Gaussian Splatting for Geometrically Accurate Radiance Fields",
SIGGRAPH 2024, its forward's `if (T > 0.5) median_depth = depth`; gsplat's 2DGS "median" output):

    m(p) = z_{i*},  i* = the LAST blended splat with T_{i*} > 1/2

i.e. the splat at which the accumulated transmittance first crosses 1/2 (T_{i*} > 1/2 >= T_{i*+1});
where T never falls to 1/2 (a pixel that is at most half covered), the last splat blended; 0 where no
splat is blended. The crossing splat is piecewise constant in every input, so the gradient flows to
that one splat's z only: dm(p)/dz_{i*} = 1, and zero for every other input (one-sided where some
T_{i+1} equals 1/2 exactly, or at a change of depth order). The forward walks each pixel's list again
with the rasteriser's arithmetic (the same T's, bit for bit) and stops at the crossing; it records
i*'s position in the tile's sorted list (-1 where none), which the backward reads: each tile's thread
adds its pixels' dL/dm to one row per (tile, splat) entry, and a second kernel sums each splat's rows
(no shared accumulator: the split CPU launch is race-free, as in the rasteriser).

Expected depth (gsplat's "ED"): the rasteriser's depth output D = sum_i z_i alpha_i T_i divided by its
alpha A = 1 - T_final,

    e(p) = D / max(A, A_MIN),  A_MIN = 1e-10 (gsplat's clamp),
    de/dD = 1 / max(A, A_MIN),  de/dA = -D / A^2 where A > A_MIN, else 0 (one-sided at A = A_MIN).

Its backward returns the cotangents of the rasteriser's depth and alpha outputs, which
kernels.splat.render_backward takes as grad_depth and grad_alpha.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.splat.modes import ALPHA_MAX_OF, DEFAULT_MODE, mode_id
from kernels.splat.raster import Raster, _check_tiles_mode
from kernels.splat.raster_kernels import ALPHA_MIN, packed_alpha, tile_box, tile_pixel
from kernels.splat.tiles import TILE_PIXELS, Splats2D, Tiles

wp.set_module_options({"enable_backward": False})

MEDIAN_T = 0.5
A_MIN = 1e-10
MIN_CHUNK = 4096


@wp.kernel
def _median_kernel(packed: wp.array2d(dtype=Any), sorted_gid: wp.array(dtype=wp.int32),
                   ranges: wp.array2d(dtype=wp.int32), width: int, height: int, tiles_x: int, alpha_max: Any,
                   n_contrib: wp.array2d(dtype=wp.int32), out_median: wp.array2d(dtype=Any),
                   out_entry: wp.array2d(dtype=wp.int32), offset: int):
    # One thread per pixel, its tile's list up to the forward's n_contrib (past it nothing was blended),
    # with the forward's per-pixel arithmetic (kernels.splat.raster_kernels: the same T's).
    tile, px, py, pxf, pyf, inside = tile_pixel(wp.tid() + offset, tiles_x, width, height, alpha_max)
    if not inside:
        return
    zero = packed.dtype(0.0)
    one = packed.dtype(1.0)
    tr = one
    med = zero
    idx = int(-1)
    for s in range(ranges[tile, 0], n_contrib[py, px]):
        g = sorted_gid[s]
        alpha = packed_alpha(packed, g, pxf, pyf, alpha_max)
        if alpha < packed.dtype(ALPHA_MIN):
            continue
        # blended, with T_i = tr > 1/2 (the walk stops once T <= 1/2)
        med = packed[g, 7]
        idx = s
        tr = tr * (one - alpha)
        if tr <= packed.dtype(MEDIAN_T):
            break
    out_median[py, px] = med
    out_entry[py, px] = idx


@wp.kernel
def _median_backward_tile_kernel(sorted_entry: wp.array(dtype=wp.int32), ranges: wp.array2d(dtype=wp.int32),
                                 width: int, height: int, tiles_x: int, entry_idx: wp.array2d(dtype=wp.int32),
                                 g_median: wp.array2d(dtype=Any), rows: wp.array(dtype=Any), offset: int):
    # One thread per tile: the rows of its entries are its own (zeros on entry); pixels in row-major order.
    tile = wp.tid() + offset
    x_lo, y_lo, x_hi, y_hi, start, end = tile_box(tile, ranges, tiles_x, width, height)
    for py in range(y_lo, y_hi):
        for px in range(x_lo, x_hi):
            s = entry_idx[py, px]
            if s >= 0:
                row = sorted_entry[s]
                rows[row] = rows[row] + g_median[py, px]


@wp.kernel
def _gather_rows_kernel(starts: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32),
                        rows: wp.array(dtype=Any), out: wp.array(dtype=Any), offset: int):
    i = wp.tid() + offset
    acc = rows.dtype(0.0)
    e0 = starts[i]
    for e in range(e0, e0 + counts[i]):
        acc += rows[e]
    out[i] = acc


@wp.kernel
def _expected_kernel(depth: wp.array2d(dtype=Any), alpha: wp.array2d(dtype=Any), out: wp.array2d(dtype=Any),
                     offset: int):
    t = wp.tid() + offset
    w = depth.shape[1]
    y = t / w
    x = t - y * w
    out[y, x] = depth[y, x] / wp.max(alpha[y, x], depth.dtype(A_MIN))


@wp.kernel
def _expected_backward_kernel(depth: wp.array2d(dtype=Any), alpha: wp.array2d(dtype=Any),
                              g_e: wp.array2d(dtype=Any), g_depth: wp.array2d(dtype=Any),
                              g_alpha: wp.array2d(dtype=Any), offset: int):
    t = wp.tid() + offset
    w = depth.shape[1]
    y = t / w
    x = t - y * w
    a = alpha[y, x]
    a_min = depth.dtype(A_MIN)
    g_depth[y, x] = g_e[y, x] / wp.max(a, a_min)
    g_alpha[y, x] = depth.dtype(0.0)
    if a > a_min:
        g_alpha[y, x] = -g_e[y, x] * depth[y, x] / (a * a)


for _k in (_median_kernel, _median_backward_tile_kernel, _gather_rows_kernel, _expected_kernel,
           _expected_backward_kernel):
    A.declare_float_overloads(_k)


# ============================================================================ entry points


@dataclass
class MedianDepth:
    """The median depth (H, W) and, per pixel, the sorted-list position of its splat (-1: none)."""

    depth: Any
    entry: Any  # (H, W) int32


def median_depth(s: Splats2D, tiles: Tiles, raster: Raster, *, mode: str = DEFAULT_MODE) -> MedianDepth:
    """The median depth (module docstring) of the image `rasterize(s, ...)` made with `tiles` and `mode`;
    in the kind of the splats' inputs."""
    mode_id(mode)
    _check_tiles_mode(tiles, mode)
    a = s.inputs()
    height, width = (int(x) for x in raster.alpha.shape)
    n_contrib = a.ints("raster.n_contrib", raster.n_contrib, (height, width))
    med, entry = a.empty((height, width)), a.empty((height, width), wp.int32)
    n_tiles = tiles.tiles_x * tiles.tiles_y
    a.launch(_median_kernel, n_tiles * TILE_PIXELS,
             [tiles.packed, tiles.sorted_gid, tiles.ranges, width, height, tiles.tiles_x, a.s(ALPHA_MAX_OF[mode]),
              n_contrib, med, entry], min_chunk=TILE_PIXELS)
    return MedianDepth(a.out(med), a.out(entry))


def median_depth_backward(s: Splats2D, tiles: Tiles, median: MedianDepth, grad_median: Any) -> Any:
    """dL/dz (N,) of every splat's depth for the cotangent `grad_median` (H, W) of `median_depth`
    (its only input with a gradient; module docstring)."""
    if not isinstance(median, MedianDepth):
        raise ValueError(f"median: expected the MedianDepth of median_depth, got {type(median).__name__}")
    a = s.inputs()
    height, width = (int(x) for x in A.check_shape("median.entry", median.entry, (None, None)))
    entry = a.ints("median.entry", median.entry, (height, width), minimum=-1)
    g = a.floats("grad_median", grad_median, (height, width))
    rows = a.zeros(max(tiles.n_entries, 1))
    a.launch(_median_backward_tile_kernel, tiles.tiles_x * tiles.tiles_y,
             [tiles.sorted_entry, tiles.ranges, width, height, tiles.tiles_x, entry, g, rows], min_chunk=1)
    out = a.zeros(s.n)
    if s.n:
        a.launch(_gather_rows_kernel, s.n, [tiles.starts, tiles.counts, rows, out], min_chunk=MIN_CHUNK)
    return a.out(out)


def _depth_alpha(depth: Any, alpha: Any, device: Any) -> tuple[A.Inputs, wp.array, wp.array]:
    a = A.Inputs(device, depth, alpha)
    d = a.floats("depth", depth, ndim=2)
    al = a.floats("alpha", alpha, tuple(int(x) for x in d.shape))
    A.check_at_least("alpha", alpha, 0.0)
    return a, d, al


def expected_depth(depth: Any, alpha: Any, *, device: Any = None) -> Any:
    """e = depth / max(alpha, A_MIN) (H, W) from the rasteriser's depth and alpha outputs (module docstring)."""
    a, d, al = _depth_alpha(depth, alpha, device)
    h, w = (int(x) for x in d.shape)
    out = a.empty((h, w))
    if h * w:
        a.launch(_expected_kernel, h * w, [d, al, out], min_chunk=MIN_CHUNK)
    return a.out(out)


def expected_depth_backward(depth: Any, alpha: Any, grad: Any, *, device: Any = None) -> tuple[Any, Any]:
    """(dL/ddepth, dL/dalpha) (H, W) each, for the cotangent `grad` (H, W) of `expected_depth`."""
    a, d, al = _depth_alpha(depth, alpha, device)
    h, w = (int(x) for x in d.shape)
    g = a.floats("grad", grad, (h, w))
    g_d, g_a = a.empty((h, w)), a.empty((h, w))
    if h * w:
        a.launch(_expected_backward_kernel, h * w, [d, al, g, g_d, g_a], min_chunk=MIN_CHUNK)
    return a.out(g_d), a.out(g_a)
