"""The AD-census cost's fused kernel: every cell of the volume in one launch, hypotheses in vector lanes.

For every cell (x, y, d) with u = x - d in [0, W) (kernels.stereo.adcensus states the terms),

    C(x, y, d) = rho_census[popcount(c_L(x, y) xor c_R(u, y))] + rho(M_grad, l_grad) + w_bt rho(M_bt, l_bt),

M the Birchfield-Tomasi window mean of a term image (kernels.stereo.bt: per row v of the window,
bt(x, v, d) = mean_c min(e_LR, e_RL), e_LR = max(0, L - R_max, R_min - L), e_RL alike; the rows
summed in ascending order, then the in-range columns [max(x - r, 0, d), min(x + r, W - 1, W - 1 + d)]
summed and divided by the cell count), rho(c, l) = 1 - exp(-c / l) (kernels.stereo.adcensus_images'
_robust_term), and out-of-range cells each term's maximum. A thread owns a band of rows and keeps,
per BT term, a ring of the 2 r + 1 rows of bt values its window needs (_fill_row, each row computed
once per band) and their row sums (_row_sums); the sums and rho run in the images' float type in
the order of the separate passes, so the volume is bit-identical to census_cost + bt_cost + one
rho pass per term. Compact mode stores round(C q) as uint8 (_store).

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
"""

from __future__ import annotations

import typing

import warp as wp

from kernels import cpu_target
from kernels._arrays import declare_float_overloads
from kernels.native import source
from kernels.stereo.adcensus_images import _robust_term

# The host's vector width (-march=native, or DRLAB_CPU_TARGET's CPU: kernels/cpu_target.py);
# fuse_fp off: no multiply-add is ever contracted into an FMA, so every value is the same on hosts with and
# without FMA units.
wp.set_module_options({"enable_backward": False, "optimization_level": 3, "fuse_fp": False,
                       "cpu_compiler_flags": cpu_target.module_flags("-mllvm=-inline-threshold=9000")})


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
def _cell(a: wp.uint64, cr: wp.array2d(dtype=wp.uint64), rho_census: wp.array(dtype=typing.Any), y: int, u: int,
          rho_grad: typing.Any, rho_bt: typing.Any, T: int):
    """One cell's cost with the right pixel u in range: rho_census[popcount(a ^ cr[y, u])] + rho_grad (+ rho_bt
    when T > 1), added in that order."""
    total = rho_census[int(wp.bit_count(a ^ cr[y, u]))]
    total = total + rho_grad
    if T > 1:
        total = total + rho_bt
    return total


@wp.func
def _cells(a: wp.uint64, cr: wp.array2d(dtype=wp.uint64), rho_census: wp.array(dtype=wp.float32), y: int, x: int,
           d0: int, rho_grad: _V32, rho_bt: _V32, T: int, out: wp.array3d(dtype=wp.float32), k0: int,
           levels: wp.float64):
    """out[y, x, k0 + i] = rho_census[popcount(a ^ cr[y, x - d0 - i])] + rho_grad[i] (+ rho_bt[i])
    (adcensus_cells16.cpp)."""
    return _cells16(a, cr, rho_census, y, x - d0, rho_grad, rho_bt, T, out, x, k0)


@wp.func
def _cells(a: wp.uint64, cr: wp.array2d(dtype=wp.uint64), rho_census: wp.array(dtype=typing.Any), y: int, x: int,
           d0: int, rho_grad: typing.Any, rho_bt: typing.Any, T: int, out: wp.array3d(dtype=typing.Any), k0: int,
           levels: wp.float64):
    """_cells of a compact (uint8, 16 lanes) or float64 (8 lanes) volume, a lane at a time."""
    for i in range(len(rho_grad)):
        _store(out, y, x, k0 + i, _cell(a, cr, rho_census, y, x - d0 - i, rho_grad[i], rho_bt[i], T), levels)
    return 0




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


declare_float_overloads(_fused_cost, VEC)
# Compact mode: float32 arithmetic, the cost quantised to uint8.
wp.overload(_fused_cost, {**{arg.label: wp.array(dtype=VEC[wp.float32] if arg.label.endswith("_v") else wp.float32,
                                                 ndim=arg.type.ndim) for arg in _fused_cost.adj.args
                             if wp.types.is_array(arg.type) and arg.type.dtype is typing.Any},
                          "out": wp.array3d(dtype=wp.uint8)})
