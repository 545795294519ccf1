"""The AD-census cost's compact mode with the vector rho: the BT terms' rho on 16 float32 lanes by a polynomial.

Vector rho (compact mode with `vector_rho`, float32 on the CPU; research.stereo.matching's DEFAULT_CONFIG runs it): the
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

import warp as wp

from kernels import cpu_target
from kernels.stereo.adcensus_kernels import LANES, VEC, _col_mean, _col_mean_v, _fill_terms, _row_sums

# The host's vector width (-march=native, or DRLAB_CPU_TARGET's CPU: kernels/cpu_target.py);
# fuse_fp off: no multiply-add is ever contracted into an FMA, so every value is the same on hosts with and
# without FMA units.
wp.set_module_options({"enable_backward": False, "optimization_level": 3, "fuse_fp": False,
                       "cpu_compiler_flags": cpu_target.module_flags("-mllvm=-inline-threshold=9000")})

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
