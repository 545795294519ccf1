"""Stereo matching on rectified pairs: cost volumes, semi-global aggregation, disparity and depth.

Conventions
-----------
Images are single-channel ``(H, W)`` float32 or float64 arrays (convert colour
first); row 0 is the top. The pair is rectified: the left pixel (x, y) with
disparity d matches the right pixel (x - d, y). A disparity range [dmin, dmax)
gives D = dmax - dmin hypotheses d_k = dmin + k, and every cost volume is
``(H, W, D)`` with the hypotheses contiguous. Lower cost = better match, except
for the feature correlation (a similarity). A cell is *in range* when its right
pixel exists, 0 <= x - d_k < W; cells out of range hold a fixed cost no real
match can beat (each cost below names it).

Costs
-----
* SAD over a (2r+1)^2 window, normalised by the number of cells summed,

      C_SAD(x, y, d) = 1/|N| sum_{(u, v) in N} |I_L(u, v) - I_R(u - d, v)|,

  where N is the window cut to the image and to the columns whose right pixel
  exists (u - d in [0, W)). Out of range: the range of all pixel values
  (max - min over both images), an upper bound of any in-range SAD.
* ZNCC over the same window N, with a variance floor eps (intensity^2 units)
  that keeps flat windows finite and drives them to zero correlation,

      rho = cov(L, R) / sqrt((var L + eps) (var R + eps)),   C_ZNCC = 1 - rho in (0, 2).

  Out of range: 2.
  Both window costs take O(1) work per cell, never O(window): per-image sums of
  I and I^2 come from integral images (summed-area tables, Crow 1984) in
  float64, and the per-disparity sums (|L - R| or L R) from running box sums: a
  thread owns a band of rows and keeps, for every (column, disparity), the sum
  over the window's rows (updated by one row in, one row out per output row),
  then slides the window along the row (one column in, one out).
* Census (Zabih & Woodfill, ECCV 1994): a (2 ry + 1) x (2 rx + 1) window
  (at most 64 bits, the centre excluded) becomes a bit string with bit
  [I(q) < I(p)] per neighbour q (raster order, coordinates clamped to the
  image); the cost is the Hamming distance popcount(c_L(x, y) xor c_R(x - d, y)).
  Out of range: the number of bits.
* Feature correlation, RAFT-Stereo's 1D correlation (Lipson, Teed & Deng, 3DV
  2021) restricted to the disparity range, for learned features F ``(C, H, W)``
  (PyTorch's layout, as kernels/corr.py):

      corr(x, y, k) = <F_L(x, y), F_R(x - d_k, y)> / sqrt(C),    0 out of range.

  Backward, for an upstream gradient G = dLoss/dcorr (both gathers, no atomics):

      dF_L(x, y) = sum_k G(x, y, k) F_R(x - d_k, y) / sqrt(C)
      dF_R(x', y) = sum_k G(x' + d_k, y, k) F_L(x' + d_k, y) / sqrt(C).

Aggregation: semi-global matching (Hirschmueller, PAMI 2008)
-------------------------------------------------------------
Along each path direction r (4 paths: left, right, up, down; 8 paths add the
diagonals), starting with L_r(p_0, d) = C(p_0, d) where the path enters the image,

    L_r(p, k) = C(p, k) + min( L_r(p - r, k),
                                L_r(p - r, k - 1) + P1,  L_r(p - r, k + 1) + P1,
                                min_i L_r(p - r, i) + P2 )  -  min_i L_r(p - r, i),

and S(p, k) = sum_r L_r(p, k). P1 penalises a one-step disparity change, P2 >=
P1 any larger one. The recurrence is sequential along a scanline but scanlines
are independent. Each axis (rows, columns, and for 8 paths the two diagonals)
is one launch with one thread per scanline, which runs the path r and then -r
back over the same pixels while they are still in cache. Each pixel lies on
exactly one scanline of an axis, so the writes of S are disjoint and the
launch splits across CPU threads (kernels.launch); axes run one after another.
The hypotheses are processed as 8-wide vectors (SIMD on the CPU): the k - 1 and
k + 1 candidates are the previous L_r shifted by one lane. D is padded to a
multiple of 8 with hypotheses costing max C + 2 P2 + |max C| + 1, which no
L_r(p, k) <= C(p, k) + P2 of a real hypothesis can reach, so the padding
changes neither the real L_r nor their minimum.

Disparity
---------
* Winner-take-all: k* = argmin_k C(p, k) (the first minimum), refined by the
  parabola through (k* - 1, k*, k* + 1) when both neighbours exist:
  d = d_{k*} + (c_- - c_+) / (2 (c_- - 2 c_0 + c_+)) (no refinement when the
  curvature is not positive). The pixel is invalid when its winner is out of
  range, or, with a uniqueness ratio u > 0, when some k with |k - k*| > 1 has
  C(p, k) (1 - u) < C(p, k*) (as OpenCV's uniquenessRatio).
  The right view's disparity comes from the same volume (Hirschmueller 2008,
  sec. 3.4): d_R(x_r) = argmin_k C(x_r + d_k, y, k), with the same refinement.
* Soft-argmin (Kendall et al., GC-Net, ICCV 2017) with temperature T:

      sigma_k = softmax_k(-C(p, k) / T),   d = sum_k d_k sigma_k,
      dd/dC(p, k) = sigma_k (d - d_k) / T.

  It runs over all D cells, in range or not (pass a volume whose out-of-range
  cells are costly, as the costs above are).
* Left-right consistency: the left pixel is valid when its own estimate is, the
  right pixel x_r = round(x - d_L) exists and is valid, and |d_L - d_R(x_r)| <=
  max_diff.

Depth
-----
Z = f b / d (f the focal length in pixels, b the baseline). A pixel with d <= 0,
a non-finite d, an invalid input flag, or a non-finite quotient is invalid and
gets Z = 0; the output never holds inf or NaN.

Entry points validate their arguments before any launch and raise ValueError
naming the argument: mismatched left/right shapes, a disparity range that is
empty or wider than the image, non-finite pixels or costs, wrong dtype or
device. NumPy arrays in give NumPy arrays out (masks as bool); wp.arrays in give
wp.arrays out (masks as uint8) on the same device.
"""

from __future__ import annotations

import math
import typing
from typing import Any

import numpy as np
import warp as wp

from kernels.launch import default_threads, launch_split

# Every backward here is a hand-written kernel; Warp's autodiff code would only add compile time.
wp.set_module_options({"enable_backward": False})

FLOATS = (wp.float32, wp.float64)
CENSUS_MAX_BITS = 64
# (dy, dx) of the SGM path directions; the first four are the 4-path set. Each axis below runs a
# direction and its opposite in one launch.
SGM_DIRECTIONS = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, -1), (1, -1), (-1, 1))
SGM_AXES = ((0, 1), (1, 0), (1, 1), (1, -1))

# SGM runs on 8-wide vectors of hypotheses (the CPU compiler turns them into SIMD); D is padded to a multiple.
SGM_LANES = 8
SGM_VEC = {wp.float32: wp.types.vector(length=SGM_LANES, dtype=wp.float32),
           wp.float64: wp.types.vector(length=SGM_LANES, dtype=wp.float64)}

COST_SAD = 0
COST_ZNCC = 1


# =========================================================================== helpers (device)


@wp.func
def _box(t: wp.array2d(dtype=wp.float64), y0: int, y1: int, x0: int, x1: int) -> wp.float64:
    """Sum over rows [y0, y1] and columns [x0, x1] (inclusive) from a zero-padded summed-area table."""
    return t[y1 + 1, x1 + 1] - t[y0, x1 + 1] - t[y1 + 1, x0] + t[y0, x0]


# =========================================================================== integral images


@wp.kernel
def _integral_rows(
    img: wp.array2d(dtype=typing.Any),
    t1: wp.array2d(dtype=wp.float64),
    t2: wp.array2d(dtype=wp.float64),
    offset: int,
):
    # Row pass: t[y + 1, x + 1] = sum_{u <= x} I(u, y) (and I^2); row 0 and column 0 stay zero.
    y = wp.tid() + offset
    s1 = wp.float64(0.0)
    s2 = wp.float64(0.0)
    for x in range(img.shape[1]):
        v = wp.float64(img[y, x])
        s1 += v
        s2 += v * v
        t1[y + 1, x + 1] = s1
        t2[y + 1, x + 1] = s2


@wp.kernel
def _integral_cols(t1: wp.array2d(dtype=wp.float64), t2: wp.array2d(dtype=wp.float64), offset: int):
    # Column pass, in place: each thread owns one column of both tables.
    x = wp.tid() + offset + 1
    for y in range(1, t1.shape[0] - 1):
        t1[y + 1, x] = t1[y + 1, x] + t1[y, x]
        t2[y + 1, x] = t2[y + 1, x] + t2[y, x]


# =========================================================================== window costs (SAD, ZNCC)


@wp.func
def _add_row(
    left: wp.array2d(dtype=typing.Any),
    right: wp.array2d(dtype=typing.Any),
    colsum: wp.array3d(dtype=wp.float64),
    b: int,
    v: int,
    sign: wp.float64,
    dmin: int,
    mode: int,
):
    """colsum[b, x, k] += sign * term(x, v, d_k) for every column x and hypothesis k of row v."""
    W = left.shape[1]
    D = colsum.shape[2]
    for x in range(W):
        lv = wp.float64(left[v, x])
        # Only the hypotheses whose right pixel u = x - d_k exists: k in [x - dmin - W + 1, x - dmin].
        k0 = wp.max(0, x - dmin - W + 1)
        k1 = wp.min(D, x - dmin + 1)
        if mode == 0:
            for k in range(k0, k1):
                colsum[b, x, k] = colsum[b, x, k] + sign * wp.abs(lv - wp.float64(right[v, x - dmin - k]))
        else:
            for k in range(k0, k1):
                colsum[b, x, k] = colsum[b, x, k] + sign * lv * wp.float64(right[v, x - dmin - k])


@wp.kernel
def _window_cost(
    left: wp.array2d(dtype=typing.Any),
    right: wp.array2d(dtype=typing.Any),
    tl: wp.array2d(dtype=wp.float64),
    tl2: wp.array2d(dtype=wp.float64),
    tr: wp.array2d(dtype=wp.float64),
    tr2: wp.array2d(dtype=wp.float64),
    colsum: wp.array3d(dtype=wp.float64),
    rowsum: wp.array2d(dtype=wp.float64),
    out: wp.array3d(dtype=typing.Any),
    dmin: int,
    radius: int,
    band: int,
    mode: int,
    invalid: wp.float64,
    eps: wp.float64,
    offset: int,
):
    # One thread per band of `band` rows; it owns colsum[b] and rowsum[b] and writes out[y0:y1].
    b = wp.tid() + offset
    H = left.shape[0]
    W = left.shape[1]
    D = out.shape[2]
    r = radius
    y0 = b * band
    y1 = wp.min(y0 + band, H)
    for x in range(W):
        for k in range(D):
            colsum[b, x, k] = wp.float64(0.0)
    for v in range(wp.max(y0 - r, 0), wp.min(y0 + r, H - 1) + 1):
        _add_row(left, right, colsum, b, v, wp.float64(1.0), dmin, mode)
    for y in range(y0, y1):
        if y > y0:
            if y + r < H:
                _add_row(left, right, colsum, b, y + r, wp.float64(1.0), dmin, mode)
            if y - r - 1 >= 0:
                _add_row(left, right, colsum, b, y - r - 1, wp.float64(-1.0), dmin, mode)
        ya = wp.max(y - r, 0)
        yb = wp.min(y + r, H - 1)
        rows = yb - ya + 1
        # rowsum[b, k] = sum of colsum over the window's columns, slid along x.
        for k in range(D):
            rowsum[b, k] = wp.float64(0.0)
        for u in range(0, wp.min(r, W)):
            for k in range(D):
                rowsum[b, k] = rowsum[b, k] + colsum[b, u, k]
        for x in range(W):
            if x + r < W:
                for k in range(D):
                    rowsum[b, k] = rowsum[b, k] + colsum[b, x + r, k]
            if x - r - 1 >= 0:
                for k in range(D):
                    rowsum[b, k] = rowsum[b, k] - colsum[b, x - r - 1, k]
            # In range: 0 <= x - d_k < W, i.e. k in [k0, k1); the other cells hold `invalid`.
            k0 = wp.max(0, x - dmin - W + 1)
            k1 = wp.min(D, x - dmin + 1)
            for k in range(0, k0):
                out[y, x, k] = out.dtype(invalid)
            for k in range(k1, D):
                out[y, x, k] = out.dtype(invalid)
            for k in range(k0, k1):
                d = dmin + k
                s = rowsum[b, k]
                lo = wp.max(wp.max(x - r, 0), d)
                hi = wp.min(wp.min(x + r, W - 1), W - 1 + d)
                n = wp.float64(rows * (hi - lo + 1))
                cost = s / n
                if mode != 0:
                    sl = _box(tl, ya, yb, lo, hi)
                    sl2 = _box(tl2, ya, yb, lo, hi)
                    sr = _box(tr, ya, yb, lo - d, hi - d)
                    sr2 = _box(tr2, ya, yb, lo - d, hi - d)
                    cov = (s - sl * sr / n) / n
                    var_l = wp.max((sl2 - sl * sl / n) / n, wp.float64(0.0))
                    var_r = wp.max((sr2 - sr * sr / n) / n, wp.float64(0.0))
                    cost = wp.float64(1.0) - cov / wp.sqrt((var_l + eps) * (var_r + eps))
                out[y, x, k] = out.dtype(cost)


# =========================================================================== census


@wp.kernel
def _census_transform(img: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=wp.uint64), ry: int, rx: int,
                      offset: int):
    i = wp.tid() + offset
    H = img.shape[0]
    W = img.shape[1]
    y = i / W
    x = i - y * W
    c = img[y, x]
    bits = wp.uint64(0)
    for dy in range(-ry, ry + 1):
        for dx in range(-rx, rx + 1):
            if dy != 0 or dx != 0:
                q = img[wp.clamp(y + dy, 0, H - 1), wp.clamp(x + dx, 0, W - 1)]
                bits = bits << wp.uint64(1)
                if q < c:
                    bits = bits | wp.uint64(1)
    out[y, x] = bits


@wp.kernel
def _census_cost(
    cl: wp.array2d(dtype=wp.uint64),
    cr: wp.array2d(dtype=wp.uint64),
    out: wp.array3d(dtype=typing.Any),
    dmin: int,
    invalid: int,
    offset: int,
):
    i = wp.tid() + offset
    W = cl.shape[1]
    y = i / W
    x = i - y * W
    a = cl[y, x]
    for k in range(out.shape[2]):
        u = x - (dmin + k)
        h = invalid
        if u >= 0 and u < W:
            h = int(wp.bit_count(a ^ cr[y, u]))
        out[y, x, k] = out.dtype(h)


# =========================================================================== feature correlation


@wp.kernel
def _channels_last(src: wp.array3d(dtype=typing.Any), dst: wp.array3d(dtype=typing.Any), offset: int):
    i = wp.tid() + offset
    W = src.shape[2]
    y = i / W
    x = i - y * W
    for c in range(src.shape[0]):
        dst[y, x, c] = src[c, y, x]


@wp.kernel
def _corr_forward(
    fl: wp.array3d(dtype=typing.Any),
    fr: wp.array3d(dtype=typing.Any),
    out: wp.array3d(dtype=typing.Any),
    dmin: int,
    scale: wp.float64,
    offset: int,
):
    # Features channels-last (H, W, C) here, so each dot product reads two contiguous rows.
    i = wp.tid() + offset
    W = fl.shape[1]
    y = i / W
    x = i - y * W
    s = out.dtype(scale)
    for k in range(out.shape[2]):
        u = x - (dmin + k)
        acc = out.dtype(0.0)
        if u >= 0 and u < W:
            for c in range(fl.shape[2]):
                acc += fl[y, x, c] * fr[y, u, c]
        out[y, x, k] = acc * s


@wp.kernel
def _corr_backward_left(
    grad: wp.array3d(dtype=typing.Any),
    fr: wp.array3d(dtype=typing.Any),
    dfl: wp.array3d(dtype=typing.Any),
    dmin: int,
    scale: wp.float64,
    offset: int,
):
    i = wp.tid() + offset
    W = fr.shape[2]
    y = i / W
    x = i - y * W
    k0 = wp.max(0, x - W + 1 - dmin)
    k1 = wp.min(grad.shape[2], x - dmin + 1)
    for c in range(fr.shape[0]):
        acc = dfl.dtype(0.0)
        for k in range(k0, k1):
            acc += grad[y, x, k] * fr[c, y, x - dmin - k]
        dfl[c, y, x] = acc * dfl.dtype(scale)


@wp.kernel
def _corr_backward_right(
    grad: wp.array3d(dtype=typing.Any),
    fl: wp.array3d(dtype=typing.Any),
    dfr: wp.array3d(dtype=typing.Any),
    dmin: int,
    scale: wp.float64,
    offset: int,
):
    # Gather form: right pixel u receives from every left pixel x = u + d_k that matched it.
    i = wp.tid() + offset
    W = fl.shape[2]
    y = i / W
    u = i - y * W
    k0 = wp.max(0, -u - dmin)  # 0 <= u + dmin + k < W
    k1 = wp.min(grad.shape[2], W - u - dmin)
    for c in range(fl.shape[0]):
        acc = dfr.dtype(0.0)
        for k in range(k0, k1):
            acc += grad[y, u + dmin + k, k] * fl[c, y, u + dmin + k]
        dfr[c, y, u] = acc * dfr.dtype(scale)


# =========================================================================== SGM


@wp.func
def _sgm_walk(
    cost: wp.array(dtype=typing.Any),
    agg: wp.array(dtype=typing.Any),
    buf: wp.array(dtype=typing.Any),
    nb: int,
    bb: int,
    base: int,
    step: int,
    n: int,
    p1: typing.Any,
    p2: typing.Any,
    write: int,
):
    """L_r along one scanline of n + 1 pixels starting at flat vector index `base`, moving by `step`.

    Each pixel holds nb vectors; buf[bb:bb + nb] carries L_r(p - r) and is updated in place. agg receives
    L_r (assigned when `write`, else added).
    """
    lanes_min = cost[base]
    for j in range(nb):
        c = cost[base + j]
        buf[bb + j] = c
        lanes_min = wp.min(lanes_min, c)
        if write != 0:
            agg[base + j] = c
        else:
            agg[base + j] = agg[base + j] + c
    prev_min = wp.min(lanes_min)
    for _s in range(n):
        base += step
        jump = prev_min + p2[0]
        jump_v = cost.dtype(jump)
        prev_v = cost.dtype(prev_min)
        # L_r(p - r, k - 1) and (k + 1) are the previous vector shifted by one lane; past either end of the
        # range the candidate is `jump`, which never undercuts the P2 candidate.
        below = jump
        cur = buf[bb]
        lanes_min = jump_v + p2
        for j in range(nb):
            nxt = cur
            above = jump
            if j + 1 < nb:
                nxt = buf[bb + j + 1]
                above = nxt[0]
            down = cost.dtype(below, cur[0], cur[1], cur[2], cur[3], cur[4], cur[5], cur[6])
            up = cost.dtype(cur[1], cur[2], cur[3], cur[4], cur[5], cur[6], cur[7], above)
            best = wp.min(wp.min(cur, jump_v), wp.min(down, up) + p1)
            lr = cost[base + j] + best - prev_v
            buf[bb + j] = lr
            lanes_min = wp.min(lanes_min, lr)
            if write != 0:
                agg[base + j] = lr
            else:
                agg[base + j] = agg[base + j] + lr
            below = cur[7]
            cur = nxt
        prev_min = wp.min(lanes_min)
    return 0


@wp.kernel
def _sgm_axis(
    cost: wp.array(dtype=typing.Any),
    agg: wp.array(dtype=typing.Any),
    buf: wp.array(dtype=typing.Any),
    H: int,
    W: int,
    dy: int,
    dx: int,
    p1: typing.Any,
    p2: typing.Any,
    first: int,
    offset: int,
):
    # One thread per scanline along axis (dy, dx), dy >= 0: it runs the path r = (dy, dx), then the
    # opposite path -r back along the same pixels, which are still in cache. Volumes are flat arrays
    # of 8-wide vectors, nb per pixel.
    i = wp.tid() + offset
    nb = buf.shape[0] / (W + H - 1)
    y = int(0)
    x = int(0)
    if dy == 0:
        y = i
    elif dx == 0:
        x = i
    elif i < W:
        x = i
    else:
        x = wp.where(dx > 0, 0, W - 1)
        y = i - W + 1
    # Steps until the line leaves the image.
    big = H + W
    n = wp.min(wp.where(dy > 0, H - 1 - y, big), wp.where(dx > 0, W - 1 - x, wp.where(dx < 0, x, big)))
    step = (dy * W + dx) * nb
    base = (y * W + x) * nb
    _sgm_walk(cost, agg, buf, nb, i * nb, base, step, n, p1, p2, first)
    _sgm_walk(cost, agg, buf, nb, i * nb, base + n * step, -step, n, p1, p2, 0)


@wp.kernel
def _pad_volume(src: wp.array3d(dtype=typing.Any), dst: wp.array3d(dtype=typing.Any), fill: wp.float64,
                offset: int):
    i = wp.tid() + offset
    W = src.shape[1]
    y = i / W
    x = i - y * W
    for k in range(dst.shape[2]):
        if k < src.shape[2]:
            dst[y, x, k] = src[y, x, k]
        else:
            dst[y, x, k] = dst.dtype(fill)


@wp.kernel
def _crop_volume(src: wp.array3d(dtype=typing.Any), dst: wp.array3d(dtype=typing.Any), offset: int):
    i = wp.tid() + offset
    W = src.shape[1]
    y = i / W
    x = i - y * W
    for k in range(dst.shape[2]):
        dst[y, x, k] = src[y, x, k]


# =========================================================================== disparity


@wp.func
def _parabola(cm: typing.Any, c0: typing.Any, cp: typing.Any):
    denom = cm - c0 - c0 + cp
    off = c0 - c0
    if denom > off:
        off = (cm - cp) / (denom + denom)
    return off


@wp.kernel
def _wta(
    cost: wp.array3d(dtype=typing.Any),
    disp: wp.array2d(dtype=typing.Any),
    valid: wp.array2d(dtype=wp.uint8),
    dmin: int,
    subpixel: int,
    uniqueness: wp.float64,
    offset: int,
):
    i = wp.tid() + offset
    W = cost.shape[1]
    D = cost.shape[2]
    y = i / W
    x = i - y * W
    best = int(0)
    cbest = cost[y, x, 0]
    for k in range(1, D):
        c = cost[y, x, k]
        if c < cbest:
            cbest = c
            best = k
    ok = int(1)
    d = dmin + best
    if x - d < 0 or x - d >= W:
        ok = 0
    if uniqueness > wp.float64(0.0):
        keep = cost.dtype(wp.float64(1.0) - uniqueness)
        for k in range(D):
            if (k < best - 1 or k > best + 1) and cost[y, x, k] * keep < cbest:
                ok = 0
    out = disp.dtype(d)
    if subpixel != 0 and best > 0 and best + 1 < D:
        out = out + disp.dtype(_parabola(cost[y, x, best - 1], cbest, cost[y, x, best + 1]))
    disp[y, x] = out
    valid[y, x] = wp.uint8(ok)


@wp.kernel
def _wta_right(
    cost: wp.array3d(dtype=typing.Any),
    disp: wp.array2d(dtype=typing.Any),
    valid: wp.array2d(dtype=wp.uint8),
    dmin: int,
    subpixel: int,
    offset: int,
):
    # Right pixel xr: hypothesis k lives in the left volume at x = xr + d_k.
    i = wp.tid() + offset
    W = cost.shape[1]
    D = cost.shape[2]
    y = i / W
    xr = i - y * W
    best = int(-1)
    cbest = cost.dtype(0.0)
    for k in range(D):
        x = xr + dmin + k
        if x >= 0 and x < W:
            c = cost[y, x, k]
            if best < 0 or c < cbest:
                cbest = c
                best = k
    out = disp.dtype(0.0)
    ok = int(0)
    if best >= 0:
        ok = 1
        out = disp.dtype(dmin + best)
        xm = xr + dmin + best - 1
        xp = xr + dmin + best + 1
        if subpixel != 0 and best > 0 and best + 1 < D and xm >= 0 and xp < W:
            out = out + disp.dtype(_parabola(cost[y, xm, best - 1], cbest, cost[y, xp, best + 1]))
    disp[y, xr] = out
    valid[y, xr] = wp.uint8(ok)


@wp.kernel
def _soft_argmin_forward(cost: wp.array3d(dtype=typing.Any), disp: wp.array2d(dtype=typing.Any), dmin: int,
                         temperature: wp.float64, offset: int):
    i = wp.tid() + offset
    W = cost.shape[1]
    y = i / W
    x = i - y * W
    inv_t = cost.dtype(wp.float64(1.0) / temperature)
    cmin = cost[y, x, 0]
    for k in range(1, cost.shape[2]):
        cmin = wp.min(cmin, cost[y, x, k])
    z = cost.dtype(0.0)
    num = cost.dtype(0.0)
    for k in range(cost.shape[2]):
        e = wp.exp((cmin - cost[y, x, k]) * inv_t)
        z += e
        num += e * cost.dtype(dmin + k)
    disp[y, x] = num / z


@wp.kernel
def _soft_argmin_backward(
    cost: wp.array3d(dtype=typing.Any),
    disp: wp.array2d(dtype=typing.Any),
    grad_disp: wp.array2d(dtype=typing.Any),
    grad_cost: wp.array3d(dtype=typing.Any),
    dmin: int,
    temperature: wp.float64,
    offset: int,
):
    # dd/dC_k = sigma_k (d - d_k) / T, with sigma recomputed from the cost and d the forward output.
    i = wp.tid() + offset
    W = cost.shape[1]
    y = i / W
    x = i - y * W
    inv_t = cost.dtype(wp.float64(1.0) / temperature)
    cmin = cost[y, x, 0]
    for k in range(1, cost.shape[2]):
        cmin = wp.min(cmin, cost[y, x, k])
    z = cost.dtype(0.0)
    for k in range(cost.shape[2]):
        z += wp.exp((cmin - cost[y, x, k]) * inv_t)
    g = grad_disp[y, x] * inv_t / z
    d = disp[y, x]
    for k in range(cost.shape[2]):
        e = wp.exp((cmin - cost[y, x, k]) * inv_t)
        grad_cost[y, x, k] = g * e * (d - cost.dtype(dmin + k))


@wp.kernel
def _left_right_check(
    disp_l: wp.array2d(dtype=typing.Any),
    valid_l: wp.array2d(dtype=wp.uint8),
    disp_r: wp.array2d(dtype=typing.Any),
    valid_r: wp.array2d(dtype=wp.uint8),
    out: wp.array2d(dtype=wp.uint8),
    max_diff: wp.float64,
    offset: int,
):
    i = wp.tid() + offset
    W = disp_l.shape[1]
    y = i / W
    x = i - y * W
    dl = disp_l[y, x]
    ok = int(0)
    if valid_l[y, x] != wp.uint8(0):
        xr = int(wp.floor(wp.float64(x) - wp.float64(dl) + wp.float64(0.5)))
        if xr >= 0 and xr < W:
            if valid_r[y, xr] != wp.uint8(0):
                if wp.abs(wp.float64(dl) - wp.float64(disp_r[y, xr])) <= max_diff:
                    ok = 1
    out[y, x] = wp.uint8(ok)


@wp.kernel
def _depth(
    disp: wp.array2d(dtype=typing.Any),
    valid: wp.array2d(dtype=wp.uint8),
    depth: wp.array2d(dtype=typing.Any),
    valid_out: wp.array2d(dtype=wp.uint8),
    fb: wp.float64,
    offset: int,
):
    i = wp.tid() + offset
    W = disp.shape[1]
    y = i / W
    x = i - y * W
    d = disp[y, x]
    z = depth.dtype(0.0)
    ok = int(0)
    if valid[y, x] != wp.uint8(0) and wp.isfinite(d) and d > disp.dtype(0.0):
        q = depth.dtype(fb) / d
        if wp.isfinite(q):
            z = q
            ok = 1
    depth[y, x] = z
    valid_out[y, x] = wp.uint8(ok)


def _declare_overloads() -> None:
    """Instantiate every generic kernel for float32 and float64 up front.

    The module then compiles once on first use; an overload first met at launch
    time would make Warp rebuild the whole module.
    """
    generic = (_integral_rows, _window_cost, _census_transform, _census_cost, _channels_last, _corr_forward,
               _corr_backward_left, _corr_backward_right, _pad_volume, _crop_volume, _wta, _wta_right,
               _soft_argmin_forward, _soft_argmin_backward, _left_right_check, _depth)
    for scalar in FLOATS:
        for kernel in generic:
            types = {a.label: wp.array(dtype=scalar, ndim=a.type.ndim) for a in kernel.adj.args
                     if wp.types.is_array(a.type) and a.type.dtype is typing.Any}
            wp.overload(kernel, types)
        vec = SGM_VEC[scalar]
        wp.overload(_sgm_axis, {"cost": wp.array(dtype=vec), "agg": wp.array(dtype=vec), "buf": wp.array(dtype=vec),
                                "p1": vec, "p2": vec})


_declare_overloads()


# =========================================================================== argument handling (host)


class _Args:
    """Converts inputs to wp.arrays on one device and remembers whether to hand back NumPy."""

    def __init__(self, device: Any):
        try:
            self.device = wp.get_device(device)
        except (RuntimeError, ValueError, TypeError) as exc:
            raise ValueError(f"device: cannot use {device!r} ({exc})") from None
        self.numpy = None  # set by the first array argument

    def _kind(self, name: str, is_numpy: bool) -> None:
        if self.numpy is None:
            self.numpy = is_numpy
        elif self.numpy != is_numpy:
            raise ValueError(f"{name}: mixes NumPy arrays and wp.arrays; pass all of one kind")

    def floats(self, name: str, x: Any, ndim: int, *, dtype: Any = None, check_finite: bool = True) -> wp.array:
        """A float32/float64 array of `ndim` dimensions (of `dtype` when given), checked finite."""
        if isinstance(x, wp.array):
            self._kind(name, False)
            if x.device != self.device:
                raise ValueError(f"{name}: is on {x.device}, expected device {self.device}")
            if x.dtype not in FLOATS:
                raise ValueError(f"{name}: dtype {wp.types.type_repr(x.dtype)}, expected float32 or float64")
            if x.ndim != ndim:
                raise ValueError(f"{name}: expected {ndim} dimensions, got shape {x.shape}")
            arr = x
            host = x.numpy() if check_finite else None
        elif isinstance(x, np.ndarray):
            self._kind(name, True)
            if x.dtype not in (np.float32, np.float64):
                raise ValueError(f"{name}: dtype {x.dtype}, expected float32 or float64")
            if x.ndim != ndim:
                raise ValueError(f"{name}: expected {ndim} dimensions, got shape {x.shape}")
            host = x if check_finite else None
            arr = None
        else:
            raise ValueError(f"{name}: expected a NumPy array or wp.array, got {type(x).__name__}")
        if min(x.shape) == 0:
            raise ValueError(f"{name}: is empty (shape {tuple(x.shape)})")
        wdt = arr.dtype if arr is not None else (wp.float32 if x.dtype == np.float32 else wp.float64)
        if dtype is not None and wdt != dtype:
            raise ValueError(f"{name}: dtype {wp.types.type_repr(wdt)}, expected {wp.types.type_repr(dtype)} "
                             "like the other inputs")
        if host is not None and not np.all(np.isfinite(host)):
            raise ValueError(f"{name}: holds non-finite values (NaN or inf)")
        if arr is None:
            arr = wp.array(np.ascontiguousarray(x), dtype=wdt, device=self.device)
        return arr

    def mask(self, name: str, m: Any, shape: tuple[int, ...]) -> wp.array:
        """A validity mask (bool or uint8 NumPy, uint8 wp.array) of `shape`, as a uint8 wp.array."""
        if isinstance(m, wp.array):
            self._kind(name, False)
            if m.device != self.device:
                raise ValueError(f"{name}: is on {m.device}, expected device {self.device}")
            if m.dtype != wp.uint8:
                raise ValueError(f"{name}: dtype {wp.types.type_repr(m.dtype)}, expected uint8")
            arr = m
        elif isinstance(m, np.ndarray):
            self._kind(name, True)
            if m.dtype not in (np.bool_, np.uint8):
                raise ValueError(f"{name}: dtype {m.dtype}, expected bool or uint8")
            arr = wp.array(np.ascontiguousarray(m, dtype=np.uint8), dtype=wp.uint8, device=self.device)
        else:
            raise ValueError(f"{name}: expected a NumPy array or wp.array, got {type(m).__name__}")
        if tuple(arr.shape) != tuple(shape):
            raise ValueError(f"{name}: shape {tuple(arr.shape)}, expected {tuple(shape)}")
        return arr

    def ones(self, shape: tuple[int, ...]) -> wp.array:
        return wp.ones(shape, dtype=wp.uint8, device=self.device)

    def out(self, x: wp.array) -> Any:
        return x.numpy() if self.numpy else x

    def out_mask(self, m: wp.array) -> Any:
        return m.numpy().astype(bool) if self.numpy else m


def _same_shape(names: tuple[str, str], a: wp.array, b: wp.array) -> None:
    if tuple(a.shape) != tuple(b.shape):
        raise ValueError(f"{names[1]}: shape {tuple(b.shape)} does not match {names[0]} shape {tuple(a.shape)}")


def _check_range(dmin: Any, dmax: Any, width: int) -> int:
    """Validate [dmin, dmax) against an image `width` pixels wide; returns D = dmax - dmin."""
    for name, v in (("dmin", dmin), ("dmax", dmax)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ValueError(f"{name}: expected an integer disparity, got {v!r}")
    if dmax <= dmin:
        raise ValueError(f"dmax: the disparity range [dmin, dmax) = [{dmin}, {dmax}) is empty")
    if dmax - dmin > width:
        raise ValueError(f"dmax: the disparity range [{dmin}, {dmax}) holds {dmax - dmin} hypotheses, "
                         f"more than the image width {width}")
    if dmin <= -width or dmax > width:
        raise ValueError(f"dmin, dmax: the range [{dmin}, {dmax}) must lie within (-{width}, {width}] "
                         "so that some pixel has a match")
    return int(dmax - dmin)


def _check_dmin(dmin: Any, n: int, width: int) -> None:
    """Validate dmin for a volume of `n` hypotheses over an image `width` pixels wide."""
    if isinstance(dmin, bool) or not isinstance(dmin, (int, np.integer)):
        raise ValueError(f"dmin: expected an integer disparity, got {dmin!r}")
    _check_range(int(dmin), int(dmin) + n, width)


def _int_at_least(name: str, v: Any, minimum: int = 0) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum:
        raise ValueError(f"{name}: expected an integer >= {minimum}, got {v!r}")
    return int(v)


def _finite_float(name: str, v: Any, *, positive: bool = False, nonneg: bool = False) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {v!r}") from None
    if not math.isfinite(f) or (positive and not f > 0) or (nonneg and not f >= 0):
        need = "a positive" if positive else ("a non-negative" if nonneg else "a finite")
        raise ValueError(f"{name}: expected {need} finite number, got {v!r}")
    return f


def _cpu_threads(device: wp.Device) -> int:
    return 1 if device.is_cuda else default_threads()


def _launch(kernel: Any, dim: int, inputs: list, device: wp.Device, min_chunk: int = 1024) -> None:
    # Every scalar float parameter of this module's kernels is float64 (Warp reads a Python float as float32).
    inputs = [wp.float64(v) if isinstance(v, float) else v for v in inputs]
    launch_split(kernel, dim, inputs, device=device, min_chunk=min_chunk)


def _image_pair(args: _Args, left: Any, right: Any) -> tuple[wp.array, wp.array]:
    l_img = args.floats("left", left, 2)
    r_img = args.floats("right", right, 2, dtype=l_img.dtype)
    _same_shape(("left", "right"), l_img, r_img)
    return l_img, r_img


# =========================================================================== entry points: costs


def _integral_tables(image: wp.array) -> tuple[wp.array, wp.array]:
    """Zero-padded float64 summed-area tables (H + 1, W + 1) of I and I^2 (image already validated)."""
    H, W = image.shape
    t1 = wp.zeros((H + 1, W + 1), dtype=wp.float64, device=image.device)
    t2 = wp.zeros((H + 1, W + 1), dtype=wp.float64, device=image.device)
    _launch(_integral_rows, H, [image, t1, t2], image.device, min_chunk=16)
    _launch(_integral_cols, W, [t1, t2], image.device, min_chunk=16)
    return t1, t2


def _window_volume(left: Any, right: Any, dmin: int, dmax: int, radius: int, mode: int, eps: float,
                   device: Any) -> Any:
    args = _Args(device)
    l_img, r_img = _image_pair(args, left, right)
    H, W = l_img.shape
    D = _check_range(dmin, dmax, W)
    r = _int_at_least("radius", radius)
    dev = args.device
    if mode == COST_SAD:
        # Out of range: the range of all pixel values bounds every in-range mean |L - R| from above.
        lh, rh = l_img.numpy(), r_img.numpy()
        invalid = float(max(lh.max(), rh.max())) - float(min(lh.min(), rh.min()))
        tables = [wp.zeros((1, 1), dtype=wp.float64, device=dev)] * 4
    else:
        invalid = 2.0
        tables = [*_integral_tables(l_img), *_integral_tables(r_img)]
    # Bands of rows: enough of them to balance the CPU threads, each long enough to amortise its start.
    band = max(2 * r + 1, math.ceil(H / (4 * _cpu_threads(dev))))
    n_bands = math.ceil(H / band)
    colsum = wp.empty((n_bands, W, D), dtype=wp.float64, device=dev)
    rowsum = wp.empty((n_bands, D), dtype=wp.float64, device=dev)
    out = wp.empty((H, W, D), dtype=l_img.dtype, device=dev)
    _launch(_window_cost, n_bands, [l_img, r_img, *tables, colsum, rowsum, out, int(dmin), r, band, mode, invalid,
                                    eps], dev, min_chunk=1)
    return args.out(out)


def sad_cost(left: Any, right: Any, dmin: int, dmax: int, radius: int = 2, *, device: Any = "cpu") -> Any:
    """Mean absolute difference over a (2 radius + 1)^2 window: volume (H, W, dmax - dmin)."""
    return _window_volume(left, right, dmin, dmax, radius, COST_SAD, 0.0, device)


def zncc_cost(left: Any, right: Any, dmin: int, dmax: int, radius: int = 3, *, eps: float = 1e-5,
              device: Any = "cpu") -> Any:
    """1 - zero-mean normalised cross-correlation over a (2 radius + 1)^2 window: volume (H, W, D)."""
    eps = _finite_float("eps", eps, positive=True)
    return _window_volume(left, right, dmin, dmax, radius, COST_ZNCC, eps, device)


def _census_radii(radius_y: Any, radius_x: Any) -> tuple[int, int, int]:
    ry = _int_at_least("radius_y", radius_y)
    rx = _int_at_least("radius_x", radius_x)
    bits = (2 * ry + 1) * (2 * rx + 1) - 1
    if bits < 1 or bits > CENSUS_MAX_BITS:
        raise ValueError(f"radius_y, radius_x: a {2 * ry + 1}x{2 * rx + 1} census window has {bits} bits; "
                         f"expected 1 to {CENSUS_MAX_BITS}")
    return ry, rx, bits


def census_transform(image: Any, radius_y: int = 3, radius_x: int = 4, *, device: Any = "cpu") -> Any:
    """Census bit strings (H, W) uint64 (see the module docstring for the bit order)."""
    args = _Args(device)
    img = args.floats("image", image, 2)
    ry, rx, _ = _census_radii(radius_y, radius_x)
    H, W = img.shape
    out = wp.empty((H, W), dtype=wp.uint64, device=args.device)
    _launch(_census_transform, H * W, [img, out, ry, rx], args.device)
    return args.out(out)


def census_cost(left: Any, right: Any, dmin: int, dmax: int, radius_y: int = 3, radius_x: int = 4, *,
                device: Any = "cpu") -> Any:
    """Hamming distance between census bit strings: volume (H, W, D) in the images' dtype."""
    args = _Args(device)
    l_img, r_img = _image_pair(args, left, right)
    H, W = l_img.shape
    D = _check_range(dmin, dmax, W)
    ry, rx, bits = _census_radii(radius_y, radius_x)
    dev = args.device
    cl = wp.empty((H, W), dtype=wp.uint64, device=dev)
    cr = wp.empty((H, W), dtype=wp.uint64, device=dev)
    _launch(_census_transform, H * W, [l_img, cl, ry, rx], dev)
    _launch(_census_transform, H * W, [r_img, cr, ry, rx], dev)
    out = wp.empty((H, W, D), dtype=l_img.dtype, device=dev)
    _launch(_census_cost, H * W, [cl, cr, out, int(dmin), bits], dev)
    return args.out(out)


def _features(args: _Args, feat_left: Any, feat_right: Any) -> tuple[wp.array, wp.array]:
    fl = args.floats("feat_left", feat_left, 3)
    fr = args.floats("feat_right", feat_right, 3, dtype=fl.dtype)
    _same_shape(("feat_left", "feat_right"), fl, fr)
    return fl, fr


def feature_correlation(feat_left: Any, feat_right: Any, dmin: int, dmax: int, *, device: Any = "cpu") -> Any:
    """<F_L(x, y), F_R(x - d, y)> / sqrt(C) for features (C, H, W): volume (H, W, D), 0 out of range."""
    args = _Args(device)
    fl, fr = _features(args, feat_left, feat_right)
    C, H, W = fl.shape
    D = _check_range(dmin, dmax, W)
    fl_last = wp.empty((H, W, C), dtype=fl.dtype, device=args.device)
    fr_last = wp.empty((H, W, C), dtype=fl.dtype, device=args.device)
    _launch(_channels_last, H * W, [fl, fl_last], args.device)
    _launch(_channels_last, H * W, [fr, fr_last], args.device)
    out = wp.empty((H, W, D), dtype=fl.dtype, device=args.device)
    _launch(_corr_forward, H * W, [fl_last, fr_last, out, int(dmin), 1.0 / math.sqrt(C)], args.device,
            min_chunk=256)
    return args.out(out)


def feature_correlation_backward(feat_left: Any, feat_right: Any, grad_corr: Any, dmin: int, *,
                                 device: Any = "cpu") -> tuple[Any, Any]:
    """Gradients (dF_L, dF_R), each (C, H, W), of a loss given grad_corr = dLoss/dcorr (H, W, D)."""
    args = _Args(device)
    fl, fr = _features(args, feat_left, feat_right)
    C, H, W = fl.shape
    g = args.floats("grad_corr", grad_corr, 3, dtype=fl.dtype)
    if tuple(g.shape[:2]) != (H, W):
        raise ValueError(f"grad_corr: shape {tuple(g.shape)}, expected ({H}, {W}, D)")
    _check_dmin(dmin, g.shape[2], W)
    dfl = wp.empty_like(fl)
    dfr = wp.empty_like(fr)
    scale = 1.0 / math.sqrt(C)
    _launch(_corr_backward_left, H * W, [g, fr, dfl, int(dmin), scale], args.device, min_chunk=256)
    _launch(_corr_backward_right, H * W, [g, fl, dfr, int(dmin), scale], args.device, min_chunk=256)
    return args.out(dfl), args.out(dfr)


# =========================================================================== entry points: aggregation


def sgm(cost: Any, p1: float, p2: float, paths: int = 8, *, device: Any = "cpu") -> Any:
    """Semi-global matching: S = sum over `paths` (4 or 8) directions of L_r; volume like `cost`."""
    args = _Args(device)
    c = args.floats("cost", cost, 3)
    if isinstance(paths, bool) or not isinstance(paths, (int, np.integer)) or paths not in (4, 8):
        raise ValueError(f"paths: expected 4 or 8, got {paths!r}")
    p1 = _finite_float("p1", p1, nonneg=True)
    p2 = _finite_float("p2", p2, nonneg=True)
    if p2 < p1:
        raise ValueError(f"p2: expected p2 >= p1 = {p1}, got {p2}")
    H, W, D = c.shape
    dev = args.device
    nb = -(-D // SGM_LANES)
    if nb * SGM_LANES != D:
        # Padding hypotheses cost more than any real L_r can reach (every L_r(p, k) <= C(p, k) + P2), so
        # with cost >= max C + 2 P2 they never undercut a real candidate, nor the running minimum.
        c_max = float(c.numpy().max())
        fill = c_max + 2.0 * p2 + abs(c_max) + 1.0
        padded = wp.empty((H, W, nb * SGM_LANES), dtype=c.dtype, device=dev)
        _launch(_pad_volume, H * W, [c, padded, fill], dev)
    else:
        padded = c.contiguous() if not c.is_contiguous else c
    vec = SGM_VEC[c.dtype]
    flat = wp.array(ptr=padded.ptr, dtype=vec, shape=(H * W * nb,), device=dev)
    agg = wp.empty((H, W, nb * SGM_LANES), dtype=c.dtype, device=dev)
    agg_flat = wp.array(ptr=agg.ptr, dtype=vec, shape=(H * W * nb,), device=dev)
    buf = wp.empty(((W + H - 1) * nb,), dtype=vec, device=dev)
    for j, (dy, dx) in enumerate(SGM_AXES[: paths // 2]):
        lines = H if dy == 0 else (W if dx == 0 else W + H - 1)
        _launch(_sgm_axis, lines, [flat, agg_flat, buf, H, W, dy, dx, vec(p1), vec(p2), int(j == 0)], dev,
                min_chunk=8)
    if nb * SGM_LANES != D:
        out = wp.empty((H, W, D), dtype=c.dtype, device=dev)
        _launch(_crop_volume, H * W, [agg, out], dev)
        agg = out
    return args.out(agg)


# =========================================================================== entry points: disparity


def _volume_and_dmin(args: _Args, cost: Any, dmin: Any) -> wp.array:
    c = args.floats("cost", cost, 3)
    _check_dmin(dmin, c.shape[2], c.shape[1])
    return c


def wta(cost: Any, dmin: int, *, subpixel: bool = True, uniqueness: float = 0.0,
        device: Any = "cpu") -> tuple[Any, Any]:
    """Winner-take-all left disparity (H, W) and its validity mask (see the module docstring)."""
    args = _Args(device)
    c = _volume_and_dmin(args, cost, dmin)
    u = _finite_float("uniqueness", uniqueness, nonneg=True)
    if u >= 1.0:
        raise ValueError(f"uniqueness: expected a ratio in [0, 1), got {uniqueness!r}")
    H, W, _ = c.shape
    disp = wp.empty((H, W), dtype=c.dtype, device=args.device)
    valid = wp.empty((H, W), dtype=wp.uint8, device=args.device)
    _launch(_wta, H * W, [c, disp, valid, int(dmin), int(bool(subpixel)), u], args.device, min_chunk=256)
    return args.out(disp), args.out_mask(valid)


def wta_right(cost: Any, dmin: int, *, subpixel: bool = True, device: Any = "cpu") -> tuple[Any, Any]:
    """The right view's winner-take-all disparity (H, W) from the left volume, and its validity mask."""
    args = _Args(device)
    c = _volume_and_dmin(args, cost, dmin)
    H, W, _ = c.shape
    disp = wp.empty((H, W), dtype=c.dtype, device=args.device)
    valid = wp.empty((H, W), dtype=wp.uint8, device=args.device)
    _launch(_wta_right, H * W, [c, disp, valid, int(dmin), int(bool(subpixel))], args.device, min_chunk=256)
    return args.out(disp), args.out_mask(valid)


def soft_argmin(cost: Any, dmin: int, temperature: float = 1.0, *, device: Any = "cpu") -> Any:
    """sum_k d_k softmax_k(-cost / temperature): disparity (H, W)."""
    args = _Args(device)
    c = _volume_and_dmin(args, cost, dmin)
    t = _finite_float("temperature", temperature, positive=True)
    H, W, _ = c.shape
    disp = wp.empty((H, W), dtype=c.dtype, device=args.device)
    _launch(_soft_argmin_forward, H * W, [c, disp, int(dmin), t], args.device, min_chunk=256)
    return args.out(disp)


def soft_argmin_backward(cost: Any, dmin: int, grad_disp: Any, temperature: float = 1.0, *,
                         device: Any = "cpu") -> Any:
    """dLoss/dcost (H, W, D) given grad_disp = dLoss/ddisp (H, W)."""
    args = _Args(device)
    c = _volume_and_dmin(args, cost, dmin)
    t = _finite_float("temperature", temperature, positive=True)
    H, W, _ = c.shape
    g = args.floats("grad_disp", grad_disp, 2, dtype=c.dtype)
    if tuple(g.shape) != (H, W):
        raise ValueError(f"grad_disp: shape {tuple(g.shape)}, expected ({H}, {W})")
    disp = wp.empty((H, W), dtype=c.dtype, device=args.device)
    _launch(_soft_argmin_forward, H * W, [c, disp, int(dmin), t], args.device, min_chunk=256)
    grad = wp.empty_like(c)
    _launch(_soft_argmin_backward, H * W, [c, disp, g, grad, int(dmin), t], args.device, min_chunk=256)
    return args.out(grad)


def left_right_check(disp_left: Any, disp_right: Any, max_diff: float = 1.0, *, valid_left: Any = None,
                     valid_right: Any = None, device: Any = "cpu") -> Any:
    """Validity mask (H, W) of the left disparity after the left-right consistency check."""
    args = _Args(device)
    dl = args.floats("disp_left", disp_left, 2)
    dr = args.floats("disp_right", disp_right, 2, dtype=dl.dtype)
    _same_shape(("disp_left", "disp_right"), dl, dr)
    tol = _finite_float("max_diff", max_diff, nonneg=True)
    shape = tuple(dl.shape)
    vl = args.ones(shape) if valid_left is None else args.mask("valid_left", valid_left, shape)
    vr = args.ones(shape) if valid_right is None else args.mask("valid_right", valid_right, shape)
    out = wp.empty(shape, dtype=wp.uint8, device=args.device)
    _launch(_left_right_check, shape[0] * shape[1], [dl, vl, dr, vr, out, tol], args.device)
    return args.out_mask(out)


def depth_from_disparity(disp: Any, focal: float, baseline: float, *, valid: Any = None,
                         device: Any = "cpu") -> tuple[Any, Any]:
    """Z = focal * baseline / d: depth (H, W) with 0 where invalid, and the validity mask."""
    args = _Args(device)
    d = args.floats("disp", disp, 2, check_finite=False)  # non-finite disparities are marked invalid
    f = _finite_float("focal", focal, positive=True)
    b = _finite_float("baseline", baseline, positive=True)
    shape = tuple(d.shape)
    v = args.ones(shape) if valid is None else args.mask("valid", valid, shape)
    depth = wp.empty(shape, dtype=d.dtype, device=args.device)
    valid_out = wp.empty(shape, dtype=wp.uint8, device=args.device)
    _launch(_depth, shape[0] * shape[1], [d, v, depth, valid_out, f * b], args.device)
    return args.out(depth), args.out_mask(valid_out)
