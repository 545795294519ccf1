"""The rasteriser's Warp kernels: depth-sorted splats blended per tile, and the per-tile reverse pass.

Per pixel p (centre (i + 0.5, j + 0.5)), front to back over its tile's list (kernels.splat.raster
states the modes and the loop order; kernels.splat.tiles the lists and packed rows):

    G_i = exp(-1/2 d^T Q_i d),  d = mean2d_i - p;  alpha_i = min(a_max, o_i G_i), skipped below 1/255
    T_{i+1} = T_i (1 - alpha_i), stopping before the splat that would bring T below the mode's bound
    rgb = sum_i colour_i alpha_i T_i + T_final b,  alpha = 1 - T_final,  depth = sum_i z_i alpha_i T_i

The forward kernels (same arithmetic, same bits): `_raster_forward_kernel`, one CPU thread per tile
over each splat's span box (kernels.splat.spans.pixel_span); `_raster_forward_rows_kernel`, the
same with each span row blended 16 pixels at once (kernels.splat.rowblend, float32 on CPUs with
AVX2 and FMA); `_raster_forward_pixel_kernel`, CUDA's thread per pixel over the whole list.

Backward, per pixel back to front from the stored T_final (T_i = T_{i+1} / (1 - alpha_i)), with S_i
the colour composited behind splat i:

    drgb/dalpha_i = T_i (c_i - S_i) - T_final b / (1 - alpha_i),  dalpha_out/dalpha_i = T_final / (1 - alpha_i),
    dalpha/do = G,  dalpha/dQ = -alpha/2 (dx^2, 2 dx dy, dy^2),  dalpha/dmean2d = -alpha Q d

(zero where the a_max clamp is active: the gradient is one-sided there; depth like a colour channel
with background 0). With the `absgrad` flag the reverse pass also sums, per splat, the absolute values
|dL/dmean2d|_p| of every pixel's term of the mean2d gradient, per component (AbsGS; kernels.splat.raster). `_raster_backward_tile_kernel` runs a tile per thread and writes one gradient
row of _GRAD_COLS per (tile, splat) pair; `_gather_entry_grads_kernel` sums each splat's rows (no
shared accumulator, so the tiles run in parallel and the result does not depend on the thread count).
"""

from __future__ import annotations

from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.splat.modes import ALPHA_MAX_OF
from kernels.splat.rowblend import blend_row
from kernels.splat.spans import pixel_span
from kernels.splat.tiles import TILE, TILE_PIXELS

wp.set_module_options({"enable_backward": False})

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = ALPHA_MAX_OF["3dgs"]  # the default mode's clamp; "gsplat" clamps at ALPHA_MAX_OF["gsplat"]
T_MIN = 1e-4
# Columns of the per-(tile, splat) gradient rows: mean2d (2), conic (3), opacity, colour (3), depth, and
# (zero unless the backward is asked for them) the sums of |per-pixel dL/dmean2d| (2).
_GRAD_COLS = 12


@wp.func
def tile_box(tile: int, ranges: wp.array2d(dtype=wp.int32), tiles_x: int, width: int, height: int):
    """The pixel box [x_lo, x_hi) x [y_lo, y_hi) of a tile (row-major tiles, cut by the image's edges) and
    its range [start, end) of the sorted list."""
    tile_y = tile / tiles_x
    x_lo = (tile - tile_y * tiles_x) * TILE
    y_lo = tile_y * TILE
    return x_lo, y_lo, wp.min(x_lo + TILE, width), wp.min(y_lo + TILE, height), ranges[tile, 0], ranges[tile, 1]


@wp.func
def packed_splat(packed: wp.array2d(dtype=Any), g: int):
    """Splat g's packed row (kernels.splat.tiles): mean (u, v), conic (qa, qb, qc), opacity o, the exponent
    threshold thr = -ln(255 o) (below it alpha < 1/255, so exp() is skipped), depth z, colour (c0, c1, c2)."""
    return (packed[g, 0], packed[g, 1], packed[g, 2], packed[g, 3], packed[g, 4], packed[g, 5], packed[g, 6],
            packed[g, 7], packed[g, 8], packed[g, 9], packed[g, 10])


@wp.func
def gauss_power(qa: Any, qb: Any, qc: Any, dx: Any, dy: Any):
    """The exponent -1/2 d^T Q d of a splat's Gaussian at offset d = (dx, dy), conic Q = [[qa, qb], [qb, qc]]."""
    return -type(dx)(0.5) * (qa * dx * dx + qc * dy * dy) - qb * dx * dy


@wp.func
def packed_alpha(packed: wp.array2d(dtype=Any), g: int, pxf: Any, pyf: Any, alpha_max: Any):
    """alpha = min(a_max, o G) of splat g's packed row at the pixel centre (pxf, pyf), or 0 where its
    exponent is positive or below thr (alpha < 1/255 there, so exp() is skipped, and so is the load of
    o); the caller skips alpha < 1/255."""
    power = gauss_power(packed[g, 2], packed[g, 3], packed[g, 4], packed[g, 0] - pxf, packed[g, 1] - pyf)
    if power > type(pxf)(0.0) or power < packed[g, 6]:
        return type(pxf)(0.0)
    return wp.min(alpha_max, packed[g, 5] * wp.exp(power))


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
    x_lo, y_lo, x_hi, y_hi, start, end = tile_box(tile, ranges, tiles_x, width, height)
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
        u, v, qa, qb, qc, o, thr, z, c0, c1, c2 = packed_splat(packed, g)
        # The splat's rows inside its widened 1/255 ellipse in this tile, and the columns of any of
        # those rows (spans.py: pixel_span).
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
                power = gauss_power(qa, qb, qc, dx, dy)
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
    x_lo, y_lo, x_hi, y_hi, start, end = tile_box(tile, ranges, tiles_x, width, height)
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
        u, v, qa, qb, qc, o, thr, z, c0, c1, c2 = packed_splat(packed, g)
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


@wp.func
def tile_pixel(t: int, tiles_x: int, width: int, height: int, like: Any):
    """(tile, px, py, the pixel centre px + 1/2, py + 1/2 in like's type, whether the pixel is in the
    image) of thread t when threads run tile by tile, TILE_PIXELS per tile, row-major within the tile
    (the per-pixel kernels' layout)."""
    tile = t / TILE_PIXELS
    local = t - tile * TILE_PIXELS
    tile_y = tile / tiles_x
    px = (tile - tile_y * tiles_x) * TILE + local % TILE
    py = tile_y * TILE + local / TILE
    half = type(like)(0.5)
    return tile, px, py, type(like)(float(px)) + half, type(like)(float(py)) + half, px < width and py < height


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
    tile, px, py, pxf, pyf, inside = tile_pixel(wp.tid() + offset, tiles_x, width, height, alpha_max)
    if not inside:
        return
    zero = packed.dtype(0.0)
    one = packed.dtype(1.0)
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
        alpha = packed_alpha(packed, g, pxf, pyf, alpha_max)
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
    g_depth: wp.array2d(dtype=Any), absgrad: int, state: wp.array3d(dtype=Any),
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
    x_lo, y_lo, x_hi, y_hi, start, end = tile_box(tile, ranges, tiles_x, width, height)
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
        u, v, qa, qb, qc, o, thr, z, c0, c1, c2 = packed_splat(packed, g)
        grad = wp.vector(length=_GRAD_COLS, dtype=packed.dtype)  # this entry's row, zeros
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
                power = gauss_power(qa, qb, qc, dx, dy)
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
                        grad[6] += wgt * gr
                        grad[7] += wgt * gg
                        grad[8] += wgt * gb
                        grad[9] += wgt * gd
                        g_a = tr * ((c0 - sr) * gr + (c1 - sg) * gg + (c2 - sb) * gb + (z - sd) * gd)
                        g_a += (g_alpha[py, px] - bg_dot) * tf / (one - alpha)
                        state[py, px, 0] = tr
                        state[py, px, 1] = alpha * c0 + (one - alpha) * sr
                        state[py, px, 2] = alpha * c1 + (one - alpha) * sg
                        state[py, px, 3] = alpha * c2 + (one - alpha) * sb
                        state[py, px, 4] = alpha * z + (one - alpha) * sd
                        if raw <= alpha_max:
                            grad[5] += gauss * g_a
                            g_p = alpha * g_a
                            g_u = -(qa * dx + qb * dy) * g_p
                            g_v = -(qb * dx + qc * dy) * g_p
                            grad[0] += g_u
                            grad[1] += g_v
                            if absgrad != 0:  # AbsGS: this pixel's contribution, per component, in absolute value
                                grad[10] += wp.abs(g_u)
                                grad[11] += wp.abs(g_v)
                            grad[2] += -half * dx * dx * g_p
                            grad[3] += -dx * dy * g_p
                            grad[4] += -half * dy * dy * g_p
        row = sorted_entry[s]
        for j in range(_GRAD_COLS):
            entry_grads[row, j] = grad[j]
        s -= 1


@wp.kernel
def _gather_entry_grads_kernel(
    starts: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32), entry_grads: wp.array2d(dtype=Any),
    g_means2d: wp.array2d(dtype=Any), g_conics: wp.array2d(dtype=Any), g_opacities: wp.array(dtype=Any),
    g_colors: wp.array2d(dtype=Any), g_depths: wp.array(dtype=Any), absgrad: int,
    g_means2d_abs: wp.array2d(dtype=Any), offset: int,
):
    i = wp.tid() + offset
    acc = wp.vector(length=_GRAD_COLS, dtype=entry_grads.dtype)
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
    if absgrad != 0:
        g_means2d_abs[i, 0] = acc[10]
        g_means2d_abs[i, 1] = acc[11]


for _k in (_raster_forward_kernel, _raster_forward_pixel_kernel, _raster_backward_tile_kernel,
           _gather_entry_grads_kernel):
    A.declare_float_overloads(_k)
