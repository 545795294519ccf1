"""Rasterisation of depth-sorted splats, and its hand-written backward.

Per pixel p (centre (i + 0.5, j + 0.5)), front to back over its tile's list (kernels/splat/tiles.py):

    G_i = exp(-1/2 d^T Q_i d),  d = mean2d_i - p
    alpha_i = min(a_max, o_i G_i); a splat with alpha_i < 1/255 (or d^T Q d < 0) is skipped;
    T_1 = 1,  T_{i+1} = T_i (1 - alpha_i); the loop stops before the splat that would bring
        T below 1e-4 (that splat is not blended)
    "3dgs" mode (3DGS's renderCUDA): a_max = 0.99, stop when T_i (1 - alpha_i) < 1e-4;
    "gsplat" mode (gsplat's rasterize_to_pixels): a_max = 0.999, stop when T_i (1 - alpha_i) <= 1e-4
    rgb = sum_i colour_i alpha_i T_i + T_final * background
    alpha = 1 - T_final
    depth = sum_i z_i alpha_i T_i   (background depth 0: the expected z-depth is depth / alpha)

Backward, written by hand (Warp's tape is wrong through loops with carried state, docs/warp.md).
Per pixel, back to front, T_i is recovered as T_{i+1} / (1 - alpha_i) from the stored T_final,
and with S_i the colour composited behind splat i (S <- alpha_j c_j + (1 - alpha_j) S over j > i),

    drgb/dalpha_i = T_i (c_i - S_i) - T_final background / (1 - alpha_i),
    dalpha_out/dalpha_i = T_final / (1 - alpha_i),

depth like a colour channel with background 0. Through alpha = o G (zero where the a_max clamp is
active) the gradients reach o, Q and mean2d:
    dalpha/do = G,  dalpha/dQ = -alpha/2 (dx^2, 2 dx dy, dy^2),  dalpha/dmean2d = -alpha Q d.
With `absgrad=True` the backward also returns AbsGS's densification statistic (Ye et al., "AbsGS:
Recovering Fine Details for 3D Gaussian Splatting", 2024; gsplat's `absgrad=True`): with
g_p = dL/dmean2d|_p the term pixel p adds to splat i's mean2d gradient (dL/dmean2d_i = sum_p g_p),

    means2d_abs_i = sum_p (|g_p,x|, |g_p,y|),

whose norm is never below the norm of the summed gradient (terms of opposite sign do not cancel). It
has no gradient of its own; the other outputs are the same bits whether it is asked for or not.
Every tile's backward runs on one thread and writes one gradient row per (tile, splat) pair,
which a second kernel sums per splat: no Warp atomic is atomic between concurrent CPU launches
(docs/warp.md), so with no shared accumulator the tiles run in parallel through
kernels.launch.launch_split, and the result does not depend on the thread count.

Loop order (speed only; every pixel's arithmetic and order are those above). On the CPU one
thread per tile walks the tile's list once, splats outside (front to back; back to front in the backward),
and for each splat only the pixels of its spans in the tile (kernels/splat/spans.py: the box of
the rows and columns inside its alpha >= 1/255 ellipse, widened for rounding; every other pixel
would skip it). Each pixel's running T and sums live in arrays between splats; the forward marks
a stopped pixel (n_contrib < 0 until the end) and ends the tile once all its pixels stopped.
On CUDA the forward runs a thread per pixel over its tile's whole list (the same results). On a CPU
with AVX2 and FMA the float32 forward blends each splat's span rows 16 pixels at once
(kernels/splat/rowblend.py: the same arithmetic per lane, glibc's expf in float64 lanes; the same
bits), the tile's per-pixel state in a scratch array and each row's running pixels in a bit mask.
The per-tile loops are while loops with the pixel centre stepped by one (exact for image sides up
to MAX_SIDE = 2^23), and both modes' stop is one comparison next_t < stop_below(mode): Warp's
range() iterator and the compound test cost more per pixel.

The kernels are in kernels.splat.raster_kernels; this module holds the entry points and their
checks, and picks the kernel (ALPHA_MIN, ALPHA_MAX and T_MIN are re-exported from there).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import fast_paths
from kernels import _arrays as A
from kernels.splat.modes import ALPHA_MAX_OF, DEFAULT_MODE, mode_id
from kernels.splat.raster_kernels import ALPHA_MAX, ALPHA_MIN  # noqa: F401 (kernels.splat's names)
from kernels.splat.raster_kernels import (T_MIN, _GRAD_COLS, _gather_entry_grads_kernel,
                                          _raster_backward_tile_kernel, _raster_forward_kernel,
                                          _raster_forward_pixel_kernel, _raster_forward_rows_kernel)
from kernels.splat.rowblend import rowblend_available
from kernels.splat.tiles import MAX_SIDE, TILE, TILE_PIXELS, Splats2D, Tiles, bin_tiles

MIN_CHUNK = 1024


# ============================================================================ entry points


@dataclass
class Raster:
    """One rasterised image: rgb, alpha, depth, and the per-pixel state the backward reads."""

    rgb: wp.array  # (H, W, 3)
    alpha: wp.array  # (H, W)
    depth: wp.array  # (H, W) sum of alpha-weighted z-depths
    final_T: wp.array  # (H, W)
    n_contrib: wp.array  # (H, W) int32: sorted entries up to and including the last one blended



def stop_below(mode: str, np_dtype: Any) -> float:
    """The kernels' stop threshold t: a pixel stops before a splat with T (1 - alpha) < t. "3dgs" stops
    below T_MIN, "gsplat" at or below it: t is T_MIN in the dtype, or the next float above it (for
    floats x <= T_MIN exactly when x < nextafter(T_MIN, inf)), so one comparison serves both modes."""
    t = np_dtype.type(T_MIN)
    if mode_id(mode) == 1:
        t = np.nextafter(t, np_dtype.type(np.inf))
    return float(t)


def background_array(a: A.Inputs, background: Any) -> wp.array:
    """The (3,) background as a wp.array (None: black)."""
    if background is None:
        return a.zeros(3)
    return a.floats("background", background, (3,))


def _check_tiles_mode(tiles: Tiles, mode: str) -> None:
    if tiles.mode != mode:
        raise ValueError(f"tiles: binned with mode={tiles.mode!r}, expected mode={mode!r}")


def rasterize_wp(s: Splats2D, width: int, height: int, bg: wp.array,
                 tiles: Tiles | None = None, mode: str = DEFAULT_MODE) -> tuple[Raster, Tiles]:
    """`rasterize` with wp.array results (the render chain's last stage); `bg` a wp.array."""
    # a thread per tile on the CPU's fast route, else a thread per pixel (CUDA's; kernels.fast_paths)
    return _rasterize_wp(s, width, height, bg, tiles, mode, per_tile=fast_paths.on(s.device))


_ROWS_OK: list[bool] = []


def _rows_ok() -> bool:
    """Whether the CPU kernels have the 16-lane row blend (AVX2 and FMA; kernels/splat/rowblend.py)."""
    if not _ROWS_OK:
        _ROWS_OK.append(rowblend_available())
    return _ROWS_OK[0]


def _rasterize_wp(s: Splats2D, width: int, height: int, bg: wp.array, tiles: Tiles | None, mode: str,
                  per_tile: bool, rows: bool = True) -> tuple[Raster, Tiles]:
    """`rasterize_wp` with the forward's layout chosen: a thread per tile (the CPU's) or per pixel (CUDA's)."""
    mode_id(mode)
    a = s.inputs()
    if tiles is None:
        tiles = bin_tiles(s, width, height, mode)
    _check_tiles_mode(tiles, mode)
    # Every pixel belongs to one tile, whose thread writes all its outputs: no zero fill needed.
    # (On the CPU the large ones recycle freed blocks: kernels/_arrays.py, HostPool.)
    out = Raster(a.empty((height, width, 3)), a.empty((height, width)), a.empty((height, width)),
                 a.empty((height, width)), a.empty((height, width), wp.int32))
    n_tiles = tiles.tiles_x * tiles.tiles_y
    args = [tiles.packed, bg, tiles.sorted_gid, tiles.ranges, width, height, tiles.tiles_x, a.s(ALPHA_MAX_OF[mode]),
            a.s(stop_below(mode, a.np_dtype)), out.rgb, out.alpha, out.depth, out.final_T, out.n_contrib]
    if per_tile and rows and a.scalar == wp.float32 and _rows_ok():
        scratch = [a.empty((n_tiles, 5 * TILE_PIXELS)), a.empty((n_tiles, TILE_PIXELS), wp.int32),
                   a.empty((n_tiles, TILE), wp.int32)]
        a.launch(_raster_forward_rows_kernel, n_tiles, [*args, *scratch], min_chunk=1)
    elif per_tile:
        a.launch(_raster_forward_kernel, n_tiles, args, min_chunk=1)
    else:
        a.launch(_raster_forward_pixel_kernel, n_tiles * TILE_PIXELS, args, min_chunk=TILE_PIXELS)
    return out, tiles


def rasterize(s: Splats2D, width: int, height: int, background: Any = None,
              tiles: Tiles | None = None, *, mode: str = DEFAULT_MODE) -> tuple[Raster, Tiles]:
    """Bin (unless `tiles` is given) and alpha-composite the splats front to back (module docstring),
    following `mode` ("3dgs" or "gsplat", kernels/splat/modes.py).

    The Raster's arrays are in the kind of the splats' inputs; the Tiles stay wp.arrays (state).
    """
    mode_id(mode)
    width = A.check_int("width", width, minimum=1, maximum=MAX_SIDE)
    height = A.check_int("height", height, minimum=1, maximum=MAX_SIDE)
    a = s.inputs()
    raster, tiles = rasterize_wp(s, width, height, background_array(a, background), tiles, mode)
    return Raster(*(a.out(x) for x in (raster.rgb, raster.alpha, raster.depth, raster.final_T,
                                        raster.n_contrib))), tiles


def rasterize_backward(s: Splats2D, width: int, height: int, background: Any, tiles: Tiles, raster: Raster,
                       grad_rgb: Any, grad_alpha: Any = None, grad_depth: Any = None, *,
                       mode: str = DEFAULT_MODE, absgrad: bool = False) -> dict[str, Any]:
    """VJP of `rasterize` (with the same `mode`).

    Returns a dict with the gradients of "means2d", "conics", "colors", "opacities", "depths"
    (shaped like the splats' arrays) and "background" (3,), in the kind of the splats' inputs.
    With `absgrad`, also "means2d_abs" (N, 2): per splat, the sum over pixels of the absolute value
    of each pixel's term of dL/dmean2d, per component (AbsGS; module docstring). It is a statistic
    for densification, not a gradient, and the other outputs are the same bits with it or without.
    """
    mode_id(mode)
    width = A.check_int("width", width, minimum=1, maximum=MAX_SIDE)
    height = A.check_int("height", height, minimum=1, maximum=MAX_SIDE)
    a = s.inputs()
    return {k: a.out(v) for k, v in rasterize_backward_wp(
        a, s, width, height, background_array(a, background), tiles, raster, grad_rgb, grad_alpha,
        grad_depth, mode, absgrad).items()}


def rasterize_backward_wp(a: A.Inputs, s: Splats2D, width: int, height: int, bg: wp.array, tiles: Tiles,
                          raster: Raster, grad_rgb: Any, grad_alpha: Any, grad_depth: Any,
                          mode: str = DEFAULT_MODE, absgrad: bool = False) -> dict[str, wp.array]:
    """`rasterize_backward` with wp.array results."""
    if not isinstance(absgrad, bool):
        raise ValueError(f"absgrad: expected True or False, got {absgrad!r}")
    _check_tiles_mode(tiles, mode)
    n = s.n
    final_t = a.floats("raster.final_T", raster.final_T, (height, width))
    n_contrib = a.ints("raster.n_contrib", raster.n_contrib, (height, width))
    g_rgb = a.floats("grad_rgb", grad_rgb, (height, width, 3))
    g_a = a.floats_or_zeros("grad_alpha", grad_alpha, (height, width))
    g_d = a.floats_or_zeros("grad_depth", grad_depth, (height, width))
    n_tiles = tiles.tiles_x * tiles.tiles_y
    # Every entry's row and every tile's background row is written by its tile's thread.
    dev = a.device
    entry_grads = wp.empty((max(tiles.n_entries, 1), _GRAD_COLS), dtype=a.scalar, device=dev)
    tile_bg = wp.empty((n_tiles, 3), dtype=a.scalar, device=dev)
    state = wp.empty((height, width, 5), dtype=a.scalar, device=dev)
    a.launch(_raster_backward_tile_kernel, n_tiles,
             [tiles.packed, bg, tiles.sorted_gid, tiles.sorted_entry, tiles.ranges, width, height,
              tiles.tiles_x, a.s(ALPHA_MAX_OF[mode]), final_t, n_contrib, g_rgb, g_a, g_d, int(absgrad), state,
              entry_grads, tile_bg], min_chunk=1)
    out = {"means2d": a.zeros((n, 2)), "conics": a.zeros((n, 3)), "opacities": a.zeros(n), "colors": a.zeros((n, 3)),
           "depths": a.zeros(n)}
    g_abs = a.zeros((n, 2)) if absgrad else a.zeros((1, 2))  # written only with absgrad
    a.launch(_gather_entry_grads_kernel, n,
             [tiles.starts, tiles.counts, entry_grads, out["means2d"], out["conics"], out["opacities"],
              out["colors"], out["depths"], int(absgrad), g_abs], min_chunk=MIN_CHUNK)
    out["background"] = wp.array(tile_bg.numpy().sum(axis=0), dtype=a.scalar, device=a.device)
    if absgrad:
        out["means2d_abs"] = g_abs
    return out
