"""Semi-global matching in two scanline sweeps (the CPU form of kernels.stereo.sgm).

It computes the same recurrence as kernels.stereo.sgm (whose docstring states it): along each path
direction r, starting with L_r(p_0, k) = C(p_0, k) where the path enters the image,

    L_r(p, k) = C(p, k) + min( L_r(p - r, k), L_r(p - r, k -+ 1) + P1, min_i L_r(p - r, i) + P2 )
                - min_i L_r(p - r, i),        S(p, k) = sum_r L_r(p, k),

but in the order of OpenCV's StereoSGBM (after Hirschmueller, PAMI 2008): no path's volume L_r is
ever stored. Sweep A walks the rows top to bottom and each row left to right, carrying the paths
r = (0, 1), (1, 0), (1, 1), (1, -1) (the first two for 4 paths); sweep B walks bottom to top and
right to left with their opposites (0, -1), (-1, 0), (-1, -1), (-1, 1). Each sweep keeps only the
previous row's L_r of its vertical and diagonal paths and the previous pixel's L_r of its
horizontal path (two rows of W + 2 slots per path, the two border slots holding L = 0, min 0, so a
path entering the image gets L = C + min(0, P1, P2) - 0 = C exactly), plus the summed volume S.

The two sweeps run at once, one CPU thread each, in two launches that write disjoint rows of S:
in the first, A stores its paths' sum into the top half's rows and B into the bottom half's; in
the second, A adds into the bottom half and B into the top half (each carrying its row state over
from the first). So every cell of S is written once and then added to once, by different threads
in different launches (race-free, docs/warp.md).

Arithmetic. The hypotheses of a pixel go through in vectors of LANES: 32 int16 lanes for uint8
costs (compact mode: 64-byte AVX-512 vectors, which the CPU compiler emits for Warp's fixed-size
vectors, docs/warp.md), 16 float32 or 8 float64 lanes for float costs. The k -+ 1 candidates are
the vectors one scalar before and after in a slot of D + 2 scalars between two sentinels INF
(unaligned vector views), so no lane is shuffled. When D is not a multiple of LANES the volume is
padded and the padding lanes of every L_r are raised to INF (`tail`), exactly as the sentinels,
so they change neither the real L_r nor their minimum, whatever the padded costs hold.

Integer mode (uint8 costs, integer P1, P2): every L_r(p, k) <= C(p, k) + P2 <= 255 + P2, and the
check P2 <= 7936 (kernels.stereo.sgm) keeps each sweep's sum of four L_r within 4 (255 + 7936) < 32767
(int16) and S within uint16; INF = 16383 exceeds every L_r and INF + P1 fits in int16. All sums
are of integers, so S equals the float32 recurrence of kernels.stereo.sgm bit for bit. Float
mode adds the paths in another order than the axis launches of kernels.stereo.sgm, so S agrees
with it to float rounding only.
"""

from __future__ import annotations

import typing

import numpy as np
import warp as wp

from kernels import cpu_target

wp.set_module_options({"enable_backward": False, "optimization_level": 3,
                       "cpu_compiler_flags": cpu_target.module_flags("-mllvm=-inline-threshold=9000")})

INT_INF = 16383
INT_MAX_P2 = 7936
LANES = {"int": 32, wp.float32: 16, wp.float64: 8}
INT_VEC = wp.types.vector(length=32, dtype=wp.int16)
COST_U8_VEC = wp.types.vector(length=32, dtype=wp.uint8)
AGG_U16_VEC = wp.types.vector(length=32, dtype=wp.uint16)
# Quarter vectors, for the minimum over a vector's lanes.
QUARTER = {wp.int16: wp.types.vector(length=8, dtype=wp.int16), wp.float32: wp.types.vector(length=4, dtype=wp.float32),
           wp.float64: wp.types.vector(length=2, dtype=wp.float64)}
FLOAT_VEC = {wp.float32: wp.types.vector(length=16, dtype=wp.float32),
             wp.float64: wp.types.vector(length=8, dtype=wp.float64)}


@wp.func
def _lanes_min(m4_v: wp.array(dtype=typing.Any), i: int):
    """The smallest lane of the vector whose four quarters are m4_v[i], ..., m4_v[i + 3]."""
    return wp.min(wp.min(wp.min(m4_v[i], m4_v[i + 1]), wp.min(m4_v[i + 2], m4_v[i + 3])))


@wp.kernel
def _sweep(cost_v: wp.array(dtype=typing.Any), agg_v: wp.array(dtype=typing.Any), buf: wp.array(dtype=typing.Any),
           win: wp.array(dtype=typing.Any), mins: wp.array(dtype=typing.Any), m_v: wp.array(dtype=typing.Any),
           m4_v: wp.array(dtype=typing.Any), tail: typing.Any, H: int, W: int,
           nb: int, lanes: int, diagonals: int, p1: typing.Any, p2: typing.Any, inf: typing.Any, phase: int,
           offset: int):
    # Thread t = 0 is sweep A (down, rightwards), t = 1 sweep B (up, leftwards). Slots of this
    # thread: 2 for the horizontal path, then 2 rows of W + 2 for each of the vertical path (q = 0)
    # and the diagonals reading x - 1 (q = 1) and x + 1 (q = 2); slot s holds scalars
    # [s R, s R + R): a sentinel, nb vectors, a sentinel.
    t = wp.tid() + offset
    R = nb * lanes + 2
    row_slots = W + 2
    T = t * (2 + 6 * row_slots)
    zero = p1 - p1
    if phase == 0:
        for s in range(2 + 6 * row_slots):
            o = (T + s) * R
            buf[o] = inf
            for k in range(1, R - 1):
                buf[o + k] = zero
            buf[o + R - 1] = inf
            mins[T + s] = zero
    half = H / 2
    n_rows = wp.where(t == 0, wp.where(phase == 0, half, H - half), wp.where(phase == 0, H - half, half))
    y0 = wp.where(t == 0, wp.where(phase == 0, 0, half), wp.where(phase == 0, H - 1, half - 1))
    dy = wp.where(t == 0, 1, -1)
    p1_v = win.dtype(p1)
    for r in range(n_rows):
        y = y0 + dy * r
        cur = y & 1
        prv = 1 - cur
        # The horizontal path enters the row: its "previous pixel" slot is all zeros, min 0.
        hs = int(0)
        o = T * R + 1
        for j in range(nb):
            win[o + lanes * j] = win.dtype(zero)
        mins[T] = zero
        for i in range(W):
            x = wp.where(t == 0, i, W - 1 - i)
            base = (y * W + x) * nb
            h_src = T + hs
            h_dst = T + 1 - hs
            v_src = T + 2 + prv * row_slots + x + 1
            v_dst = T + 2 + cur * row_slots + x + 1
            a_src = T + 2 + (2 + prv) * row_slots + x
            a_dst = T + 2 + (2 + cur) * row_slots + x + 1
            b_src = T + 2 + (4 + prv) * row_slots + x + 2
            b_dst = T + 2 + (4 + cur) * row_slots + x + 1
            ph = mins[h_src]
            pv = mins[v_src]
            pa = mins[a_src]
            pb = mins[b_src]
            jh = win.dtype(ph + p2)
            jv = win.dtype(pv + p2)
            ja = win.dtype(pa + p2)
            jb = win.dtype(pb + p2)
            ph_v = win.dtype(ph)
            pv_v = win.dtype(pv)
            pa_v = win.dtype(pa)
            pb_v = win.dtype(pb)
            # The running minima over the blocks live in memory (m_v, 4 vectors per thread): a vector
            # carried through a loop of run-time length is compiled lane by lane.
            for j in range(nb):
                c = win.dtype(cost_v[base + j])
                o = lanes * j + 1
                # L_r(p) = C + min(L(k), L(k -+ 1) + P1, min L + P2) - min L, per path (inlined: with
                # this expression, or a whole path's step, as a @wp.func the sweep ran 2.3-3x slower).
                s = h_src * R + o
                lh = c + wp.min(wp.min(win[s], jh), wp.min(win[s - 1], win[s + 1]) + p1_v) - ph_v
                s = v_src * R + o
                lv = c + wp.min(wp.min(win[s], jv), wp.min(win[s - 1], win[s + 1]) + p1_v) - pv_v
                if j == nb - 1:
                    lh = wp.max(lh, tail)
                    lv = wp.max(lv, tail)
                win[h_dst * R + o] = lh
                win[v_dst * R + o] = lv
                if j == 0:
                    m_v[4 * t] = lh
                    m_v[4 * t + 1] = lv
                else:
                    m_v[4 * t] = wp.min(m_v[4 * t], lh)
                    m_v[4 * t + 1] = wp.min(m_v[4 * t + 1], lv)
                acc = lh + lv
                if diagonals != 0:
                    s = a_src * R + o
                    la = c + wp.min(wp.min(win[s], ja), wp.min(win[s - 1], win[s + 1]) + p1_v) - pa_v
                    s = b_src * R + o
                    lb = c + wp.min(wp.min(win[s], jb), wp.min(win[s - 1], win[s + 1]) + p1_v) - pb_v
                    if j == nb - 1:
                        la = wp.max(la, tail)
                        lb = wp.max(lb, tail)
                    win[a_dst * R + o] = la
                    win[b_dst * R + o] = lb
                    if j == 0:
                        m_v[4 * t + 2] = la
                        m_v[4 * t + 3] = lb
                    else:
                        m_v[4 * t + 2] = wp.min(m_v[4 * t + 2], la)
                        m_v[4 * t + 3] = wp.min(m_v[4 * t + 3], lb)
                    acc = acc + la + lb
                if phase == 0:
                    agg_v[base + j] = agg_v.dtype(acc)
                else:
                    agg_v[base + j] = agg_v[base + j] + agg_v.dtype(acc)
            # min over the lanes: the four quarter vectors of each first (m4_v views m_v), then one
            # quarter's lanes.
            mins[h_dst] = _lanes_min(m4_v, 16 * t)
            mins[v_dst] = _lanes_min(m4_v, 16 * t + 4)
            if diagonals != 0:
                mins[a_dst] = _lanes_min(m4_v, 16 * t + 8)
                mins[b_dst] = _lanes_min(m4_v, 16 * t + 12)
            hs = 1 - hs


# Integer mode: uint8 costs, int16 arithmetic, a uint16 S.
wp.overload(_sweep, {"cost_v": wp.array(dtype=COST_U8_VEC), "agg_v": wp.array(dtype=AGG_U16_VEC),
                     "buf": wp.array(dtype=wp.int16), "win": wp.array(dtype=INT_VEC),
                     "mins": wp.array(dtype=wp.int16), "m_v": wp.array(dtype=INT_VEC),
                     "m4_v": wp.array(dtype=QUARTER[wp.int16]), "tail": INT_VEC, "p1": wp.int16, "p2": wp.int16,
                     "inf": wp.int16})
for _s, _v in FLOAT_VEC.items():
    wp.overload(_sweep, {"cost_v": wp.array(dtype=_v), "agg_v": wp.array(dtype=_v), "buf": wp.array(dtype=_s),
                         "win": wp.array(dtype=_v), "mins": wp.array(dtype=_s), "m_v": wp.array(dtype=_v),
                         "m4_v": wp.array(dtype=QUARTER[_s]), "tail": _v, "p1": _s, "p2": _s,
                         "inf": _s})


def lanes_of(integer: bool, scalar: typing.Any) -> int:
    """The vector width of the sweep for integer mode, or for a float scalar type."""
    return LANES["int"] if integer else LANES[scalar]


def sweep(cost_v: wp.array, agg_v: wp.array, H: int, W: int, D: int, paths: int, p1: float, p2: float,
          scalar: typing.Any, integer: bool, launch: typing.Callable[..., None]) -> None:
    """S of `paths` (4 or 8) directions into agg_v, from cost_v: flat vector views (H W nb vectors of
    lanes_of(integer, scalar) hypotheses, D of them real). `launch(kernel, dim, inputs, min_chunk)`
    runs the two launches (kernels._arrays.Inputs.launch). The caller has checked the arguments."""
    lanes = lanes_of(integer, scalar)
    nb = -(-D // lanes)
    device = cost_v.device
    slots = 2 * (2 + 6 * (W + 2))
    R = nb * lanes + 2
    if integer:
        s_type, vec, inf = wp.int16, INT_VEC, INT_INF
        tail_np = np.where(np.arange(lanes) + (nb - 1) * lanes < D, -INT_INF, INT_INF)
    else:
        s_type, vec, inf = scalar, FLOAT_VEC[scalar], np.inf
        tail_np = np.where(np.arange(lanes) + (nb - 1) * lanes < D, -np.inf, np.inf)
    cast = int if integer else float
    buf = wp.empty((slots * R,), dtype=s_type, device=device)
    item = wp.types.type_size_in_bytes(s_type)
    win = wp.array(ptr=buf.ptr, dtype=vec, shape=(slots * R - lanes + 1,), strides=(item,), device=device)
    mins = wp.empty((slots,), dtype=s_type, device=device)
    tail = vec(*[cast(v) for v in tail_np])
    cast = int if integer else float
    m_v = wp.empty((8,), dtype=vec, device=device)
    m4_v = wp.array(ptr=m_v.ptr, dtype=QUARTER[s_type], shape=(32,), device=device)
    args = [cost_v, agg_v, buf, win, mins, m_v, m4_v, tail, H, W, nb, lanes, int(paths == 8), s_type(cast(p1)),
            s_type(cast(p2)), s_type(cast(inf))]
    for phase in (0, 1):
        launch(_sweep, 2, [*args, phase], 1)
