"""Matching costs of a rectified pair: SAD, ZNCC, census and feature correlation volumes (H, W, D).

Every volume holds, for the pixel (x, y) and the hypothesis d_k = dmin + k, the cost of matching
the left pixel (x, y) with the right pixel (x - d_k, y); lower is better, except for the feature
correlation (a similarity). A cell is *in range* when its right pixel exists, 0 <= x - d_k < W;
cells out of range hold a fixed cost no real match can beat (each cost below names it).

* SAD over a (2r+1)^2 window, normalised by the number of cells summed,

      C_SAD(x, y, d) = 1/|N| sum_{(u, v) in N} |I_L(u, v) - I_R(u - d, v)|,

  where N is the window cut to the image and to the columns whose right pixel exists
  (u - d in [0, W)). Out of range: the range of all pixel values (max - min over both images),
  an upper bound of any in-range SAD.
* ZNCC over the same window N, with a variance floor eps (intensity^2 units) that keeps flat
  windows finite and drives them to zero correlation,

      rho = cov(L, R) / sqrt((var L + eps) (var R + eps)),   C_ZNCC = 1 - rho in (0, 2).

  Out of range: 2.
  Both window costs take O(1) work per cell, never O(window): per-image sums of I and I^2 come
  from integral images (summed-area tables, Crow 1984) in float64, and the per-disparity sums
  (|L - R| or L R) from running box sums: a thread owns a band of rows and keeps, for every
  (column, disparity), the sum over the window's rows (updated by one row in, one row out per
  output row), then slides the window along the row (one column in, one out).
* Census (Zabih & Woodfill, ECCV 1994): a (2 ry + 1) x (2 rx + 1) window (at most 64 bits, the
  centre excluded) becomes a bit string with bit [I(q) < I(p)] per neighbour q (raster order,
  coordinates clamped to the image); the cost is the Hamming distance
  popcount(c_L(x, y) xor c_R(x - d, y)). Out of range: the number of bits. With `compact` the
  volume is uint8 (every distance is an integer <= 64), for kernels.stereo.sgm's compact mode. The
  transform runs in kernels.stereo.census (one kernel per window size, its loops unrolled; float32
  on the CPU a row per thread in vector lanes).
* Feature correlation, RAFT-Stereo's 1D correlation (Lipson, Teed & Deng, 3DV 2021) restricted to
  the disparity range, for learned features F (C, H, W) (PyTorch's layout, as kernels/corr.py):

      corr(x, y, k) = <F_L(x, y), F_R(x - d_k, y)> / sqrt(C),    0 out of range.

  Backward, for an upstream gradient G = dLoss/dcorr, both as gathers: each thread writes only its
  own pixel, so no atomics are needed (Warp's are not atomic between concurrent CPU launches,
  docs/warp.md):

      dF_L(x, y) = sum_k G(x, y, k) F_R(x - d_k, y) / sqrt(C)
      dF_R(x', y) = sum_k G(x' + d_k, y, k) F_L(x' + d_k, y) / sqrt(C).
"""

from __future__ import annotations

import math
import typing
from typing import Any

import warp as wp

from kernels import fast_paths
from kernels._arrays import Inputs, check_float, check_int, declare_float_overloads
from kernels.launch import default_threads
from kernels.stereo._common import check_dmin, check_range, image_pair, pixel
from kernels.stereo.census import census_kernel, census_rows_f32

# Every backward here is a hand-written kernel; Warp's autodiff code would only add compile time.
wp.set_module_options({"enable_backward": False})

CENSUS_MAX_BITS = 64
# The census cost is written as 8-wide vectors of hypotheses (SIMD stores on the CPU).
CENSUS_VEC = {wp.float32: wp.types.vector(length=8, dtype=wp.float32),
              wp.float64: wp.types.vector(length=8, dtype=wp.float64)}
COST_SAD = 0
COST_ZNCC = 1


# =========================================================================== helpers (device)


@wp.func
def _box(t: wp.array2d(dtype=wp.float64), y0: int, y1: int, x0: int, x1: int) -> wp.float64:
    """Sum over rows [y0, y1] and columns [x0, x1] (inclusive) from a zero-padded summed-area table."""
    return t[y1 + 1, x1 + 1] - t[y0, x1 + 1] - t[y1 + 1, x0] + t[y0, x0]


# =========================================================================== integral images


@wp.kernel
def _integral_rows(img: wp.array2d(dtype=typing.Any), t1: wp.array2d(dtype=wp.float64),
                   t2: wp.array2d(dtype=wp.float64), offset: int):
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
def _add_row(left: wp.array2d(dtype=typing.Any), right: wp.array2d(dtype=typing.Any),
             colsum: wp.array3d(dtype=wp.float64), b: int, v: int, sign: wp.float64, dmin: int, mode: int):
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
def _window_cost(left: wp.array2d(dtype=typing.Any), right: wp.array2d(dtype=typing.Any),
                 tl: wp.array2d(dtype=wp.float64), tl2: wp.array2d(dtype=wp.float64),
                 tr: wp.array2d(dtype=wp.float64), tr2: wp.array2d(dtype=wp.float64),
                 colsum: wp.array3d(dtype=wp.float64), rowsum: wp.array2d(dtype=wp.float64),
                 out: wp.array3d(dtype=typing.Any),
                 dmin: int, radius: int, band: int, mode: int, invalid: wp.float64, eps: wp.float64, offset: int):
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


@wp.func
def _hamming(a: wp.uint64, cr: wp.array2d(dtype=wp.uint64), y: int, u: int, invalid: int) -> int:
    """popcount(a ^ cr[y, u]), the census distance to the right pixel u of row y; `invalid` outside the row."""
    if u >= 0 and u < cr.shape[1]:
        return int(wp.bit_count(a ^ cr[y, u]))
    return invalid


@wp.kernel
def _census_cost(cl: wp.array2d(dtype=wp.uint64), cr: wp.array2d(dtype=wp.uint64), out: wp.array3d(dtype=typing.Any),
                 dmin: int, invalid: int, offset: int):
    W = cl.shape[1]
    y, x = pixel(wp.tid() + offset, W)
    a = cl[y, x]
    for k in range(out.shape[2]):
        out[y, x, k] = out.dtype(_hamming(a, cr, y, x - (dmin + k), invalid))


@wp.kernel
def _census_cost_v(cl: wp.array2d(dtype=wp.uint64), cr: wp.array2d(dtype=wp.uint64), out_v: wp.array(dtype=typing.Any),
                   dmin: int, invalid: int, offset: int):
    # _census_cost for D a multiple of 8: the volume as a flat array of 8-wide vectors, nb = D / 8 per
    # pixel, each built in registers and stored whole.
    W = cl.shape[1]
    y, x = pixel(wp.tid() + offset, W)
    nb = out_v.shape[0] / (cl.shape[0] * W)
    a = cl[y, x]
    base = (y * W + x) * nb
    for j in range(nb):
        v = out_v.dtype()
        u0 = x - (dmin + j * 8)
        if u0 - 7 >= 0 and u0 < W:  # every lane's right pixel exists: no test per lane
            for lane in range(8):
                v[lane] = type(v[0])(wp.bit_count(a ^ cr[y, u0 - lane]))
        else:
            for lane in range(8):
                v[lane] = type(v[0])(_hamming(a, cr, y, u0 - lane, invalid))
        out_v[base + j] = v


# =========================================================================== feature correlation


@wp.kernel
def _channels_last(src: wp.array3d(dtype=typing.Any), dst: wp.array3d(dtype=typing.Any), offset: int):
    W = src.shape[2]
    y, x = pixel(wp.tid() + offset, W)
    for c in range(src.shape[0]):
        dst[y, x, c] = src[c, y, x]


@wp.kernel
def _corr_forward(fl: wp.array3d(dtype=typing.Any), fr: wp.array3d(dtype=typing.Any), out: wp.array3d(dtype=typing.Any),
                  dmin: int, scale: wp.float64, offset: int):
    # Features channels-last (H, W, C) here, so each dot product reads two contiguous rows.
    W = fl.shape[1]
    y, x = pixel(wp.tid() + offset, W)
    s = out.dtype(scale)
    for k in range(out.shape[2]):
        u = x - (dmin + k)
        acc = out.dtype(0.0)
        if u >= 0 and u < W:
            for c in range(fl.shape[2]):
                acc += fl[y, x, c] * fr[y, u, c]
        out[y, x, k] = acc * s


@wp.kernel
def _corr_backward_left(grad: wp.array3d(dtype=typing.Any), fr: wp.array3d(dtype=typing.Any),
                        dfl: wp.array3d(dtype=typing.Any), dmin: int, scale: wp.float64, offset: int):
    W = fr.shape[2]
    y, x = pixel(wp.tid() + offset, W)
    k0 = wp.max(0, x - W + 1 - dmin)
    k1 = wp.min(grad.shape[2], x - dmin + 1)
    for c in range(fr.shape[0]):
        acc = dfl.dtype(0.0)
        for k in range(k0, k1):
            acc += grad[y, x, k] * fr[c, y, x - dmin - k]
        dfl[c, y, x] = acc * dfl.dtype(scale)


@wp.kernel
def _corr_backward_right(grad: wp.array3d(dtype=typing.Any), fl: wp.array3d(dtype=typing.Any),
                         dfr: wp.array3d(dtype=typing.Any), dmin: int, scale: wp.float64, offset: int):
    # Gather form: right pixel u receives from every left pixel x = u + d_k that matched it.
    W = fl.shape[2]
    y, u = pixel(wp.tid() + offset, W)
    k0 = wp.max(0, -u - dmin)  # 0 <= u + dmin + k < W
    k1 = wp.min(grad.shape[2], W - u - dmin)
    for c in range(fl.shape[0]):
        acc = dfr.dtype(0.0)
        for k in range(k0, k1):
            acc += grad[y, u + dmin + k, k] * fl[c, y, u + dmin + k]
        dfr[c, y, u] = acc * dfr.dtype(scale)


declare_float_overloads(_census_cost_v, vector_types=CENSUS_VEC)
CENSUS_U8_VEC = wp.types.vector(length=8, dtype=wp.uint8)
wp.overload(_census_cost_v, {"out_v": wp.array(dtype=CENSUS_U8_VEC)})
wp.overload(_census_cost, {"out": wp.array3d(dtype=wp.uint8)})
for _kernel in (_integral_rows, _window_cost, _census_cost, _channels_last, _corr_forward,
                _corr_backward_left, _corr_backward_right):
    declare_float_overloads(_kernel)


# =========================================================================== entry points


def _integral_tables(a: Inputs, image: wp.array) -> tuple[wp.array, wp.array]:
    """Zero-padded float64 summed-area tables (H + 1, W + 1) of I and I^2 (image already validated)."""
    H, W = image.shape
    t1 = a.zeros((H + 1, W + 1), wp.float64)
    t2 = a.zeros((H + 1, W + 1), wp.float64)
    a.launch(_integral_rows, H, [image, t1, t2], min_chunk=16)
    a.launch(_integral_cols, W, [t1, t2], min_chunk=16)
    return t1, t2


def _window_volume(left: Any, right: Any, dmin: int, dmax: int, radius: int, mode: int, eps: float,
                   device: Any) -> Any:
    a = Inputs(device, left, right)
    l_img, r_img = image_pair(a, left, right)
    H, W = l_img.shape
    dmin, D = check_range(dmin, dmax, W)
    r = check_int("radius", radius, minimum=0)
    if mode == COST_SAD:
        # Out of range: the range of all pixel values bounds every in-range mean |L - R| from above.
        lh, rh = l_img.numpy(), r_img.numpy()
        invalid = float(max(lh.max(), rh.max())) - float(min(lh.min(), rh.min()))
        tables = [a.zeros((1, 1), wp.float64)] * 4
    else:
        invalid = 2.0
        tables = [*_integral_tables(a, l_img), *_integral_tables(a, r_img)]
    # Bands of rows: enough of them to balance the CPU threads, each long enough to amortise its start.
    threads = 1 if a.device.is_cuda else default_threads()
    band = max(2 * r + 1, math.ceil(H / (4 * threads)))
    n_bands = math.ceil(H / band)
    colsum = a.empty((n_bands, W, D), wp.float64)
    rowsum = a.empty((n_bands, D), wp.float64)
    out = a.empty((H, W, D))
    a.launch(_window_cost, n_bands, [l_img, r_img, *tables, colsum, rowsum, out, dmin, r, band, mode,
                                     wp.float64(invalid), wp.float64(eps)], min_chunk=1)
    return a.out(out)


def sad_cost(left: Any, right: Any, dmin: int, dmax: int, radius: int = 2, *, device: Any = None) -> Any:
    """Mean absolute difference over a (2 radius + 1)^2 window: volume (H, W, dmax - dmin)."""
    return _window_volume(left, right, dmin, dmax, radius, COST_SAD, 0.0, device)


def zncc_cost(left: Any, right: Any, dmin: int, dmax: int, radius: int = 3, *, eps: float = 1e-5,
              device: Any = None) -> Any:
    """1 - zero-mean normalised cross-correlation over a (2 radius + 1)^2 window: volume (H, W, D)."""
    eps = check_float("eps", eps, positive=True)
    return _window_volume(left, right, dmin, dmax, radius, COST_ZNCC, eps, device)


def _census_radii(radius_y: Any, radius_x: Any) -> tuple[int, int, int]:
    ry = check_int("radius_y", radius_y, minimum=0)
    rx = check_int("radius_x", radius_x, minimum=0)
    bits = (2 * ry + 1) * (2 * rx + 1) - 1
    if bits < 1 or bits > CENSUS_MAX_BITS:
        raise ValueError(f"radius_y, radius_x: a {2 * ry + 1}x{2 * rx + 1} census window has {bits} bits; "
                         f"expected 1 to {CENSUS_MAX_BITS}")
    return ry, rx, bits


def _census_launch(a: Inputs, img: wp.array, out: wp.array, ry: int, rx: int) -> None:
    """The census strings of `img` into `out`: float32 on the CPU a row per thread in vector lanes
    (kernels.stereo.census.census_rows_f32), else a pixel per thread (census_kernel); the same bits."""
    if fast_paths.on(a.device) and img.dtype == wp.float32:
        a.launch(census_rows_f32, img.shape[0], [img, out, ry, rx], min_chunk=4)
    else:
        a.launch(census_kernel(ry, rx), img.size, [img, out])


def census_transform(image: Any, radius_y: int = 3, radius_x: int = 4, *, device: Any = None) -> Any:
    """Census bit strings (H, W) uint64 (see the module docstring for the bit order)."""
    a = Inputs(device, image)
    img = a.floats("image", image, ndim=2, nonempty=True)
    ry, rx, _ = _census_radii(radius_y, radius_x)
    out = a.empty(img.shape, wp.uint64)
    _census_launch(a, img, out, ry, rx)
    return a.out(out)


def census_cost(left: Any, right: Any, dmin: int, dmax: int, radius_y: int = 3, radius_x: int = 4, *,
                compact: bool = False, device: Any = None) -> Any:
    """Hamming distance between census bit strings: volume (H, W, D) in the images' dtype, or in uint8 with
    `compact` (a quarter of float32's memory; the distances are integers <= 64, stored exactly)."""
    a = Inputs(device, left, right)
    l_img, r_img = image_pair(a, left, right)
    H, W = l_img.shape
    dmin, D = check_range(dmin, dmax, W)
    ry, rx, bits = _census_radii(radius_y, radius_x)
    cl = a.empty((H, W), wp.uint64)
    cr = a.empty((H, W), wp.uint64)
    _census_launch(a, l_img, cl, ry, rx)
    _census_launch(a, r_img, cr, ry, rx)
    out = a.empty((H, W, D), wp.uint8 if compact else None)
    if D % 8 == 0:
        vec = CENSUS_U8_VEC if compact else CENSUS_VEC[a.scalar]
        out_v = wp.array(ptr=out.ptr, dtype=vec, shape=(H * W * D // 8,), device=a.device)
        a.launch(_census_cost_v, H * W, [cl, cr, out_v, dmin, bits])
    else:
        a.launch(_census_cost, H * W, [cl, cr, out, dmin, bits])
    return a.out(out)


def feature_correlation(feat_left: Any, feat_right: Any, dmin: int, dmax: int, *, device: Any = None) -> Any:
    """<F_L(x, y), F_R(x - d, y)> / sqrt(C) for features (C, H, W): volume (H, W, D), 0 out of range."""
    a = Inputs(device, feat_left, feat_right)
    fl, fr = image_pair(a, feat_left, feat_right, 3, ("feat_left", "feat_right"))
    C, H, W = fl.shape
    dmin, D = check_range(dmin, dmax, W)
    fl_last = a.empty((H, W, C))
    fr_last = a.empty((H, W, C))
    a.launch(_channels_last, H * W, [fl, fl_last])
    a.launch(_channels_last, H * W, [fr, fr_last])
    out = a.empty((H, W, D))
    a.launch(_corr_forward, H * W, [fl_last, fr_last, out, dmin, wp.float64(1.0 / math.sqrt(C))], min_chunk=256)
    return a.out(out)


def feature_correlation_backward(feat_left: Any, feat_right: Any, grad_corr: Any, dmin: int, *,
                                 device: Any = None) -> dict[str, Any]:
    """Gradients of a loss given grad_corr = dLoss/dcorr (H, W, D).

    Returns a dict {"feat_left": dLoss/dF_L, "feat_right": dLoss/dF_R}, each (C, H, W), in the
    kind of `feat_left` (NumPy arrays, or wp.arrays on the device).
    """
    a = Inputs(device, feat_left, feat_right, grad_corr)
    fl, fr = image_pair(a, feat_left, feat_right, 3, ("feat_left", "feat_right"))
    C, H, W = fl.shape
    g = a.floats("grad_corr", grad_corr, (H, W, None))
    dmin = check_dmin(dmin, g.shape[2], W, "grad_corr")
    dfl = a.empty(fl.shape)
    dfr = a.empty(fr.shape)
    scale = wp.float64(1.0 / math.sqrt(C))
    a.launch(_corr_backward_left, H * W, [g, fr, dfl, dmin, scale], min_chunk=256)
    a.launch(_corr_backward_right, H * W, [g, fl, dfr, dmin, scale], min_chunk=256)
    return {"feat_left": a.out(dfl), "feat_right": a.out(dfr)}
