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
Every tile's backward runs on one thread and writes one gradient row per (tile, splat) pair,
which a second kernel sums per splat: no Warp atomic is atomic between concurrent CPU launches
(docs/warp.md), so with no shared accumulator the tiles run in parallel through
kernels.launch.launch_split, and the result does not depend on the thread count.

Loop order (speed only; every pixel's arithmetic and order are those above). On the CPU one
thread per tile walks the tile's list once, splats outside (front to back; back to front in the backward),
and for each splat only the pixels of its spans in the tile (kernels/splat/tiles.py: the box of
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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import fast_paths
from kernels import _arrays as A
from kernels.splat.modes import ALPHA_MAX_OF, DEFAULT_MODE, mode_id
from kernels.splat.rowblend import blend_row, rowblend_available
from kernels.splat.tiles import MAX_SIDE, TILE, TILE_PIXELS, Splats2D, Tiles, bin_tiles, pixel_span

wp.set_module_options({"enable_backward": False})

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = ALPHA_MAX_OF["3dgs"]  # the default mode's clamp; "gsplat" clamps at ALPHA_MAX_OF["gsplat"]
T_MIN = 1e-4
MIN_CHUNK = 1024
# Columns of the per-(tile, splat) gradient rows: mean2d (2), conic (3), opacity, colour (3), depth.
_GRAD_COLS = 10


@wp.kernel
def _raster_forward_kernel(
    packed: wp.array2d(dtype=Any), background: wp.array(dtype=Any),
    sorted_gid: wp.array(dtype=wp.int32), ranges: wp.array2d(dtype=wp.int32),
    width: int, height: int, tiles_x: int, alpha_max: Any, t_stop: Any, out_rgb: wp.array3d(dtype=Any),
    out_alpha: wp.array2d(dtype=Any), out_depth: wp.array2d(dtype=Any),
    final_T: wp.array2d(dtype=Any), n_contrib: wp.array2d(dtype=wp.int32), offset: int,
):
    # One thread per tile, splats in the outer loop (front to back), the pixels of each splat's span
    # in the inner one. Each pixel sees the same splats in the same order, with the same arithmetic,
    # as a loop over the tile's list per pixel; its running sums live in the output arrays
    # (final_T = T, out_rgb and out_depth the blended sums), and n_contrib < 0 marks a stopped pixel
    # (-1 - its count). The loops over splats, rows and pixels are while loops, and the pixel centre
    # px + 1/2 steps by one (exact: image sides < 2^23, MAX_SIDE): Warp's range() iterator costs
    # more per pixel than these.
    tile = wp.tid() + offset
    zero = packed.dtype(0.0)
    one = packed.dtype(1.0)
    half = packed.dtype(0.5)
    tile_y = tile / tiles_x
    x_lo = (tile - tile_y * tiles_x) * TILE
    y_lo = tile_y * TILE
    x_hi = wp.min(x_lo + TILE, width)
    y_hi = wp.min(y_lo + TILE, height)
    start = ranges[tile, 0]
    end = ranges[tile, 1]
    for py in range(y_lo, y_hi):
        for px in range(x_lo, x_hi):
            final_T[py, px] = one
            out_rgb[py, px, 0] = zero
            out_rgb[py, px, 1] = zero
            out_rgb[py, px, 2] = zero
            out_depth[py, px] = zero
            n_contrib[py, px] = start
    n_pix = (x_hi - x_lo) * (y_hi - y_lo)
    stopped = int(0)
    s = start - 1
    while s < end - 1:
        s += 1
        g = sorted_gid[s]
        u = packed[g, 0]
        v = packed[g, 1]
        qa = packed[g, 2]
        qb = packed[g, 3]
        qc = packed[g, 4]
        o = packed[g, 5]
        # packed[g, 6] = -ln(255 o): below it alpha < 1/255, so exp() is skipped.
        thr = packed[g, 6]
        z = packed[g, 7]
        c0 = packed[g, 8]
        c1 = packed[g, 9]
        c2 = packed[g, 10]
        # The splat's rows inside its widened 1/255 ellipse in this tile, and the columns of any of
        # those rows (tiles.py: pixel_span).
        row0, row1, col0, col1 = pixel_span(packed, g, x_lo, x_hi, y_lo, y_hi)
        py = row0 - 1
        while py < row1 - 1:
            py += 1
            pyf = packed.dtype(float(py)) + half
            px = col0 - 1
            pxf = packed.dtype(float(px)) + half
            while px < col1 - 1:
                px += 1
                pxf += one
                nc = n_contrib[py, px]
                if nc < 0:
                    continue
                dx = u - pxf
                dy = v - pyf
                power = -half * (qa * dx * dx + qc * dy * dy) - qb * dx * dy
                if power > zero or power < thr:
                    continue
                alpha = wp.min(alpha_max, o * wp.exp(power))
                if alpha < packed.dtype(ALPHA_MIN):
                    continue
                tr = final_T[py, px]
                next_t = tr * (one - alpha)
                if next_t < t_stop:
                    n_contrib[py, px] = -1 - nc
                    stopped += 1
                    continue
                wgt = alpha * tr
                out_rgb[py, px, 0] = out_rgb[py, px, 0] + wgt * c0
                out_rgb[py, px, 1] = out_rgb[py, px, 1] + wgt * c1
                out_rgb[py, px, 2] = out_rgb[py, px, 2] + wgt * c2
                out_depth[py, px] = out_depth[py, px] + wgt * z
                final_T[py, px] = next_t
                n_contrib[py, px] = s + 1
        if stopped == n_pix:
            break
    for py in range(y_lo, y_hi):
        for px in range(x_lo, x_hi):
            tr = final_T[py, px]
            out_rgb[py, px, 0] = out_rgb[py, px, 0] + tr * background[0]
            out_rgb[py, px, 1] = out_rgb[py, px, 1] + tr * background[1]
            out_rgb[py, px, 2] = out_rgb[py, px, 2] + tr * background[2]
            out_alpha[py, px] = one - tr
            nc = n_contrib[py, px]
            if nc < 0:
                n_contrib[py, px] = -1 - nc


@wp.kernel
def _raster_forward_rows_kernel(
    packed: wp.array2d(dtype=wp.float32), background: wp.array(dtype=wp.float32),
    sorted_gid: wp.array(dtype=wp.int32), ranges: wp.array2d(dtype=wp.int32),
    width: int, height: int, tiles_x: int, alpha_max: wp.float32, t_stop: wp.float32,
    out_rgb: wp.array3d(dtype=wp.float32), out_alpha: wp.array2d(dtype=wp.float32),
    out_depth: wp.array2d(dtype=wp.float32), final_T: wp.array2d(dtype=wp.float32),
    n_contrib: wp.array2d(dtype=wp.int32), state: wp.array2d(dtype=wp.float32), nc: wp.array2d(dtype=wp.int32),
    live: wp.array2d(dtype=wp.int32), offset: int,
):
    # _raster_forward_kernel for float32 on a CPU with AVX2 and FMA: the same walk over the tile's
    # splats, each splat's span rows blended 16 pixels at once (kernels/splat/rowblend.py, the same
    # bits); the tile's per-pixel state lives in `state` / `nc` until the end, and `live` holds
    # each row's running pixels, so stopped pixels cost nothing.
    tile = wp.tid() + offset
    half = wp.float32(0.5)
    one = wp.float32(1.0)
    tile_y = tile / tiles_x
    x_lo = (tile - tile_y * tiles_x) * TILE
    y_lo = tile_y * TILE
    x_hi = wp.min(x_lo + TILE, width)
    y_hi = wp.min(y_lo + TILE, height)
    start = ranges[tile, 0]
    end = ranges[tile, 1]
    for k in range(TILE_PIXELS):
        state[tile, k] = one
        state[tile, TILE_PIXELS + k] = wp.float32(0.0)
        state[tile, 2 * TILE_PIXELS + k] = wp.float32(0.0)
        state[tile, 3 * TILE_PIXELS + k] = wp.float32(0.0)
        state[tile, 4 * TILE_PIXELS + k] = wp.float32(0.0)
        nc[tile, k] = start
    row_bits = (int(1) << (x_hi - x_lo)) - 1
    for r in range(TILE):
        live[tile, r] = 0
        if r < y_hi - y_lo:
            live[tile, r] = row_bits
    n_pix = (x_hi - x_lo) * (y_hi - y_lo)
    stopped = int(0)
    s = start - 1
    while s < end - 1:
        s += 1
        g = sorted_gid[s]
        row0, row1, col0, col1 = pixel_span(packed, g, x_lo, x_hi, y_lo, y_hi)
        if col1 <= col0 or row1 <= row0:
            continue
        cols = ((int(1) << (col1 - col0)) - 1) << (col0 - x_lo)
        u = packed[g, 0]
        v = packed[g, 1]
        qa = packed[g, 2]
        qb = packed[g, 3]
        qc = packed[g, 4]
        o = packed[g, 5]
        thr = packed[g, 6]
        z = packed[g, 7]
        c0 = packed[g, 8]
        c1 = packed[g, 9]
        c2 = packed[g, 10]
        py = row0 - 1
        while py < row1 - 1:
            py += 1
            dy = v - (wp.float32(float(py)) + half)
            stopped += blend_row(state, nc, live, tile, py - y_lo, cols, x_lo, dy, u, qa, qb, qc, o, thr, z, c0, c1,
                                 c2, alpha_max, t_stop, s + 1)
        if stopped == n_pix:
            break
    for py in range(y_lo, y_hi):
        for px in range(x_lo, x_hi):
            k = (py - y_lo) * TILE + (px - x_lo)
            tr = state[tile, k]
            out_rgb[py, px, 0] = state[tile, TILE_PIXELS + k] + tr * background[0]
            out_rgb[py, px, 1] = state[tile, 2 * TILE_PIXELS + k] + tr * background[1]
            out_rgb[py, px, 2] = state[tile, 3 * TILE_PIXELS + k] + tr * background[2]
            out_depth[py, px] = state[tile, 4 * TILE_PIXELS + k]
            out_alpha[py, px] = one - tr
            final_T[py, px] = tr
            n_contrib[py, px] = nc[tile, k]


@wp.kernel
def _raster_forward_pixel_kernel(
    packed: wp.array2d(dtype=Any), background: wp.array(dtype=Any),
    sorted_gid: wp.array(dtype=wp.int32), ranges: wp.array2d(dtype=wp.int32), width: int, height: int, tiles_x: int,
    alpha_max: Any, t_stop: Any, out_rgb: wp.array3d(dtype=Any), out_alpha: wp.array2d(dtype=Any),
    out_depth: wp.array2d(dtype=Any), final_T: wp.array2d(dtype=Any), n_contrib: wp.array2d(dtype=wp.int32),
    offset: int,
):
    # The same forward with one thread per pixel walking its tile's whole list: the layout for CUDA,
    # whose threads are many and cheap (the CPU runs _raster_forward_kernel).
    t = wp.tid() + offset
    tile = t / TILE_PIXELS
    local = t - tile * TILE_PIXELS
    tile_y = tile / tiles_x
    px = (tile - tile_y * tiles_x) * TILE + local % TILE
    py = tile_y * TILE + local / TILE
    if px >= width or py >= height:
        return
    zero = packed.dtype(0.0)
    one = packed.dtype(1.0)
    half = packed.dtype(0.5)
    pxf = packed.dtype(float(px)) + half
    pyf = packed.dtype(float(py)) + half
    start = ranges[tile, 0]
    end = ranges[tile, 1]
    tr = one
    cr = zero
    cg = zero
    cb = zero
    cd = zero
    last = start
    for s in range(start, end):
        g = sorted_gid[s]
        dx = packed[g, 0] - pxf
        dy = packed[g, 1] - pyf
        power = -half * (packed[g, 2] * dx * dx + packed[g, 4] * dy * dy) - packed[g, 3] * dx * dy
        if power > zero or power < packed[g, 6]:
            continue
        alpha = wp.min(alpha_max, packed[g, 5] * wp.exp(power))
        if alpha < packed.dtype(ALPHA_MIN):
            continue
        next_t = tr * (one - alpha)
        if next_t < t_stop:
            break
        wgt = alpha * tr
        cr += wgt * packed[g, 8]
        cg += wgt * packed[g, 9]
        cb += wgt * packed[g, 10]
        cd += wgt * packed[g, 7]
        tr = next_t
        last = s + 1
    out_rgb[py, px, 0] = cr + tr * background[0]
    out_rgb[py, px, 1] = cg + tr * background[1]
    out_rgb[py, px, 2] = cb + tr * background[2]
    out_alpha[py, px] = one - tr
    out_depth[py, px] = cd
    final_T[py, px] = tr
    n_contrib[py, px] = last


@wp.kernel
def _raster_backward_tile_kernel(
    packed: wp.array2d(dtype=Any), background: wp.array(dtype=Any),
    sorted_gid: wp.array(dtype=wp.int32), sorted_entry: wp.array(dtype=wp.int32), ranges: wp.array2d(dtype=wp.int32),
    width: int, height: int, tiles_x: int, alpha_max: Any, final_T: wp.array2d(dtype=Any),
    n_contrib: wp.array2d(dtype=wp.int32), g_rgb: wp.array3d(dtype=Any), g_alpha: wp.array2d(dtype=Any),
    g_depth: wp.array2d(dtype=Any), state: wp.array3d(dtype=Any),
    entry_grads: wp.array2d(dtype=Any), tile_bg_grads: wp.array2d(dtype=Any), offset: int,
):
    # One thread per tile: it alone writes the rows of its (tile, splat) entries and its background
    # row. Splats in the outer loop, back to front, the pixels of each splat's spans inside: each
    # pixel sees the splats it blended in the same (reverse) order and arithmetic as a walk down its
    # own list, with its running T and colour behind in `state` (T, S_r, S_g, S_b, S_depth); an
    # entry's row sums its pixels' terms in the same (row-major) pixel order, then is written once.
    tile = wp.tid() + offset
    zero = packed.dtype(0.0)
    one = packed.dtype(1.0)
    half = packed.dtype(0.5)
    tile_y = tile / tiles_x
    x_lo = (tile - tile_y * tiles_x) * TILE
    y_lo = tile_y * TILE
    x_hi = wp.min(x_lo + TILE, width)
    y_hi = wp.min(y_lo + TILE, height)
    start = ranges[tile, 0]
    end = ranges[tile, 1]
    bg0 = background[0]
    bg1 = background[1]
    bg2 = background[2]
    gbg0 = zero
    gbg1 = zero
    gbg2 = zero
    last = start
    for py in range(y_lo, y_hi):
        for px in range(x_lo, x_hi):
            tf = final_T[py, px]
            gbg0 += tf * g_rgb[py, px, 0]
            gbg1 += tf * g_rgb[py, px, 1]
            gbg2 += tf * g_rgb[py, px, 2]
            state[py, px, 0] = tf
            state[py, px, 1] = zero
            state[py, px, 2] = zero
            state[py, px, 3] = zero
            state[py, px, 4] = zero
            last = wp.max(last, n_contrib[py, px])
    tile_bg_grads[tile, 0] = gbg0
    tile_bg_grads[tile, 1] = gbg1
    tile_bg_grads[tile, 2] = gbg2
    for s in range(last, end):  # entries no pixel reached
        row = sorted_entry[s]
        for j in range(_GRAD_COLS):
            entry_grads[row, j] = zero
    s = last - 1
    while s >= start:
        g = sorted_gid[s]
        u = packed[g, 0]
        v = packed[g, 1]
        qa = packed[g, 2]
        qb = packed[g, 3]
        qc = packed[g, 4]
        o = packed[g, 5]
        thr = packed[g, 6]
        z = packed[g, 7]
        c0 = packed[g, 8]
        c1 = packed[g, 9]
        c2 = packed[g, 10]
        a0 = zero
        a1 = zero
        a2 = zero
        a3 = zero
        a4 = zero
        a5 = zero
        a6 = zero
        a7 = zero
        a8 = zero
        a9 = zero
        row0, row1, col0, col1 = pixel_span(packed, g, x_lo, x_hi, y_lo, y_hi)
        py = row0 - 1
        while py < row1 - 1:  # while loops and a stepped pixel centre, as in the forward
            py += 1
            pyf = packed.dtype(float(py)) + half
            px = col0 - 1
            pxf = packed.dtype(float(px)) + half
            while px < col1 - 1:
                px += 1
                pxf += one
                if s >= n_contrib[py, px]:
                    continue
                dx = u - pxf
                dy = v - pyf
                power = -half * (qa * dx * dx + qc * dy * dy) - qb * dx * dy
                if power <= zero and power >= thr:
                    gauss = wp.exp(power)
                    raw = o * gauss
                    alpha = wp.min(alpha_max, raw)
                    if alpha >= packed.dtype(ALPHA_MIN):
                        gr = g_rgb[py, px, 0]
                        gg = g_rgb[py, px, 1]
                        gb = g_rgb[py, px, 2]
                        gd = g_depth[py, px]
                        tf = final_T[py, px]
                        bg_dot = bg0 * gr + bg1 * gg + bg2 * gb
                        tr = state[py, px, 0] / (one - alpha)
                        sr = state[py, px, 1]
                        sg = state[py, px, 2]
                        sb = state[py, px, 3]
                        sd = state[py, px, 4]
                        wgt = alpha * tr
                        a6 += wgt * gr
                        a7 += wgt * gg
                        a8 += wgt * gb
                        a9 += wgt * gd
                        g_a = tr * ((c0 - sr) * gr + (c1 - sg) * gg + (c2 - sb) * gb + (z - sd) * gd)
                        g_a += (g_alpha[py, px] - bg_dot) * tf / (one - alpha)
                        state[py, px, 0] = tr
                        state[py, px, 1] = alpha * c0 + (one - alpha) * sr
                        state[py, px, 2] = alpha * c1 + (one - alpha) * sg
                        state[py, px, 3] = alpha * c2 + (one - alpha) * sb
                        state[py, px, 4] = alpha * z + (one - alpha) * sd
                        if raw <= alpha_max:
                            a5 += gauss * g_a
                            g_p = alpha * g_a
                            a0 += -(qa * dx + qb * dy) * g_p
                            a1 += -(qb * dx + qc * dy) * g_p
                            a2 += -half * dx * dx * g_p
                            a3 += -dx * dy * g_p
                            a4 += -half * dy * dy * g_p
        row = sorted_entry[s]
        entry_grads[row, 0] = a0
        entry_grads[row, 1] = a1
        entry_grads[row, 2] = a2
        entry_grads[row, 3] = a3
        entry_grads[row, 4] = a4
        entry_grads[row, 5] = a5
        entry_grads[row, 6] = a6
        entry_grads[row, 7] = a7
        entry_grads[row, 8] = a8
        entry_grads[row, 9] = a9
        s -= 1


@wp.kernel
def _gather_entry_grads_kernel(
    starts: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32), entry_grads: wp.array2d(dtype=Any),
    g_means2d: wp.array2d(dtype=Any), g_conics: wp.array2d(dtype=Any), g_opacities: wp.array(dtype=Any),
    g_colors: wp.array2d(dtype=Any), g_depths: wp.array(dtype=Any), offset: int,
):
    i = wp.tid() + offset
    acc = wp.vector(length=10, dtype=entry_grads.dtype)
    e0 = starts[i]
    for e in range(e0, e0 + counts[i]):
        for j in range(_GRAD_COLS):
            acc[j] += entry_grads[e, j]
    g_means2d[i, 0] = acc[0]
    g_means2d[i, 1] = acc[1]
    g_conics[i, 0] = acc[2]
    g_conics[i, 1] = acc[3]
    g_conics[i, 2] = acc[4]
    g_opacities[i] = acc[5]
    g_colors[i, 0] = acc[6]
    g_colors[i, 1] = acc[7]
    g_colors[i, 2] = acc[8]
    g_depths[i] = acc[9]


for _k in (_raster_forward_kernel, _raster_forward_pixel_kernel, _raster_backward_tile_kernel,
           _gather_entry_grads_kernel):
    A.declare_float_overloads(_k)


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
                       mode: str = DEFAULT_MODE) -> dict[str, Any]:
    """VJP of `rasterize` (with the same `mode`).

    Returns a dict with the gradients of "means2d", "conics", "colors", "opacities", "depths"
    (shaped like the splats' arrays) and "background" (3,), in the kind of the splats' inputs.
    """
    mode_id(mode)
    width = A.check_int("width", width, minimum=1, maximum=MAX_SIDE)
    height = A.check_int("height", height, minimum=1, maximum=MAX_SIDE)
    a = s.inputs()
    return {k: a.out(v) for k, v in rasterize_backward_wp(
        a, s, width, height, background_array(a, background), tiles, raster, grad_rgb, grad_alpha,
        grad_depth, mode).items()}


def rasterize_backward_wp(a: A.Inputs, s: Splats2D, width: int, height: int, bg: wp.array, tiles: Tiles,
                          raster: Raster, grad_rgb: Any, grad_alpha: Any, grad_depth: Any,
                          mode: str = DEFAULT_MODE) -> dict[str, wp.array]:
    """`rasterize_backward` with wp.array results."""
    _check_tiles_mode(tiles, mode)
    n = s.n
    final_t = a.floats("raster.final_T", raster.final_T, (height, width))
    n_contrib = a.ints("raster.n_contrib", raster.n_contrib, (height, width))
    g_rgb = a.floats("grad_rgb", grad_rgb, (height, width, 3))
    g_a = a.zeros((height, width)) if grad_alpha is None else a.floats("grad_alpha", grad_alpha, (height, width))
    g_d = a.zeros((height, width)) if grad_depth is None else a.floats("grad_depth", grad_depth, (height, width))
    n_tiles = tiles.tiles_x * tiles.tiles_y
    # Every entry's row and every tile's background row is written by its tile's thread.
    dev = a.device
    entry_grads = wp.empty((max(tiles.n_entries, 1), _GRAD_COLS), dtype=a.scalar, device=dev)
    tile_bg = wp.empty((n_tiles, 3), dtype=a.scalar, device=dev)
    state = wp.empty((height, width, 5), dtype=a.scalar, device=dev)
    a.launch(_raster_backward_tile_kernel, n_tiles,
             [tiles.packed, bg, tiles.sorted_gid, tiles.sorted_entry, tiles.ranges, width, height,
              tiles.tiles_x, a.s(ALPHA_MAX_OF[mode]), final_t, n_contrib, g_rgb, g_a, g_d, state, entry_grads, tile_bg],
             min_chunk=1)
    out = {"means2d": a.zeros((n, 2)), "conics": a.zeros((n, 3)), "opacities": a.zeros(n), "colors": a.zeros((n, 3)),
           "depths": a.zeros(n)}
    a.launch(_gather_entry_grads_kernel, n,
             [tiles.starts, tiles.counts, entry_grads, out["means2d"], out["conics"], out["opacities"],
              out["colors"], out["depths"]], min_chunk=MIN_CHUNK)
    out["background"] = wp.array(tile_bg.numpy().sum(axis=0), dtype=a.scalar, device=a.device)
    return out
