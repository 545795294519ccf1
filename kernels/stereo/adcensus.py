"""A matching cost for real camera pairs: census + Birchfield-Tomasi on a clipped x-gradient (+ intensity).

Real pairs differ in gain, offset and vignetting between the cameras, which an intensity cost
(SAD, BT) reads as mismatch. This cost combines terms that are robust to those differences, each
squashed to [0, 1) by rho(c, lambda) = 1 - exp(-c / lambda) before they are summed, as AD-Census does
(Mei et al., ICCV Workshops 2011), so that no term dominates by its units and one outlying term
cannot exceed its weight:

    C(x, y, d) = rho(C_census, l_census) + rho(C_grad, l_grad) + w_bt rho(C_bt, l_bt).

* C_census: the Hamming distance of census bit strings (kernels.stereo.costs.census_cost) over a
  (2 ry + 1) x (2 rx + 1) window of the grey images; invariant to any monotonic intensity change
  (gain, offset, gamma); l_census in bits. With a tolerance census_eps > 0 (in [0, 1] intensity units)
  the bit is [I(q) < I(p) - eps]: on a flat, noisy surface (a textureless wall) every bit is then 0
  in both views instead of a coin toss, so the term is flat there; still invariant to an offset, not
  to gain (it did not improve drlab's tuning pairs, research.stereo; off by default).
* C_grad: the Birchfield-Tomasi window mean (kernels.stereo.bt) on the images' clipped x-gradient,
  StereoSGBM's prefilter. Per channel c of an image I in [0, 1] (rows clamped at the border),

      g(x, y) = sum_{dy in -1..1} w_dy (I(x + 1, y + dy) - I(x - 1, y + dy)),  w = (1, 2, 1),
      G(x, y) = (clip(g, -cap, cap) + cap) / (2 cap)  in [0, 1],

  (columns clamped too), the x-Sobel filter; it does not see an intensity offset, and the clip
  bounds what a gain change can do to strong edges. l_grad in units of G, i.e. fractions of the
  clipped gradient range 2 cap.
* C_bt: the Birchfield-Tomasi window mean on the intensities (grey or the channel mean of colour),
  with weight w_bt (0 drops it); l_bt in [0, 1] intensity units.

Every term is independent of the stored image range once the images are in [0, 1] (research.images'
normalisation). Each term's out-of-range cells (x - d outside [0, W)) hold its own maximum (census:
the bit count; BT: the value range), so the sum's out-of-range cost is at least every in-range one.

Launches: the census bit strings of each grey image (one uint64 per pixel, computed once;
kernels.stereo.costs.census_transform), the gradient images, each term image's half-pixel ranges
(I_min, I_max) of the BT dissimilarity, a table rho(h, l_census) for every Hamming distance h, then ONE
fused launch that writes the final cost: a thread owns a band of rows and keeps, per BT term, a ring
of the 2 r + 1 rows of per-pixel bt values its window needs (each row computed once per band) and
their row sums; for every cell it adds rho(popcount(c_L xor c_R)) from the table and the two terms'
rho(window mean). The sums and rho run in the images' float type in the order of the separate passes
(kernels.stereo.bt's, then the terms added in order), so the volume is bit-identical to the former
composition of census_cost, bt_cost and one rho-accumulation pass per term. No (H, W, D) volume besides the
result exists; the band buffers hold 2 (2 r + 2) W D' values per band (D' = D rounded up to whole vectors).

Vector form. The hypotheses of a pixel go through in vectors of 16 float32 (8 float64) lanes, Warp's fixed-size
vectors, which the CPU compiler turns into the host's SIMD registers (compiled with -march=native as
kernels.stereo.sweep, and with FMA contraction off so no multiply-add is fused on any host). Each right term
image and its half-pixel ranges are first copied with every row mirrored and the channels planar, so that
R(x - d_k) over consecutive k is a run of consecutive scalars (read as an unaligned vector; zero margins of one
vector width on each side cover the lanes past the image). A ring row is filled a vector at a time (every vector
holding an in-range cell of the row; its other lanes hold finite values that are never read), the row sums are
vector sums, and where a vector's 16 cells all lie in range with the same window [max(x - r, 0), min(x + r,
W - 1)] (the window bounds of kernels.stereo.bt's mean then do not depend on d) the window mean is a vector sum
divided by the cell count. In float32 each BT term's rho then runs on the 16 lanes with kernels._vexp's exp, which
has the bits of glibc's expf (what wp.exp calls on the CPU) for every float32 (C++ via wp.func_native,
kernels/native/adcensus_rho16.cpp, where the CPU has AVX2 and FMA; elsewhere and on CUDA, wp.exp lane by lane), and
for float32 volumes the census lookup, the sum and the store run in C++ as well (adcensus_cells16.cpp); float64 rho
and compact volumes' sums and stores go lane by lane. Other vectors (near the image's left and right ends, a
partial last vector) run a lane at a time as before.
Every vector operation is the scalar operation on each lane in the same order, so the volume is bit for bit the
scalar kernel's (tests: the vector and the lane-at-a-time hypotheses agree exactly).

Compact mode (`levels` = q > 0, float32 images): the cost is stored as the uint8 round(C q), with
q <= 255 / (2 + w_bt) so that every cost (< 2 + w_bt) fits; the quantisation step is 1 / q
(compact_levels(0.3) = 110: a step of 0.0091, at most 0.0045 off), a quarter of float32's memory,
and the volume kernels.stereo.sgm's compact mode takes with integer penalties P q.

Vector rho (compact mode with `vector_rho`, float32 on the CPU; research.stereo's DEFAULT_CONFIG runs it): the
two BT terms' rho go through 16 lanes at once instead of one scalar exp per lane. For z = c / lambda,

    e^-z ~ p(min(z, 24) / 32)^32,   p(t) = sum_{n=0..8} (-t)^n / n!   (Horner, then 5 squarings),

in float32 without FMA contraction. For t <= 0.75 the Taylor remainder is below 0.75^9 / 9! = 2.1e-7 relative,
which the squarings multiply by 32 (6.6e-6), plus float32 rounding of the same order; clipping z at 24 moves
e^-z by under 4e-11. So each rho is within about 2e-5 of 1 - exp(-z), under 3e-3 levels at q = 110: a cell's
uint8 round(C q) can differ from the scalar-exp volume's by one level only where C q lies that close to a half
level (2.6e-6 of the cells at 741x500x64 on the bench pair; tests bound it). The census term keeps its table
(exact), out-of-range lanes take each term's out-of-range value through the same polynomial, and the sum,
quantisation and store run on the vector (uint8 lanes). A cell's value depends only on (x, y, d): vectors
and lanes computed one at a time (the image's left columns, a partial last vector) agree exactly. The window's
row sums are running sums in this mode (row y - r - 1 subtracted, row y + r added; recomputed at each band's
first row) instead of 2 r + 1 rows added per row: float32 rounding of a sum of at most 2 r + 1 terms in [0, 1]
per band, far below the quantisation step (2.8e-6 of the cells at 741x500x64 differ by one level from the
scalar-exp compact volume, polynomial included).
"""

from __future__ import annotations

import math
import typing
from typing import Any

import warp as wp

from kernels._arrays import Inputs, check_float, check_int, declare_float_overloads
from kernels.launch import default_threads
from kernels.native import source
from kernels.stereo._common import check_range, image_pair, pixel
from kernels.stereo.bt import _half_range
from kernels.stereo.costs import _census_radii, census_transform

# The host's vector width (-march=native, as kernels.stereo.sweep); fuse_fp off: no multiply-add is ever contracted
# into an FMA, so every value is the same on hosts with and without FMA units.
wp.set_module_options({"enable_backward": False, "optimization_level": 3, "fuse_fp": False,
                       "cpu_compiler_flags": "-march=native -mllvm=-inline-threshold=9000"})


# The per-image passes below (_sobel_x, _half_ranges, _reverse_planar) run one thread per row: a thread per pixel
# spent most of its time in the launch's per-thread overhead, the work per pixel being a few loads and min / max.


@wp.kernel
def _sobel_x(img: wp.array3d(dtype=typing.Any), out: wp.array3d(dtype=typing.Any), cap: wp.float64,
             offset: int):
    H = img.shape[0]
    W = img.shape[1]
    y = wp.tid() + offset
    ym = wp.max(y - 1, 0)
    yp = wp.min(y + 1, H - 1)
    c_ = img.dtype(cap)
    two = img.dtype(2.0)
    for x in range(W):
        xm = wp.max(x - 1, 0)
        xp = wp.min(x + 1, W - 1)
        for c in range(img.shape[2]):
            g = (img[ym, xp, c] - img[ym, xm, c]) + two * (img[y, xp, c] - img[y, xm, c]) + \
                (img[yp, xp, c] - img[yp, xm, c])
            g = wp.min(wp.max(g, -c_), c_)
            out[y, x, c] = (g + c_) / (two * c_)


@wp.kernel
def _census_eps(img: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=wp.uint64), ry: int, rx: int,
                eps: wp.float64, offset: int):
    # kernels.stereo.costs' census transform with the bit [I(q) < I(p) - eps] (same order, clamped coordinates).
    H = img.shape[0]
    W = img.shape[1]
    y, x = pixel(wp.tid() + offset, W)
    c = img[y, x] - img.dtype(eps)
    bits = wp.uint64(0)
    for dy in range(-ry, ry + 1):
        yy = wp.clamp(y + dy, 0, H - 1)
        for dx in range(-rx, rx + 1):
            if dy != 0 or dx != 0:
                q = img[yy, wp.clamp(x + dx, 0, W - 1)]
                bits = (bits << wp.uint64(1)) | wp.uint64(wp.where(q < c, 1, 0))
    out[y, x] = bits


@wp.kernel
def _half_ranges(img: wp.array3d(dtype=typing.Any), lo: wp.array3d(dtype=typing.Any),
                 hi: wp.array3d(dtype=typing.Any), offset: int):
    # (I_min, I_max) of every pixel's half-pixel neighbourhood per channel (kernels.stereo.bt's _half_range).
    y = wp.tid() + offset
    for x in range(img.shape[1]):
        for c in range(img.shape[2]):
            a, b = _half_range(img, y, x, c)
            lo[y, x, c] = a
            hi[y, x, c] = b


@wp.func
def _robust_term(c: typing.Any, lam: wp.float64, weight: wp.float64):
    """w rho(c, lambda) = w (1 - exp(-c / lambda)), with 1 / lambda rounded to c's type once."""
    inv = type(c)(wp.float64(1.0) / lam)
    return type(c)(weight) * (type(c)(1.0) - wp.exp(-c * inv))


@wp.kernel
def _rho_table(table: wp.array(dtype=typing.Any), lam: wp.float64, offset: int):
    # table[h] = 1 - exp(-h / lambda) for the census distance h, with _robust_term's arithmetic.
    h = wp.tid() + offset
    table[h] = _robust_term(table.dtype(h), lam, wp.float64(1.0))


@wp.func
def _bt_cell(L: wp.array3d(dtype=typing.Any), l_lo: wp.array3d(dtype=typing.Any), l_hi: wp.array3d(dtype=typing.Any),
             R: wp.array3d(dtype=typing.Any), r_lo: wp.array3d(dtype=typing.Any), r_hi: wp.array3d(dtype=typing.Any),
             y: int, x: int, u: int):
    """bt(x, y, d) for u = x - d inside the image, the channel mean (kernels.stereo.bt's _bt_pixel)."""
    zero = L.dtype(0.0)
    acc = zero
    C = L.shape[2]
    for c in range(C):
        lv = L[y, x, c]
        rv = R[y, u, c]
        e_lr = wp.max(wp.max(zero, lv - r_hi[y, u, c]), r_lo[y, u, c] - lv)
        e_rl = wp.max(wp.max(zero, rv - l_hi[y, x, c]), l_lo[y, x, c] - rv)
        acc += wp.min(e_lr, e_rl)
    return acc * (L.dtype(1.0) / L.dtype(C))


# Hypotheses go through in vectors of LANES (16 float32 or 8 float64; AVX-512 registers where the CPU has them):
# every vector operation below is the scalar operation of the same name on each lane, so a lane's value is the
# scalar loop's value bit for bit (module docstring: Vector form).
LANES = {wp.float32: 16, wp.float64: 8}
VEC = {s: wp.types.vector(length=n, dtype=s) for s, n in LANES.items()}


_V32 = VEC[wp.float32]
_V64 = VEC[wp.float64]

# w rho(c) = w (1 - exp(-c inv)) on 16 float32 lanes: _robust_term's operations in its order on each lane, with
# kernels._vexp's exp (glibc expf's bits, wp.exp's on the CPU); no contraction, one operation per statement. Where
# the lanes' exp is not compiled (CUDA, CPUs without AVX2 / FMA), wp.exp lane by lane.
@wp.func_native(source("adcensus_rho16.cpp"))
def _rho16(c: _V32, inv: wp.float32, weight: wp.float32) -> _V32: ...


@wp.func
def _rho_lanes(c: _V32, inv: wp.float32, weight: wp.float32):
    """_robust_term of every lane with 1 / lambda = inv (adcensus_rho16.cpp)."""
    return _rho16(c, inv, weight)


@wp.func
def _rho_lanes(c: _V64, inv: wp.float64, weight: wp.float64):
    """_robust_term of every lane with 1 / lambda = inv, a lane at a time."""
    res = _V64()
    for i in range(8):
        res[i] = weight * (wp.float64(1.0) - wp.exp(-c[i] * inv))
    return res


# The 16 cells (x, d0 + i) of a vector whose lanes are all in range, float32 volume: census table + rho_grad
# (+ rho_bt), stored; the fused kernel's lane loop in C++ (the same operations in its order, contraction off), so
# the sums and stores run on the vector.
@wp.func_native(source("adcensus_cells16.cpp"))
def _cells16(a: wp.uint64, cr: wp.array2d(dtype=wp.uint64), rho: wp.array(dtype=wp.float32), y: int, u: int,
             rg: _V32, rb: _V32, terms: int, out: wp.array3d(dtype=wp.float32), x: int, k0: int) -> int: ...


@wp.func
def _cells(a: wp.uint64, cr: wp.array2d(dtype=wp.uint64), rho_census: wp.array(dtype=wp.float32), y: int, x: int,
           d0: int, rho_grad: _V32, rho_bt: _V32, T: int, out: wp.array3d(dtype=wp.float32), k0: int,
           levels: wp.float64):
    """out[y, x, k0 + i] = rho_census[popcount(a ^ cr[y, x - d0 - i])] + rho_grad[i] (+ rho_bt[i])
    (adcensus_cells16.cpp)."""
    return _cells16(a, cr, rho_census, y, x - d0, rho_grad, rho_bt, T, out, x, k0)


@wp.func
def _cells(a: wp.uint64, cr: wp.array2d(dtype=wp.uint64), rho_census: wp.array(dtype=wp.float32), y: int, x: int,
           d0: int, rho_grad: _V32, rho_bt: _V32, T: int, out: wp.array3d(dtype=wp.uint8), k0: int,
           levels: wp.float64):
    """_cells of a compact volume, a lane at a time."""
    for i in range(16):
        total = rho_census[int(wp.bit_count(a ^ cr[y, x - d0 - i]))]
        total = total + rho_grad[i]
        if T > 1:
            total = total + rho_bt[i]
        _store(out, y, x, k0 + i, total, levels)
    return 0


@wp.func
def _cells(a: wp.uint64, cr: wp.array2d(dtype=wp.uint64), rho_census: wp.array(dtype=wp.float64), y: int, x: int,
           d0: int, rho_grad: _V64, rho_bt: _V64, T: int, out: wp.array3d(dtype=wp.float64), k0: int,
           levels: wp.float64):
    """_cells of a float64 volume, a lane at a time."""
    for i in range(8):
        total = rho_census[int(wp.bit_count(a ^ cr[y, x - d0 - i]))]
        total = total + rho_grad[i]
        if T > 1:
            total = total + rho_bt[i]
        _store(out, y, x, k0 + i, total, levels)
    return 0


@wp.kernel
def _reverse_planar(img: wp.array3d(dtype=typing.Any), out: wp.array(dtype=typing.Any), row: int, pad: int,
                    offset: int):
    # out[(c H + y) row + pad + W - 1 - x] = img[y, x, c]: each channel's rows mirrored, so that R(x - d) over
    # consecutive d is a run of consecutive scalars; the margins (pad each side) stay zero.
    H = img.shape[0]
    W = img.shape[1]
    y = wp.tid() + offset
    for x in range(W):
        for c in range(img.shape[2]):
            out[(c * H + y) * row + pad + W - 1 - x] = img[y, x, c]


@wp.func
def _fill_row(L: wp.array3d(dtype=typing.Any), l_lo: wp.array3d(dtype=typing.Any), l_hi: wp.array3d(dtype=typing.Any),
              rev_v: wp.array(dtype=typing.Any), rev_lo_v: wp.array(dtype=typing.Any),
              rev_hi_v: wp.array(dtype=typing.Any), ring_v: wp.array(dtype=typing.Any), t: int, v: int, dmin: int,
              D: int, nb: int, lanes: int, slots: int, row: int, pad: int):
    """ring[t, v mod slots, x, k] = bt(x, v, d_k) (kernels.stereo.bt's _bt_pixel, the channel mean) for every vector
    of hypotheses holding an in-range cell of row v; its other lanes hold finite values that are never read."""
    H = L.shape[0]
    W = L.shape[1]
    C = L.shape[2]
    s = v % slots
    zero = rev_v.dtype(L.dtype(0.0))
    scale = L.dtype(1.0) / L.dtype(C)
    for x in range(W):
        kl = wp.max(0, x - dmin - W + 1)
        kh = wp.min(D, x - dmin + 1)
        if kl < kh:
            for j in range(kl / lanes, (kh - 1) / lanes + 1):
                acc = zero
                for c in range(C):
                    q = (c * H + v) * row + pad + W - 1 - x + dmin + j * lanes  # lane i: R(x - dmin - k0 - i)
                    lv = rev_v.dtype(L[v, x, c])
                    rv = rev_v[q]
                    e_lr = wp.max(wp.max(zero, lv - rev_hi_v[q]), rev_lo_v[q] - lv)
                    e_rl = wp.max(wp.max(zero, rv - rev_v.dtype(l_hi[v, x, c])), rev_v.dtype(l_lo[v, x, c]) - rv)
                    acc = acc + wp.min(e_lr, e_rl)
                ring_v[((t * slots + s) * W + x) * nb + j] = acc * scale
    return 0


@wp.func
def _fill_terms(gl: wp.array3d(dtype=typing.Any), gl_lo: wp.array3d(dtype=typing.Any),
                gl_hi: wp.array3d(dtype=typing.Any), gr_v: wp.array(dtype=typing.Any),
                gr_lo_v: wp.array(dtype=typing.Any), gr_hi_v: wp.array(dtype=typing.Any),
                il: wp.array3d(dtype=typing.Any), il_lo: wp.array3d(dtype=typing.Any),
                il_hi: wp.array3d(dtype=typing.Any), ir_v: wp.array(dtype=typing.Any),
                ir_lo_v: wp.array(dtype=typing.Any), ir_hi_v: wp.array(dtype=typing.Any),
                ring_v: wp.array(dtype=typing.Any), b: int, terms: int, v: int, dmin: int, D: int, nb: int,
                lanes: int, slots: int, row: int, pad: int):
    """Band b's ring rows v of its terms (_fill_row): slot 2 b the gradient term, 2 b + 1 the intensity term
    when `terms` > 1."""
    _fill_row(gl, gl_lo, gl_hi, gr_v, gr_lo_v, gr_hi_v, ring_v, 2 * b, v, dmin, D, nb, lanes, slots, row, pad)
    if terms > 1:
        _fill_row(il, il_lo, il_hi, ir_v, ir_lo_v, ir_hi_v, ring_v, 2 * b + 1, v, dmin, D, nb, lanes, slots, row, pad)
    return 0


@wp.func
def _row_sums(ring_v: wp.array(dtype=typing.Any), rowsum_v: wp.array(dtype=typing.Any), t: int, v0: int, v1: int,
              W: int, nb: int, slots: int):
    """rowsum[t, x, k] = sum over v in [v0, v1] of bt(x, v, d_k), rows added in ascending order (bt's _sum_rows;
    the first row is assigned, which equals adding it to 0 exactly), a vector of hypotheses at a time."""
    for v in range(v0, v1 + 1):
        src = (t * slots + v % slots) * W * nb
        dst = t * W * nb
        for i in range(W * nb):
            if v == v0:
                rowsum_v[dst + i] = ring_v[src + i]
            else:
                rowsum_v[dst + i] = rowsum_v[dst + i] + ring_v[src + i]
    return 0


@wp.func
def _col_mean(rowsum: wp.array(dtype=typing.Any), t: int, W: int, Dp: int, x: int, k: int, d: int, radius: int,
              rows: int):
    """The window mean of the in-range columns (bt's _mean_cols); (x, d) must be in range."""
    lo = wp.max(wp.max(x - radius, 0), d)
    hi = wp.min(wp.min(x + radius, W - 1), W - 1 + d)
    s = rowsum.dtype(0.0)
    for u in range(lo, hi + 1):
        s += rowsum[(t * W + u) * Dp + k]
    return s / rowsum.dtype(rows * (hi - lo + 1))


@wp.func
def _col_mean_v(rowsum_v: wp.array(dtype=typing.Any), t: int, W: int, nb: int, j: int, lo: int, hi: int,
                rows: int, scalar: typing.Any):
    """_col_mean of a vector of hypotheses whose window [lo, hi] is the same for every lane, lanes added alike."""
    s = rowsum_v.dtype(scalar)
    for u in range(lo, hi + 1):
        s = s + rowsum_v[(t * W + u) * nb + j]
    return s / type(scalar)(rows * (hi - lo + 1))


@wp.func
def _store(out: wp.array3d(dtype=typing.Any), y: int, x: int, k: int, total: typing.Any, levels: wp.float64):
    if levels > wp.float64(0.0):
        out[y, x, k] = out.dtype(wp.min(int(total * type(total)(levels) + type(total)(0.5)), 255))
    else:
        out[y, x, k] = out.dtype(total)
    return 0


@wp.kernel
def _fused_cost(cl: wp.array2d(dtype=wp.uint64), cr: wp.array2d(dtype=wp.uint64),
                rho_census: wp.array(dtype=typing.Any),
                gl: wp.array3d(dtype=typing.Any), gl_lo: wp.array3d(dtype=typing.Any),
                gl_hi: wp.array3d(dtype=typing.Any),
                gr_v: wp.array(dtype=typing.Any), gr_lo_v: wp.array(dtype=typing.Any),
                gr_hi_v: wp.array(dtype=typing.Any),
                il: wp.array3d(dtype=typing.Any), il_lo: wp.array3d(dtype=typing.Any),
                il_hi: wp.array3d(dtype=typing.Any),
                ir_v: wp.array(dtype=typing.Any), ir_lo_v: wp.array(dtype=typing.Any),
                ir_hi_v: wp.array(dtype=typing.Any),
                ring_v: wp.array(dtype=typing.Any), rowsum: wp.array(dtype=typing.Any),
                rowsum_v: wp.array(dtype=typing.Any), out: wp.array3d(dtype=typing.Any),
                dmin: int, radius: int, band: int, bits: int, lanes: int, row: int, pad: int,
                lambda_grad: wp.float64, invalid_grad: wp.float64,
                bt_weight: wp.float64, lambda_bt: wp.float64, invalid_bt: wp.float64, levels: wp.float64,
                offset: int):
    # One thread per band of `band` rows; it owns ring slots [2 b, 2 b + 2) and rowsum slots [2 b, 2 b + 2) (t = 0:
    # the gradient term, 1: the intensity term) and writes out[y0:y1].
    b = wp.tid() + offset
    H = cl.shape[0]
    W = cl.shape[1]
    D = out.shape[2]
    nb = (D + lanes - 1) / lanes
    Dp = nb * lanes
    r = radius
    S = 2 * r + 1
    T = 1 + wp.where(bt_weight > wp.float64(0.0), 1, 0)
    zero = gl.dtype(0.0)
    # _robust_term's 1 / lambda and weights in the images' type
    one = gl.dtype(1.0)
    inv_grad = gl.dtype(wp.float64(1.0) / lambda_grad)
    inv_bt = gl.dtype(wp.float64(1.0) / lambda_bt)
    w_bt = gl.dtype(bt_weight)
    y0 = b * band
    y1 = wp.min(y0 + band, H)
    for v in range(wp.max(y0 - r, 0), wp.min(y0 + r, H - 1) + 1):
        _fill_terms(gl, gl_lo, gl_hi, gr_v, gr_lo_v, gr_hi_v, il, il_lo, il_hi, ir_v, ir_lo_v, ir_hi_v, ring_v, b, T, v,
                    dmin, D, nb, lanes, S, row, pad)
    for y in range(y0, y1):
        if y > y0 and y + r < H:
            _fill_terms(gl, gl_lo, gl_hi, gr_v, gr_lo_v, gr_hi_v, il, il_lo, il_hi, ir_v, ir_lo_v, ir_hi_v, ring_v, b,
                        T, y + r, dmin, D, nb, lanes, S, row, pad)
        v0 = wp.max(y - r, 0)
        v1 = wp.min(y + r, H - 1)
        rows = v1 - v0 + 1
        for t in range(T):
            _row_sums(ring_v, rowsum_v, 2 * b + t, v0, v1, W, nb, S)
        for x in range(W):
            a = cl[y, x]
            lo = wp.max(x - r, 0)
            hi = wp.min(x + r, W - 1)
            for j in range(nb):
                k0 = j * lanes
                d0 = dmin + k0
                # Every lane in range with the window [lo, hi] (_col_mean's bounds do not depend on d): vector means.
                if k0 + lanes <= D and d0 + lanes - 1 <= lo and d0 >= hi - (W - 1) and d0 > x - W:
                    # rho on the vector (_rho_lanes: _robust_term's operations on each lane), then lane by lane.
                    rho_grad = _rho_lanes(_col_mean_v(rowsum_v, 2 * b, W, nb, j, lo, hi, rows, zero), inv_grad, one)
                    rho_bt = rho_grad
                    if T > 1:
                        rho_bt = _rho_lanes(_col_mean_v(rowsum_v, 2 * b + 1, W, nb, j, lo, hi, rows, zero), inv_bt,
                                            w_bt)
                    _cells(a, cr, rho_census, y, x, d0, rho_grad, rho_bt, T, out, k0, levels)
                else:
                    for k in range(k0, wp.min(k0 + lanes, D)):
                        d = dmin + k
                        u = x - d
                        if u >= 0 and u < W:
                            total = rho_census[int(wp.bit_count(a ^ cr[y, u]))]
                            total = total + _robust_term(_col_mean(rowsum, 2 * b, W, Dp, x, k, d, r, rows),
                                                         lambda_grad, wp.float64(1.0))
                            if T > 1:
                                total = total + _robust_term(_col_mean(rowsum, 2 * b + 1, W, Dp, x, k, d, r, rows),
                                                             lambda_bt, bt_weight)
                        else:
                            total = rho_census[bits]
                            total = total + _robust_term(gl.dtype(invalid_grad), lambda_grad, wp.float64(1.0))
                            if T > 1:
                                total = total + _robust_term(gl.dtype(invalid_bt), lambda_bt, bt_weight)
                        _store(out, y, x, k, total, levels)


# Vector rho (compact mode with vector_rho): e^-z for z = c / lambda clipped to [0, RHO_ZMAX], as (e^-(z / 32))^32 with
# e^-(z / 32) (z / 32 <= 0.75) by its Taylor polynomial of degree 8 (module docstring: Vector rho).
RHO_ZMAX = 24.0
RHO_HALVINGS = 5
RHO_TAYLOR = tuple((-1.0) ** n / math.factorial(n) for n in range(9))
_ZMAX = wp.constant(wp.float32(RHO_ZMAX))
_ZSCALE = wp.constant(wp.float32(1.0 / 2.0**RHO_HALVINGS))
_T0, _T1, _T2, _T3, _T4, _T5, _T6, _T7, _T8 = (wp.constant(wp.float32(c)) for c in RHO_TAYLOR)
V32 = VEC[wp.float32]
U8_VEC = wp.types.vector(length=LANES[wp.float32], dtype=wp.uint8)


@wp.func
def _rho_v(c: V32, inv: wp.float32, weight: wp.float32):
    """w (1 - e^-(c inv)) on 16 lanes, e^- by the polynomial of RHO_TAYLOR and RHO_HALVINGS squarings."""
    z = wp.min(c * inv, V32(_ZMAX)) * _ZSCALE
    p = V32(_T8)
    p = wp.cw_mul(p, z) + V32(_T7)
    p = wp.cw_mul(p, z) + V32(_T6)
    p = wp.cw_mul(p, z) + V32(_T5)
    p = wp.cw_mul(p, z) + V32(_T4)
    p = wp.cw_mul(p, z) + V32(_T3)
    p = wp.cw_mul(p, z) + V32(_T2)
    p = wp.cw_mul(p, z) + V32(_T1)
    p = wp.cw_mul(p, z) + V32(_T0)
    for _i in range(wp.static(RHO_HALVINGS)):
        p = wp.cw_mul(p, p)
    return (V32(wp.float32(1.0)) - p) * weight


@wp.func
def _row_update(ring_v: wp.array(dtype=typing.Any), rowsum_v: wp.array(dtype=typing.Any), t: int, v: int, W: int,
                nb: int, slots: int, add: int):
    """rowsum[t] += ring row v (add = 1) or -= it (add = 0), a vector of hypotheses at a time."""
    src = (t * slots + v % slots) * W * nb
    dst = t * W * nb
    if add == 1:
        for i in range(W * nb):
            rowsum_v[dst + i] = rowsum_v[dst + i] + ring_v[src + i]
    else:
        for i in range(W * nb):
            rowsum_v[dst + i] = rowsum_v[dst + i] - ring_v[src + i]
    return 0


@wp.kernel
def _fused_cost_vrho(cl: wp.array2d(dtype=wp.uint64), cr: wp.array2d(dtype=wp.uint64),
                     rho_census: wp.array(dtype=wp.float32),
                     gl: wp.array3d(dtype=wp.float32), gl_lo: wp.array3d(dtype=wp.float32),
                     gl_hi: wp.array3d(dtype=wp.float32),
                     gr_v: wp.array(dtype=V32), gr_lo_v: wp.array(dtype=V32), gr_hi_v: wp.array(dtype=V32),
                     il: wp.array3d(dtype=wp.float32), il_lo: wp.array3d(dtype=wp.float32),
                     il_hi: wp.array3d(dtype=wp.float32),
                     ir_v: wp.array(dtype=V32), ir_lo_v: wp.array(dtype=V32), ir_hi_v: wp.array(dtype=V32),
                     ring_v: wp.array(dtype=V32), rowsum: wp.array(dtype=wp.float32), rowsum_v: wp.array(dtype=V32),
                     out: wp.array3d(dtype=wp.uint8), out_v: wp.array(dtype=U8_VEC),
                     dmin: int, radius: int, band: int, bits: int, row: int, pad: int,
                     inv_grad: wp.float32, invalid_grad: wp.float32, bt_weight: wp.float32, inv_bt: wp.float32,
                     invalid_bt: wp.float32, levels: wp.float32, offset: int):
    # _fused_cost in compact mode with every rho of the BT terms on 16 lanes (_rho_v): the window means of a
    # vector of hypotheses (vector sums where every lane shares one window, else lane by lane, the term's
    # out-of-range value in lanes outside the image), the census table lane by lane, then rho, the sum, the
    # quantisation and the store on the vector.
    b = wp.tid() + offset
    lanes = 16
    H = cl.shape[0]
    W = cl.shape[1]
    D = out.shape[2]
    nb = (D + lanes - 1) / lanes
    Dp = nb * lanes
    r = radius
    S = 2 * r + 1
    T = 1 + wp.where(bt_weight > wp.float32(0.0), 1, 0)
    zero = wp.float32(0.0)
    y0 = b * band
    y1 = wp.min(y0 + band, H)
    for v in range(wp.max(y0 - r, 0), wp.min(y0 + r, H - 1) + 1):
        _fill_terms(gl, gl_lo, gl_hi, gr_v, gr_lo_v, gr_hi_v, il, il_lo, il_hi, ir_v, ir_lo_v, ir_hi_v, ring_v, b, T, v,
                    dmin, D, nb, lanes, S, row, pad)
    for y in range(y0, y1):
        v0 = wp.max(y - r, 0)
        v1 = wp.min(y + r, H - 1)
        rows = v1 - v0 + 1
        if y == y0:
            for t in range(T):
                _row_sums(ring_v, rowsum_v, 2 * b + t, v0, v1, W, nb, S)
        else:
            # Running row sums: row y - r - 1 leaves the window (before row y + r takes its ring slot), y + r enters.
            if y - r - 1 >= 0:
                for t in range(T):
                    _row_update(ring_v, rowsum_v, 2 * b + t, y - r - 1, W, nb, S, 0)
            if y + r < H:
                _fill_terms(gl, gl_lo, gl_hi, gr_v, gr_lo_v, gr_hi_v, il, il_lo, il_hi, ir_v, ir_lo_v, ir_hi_v, ring_v,
                            b, T, y + r, dmin, D, nb, lanes, S, row, pad)
                for t in range(T):
                    _row_update(ring_v, rowsum_v, 2 * b + t, y + r, W, nb, S, 1)
        for x in range(W):
            a = cl[y, x]
            lo = wp.max(x - r, 0)
            hi = wp.min(x + r, W - 1)
            for j in range(nb):
                k0 = j * lanes
                d0 = dmin + k0
                m_grad = V32(invalid_grad)
                m_bt = V32(invalid_bt)
                if k0 + lanes <= D and d0 + lanes - 1 <= lo and d0 >= hi - (W - 1) and d0 > x - W:
                    m_grad = _col_mean_v(rowsum_v, 2 * b, W, nb, j, lo, hi, rows, zero)
                    if T > 1:
                        m_bt = _col_mean_v(rowsum_v, 2 * b + 1, W, nb, j, lo, hi, rows, zero)
                else:
                    for i in range(16):
                        k = k0 + i
                        d = dmin + k
                        if k < D and x - d >= 0 and x - d < W:
                            m_grad[i] = _col_mean(rowsum, 2 * b, W, Dp, x, k, d, r, rows)
                            if T > 1:
                                m_bt[i] = _col_mean(rowsum, 2 * b + 1, W, Dp, x, k, d, r, rows)
                cen = V32()
                for i in range(16):
                    u = x - d0 - i
                    h = bits
                    if u >= 0 and u < W:
                        h = int(wp.bit_count(a ^ cr[y, u]))
                    cen[i] = rho_census[h]
                total = cen + _rho_v(m_grad, inv_grad, wp.float32(1.0))
                if T > 1:
                    total = total + _rho_v(m_bt, inv_bt, bt_weight)
                q = U8_VEC(wp.min(total * levels + V32(wp.float32(0.5)), V32(wp.float32(255.0))))
                if k0 + lanes <= D:
                    out_v[(y * W + x) * D + k0] = q
                else:
                    for i in range(16):
                        if k0 + i < D:
                            out[y, x, k0 + i] = q[i]


for _kernel in (_sobel_x, _census_eps, _half_ranges, _rho_table, _reverse_planar):
    declare_float_overloads(_kernel)
declare_float_overloads(_fused_cost, VEC)
# Compact mode: float32 arithmetic, the cost quantised to uint8.
wp.overload(_fused_cost, {**{arg.label: wp.array(dtype=VEC[wp.float32] if arg.label.endswith("_v") else wp.float32,
                                                 ndim=arg.type.ndim) for arg in _fused_cost.adj.args
                             if wp.types.is_array(arg.type) and arg.type.dtype is typing.Any},
                          "out": wp.array3d(dtype=wp.uint8)})


def _vector_view(flat: wp.array, lanes: int) -> wp.array:
    """Vectors of `lanes` consecutive scalars of `flat` starting at any scalar (unaligned, strides of one scalar)."""
    item = wp.types.type_size_in_bytes(flat.dtype)
    return wp.array(ptr=flat.ptr, dtype=VEC[flat.dtype], shape=(flat.shape[0] - lanes + 1,), strides=(item,),
                    device=flat.device)


def compact_levels(bt_weight: float) -> int:
    """Quantisation levels per unit cost of compact mode: the largest q with q (2 + bt_weight) <= 255, so every
    cost (< 2 + bt_weight) fits a uint8 as round(C q)."""
    return int(255 // (2.0 + float(bt_weight)))


def sobel_x_clipped(image: Any, cap: float = 0.25, *, device: Any = None) -> Any:
    """G = (clip(Sobel_x I, -cap, cap) + cap) / (2 cap) per channel (module docstring), same shape as `image`."""
    a = Inputs(device, image)
    ndim = len(getattr(image, "shape", ()))
    if ndim not in (2, 3):
        raise ValueError(f"image: expected a grey (H, W) or colour (H, W, C) image, got shape "
                         f"{tuple(getattr(image, 'shape', ()))}")
    img = a.floats("image", image, ndim=ndim, nonempty=True)
    cap = check_float("cap", cap, positive=True)
    H, W = img.shape[:2]
    src = img.contiguous().reshape((H, W, 1)) if ndim == 2 else img
    out = a.empty(src.shape)
    a.launch(_sobel_x, H, [src, out, wp.float64(cap)], min_chunk=8)
    return a.out(out.reshape((H, W)) if ndim == 2 else out)


def adcensus_cost(left: Any, right: Any, dmin: int, dmax: int, *, grey: tuple[Any, Any] | None = None,
                  census_radii: tuple[int, int] = (3, 4), radius: int = 2, grad_cap: float = 0.25,
                  lambda_census: float = 30.0, lambda_grad: float = 0.04, bt_weight: float = 0.0,
                  lambda_bt: float = 0.04, census_eps: float = 0.0, levels: int = 0, vector_rho: bool = False,
                  device: Any = None) -> Any:
    """The combined cost volume (H, W, dmax - dmin) of the module docstring.

    `left`, `right`: grey (H, W) or colour (H, W, C) float images in [0, 1] (the gradient and BT terms);
    `grey`: the (left, right) grey images the census term reads, required for colour input (grey input
    is its own grey image). `radius`: the window radius of the BT terms. `census_eps` >= 0: the census
    tolerance (module docstring; 0 is the plain census transform). `levels` > 0 (compact mode): the
    cost as uint8 round(C levels), at most compact_levels(bt_weight) levels per unit (float32 images).
    `vector_rho` (compact mode on the CPU only): the BT terms' rho on 16 lanes by a polynomial (module docstring:
    Vector rho), not bit-identical to the scalar exp's volume: a cell may differ by one level.
    """
    a = Inputs(device, left, right)
    ndim = len(getattr(left, "shape", ()))
    if ndim not in (2, 3):
        raise ValueError(f"left: expected a grey (H, W) or colour (H, W, C) image, got shape "
                         f"{tuple(getattr(left, 'shape', ()))}")
    l_img, r_img = image_pair(a, left, right, ndim)
    H, W = l_img.shape[:2]
    check_range(dmin, dmax, W)
    _census_radii(*census_radii)
    if grey is None:
        if ndim == 3:
            raise ValueError("grey: expected the (left, right) grey images for the census term of colour input")
        g_l, g_r = l_img, r_img
    else:
        if not (isinstance(grey, (tuple, list)) and len(grey) == 2):
            raise ValueError(f"grey: expected a (left, right) pair of grey images, got {type(grey).__name__}")
        g_l, g_r = image_pair(a, grey[0], grey[1], 2, names=("grey[0]", "grey[1]"))
        if tuple(g_l.shape) != (H, W):
            raise ValueError(f"grey[0]: expected shape ({H}, {W}) like left, got {tuple(g_l.shape)}")
    for name, value in (("grad_cap", grad_cap), ("lambda_census", lambda_census), ("lambda_grad", lambda_grad),
                        ("lambda_bt", lambda_bt)):
        check_float(name, value, positive=True)
    bt_weight = check_float("bt_weight", bt_weight, nonnegative=True)
    r = check_int("radius", radius, minimum=0)
    census_eps = check_float("census_eps", census_eps, nonnegative=True)
    levels = check_int("levels", levels, minimum=0)
    if levels and levels * (2.0 + bt_weight) > 255:
        raise ValueError(f"levels: expected at most {compact_levels(bt_weight)} levels per unit so that every cost "
                         f"(< 2 + bt_weight = {2 + bt_weight:g}) fits a uint8, got {levels}")
    if levels and a.scalar != wp.float32:
        raise ValueError("levels: compact mode (levels > 0) takes float32 images")
    if not isinstance(vector_rho, bool):
        raise ValueError(f"vector_rho: expected True or False, got {vector_rho!r}")
    if vector_rho and not (levels and a.device.is_cpu):
        raise ValueError("vector_rho: only compact mode (levels > 0) on the CPU takes the vector rho")
    ry, rx, bits = _census_radii(*census_radii)
    dmin, D = check_range(dmin, dmax, W)
    if census_eps > 0:
        cl, cr = a.empty((H, W), wp.uint64), a.empty((H, W), wp.uint64)
        a.launch(_census_eps, H * W, [g_l, cl, ry, rx, wp.float64(census_eps)], min_chunk=1024)
        a.launch(_census_eps, H * W, [g_r, cr, ry, rx, wp.float64(census_eps)], min_chunk=1024)
    else:
        cl = census_transform(g_l, ry, rx, device=a.device)
        cr = census_transform(g_r, ry, rx, device=a.device)
    rho_census = a.empty((bits + 1,))
    a.launch(_rho_table, bits + 1, [rho_census, wp.float64(lambda_census)])
    src = l_img if ndim == 3 else l_img.contiguous().reshape((H, W, 1))
    dst = r_img if ndim == 3 else r_img.contiguous().reshape((H, W, 1))
    terms = [sobel_x_clipped(src, grad_cap, device=a.device), sobel_x_clipped(dst, grad_cap, device=a.device)]
    if bt_weight > 0:
        terms += [src, dst]
    scalar = a.scalar
    lanes = LANES[scalar]
    nb = -(-D // lanes)
    pad = lanes  # the mirrored rows' margins: a vector holding one in-range cell reads at most lanes - 1 beyond
    row = W + 2 * pad
    images, invalid, keep = [], [], []  # keep: the mirrored arrays the vector views (no owners) point into
    for j, img in enumerate(terms):
        lo, hi = a.empty(img.shape), a.empty(img.shape)
        a.launch(_half_ranges, H, [img, lo, hi], min_chunk=8)
        if j % 2:  # right images: mirrored planar rows, read as vectors over d (kernels' _fill_row)
            views = []
            for arr in (img, lo, hi):
                flat = a.zeros((img.shape[2] * H * row,))
                a.launch(_reverse_planar, H, [arr, flat, row, pad], min_chunk=8)
                keep.append(flat)
                views.append(_vector_view(flat, lanes))
            images += views
            # the term's out-of-range cost: the range of both images' values (kernels.stereo.bt)
            lh, rh = terms[j - 1].numpy(), img.numpy()
            invalid.append(float(max(lh.max(), rh.max())) - float(min(lh.min(), rh.min())))
        else:
            images += [img, lo, hi]
    if bt_weight == 0:  # unused stand-ins for the intensity term's arrays
        images += images[:6]
        invalid.append(0.0)
    # Bands of rows: at least 4 (r + 1) rows, so the 2 r rows each band's ring starts with add under half its
    # work and all buffers together never exceed one float volume; on the CPU, fewer and longer bands where
    # 4 per thread balance the threads.
    band = 4 * (r + 1) if a.device.is_cuda else max(4 * (r + 1), math.ceil(H / (4 * default_threads())))
    n_bands = math.ceil(H / band)
    vec = VEC[scalar]
    # zeros: the lanes past the in-range cells stay finite (never read, but summed alongside)
    ring_v = wp.zeros((2 * n_bands * (2 * r + 1) * W * nb,), dtype=vec, device=a.device)
    rowsum = a.zeros((2 * n_bands * W * nb * lanes,))
    rowsum_v = wp.array(ptr=rowsum.ptr, dtype=vec, shape=(2 * n_bands * W * nb,), device=a.device)
    out = a.empty((H, W, D), wp.uint8 if levels else None)
    if vector_rho:
        out_v = wp.array(ptr=out.ptr, dtype=U8_VEC, shape=(H * W * D - lanes + 1,), strides=(1,), device=a.device)
        f32 = wp.float32
        a.launch(_fused_cost_vrho, n_bands,
                 [cl, cr, rho_census, *images, ring_v, rowsum, rowsum_v, out, out_v, dmin, r, band, bits, row, pad,
                  f32(1.0 / lambda_grad), f32(invalid[0]), f32(bt_weight), f32(1.0 / lambda_bt), f32(invalid[1]),
                  f32(levels)], min_chunk=1)
        return a.out(out)
    a.launch(_fused_cost, n_bands, [cl, cr, rho_census, *images, ring_v, rowsum, rowsum_v, out, dmin, r, band, bits,
                                    lanes, row, pad, wp.float64(lambda_grad), wp.float64(invalid[0]),
                                    wp.float64(bt_weight), wp.float64(lambda_bt), wp.float64(invalid[1]),
                                    wp.float64(levels)], min_chunk=1)
    return a.out(out)
