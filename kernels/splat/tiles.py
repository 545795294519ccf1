"""Tile binning: which splats each 16 x 16 pixel tile blends, front to back; and each splat's spans.

As in 3DGS (Kerbl et al. 2023), a visible splat belongs to the tiles its square mean2d +- radius
meets, by the tile rule of the mode (kernels/splat/modes.py): "3dgs" 3DGS's getRect,
floor((u - 1/2 - r)/16) <= tx < floor((u - 1/2 + r + 15)/16), "gsplat" gsplat's
floor((u - r)/16) <= tx < ceil((u + r)/16) (rows likewise, both clamped to the image's tiles).
Of these it is listed only in those that also meet the bounding box of the ellipse
d^T Q d <= 2 ln(255 o) (half-sizes sqrt(2 ln(255 o) Q11 / det Q) and sqrt(2 ln(255 o) Q00 / det Q)),
outside which alpha < 1/255 and the rasteriser skips it anyway: the image is the same, and splats
with 255 o < 1 are never listed.

The spans (kernels.splat.spans), which the rasteriser visits instead of every pixel of a tile: the
pixels (centres (px + 1/2, py + 1/2)) inside the ellipse d^T Q d <= k, d = mean2d - p, k = 2 ln(255 o)
widened by a rounding margin, outside which the rasteriser's own test skips the splat. Pixel row py (dy = v - py - 1/2, |dy| <= hy) holds the columns
px in [(u - 1/2) + S dy - sqrt(B - C dy^2), (u - 1/2) + S dy + sqrt(B - C dy^2)],
S = Q01 / Q00, B = k / Q00, C = det Q / Q00^2, hy = sqrt(B / C); spans.band_columns bounds the
columns over a band of rows in closed form. A conic too elongated for the margin's bound
(1 - |Q01| / sqrt(Q00 Q11) < 1e-3) has no spans: the rasteriser visits every pixel of its tiles.
(Listing a splat only in the tiles its spans reach was tried: it cut the entries by 14-18% but
cost more in the binning than it saved, as the rasteriser passes an unreached entry in a few ns.)
Each splat's packed row (PACKED_COLS: mean, conic, opacity, -ln(255 o), depth, colour, spans) is
all the rasteriser reads of it: one 64-byte cache line in float32.

The (tile, splat) pairs are listed sorted by (tile, depth rank): the splats are ordered by depth
(a stable radix sort, culled splats last), each splat's pairs are emitted as one slice
[starts[i], starts[i] + counts[i]) (its tiles in row-major order), the slices laid out in depth
order, and a stable sort by tile alone then lists every tile's splats front to back; per-tile
ranges [start, end) index the sorted list, and each sorted entry keeps its emitted index (the
backward's gradient row) and its splat. On the CPU the sort is a counting sort by tile straight
from the splats' tile boxes, without writing the emitted entries (_counting_sort: the boxes gathered
into depth order, per-chunk histograms, a scan, a scatter; up to SERIAL_SORT_MAX entries, where it
would run one chunk, _serial_sort does the same in one single-threaded kernel, without the host
scans); on CUDA the emitted entries' radix sort
(wp.utils.radix_sort_pairs, ceil(log2 tiles) bits); all give the same lists. Every kernel writes
only its own slots (the emit kernel splat i's slice, a sort chunk its histogram row and slots),
so all run split over CPU threads.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import fast_paths
from kernels import _arrays as A
from kernels.splat.modes import DEFAULT_MODE, mode_id
from kernels.splat.spans import UNIT_ROUNDOFF, _span_widening

wp.set_module_options({"enable_backward": False})

TILE = 16
TILE_PIXELS = TILE * TILE
# The largest image side: pixel centres px + 1/2 are exact in float32 below 2^23 (the rasteriser steps
# them by one).
MAX_SIDE = 1 << 23
MIN_CHUNK = 1024
# Columns of a splat's packed row, all the rasteriser reads of it (16 float32 = one 64-byte cache
# line): 0-1 mean2d u, v; 2-4 conic Q00, Q01, Q11; 5 opacity o; 6 -ln(255 o); 7 depth; 8-10 colour;
# 11-15 its spans S, B, C, hy, dy* (hy < 0: no spans; spans.band_columns).
PACKED_COLS = 16
# The CPU's counting sort by tile: at most SORT_CHUNKS chunks of at least SORT_CHUNK_MIN entries.
SORT_CHUNKS = 32
SORT_CHUNK_MIN = 1 << 16
# Up to this many entries (where the chunked counting sort would run one chunk anyway) the CPU lists
# them with one serial kernel (_serial_sort), without the emitted entries and the host scans.
SERIAL_SORT_MAX = 2 * SORT_CHUNK_MIN


@wp.kernel
def _tile_counts_kernel(
    means2d: wp.array2d(dtype=Any), conics: wp.array2d(dtype=Any), colors: wp.array2d(dtype=Any),
    opacities: wp.array(dtype=Any), depths: wp.array(dtype=Any), radii: wp.array(dtype=wp.int32), tiles_x: int,
    tiles_y: int, mode: int, unit: wp.float64, rects: wp.array2d(dtype=wp.int32),
    counts: wp.array(dtype=wp.int32), packed: wp.array2d(dtype=Any), depth_keys: wp.array(dtype=Any),
    order: wp.array(dtype=wp.int32), offset: int,
):
    i = wp.tid() + offset
    r = radii[i]
    # The keys of the depth sort: culled splats sort last (their rank is never used).
    depth_keys[i] = depths[i]
    if r <= 0:
        depth_keys[i] = depths.dtype(1e30)
    order[i] = i
    counts[i] = 0
    for j in range(4):
        rects[i, j] = 0
    for j in range(PACKED_COLS):  # every row fully written: the arrays need no zero fill
        packed[i, j] = means2d.dtype(0.0)
    packed[i, 14] = means2d.dtype(-1.0)
    o = opacities[i]
    # The splat's alpha reaches 1/255 only inside the ellipse d^T Q d <= k2 (and never if 255 o < 1).
    if r <= 0 or o * means2d.dtype(255.0) < means2d.dtype(1.0):
        return
    qa = conics[i, 0]
    qb = conics[i, 1]
    qc = conics[i, 2]
    k2 = means2d.dtype(2.0) * wp.log(o * means2d.dtype(255.0))
    det = qa * qc - qb * qb
    rf = means2d.dtype(float(r))
    t = means2d.dtype(float(TILE))
    # The ellipse's box, capped where it can no longer cut the mode's square: at r ("gsplat", whose
    # square rule is the same floor / ceil) or r + 16 ("3dgs", whose getRect reaches 15 px further).
    cap = rf
    if mode == 0:
        cap = rf + t
    ext_x = cap
    ext_y = cap
    if det > means2d.dtype(0.0):  # else a conic rounded to 0 (float32, huge splat): the radius alone
        ext_x = wp.min(cap, wp.sqrt(k2 * qc / det))
        ext_y = wp.min(cap, wp.sqrt(k2 * qa / det))
    u = means2d[i, 0]
    v = means2d[i, 1]
    x0 = wp.clamp(int(wp.floor((u - ext_x) / t)), 0, tiles_x)
    x1 = wp.clamp(int(wp.ceil((u + ext_x) / t)), 0, tiles_x)
    y0 = wp.clamp(int(wp.floor((v - ext_y) / t)), 0, tiles_y)
    y1 = wp.clamp(int(wp.ceil((v + ext_y) / t)), 0, tiles_y)
    if mode == 0:
        # 3DGS's getRect of the square (pixel centres at integers there: u - 1/2), cut as above.
        half = means2d.dtype(0.5)
        reach = means2d.dtype(float(TILE - 1)) - half
        x0 = wp.max(x0, wp.clamp(int(wp.floor((u - half - rf) / t)), 0, tiles_x))
        x1 = wp.max(x0, wp.min(x1, wp.clamp(int(wp.floor((u + rf + reach) / t)), 0, tiles_x)))
        y0 = wp.max(y0, wp.clamp(int(wp.floor((v - half - rf) / t)), 0, tiles_y))
        y1 = wp.max(y0, wp.min(y1, wp.clamp(int(wp.floor((v + rf + reach) / t)), 0, tiles_y)))
    rects[i, 0] = x0
    rects[i, 1] = x1
    rects[i, 2] = y0
    rects[i, 3] = y1
    thr = -means2d.dtype(0.5) * k2
    packed[i, 0] = u
    packed[i, 1] = v
    packed[i, 2] = qa
    packed[i, 3] = qb
    packed[i, 4] = qc
    packed[i, 5] = o
    packed[i, 6] = thr
    packed[i, 7] = depths[i]
    packed[i, 8] = colors[i, 0]
    packed[i, 9] = colors[i, 1]
    packed[i, 10] = colors[i, 2]
    # The spans: rows and columns inside the ellipse d^T Q d <= k, the rasteriser's threshold
    # -2 thr widened for rounding (_span_widening); computed in float64 from the stored values.
    qa64 = wp.float64(qa)
    qb64 = wp.float64(qb)
    qc64 = wp.float64(qc)
    grow = _span_widening(qa64, qb64, qc64, unit)
    if grow > wp.float64(0.0):
        kk = wp.float64(-2.0) * wp.float64(thr) * grow
        det64 = qa64 * qc64 - qb64 * qb64
        sl = qb64 / qa64
        bb = kk / qa64
        cc = det64 / (qa64 * qa64)
        packed[i, 11] = means2d.dtype(sl)
        packed[i, 12] = means2d.dtype(bb)
        packed[i, 13] = means2d.dtype(cc)
        packed[i, 14] = means2d.dtype(wp.sqrt(bb / cc))
        packed[i, 15] = means2d.dtype(sl * wp.sqrt(bb / (cc * (cc + sl * sl))))
    counts[i] = (x1 - x0) * (y1 - y0)


@wp.kernel
def _ranked_counts_kernel(order: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32),
                          ranked_counts: wp.array(dtype=wp.int32), offset: int):
    j = wp.tid() + offset
    ranked_counts[j] = counts[order[j]]


@wp.kernel
def _starts_kernel(order: wp.array(dtype=wp.int32), ranked_starts: wp.array(dtype=wp.int32),
                   starts: wp.array(dtype=wp.int32), offset: int):
    j = wp.tid() + offset
    starts[order[j]] = ranked_starts[j]


@wp.kernel
def _emit_kernel(
    rects: wp.array2d(dtype=wp.int32), starts: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32),
    tiles_x: int, keys: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.int64), offset: int,
):
    i = wp.tid() + offset
    if counts[i] == 0:
        return
    e = starts[i]
    for ty in range(rects[i, 2], rects[i, 3]):
        for tx in range(rects[i, 0], rects[i, 1]):
            keys[e] = ty * tiles_x + tx
            # The value carries both the emitted index (high 32 bits) and the splat (low 32 bits), so the
            # sorted entries need no gather through the emitted order afterwards.
            values[e] = (wp.int64(e) << wp.int64(32)) | wp.int64(i)
            e += 1


@wp.kernel
def _rank_rects_kernel(order: wp.array(dtype=wp.int32), rects: wp.array2d(dtype=wp.int32),
                       ranked_rects: wp.array2d(dtype=wp.int32), offset: int):
    # The splats' tile boxes in depth order (one gather), so that the sort's chunks read them in sequence.
    j = wp.tid() + offset
    i = order[j]
    ranked_rects[j, 0] = rects[i, 0]
    ranked_rects[j, 1] = rects[i, 1]
    ranked_rects[j, 2] = rects[i, 2]
    ranked_rects[j, 3] = rects[i, 3]


@wp.kernel
def _rank_hist_kernel(ranked_rects: wp.array2d(dtype=wp.int32), bounds: wp.array(dtype=wp.int32), tiles_x: int,
                      n_tiles: int, hist: wp.array2d(dtype=wp.int32), offset: int):
    # Chunk c (the splats of depth ranks bounds[c] .. bounds[c + 1] - 1) counts its entries per tile
    # into its own histogram row, straight from their tile boxes.
    c = wp.tid() + offset
    for t in range(n_tiles):
        hist[c, t] = 0
    for j in range(bounds[c], bounds[c + 1]):
        for ty in range(ranked_rects[j, 2], ranked_rects[j, 3]):
            row = ty * tiles_x
            for tx in range(ranked_rects[j, 0], ranked_rects[j, 1]):
                hist[c, row + tx] = hist[c, row + tx] + 1


@wp.kernel
def _rank_scatter_kernel(
    ranked_rects: wp.array2d(dtype=wp.int32), order: wp.array(dtype=wp.int32),
    ranked_starts: wp.array(dtype=wp.int32), bounds: wp.array(dtype=wp.int32), tiles_x: int,
    next_slot: wp.array2d(dtype=wp.int32), sorted_gid: wp.array(dtype=wp.int32),
    sorted_entry: wp.array(dtype=wp.int32), offset: int,
):
    # Chunk c places its splats' entries, in depth order and each splat's tiles in row-major order (the
    # emitted order), at its own run of slots in each tile's list.
    c = wp.tid() + offset
    for j in range(bounds[c], bounds[c + 1]):
        i = order[j]
        e = ranked_starts[j]
        for ty in range(ranked_rects[j, 2], ranked_rects[j, 3]):
            row = ty * tiles_x
            for tx in range(ranked_rects[j, 0], ranked_rects[j, 1]):
                t = row + tx
                pos = next_slot[c, t]
                next_slot[c, t] = pos + 1
                sorted_gid[pos] = i
                sorted_entry[pos] = e
                e += 1


@wp.kernel
def _serial_sort_kernel(
    rects: wp.array2d(dtype=wp.int32), counts: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32), n: int,
    tiles_x: int, n_tiles: int, starts: wp.array(dtype=wp.int32), next_slot: wp.array(dtype=wp.int32),
    ranges: wp.array2d(dtype=wp.int32), sorted_gid: wp.array(dtype=wp.int32), sorted_entry: wp.array(dtype=wp.int32),
    offset: int,
):
    # The counting sort of _counting_sort as one chunk, on one thread, straight from the splats' tile
    # boxes: the slices' starts (a scan of the counts in depth order), the per-tile histogram, its
    # scan (the ranges), and every splat's entries placed in depth order (the emitted order).
    e = int(0)
    for j in range(n):
        i = order[j]
        starts[i] = e
        e += counts[i]
    for t in range(n_tiles):
        next_slot[t] = 0
    for i in range(n):
        if counts[i] > 0:
            for ty in range(rects[i, 2], rects[i, 3]):
                for tx in range(rects[i, 0], rects[i, 1]):
                    t = ty * tiles_x + tx
                    next_slot[t] = next_slot[t] + 1
    first = int(0)
    for t in range(n_tiles):
        c = next_slot[t]
        ranges[t, 0] = 0
        ranges[t, 1] = 0
        if c > 0:
            ranges[t, 0] = first
            ranges[t, 1] = first + c
        next_slot[t] = first
        first += c
    for j in range(n):
        i = order[j]
        if counts[i] > 0:
            e = starts[i]
            for ty in range(rects[i, 2], rects[i, 3]):
                for tx in range(rects[i, 0], rects[i, 1]):
                    t = ty * tiles_x + tx
                    pos = next_slot[t]
                    next_slot[t] = pos + 1
                    sorted_gid[pos] = i
                    sorted_entry[pos] = e
                    e += 1


@wp.kernel
def _ranges_kernel(
    keys: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.int64), n: int,
    sorted_gid: wp.array(dtype=wp.int32), sorted_entry: wp.array(dtype=wp.int32), ranges: wp.array2d(dtype=wp.int32),
    offset: int,
):
    s = wp.tid() + offset
    v = values[s]
    sorted_gid[s] = int(v & wp.int64(0xFFFFFFFF))
    sorted_entry[s] = int(v >> wp.int64(32))
    tile = keys[s]
    if s == 0:
        ranges[tile, 0] = s
    elif keys[s - 1] != tile:
        ranges[tile, 0] = s
    if s == n - 1:
        ranges[tile, 1] = s + 1
    elif keys[s + 1] != tile:
        ranges[tile, 1] = s + 1


@dataclass
class Splats2D:
    """Screen-space splats, the input of the rasteriser: wp.arrays on one device.

    `as_numpy` is the kind of the caller's arrays, which the rasteriser's results follow.
    """

    means2d: wp.array
    conics: wp.array
    colors: wp.array
    opacities: wp.array
    depths: wp.array
    radii: wp.array
    scalar: Any
    device: wp.Device
    as_numpy: bool

    @property
    def n(self) -> int:
        return self.means2d.shape[0]

    def inputs(self) -> A.Inputs:
        """An `Inputs` for a call on these splats: their device, dtype and output kind."""
        return A.Inputs.like(self.device, self.scalar, self.as_numpy)


@wp.kernel
def _count_invalid_kernel(conics: wp.array2d(dtype=Any), opacities: wp.array(dtype=Any),
                          radii: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32)):
    # Value checks on a CUDA device (one launch; the CPU reads a zero-copy view instead).
    i = wp.tid()
    zero = conics.dtype(0.0)
    if radii[i] > 0 and (conics[i, 0] <= zero or conics[i, 0] * conics[i, 2] - conics[i, 1] * conics[i, 1] <= zero):
        wp.atomic_add(count, 0, 1)
    if opacities[i] < zero or opacities[i] > conics.dtype(1.0):
        wp.atomic_add(count, 1, 1)


def _check_splats(conics: wp.array, opacities: wp.array, radii: wp.array) -> None:
    if not A.values_checked() or radii.shape[0] == 0:
        return
    if conics.device.is_cpu:
        r, q, o = radii.numpy(), conics.numpy(), opacities.numpy()
        q = q[r > 0]
        bad_q = bool(np.any(q[:, 0] <= 0) or np.any(q[:, 0] * q[:, 2] - q[:, 1] ** 2 <= 0))
        bad_o = bool(np.any(o < 0) or np.any(o > 1))
    else:
        bad_q, bad_o = (bool(c) for c in A.device_counts(_count_invalid_kernel, radii.shape[0],
                                                          [conics, opacities, radii], conics.device, slots=2))
    if bad_q:
        raise ValueError("conics: expected positive definite (Q00, Q01, Q11) for every splat with radius > 0")
    if bad_o:
        raise ValueError("opacities: expected values in [0, 1]")


def splats_2d(means2d: Any, conics: Any, colors: Any, opacities: Any, depths: Any, radii: Any,
              device: Any = None) -> Splats2D:
    """Validate screen-space splats (conics positive definite where radius > 0, opacities in [0, 1],
    radii non-negative int32); NumPy or wp.array inputs (kernels/_arrays.py)."""
    a = A.Inputs(device, means2d, conics, colors, opacities, depths, radii)
    m = a.floats("means2d", means2d, (None, 2))
    n = m.shape[0]
    r = a.ints("radii", radii, (n,), minimum=0)
    out = Splats2D(m, a.floats("conics", conics, (n, 3)), a.floats("colors", colors, (n, 3)),
                   a.floats("opacities", opacities, (n,)), a.floats("depths", depths, (n,)), r, a.scalar,
                   a.device, a.as_numpy)
    _check_splats(out.conics, out.opacities, out.radii)
    return out


for _k in (_tile_counts_kernel, _count_invalid_kernel):
    A.declare_float_overloads(_k)


@dataclass
class Tiles:
    """Depth-sorted (tile, splat) lists: entries ranges[t, 0]:ranges[t, 1] of sorted_gid belong to tile t."""

    tiles_x: int
    tiles_y: int
    n_entries: int
    starts: wp.array  # (N,) first emitted entry of each splat
    counts: wp.array  # (N,) tiles each splat covers
    sorted_gid: wp.array  # (E,) splat of each sorted entry
    sorted_entry: wp.array  # (E,) emitted index of each sorted entry
    ranges: wp.array  # (n_tiles, 2)
    packed: wp.array  # (N, PACKED_COLS): one row per splat, the columns of PACKED_COLS' comment
    mode: str = DEFAULT_MODE  # the tile rule they were binned with (kernels/splat/modes.py)


def bin_tiles(s: Splats2D, width: int, height: int, mode: str = DEFAULT_MODE) -> Tiles:
    """Sort (tile, splat) pairs by tile, then depth; per-tile ranges (see the module docstring).

    A splat is listed in the tiles that meet the square mean2d +- radius (by the tile rule of
    `mode`, "3dgs" or "gsplat") AND the bounding box of its ellipse d^T Q d <= 2 ln(255 o),
    outside which its alpha is below 1/255: the second bound only drops pixels the rasteriser
    would skip.
    """
    mode_id(mode)
    width = A.check_int("width", width, minimum=1, maximum=MAX_SIDE)
    height = A.check_int("height", height, minimum=1, maximum=MAX_SIDE)
    # the counting sort on the CPU's fast route, else the radix sort (CUDA's; kernels.fast_paths)
    return _bin_tiles(s, width, height, mode, counting_sort=fast_paths.on(s.device))


def _bin_tiles(s: Splats2D, width: int, height: int, mode: str, counting_sort: bool,
               serial_max: int = SERIAL_SORT_MAX, chunk_min: int = SORT_CHUNK_MIN) -> Tiles:
    """`bin_tiles` with the entry sort chosen: the counting sort (the CPU's; one serial kernel up to
    `serial_max` entries, else chunks of at least `chunk_min` entries) or the radix sort (CUDA's)."""
    mid = mode_id(mode)
    a = s.inputs()
    dev = s.device
    n = s.n
    tiles_x, tiles_y = (width + TILE - 1) // TILE, (height + TILE - 1) // TILE
    n_tiles = tiles_x * tiles_y
    # Fully written arrays; on the CPU the large ones recycle freed blocks (kernels/_arrays.py: HostPool).
    rects = a.empty((n, 4), wp.int32)
    counts = a.empty(n, wp.int32)
    packed = a.empty((n, PACKED_COLS), s.scalar)
    dkeys = a.empty(2 * n, s.scalar)  # the radix sort's keys and values take 2n slots
    order = a.empty(2 * n, wp.int32)
    a.launch(_tile_counts_kernel, n, [s.means2d, s.conics, s.colors, s.opacities, s.depths, s.radii,
                                     tiles_x, tiles_y, mid, wp.float64(UNIT_ROUNDOFF[s.scalar]), rects, counts, packed,
                                     dkeys, order],
             min_chunk=MIN_CHUNK)
    if n == 0:
        return Tiles(tiles_x, tiles_y, 0, counts, counts, wp.zeros(1, dtype=wp.int32, device=dev),
                     wp.zeros(1, dtype=wp.int32, device=dev), wp.zeros((n_tiles, 2), dtype=wp.int32, device=dev),
                     packed, mode)

    # Depth order by a stable sort of the depths (culled splats last).
    wp.utils.radix_sort_pairs(dkeys, order, n)
    if counting_sort:
        n_entries = int(counts.numpy().sum(dtype=np.int64))  # a zero-copy view on the CPU
        if 0 < n_entries <= serial_max:
            return _serial_sort(a, rects, packed, counts, order, n, n_entries, tiles_x, tiles_y, mode)
    # Each splat's entries are the slice [starts[i], starts[i] + counts[i)), its tiles in row-major
    # order; the slices follow one another in depth order, so that the entries come out depth-ordered.
    starts = a.empty(n, wp.int32)
    if counting_sort:  # the CPU: the same scan through zero-copy NumPy views, without three launches
        rank_order = order.numpy()[:n]
        ranked_counts_np = counts.numpy()[rank_order]
        ranked_starts_np = np.cumsum(ranked_counts_np, dtype=np.int64) - ranked_counts_np
        n_entries = int(ranked_starts_np[-1] + ranked_counts_np[-1])
        starts.numpy()[rank_order] = ranked_starts_np
    else:
        ranked_counts = wp.empty(n, dtype=wp.int32, device=dev)
        a.launch(_ranked_counts_kernel, n, [order, counts, ranked_counts], min_chunk=MIN_CHUNK)
        ranked_starts = wp.empty(n, dtype=wp.int32, device=dev)
        wp.utils.array_scan(ranked_counts, ranked_starts, inclusive=False)
        n_entries = int(ranked_starts[n - 1:n].numpy()[0]) + int(ranked_counts[n - 1:n].numpy()[0])
        a.launch(_starts_kernel, n, [order, ranked_starts, starts], min_chunk=MIN_CHUNK)
    if n_entries == 0:
        return Tiles(tiles_x, tiles_y, 0, starts, counts, wp.zeros(1, dtype=wp.int32, device=dev),
                     wp.zeros(1, dtype=wp.int32, device=dev), wp.zeros((n_tiles, 2), dtype=wp.int32, device=dev),
                     packed, mode)
    if counting_sort:
        return _counting_sort(a, rects, packed, starts, counts, order, ranked_starts_np, n, n_entries, tiles_x,
                              tiles_y, mode, chunk_min)
    ranges = wp.zeros((n_tiles, 2), dtype=wp.int32, device=dev)

    # Keys are the tiles; values the emitted indices. The radix sort is stable, so a tile's entries keep
    # the depth order they were emitted in: the result is the order of the keys (tile, depth rank).
    tile_bits = max(1, (n_tiles - 1).bit_length())
    keys = wp.empty(2 * n_entries, dtype=wp.int32, device=dev)
    values = wp.empty(2 * n_entries, dtype=wp.int64, device=dev)
    # The emit kernel writes the disjoint slice [starts[i], starts[i] + counts[i]) of splat i.
    a.launch(_emit_kernel, n, [rects, starts, counts, tiles_x, keys, values], min_chunk=MIN_CHUNK)
    wp.utils.radix_sort_pairs(keys, values, n_entries, 0, tile_bits)
    sorted_gid = wp.empty(n_entries, dtype=wp.int32, device=dev)
    sorted_entry = wp.empty(n_entries, dtype=wp.int32, device=dev)
    a.launch(_ranges_kernel, n_entries, [keys, values, n_entries, sorted_gid, sorted_entry, ranges],
             min_chunk=MIN_CHUNK)
    return Tiles(tiles_x, tiles_y, n_entries, starts, counts, sorted_gid, sorted_entry, ranges, packed, mode)


def _serial_sort(a: A.Inputs, rects: wp.array, packed: wp.array, counts: wp.array, order: wp.array, n: int,
                 n_entries: int, tiles_x: int, tiles_y: int, mode: str) -> Tiles:
    """The CPU's lists for few entries: _counting_sort's, from one serial kernel (_serial_sort_kernel)."""
    dev = a.device
    n_tiles = tiles_x * tiles_y
    starts = wp.empty(n, dtype=wp.int32, device=dev)
    next_slot = wp.empty(n_tiles, dtype=wp.int32, device=dev)
    ranges = wp.empty((n_tiles, 2), dtype=wp.int32, device=dev)
    sorted_gid = wp.empty(n_entries, dtype=wp.int32, device=dev)
    sorted_entry = wp.empty(n_entries, dtype=wp.int32, device=dev)
    a.launch(_serial_sort_kernel, 1, [rects, counts, order, n, tiles_x, n_tiles, starts, next_slot, ranges, sorted_gid,
                                      sorted_entry], min_chunk=1)
    return Tiles(tiles_x, tiles_y, n_entries, starts, counts, sorted_gid, sorted_entry, ranges, packed, mode)


def _counting_sort(a: A.Inputs, rects: wp.array, packed: wp.array, starts: wp.array, counts: wp.array,
                   order: wp.array, ranked_starts_np: np.ndarray, n: int, n_entries: int, tiles_x: int, tiles_y: int,
                   mode: str, chunk_min: int = SORT_CHUNK_MIN) -> Tiles:
    """The CPU's (tile, depth) order: a stable counting sort of the entries by tile, straight from the
    splats' tile boxes.

    The splats in depth order (their boxes gathered once into that order) are cut into chunks of
    about equal entry counts; each chunk counts its entries per tile (one histogram row per chunk);
    a scan of the histogram in (tile, chunk) order gives every chunk its first slot in every tile's
    list, and each chunk writes its splats' entries there in emitted order (depth rank, then each
    splat's tiles in row-major order). The lists are the radix sort's of the emitted entries (stable,
    by tile) for any cut into chunks, without writing the emitted keys and splats first; every chunk
    writes only its own histogram row and slots, so both kernels run split over the CPU threads.
    """
    dev = a.device
    n_tiles = tiles_x * tiles_y
    ranked_rects = a.empty((n, 4), wp.int32)
    a.launch(_rank_rects_kernel, n, [order, rects, ranked_rects], min_chunk=MIN_CHUNK)
    n_chunks = max(1, min(SORT_CHUNKS, n_entries // max(1, chunk_min)))
    # Chunk c takes the splats whose first entry lies in [c E / n_chunks, (c + 1) E / n_chunks).
    targets = (np.arange(n_chunks + 1, dtype=np.int64) * n_entries) // n_chunks
    bounds_np = np.searchsorted(ranked_starts_np, targets, side="left").astype(np.int32)
    bounds_np[-1] = n
    bounds = wp.array(bounds_np, dtype=wp.int32, device=dev)
    ranked_starts = wp.array(ranked_starts_np.astype(np.int32), dtype=wp.int32, device=dev)
    hist = a.empty((n_chunks, n_tiles), wp.int32)
    a.launch(_rank_hist_kernel, n_chunks, [ranked_rects, bounds, tiles_x, n_tiles, hist], min_chunk=1)
    h = hist.numpy().T  # (tiles, chunks), a zero-copy view on the CPU
    first = (np.cumsum(h, dtype=np.int64).reshape(h.shape) - h).astype(np.int32)  # scan in (tile, chunk) order
    total = h.sum(axis=1)
    ranges = np.stack([first[:, 0], first[:, 0] + total], axis=1).astype(np.int32)
    ranges[total == 0] = 0
    next_slot = wp.array(np.ascontiguousarray(first.T), dtype=wp.int32, device=dev)
    sorted_gid = a.empty(n_entries, wp.int32)
    sorted_entry = a.empty(n_entries, wp.int32)
    a.launch(_rank_scatter_kernel, n_chunks, [ranked_rects, order, ranked_starts, bounds, tiles_x, next_slot,
                                              sorted_gid, sorted_entry], min_chunk=1)
    return Tiles(tiles_x, tiles_y, n_entries, starts, counts, sorted_gid, sorted_entry,
                 wp.array(ranges, dtype=wp.int32, device=dev), packed, mode)
