"""Tile binning: which splats each 16 x 16 pixel tile blends, front to back.

As in 3DGS (Kerbl et al. 2023), a visible splat belongs to the tiles its square mean2d +- radius
meets, by the tile rule of the mode (kernels/splat/modes.py): "3dgs" 3DGS's getRect,
floor((u - 1/2 - r)/16) <= tx < floor((u - 1/2 + r + 15)/16), "gsplat" gsplat's
floor((u - r)/16) <= tx < ceil((u + r)/16) (rows likewise, both clamped to the image's tiles).
Of these it is listed only in those that also meet the bounding box of the ellipse
d^T Q d <= 2 ln(255 o) (half-sizes sqrt(2 ln(255 o) Q11 / det Q) and sqrt(2 ln(255 o) Q00 / det Q)),
outside which alpha < 1/255 and the rasteriser skips it anyway: the image is the same, and splats
with 255 o < 1 are never listed. Splats are ranked by depth (a stable radix sort, culled splats
last), and each (tile, splat) pair gets the key tile * 2^b + rank with 2^b > N; one radix sort of
these keys (wp.utils.radix_sort_pairs) lists every tile's splats front to back, and per-tile
ranges [start, end) index the sorted list. Every kernel writes only its own slots (the emit
kernel the disjoint slice [starts[i], starts[i] + counts[i]) of splat i), so all run split over
CPU threads.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.splat.modes import DEFAULT_MODE, mode_id

wp.set_module_options({"enable_backward": False})

TILE = 16
TILE_PIXELS = TILE * TILE
MIN_CHUNK = 1024


@wp.kernel
def _tile_counts_kernel(
    means2d: wp.array2d(dtype=Any), conics: wp.array2d(dtype=Any), opacities: wp.array(dtype=Any),
    depths: wp.array(dtype=Any), radii: wp.array(dtype=wp.int32), tiles_x: int, tiles_y: int, mode: int,
    rects: wp.array2d(dtype=wp.int32), counts: wp.array(dtype=wp.int32), packed: wp.array2d(dtype=Any), offset: int,
):
    i = wp.tid() + offset
    r = radii[i]
    counts[i] = 0
    for j in range(4):
        rects[i, j] = 0
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
    counts[i] = (x1 - x0) * (y1 - y0)
    packed[i, 0] = u
    packed[i, 1] = v
    packed[i, 2] = qa
    packed[i, 3] = qb
    packed[i, 4] = qc
    packed[i, 5] = o
    packed[i, 6] = -means2d.dtype(0.5) * k2
    packed[i, 7] = depths[i]


@wp.kernel
def _depth_keys_kernel(
    depths: wp.array(dtype=Any), radii: wp.array(dtype=wp.int32), keys: wp.array(dtype=Any),
    values: wp.array(dtype=wp.int32), offset: int,
):
    i = wp.tid() + offset
    # Culled splats sort last; their rank is never used.
    keys[i] = depths[i]
    if radii[i] <= 0:
        keys[i] = depths.dtype(1e30)
    values[i] = i


@wp.kernel
def _rank_kernel(order: wp.array(dtype=wp.int32), rank: wp.array(dtype=wp.int32), offset: int):
    j = wp.tid() + offset
    rank[order[j]] = j


@wp.kernel
def _emit_kernel(
    rects: wp.array2d(dtype=wp.int32), starts: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32),
    rank: wp.array(dtype=wp.int32), tiles_x: int, rank_stride: wp.int64,
    keys: wp.array(dtype=wp.int64), values: wp.array(dtype=wp.int32), entry_gid: wp.array(dtype=wp.int32), offset: int,
):
    i = wp.tid() + offset
    if counts[i] == 0:
        return
    e = starts[i]
    for ty in range(rects[i, 2], rects[i, 3]):
        for tx in range(rects[i, 0], rects[i, 1]):
            keys[e] = wp.int64(ty * tiles_x + tx) * rank_stride + wp.int64(rank[i])
            values[e] = e
            entry_gid[e] = i
            e += 1


@wp.kernel
def _ranges_kernel(
    keys: wp.array(dtype=wp.int64), values: wp.array(dtype=wp.int32), entry_gid: wp.array(dtype=wp.int32),
    n: int, rank_stride: wp.int64,
    sorted_gid: wp.array(dtype=wp.int32), ranges: wp.array2d(dtype=wp.int32), offset: int,
):
    s = wp.tid() + offset
    sorted_gid[s] = entry_gid[values[s]]
    tile = int(keys[s] / rank_stride)
    if s == 0:
        ranges[tile, 0] = s
    elif int(keys[s - 1] / rank_stride) != tile:
        ranges[tile, 0] = s
    if s == n - 1:
        ranges[tile, 1] = s + 1
    elif int(keys[s + 1] / rank_stride) != tile:
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


for _k in (_tile_counts_kernel, _depth_keys_kernel, _count_invalid_kernel):
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
    packed: wp.array  # (N, 8): u, v, Q00, Q01, Q11, opacity, -ln(255 opacity), depth (rows of binned splats)
    mode: str = DEFAULT_MODE  # the tile rule they were binned with (kernels/splat/modes.py)


def bin_tiles(s: Splats2D, width: int, height: int, mode: str = DEFAULT_MODE) -> Tiles:
    """Sort (tile, splat) pairs by tile, then depth; per-tile ranges (see the module docstring).

    A splat is listed in the tiles that meet the square mean2d +- radius (by the tile rule of
    `mode`, "3dgs" or "gsplat") AND the bounding box of its ellipse d^T Q d <= 2 ln(255 o),
    outside which its alpha is below 1/255: the second bound only drops pixels the rasteriser
    would skip.
    """
    mid = mode_id(mode)
    width = A.check_int("width", width, minimum=1)
    height = A.check_int("height", height, minimum=1)
    a = s.inputs()
    dev = s.device
    n = s.n
    tiles_x, tiles_y = (width + TILE - 1) // TILE, (height + TILE - 1) // TILE
    n_tiles = tiles_x * tiles_y
    rects = wp.zeros((n, 4), dtype=wp.int32, device=dev)
    counts = wp.zeros(n, dtype=wp.int32, device=dev)
    packed = wp.zeros((n, 8), dtype=s.scalar, device=dev)
    a.launch(_tile_counts_kernel, n, [s.means2d, s.conics, s.opacities, s.depths, s.radii, tiles_x, tiles_y, mid, rects,
                                     counts, packed], min_chunk=MIN_CHUNK)
    starts = wp.zeros(n, dtype=wp.int32, device=dev)
    n_entries = 0
    if n:
        wp.utils.array_scan(counts, starts, inclusive=False)
        n_entries = int(starts[n - 1:n].numpy()[0]) + int(counts[n - 1:n].numpy()[0])
    ranges = wp.zeros((n_tiles, 2), dtype=wp.int32, device=dev)
    sorted_gid = wp.zeros(max(n_entries, 1), dtype=wp.int32, device=dev)
    sorted_entry = wp.zeros(max(n_entries, 1), dtype=wp.int32, device=dev)
    if n_entries == 0:
        return Tiles(tiles_x, tiles_y, 0, starts, counts, sorted_gid, sorted_entry, ranges, packed, mode)
    means2d, radii, depths = s.means2d, s.radii, s.depths

    # Depth ranks by a stable sort of the depths (culled splats last).
    dkeys = wp.zeros(2 * n, dtype=means2d.dtype, device=dev)
    order = wp.zeros(2 * n, dtype=wp.int32, device=dev)
    a.launch(_depth_keys_kernel, n, [depths, radii, dkeys, order], min_chunk=MIN_CHUNK)
    wp.utils.radix_sort_pairs(dkeys, order, n)
    rank = wp.zeros(n, dtype=wp.int32, device=dev)
    a.launch(_rank_kernel, n, [order, rank], min_chunk=MIN_CHUNK)

    rank_bits = max(1, (n - 1).bit_length())
    tile_bits = max(1, (n_tiles - 1).bit_length())
    stride = 1 << rank_bits
    keys = wp.zeros(2 * n_entries, dtype=wp.int64, device=dev)
    values = wp.zeros(2 * n_entries, dtype=wp.int32, device=dev)
    entry_gid = wp.zeros(n_entries, dtype=wp.int32, device=dev)
    # The emit kernel writes the disjoint slice [starts[i], starts[i] + counts[i]) of splat i.
    a.launch(_emit_kernel, n, [rects, starts, counts, rank, tiles_x, wp.int64(stride), keys, values, entry_gid],
             min_chunk=MIN_CHUNK)
    wp.utils.radix_sort_pairs(keys, values, n_entries, 0, rank_bits + tile_bits)
    a.launch(_ranges_kernel, n_entries, [keys, values, entry_gid, n_entries, wp.int64(stride), sorted_gid, ranges],
             min_chunk=MIN_CHUNK)
    wp.copy(sorted_entry, values, count=n_entries)
    return Tiles(tiles_x, tiles_y, n_entries, starts, counts, sorted_gid, sorted_entry, ranges, packed, mode)
