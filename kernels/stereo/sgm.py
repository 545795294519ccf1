"""Semi-global matching (Hirschmueller, PAMI 2008): aggregate a cost volume (H, W, D) along paths.

Along each path direction r (4 paths: left, right, up, down; 8 paths add the diagonals), starting
with L_r(p_0, k) = C(p_0, k) where the path enters the image,

    L_r(p, k) = C(p, k) + min( L_r(p - r, k),
                                L_r(p - r, k - 1) + P1,  L_r(p - r, k + 1) + P1,
                                min_i L_r(p - r, i) + P2 )  -  min_i L_r(p - r, i),

and S(p, k) = sum_r L_r(p, k). P1 penalises a one-step disparity change, P2 >= P1 any larger one.

Two schemes compute S. On the CPU (method "sweep", the default there) kernels.stereo.sweep runs
two scanline sweeps in SGBM's order, four paths each, on two threads, keeping only a row of L_r per
path; its docstring has the details. On other devices (method "axes") each axis (rows, columns,
and for 8 paths the two diagonals) is one launch with one thread per scanline, which runs the path
r and then -r back over the same pixels while they are still in cache. Each pixel lies on exactly
one scanline of an axis, so the writes of S are disjoint and the launch splits across CPU threads
(kernels.launch: a CPU launch runs on one thread and releases the GIL, docs/warp.md); axes run one
after another. The two schemes add the same L_r in another order: equal for integer costs and
penalties, equal to float rounding otherwise.

In the axis scheme the hypotheses are processed as 8-wide vectors. Each scanline keeps L_r(p - r)
in a row buffer between +inf sentinels, and reads the k - 1 and k + 1 candidates as the vectors
that start one scalar before and after (unaligned vector views of the buffer), so no lane is
shuffled; L_r(p) goes to a second row buffer and the two swap every step. D is padded to a
multiple of 8 with hypotheses costing max C + 2 P2 + |max C| + 1, which no L_r(p, k) <= C(p, k) +
P2 of a real hypothesis can reach, so the padding changes neither the real L_r nor their minimum.

Compact mode (a uint8 cost volume, for instance census Hamming distances): the aggregate S is
uint16, 3 bytes per cell in all instead of float32's 8. With integer costs and integer P1, P2
every L_r and S is an integer, so S equals the float32 pipeline's bit for bit, provided S fits:
every L_r(p, k) <= C(p, k) + P2 <= 255 + P2, and P2 <= 7936 (checked) keeps 8 paths' sum within
65535. The sweeps compute in int16 vectors; the axis scheme runs float32 vectors (integers below
2^24, exact), converting each cost vector on load and each aggregate vector on load and store, and
needs D a multiple of 8 (no padding in this mode).
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels._arrays import Inputs, check_float, check_int, declare_float_overloads
from kernels.stereo import sweep
from kernels.stereo._common import compact_volume, pixel
from kernels.stereo.sweep import INT_MAX_P2

wp.set_module_options({"enable_backward": False})

# (dy, dx) of the path directions; the first four are the 4-path set. Each axis below runs a
# direction and its opposite in one launch.
SGM_DIRECTIONS = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, -1), (1, -1), (-1, 1))
SGM_AXES = ((0, 1), (1, 0), (1, 1), (1, -1))

# 8-wide vectors of hypotheses (the CPU compiler turns them into SIMD); D is padded to a multiple.
SGM_LANES = 8
SGM_VEC = {wp.float32: wp.types.vector(length=SGM_LANES, dtype=wp.float32),
           wp.float64: wp.types.vector(length=SGM_LANES, dtype=wp.float64)}


@wp.func
def _store_path(win_v: wp.array(dtype=typing.Any), w: int, agg_v: wp.array(dtype=typing.Any), i: int, lr: typing.Any,
                write: int, lanes_min: typing.Any):
    """One vector of L_r: into the scanline's row at win_v[w] and the aggregate agg_v[i] (assigned when
    `write`, the first axis, else added, in L_r's vector type); returns the lane minima with it folded in."""
    win_v[w] = lr
    if write != 0:
        agg_v[i] = agg_v.dtype(lr)
    else:
        agg_v[i] = agg_v.dtype(type(lr)(agg_v[i]) + lr)
    return wp.min(lanes_min, lr)


@wp.func
def _sgm_walk(cost_v: wp.array(dtype=typing.Any), agg_v: wp.array(dtype=typing.Any), win_v: wp.array(dtype=typing.Any),
              nb: int, b0: int, b1: int, base: int, step: int, n: int, p1: typing.Any, p2: typing.Any, write: int):
    """L_r along one scanline of n + 1 pixels starting at flat vector index `base`, moving by `step`.

    Each pixel holds nb vectors. win_v views a scalar buffer as vectors starting at any scalar
    offset; b0 and b1 are the offsets of two rows of nb * 8 scalars (each with a +inf sentinel
    before and after) that hold L_r(p - r) and receive L_r(p), swapped every step. agg_v receives
    L_r (assigned when `write`, else added).
    """
    # Arithmetic in win_v's float vectors; the volumes may hold integers (compact mode), converted on
    # load and store (exact: compact mode runs on integer costs and penalties, module docstring).
    p1_v = win_v.dtype(p1)
    lanes_min = win_v.dtype(cost_v[base])
    for j in range(nb):
        c = win_v.dtype(cost_v[base + j])
        lanes_min = _store_path(win_v, b0 + 8 * j, agg_v, base + j, c, write, lanes_min)
    prev_min = wp.min(lanes_min)
    src = b0
    dst = b1
    for _s in range(n):
        base += step
        jump_v = win_v.dtype(prev_min + p2)
        prev_v = win_v.dtype(prev_min)
        # min_k L_r(p, k), from +inf: any finite start could undercut it (costs may rise by more than
        # P2 from one pixel to the next, or be negative), and a wrong minimum changes the P2 candidate.
        lanes_min = win_v.dtype(wp.inf)
        for j in range(nb):
            # L_r(p - r, k - 1) and (k + 1) are the vectors one scalar before and after; past either end of
            # the range the sentinel is +inf, which never undercuts the P2 candidate `jump`.
            o = src + 8 * j
            best = wp.min(wp.min(win_v[o], jump_v), wp.min(win_v[o - 1], win_v[o + 1]) + p1_v)
            lr = win_v.dtype(cost_v[base + j]) + best - prev_v
            lanes_min = _store_path(win_v, dst + 8 * j, agg_v, base + j, lr, write, lanes_min)
        prev_min = wp.min(lanes_min)
        t = src
        src = dst
        dst = t
    return 0


@wp.kernel
def _sgm_axis(cost_v: wp.array(dtype=typing.Any), agg_v: wp.array(dtype=typing.Any), win_v: wp.array(dtype=typing.Any),
              H: int, W: int, dy: int, dx: int, p1: typing.Any, p2: typing.Any, first: int, offset: int):
    # One thread per scanline along axis (dy, dx), dy >= 0: it runs the path r = (dy, dx), then the
    # opposite path -r back along the same pixels, which are still in cache. Volumes are flat arrays
    # of 8-wide vectors, nb per pixel; scanline i owns 2 (nb * 8 + 2) scalars of the row buffers.
    i = wp.tid() + offset
    nb = agg_v.shape[0] / (H * W)
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
    row = nb * SGM_LANES + 2
    b0 = i * 2 * row + 1
    _sgm_walk(cost_v, agg_v, win_v, nb, b0, b0 + row, base, step, n, p1, p2, first)
    _sgm_walk(cost_v, agg_v, win_v, nb, b0, b0 + row, base + n * step, -step, n, p1, p2, 0)


@wp.kernel
def _copy_hypotheses(src: wp.array3d(dtype=typing.Any), dst: wp.array3d(dtype=typing.Any), fill: wp.float64,
                     offset: int):
    # dst[y, x, k] = src[y, x, k] for the hypotheses both hold; dst's extra ones (padding) get `fill`.
    y, x = pixel(wp.tid() + offset, src.shape[1])
    for k in range(dst.shape[2]):
        if k < src.shape[2]:
            dst[y, x, k] = src[y, x, k]
        else:
            dst[y, x, k] = dst.dtype(fill)


declare_float_overloads(_sgm_axis, vector_types=SGM_VEC)
# Compact mode: uint8 costs in, uint16 aggregate out, float32 arithmetic.
COMPACT_COST_VEC = wp.types.vector(length=SGM_LANES, dtype=wp.uint8)
COMPACT_AGG_VEC = wp.types.vector(length=SGM_LANES, dtype=wp.uint16)
wp.overload(_sgm_axis, {"cost_v": wp.array(dtype=COMPACT_COST_VEC), "agg_v": wp.array(dtype=COMPACT_AGG_VEC),
                        "win_v": wp.array(dtype=SGM_VEC[wp.float32]), "p1": wp.float32, "p2": wp.float32})
declare_float_overloads(_copy_hypotheses)
for _t in (wp.uint8, wp.uint16):
    wp.overload(_copy_hypotheses, {"src": wp.array3d(dtype=_t), "dst": wp.array3d(dtype=_t)})


def checked(a: Inputs, cost: Any, p1: Any, p2: Any, paths: Any) -> tuple[wp.array, int, float, float]:
    """`sgm`'s arguments checked: (the volume as a wp.array, paths, p1, p2); a uint8 volume sets a.scalar
    to float32 (its results' type)."""
    compact = _is_uint8(cost)
    if compact:
        c = compact_volume(a, "cost", cost, wp.uint8)
    else:
        c = a.floats("cost", cost, ndim=3, nonempty=True)
    if check_int("paths", paths) not in (4, 8):
        raise ValueError(f"paths: expected 4 or 8, got {paths!r}")
    p1 = check_float("p1", p1, nonnegative=True)
    p2 = check_float("p2", p2, nonnegative=True)
    if p2 < p1:
        raise ValueError(f"p2: expected p2 >= p1 = {p1}, got {p2}")
    H, W, D = c.shape
    if compact:
        for name, value in (("p1", p1), ("p2", p2)):
            if value != int(value):
                raise ValueError(f"{name}: a uint8 volume needs integer penalties, got {value}")
        # A bound from the dtype, not from the volume's values (no read-back to the host).
        if p2 > INT_MAX_P2:
            raise ValueError(f"p2: a uint8 volume needs P2 <= {INT_MAX_P2} (so that 8 paths x (255 + P2) fit the "
                             f"uint16 aggregate), got {p2:g}; use a float volume")
        a.scalar = wp.float32
    return c, paths, p1, p2


def sgm(cost: Any, p1: float, p2: float, paths: int = 8, *, device: Any = None, method: str = "auto") -> Any:
    """Semi-global matching: S = sum over `paths` (4 or 8) directions of L_r.

    A float volume gives a volume like `cost`. A uint8 volume (compact mode, module docstring) gives
    a uint16 one; it needs integer P1 and P2 and P2 <= 7936 (and, with method "axes", D a multiple
    of 8). `method`: "sweep" (kernels.stereo.sweep, CPU only), "axes"
    (one launch per axis, one thread per scanline: the GPU form), or "auto": "sweep" on the CPU,
    "axes" elsewhere. Both give the same S for integer costs, and agree to float rounding otherwise.
    """
    a = Inputs(device, cost)
    if method not in ("auto", "sweep", "axes"):
        raise ValueError(f"method: expected 'auto', 'sweep' or 'axes', got {method!r}")
    if method == "sweep" and not a.device.is_cpu:
        raise ValueError(f"method: 'sweep' runs on the CPU only, got device {a.device}")
    c, paths, p1, p2 = checked(a, cost, p1, p2, paths)
    compact = c.dtype == wp.uint8
    H, W, D = c.shape
    if method == "sweep" or (method == "auto" and a.device.is_cpu):
        return a.out(_sweep_cpu(a, c, H, W, D, p1, p2, paths, compact))
    nb = -(-D // SGM_LANES)
    if compact:
        if D % SGM_LANES:
            raise ValueError(f"cost: a uint8 volume needs a multiple of {SGM_LANES} hypotheses on {a.device}, got {D}")
        cost_v = wp.array(ptr=c.ptr, dtype=COMPACT_COST_VEC, shape=(H * W * nb,), device=a.device)
        agg = a.empty((H, W, D), wp.uint16)
        agg_v = wp.array(ptr=agg.ptr, dtype=COMPACT_AGG_VEC, shape=(H * W * nb,), device=a.device)
        _aggregate(a, cost_v, agg_v, H, W, nb, p1, p2, paths)
        return a.out(agg)
    padded = c
    if nb * SGM_LANES != D:
        # Padding hypotheses cost more than any real L_r can reach (every L_r(p, k) <= C(p, k) + P2), so
        # with cost >= max C + 2 P2 they never undercut a real candidate, nor the running minimum.
        c_max = float(c.numpy().max())
        fill = c_max + 2.0 * p2 + abs(c_max) + 1.0
        padded = a.empty((H, W, nb * SGM_LANES))
        a.launch(_copy_hypotheses, H * W, [c, padded, wp.float64(fill)])
    vec = SGM_VEC[a.scalar]
    cost_v = wp.array(ptr=padded.ptr, dtype=vec, shape=(H * W * nb,), device=a.device)
    agg = a.empty((H, W, nb * SGM_LANES))
    agg_v = wp.array(ptr=agg.ptr, dtype=vec, shape=(H * W * nb,), device=a.device)
    _aggregate(a, cost_v, agg_v, H, W, nb, p1, p2, paths)
    if nb * SGM_LANES != D:
        out = a.empty((H, W, D))
        a.launch(_copy_hypotheses, H * W, [agg, out, wp.float64(0.0)])
        agg = out
    return a.out(agg)


def _sweep_cpu(a: Inputs, c: wp.array, H: int, W: int, D: int, p1: float, p2: float, paths: int,
               compact: bool, padded_out: bool = False) -> wp.array:
    """S by kernels.stereo.sweep (CPU): the volume padded to whole vectors when needed (the padding's
    values do not matter there), the aggregate cut back to D hypotheses unless `padded_out`."""
    lanes = sweep.lanes_of(compact, a.scalar)
    Dp = -(-D // lanes) * lanes
    padded = c
    if Dp != D:
        padded = a.empty((H, W, Dp), c.dtype)
        a.launch(_copy_hypotheses, H * W, [c, padded, wp.float64(0.0)])
    if compact:
        cost_v = wp.array(ptr=padded.ptr, dtype=sweep.COST_U8_VEC, shape=(H * W * Dp // lanes,), device=a.device)
        agg = a.empty((H, W, Dp), wp.uint16)
        agg_v = wp.array(ptr=agg.ptr, dtype=sweep.AGG_U16_VEC, shape=(H * W * Dp // lanes,), device=a.device)
    else:
        vec = sweep.FLOAT_VEC[a.scalar]
        cost_v = wp.array(ptr=padded.ptr, dtype=vec, shape=(H * W * Dp // lanes,), device=a.device)
        agg = a.empty((H, W, Dp))
        agg_v = wp.array(ptr=agg.ptr, dtype=vec, shape=(H * W * Dp // lanes,), device=a.device)
    sweep.sweep(cost_v, agg_v, H, W, D, paths, p1, p2, a.scalar, compact, a.launch)
    del padded
    if Dp != D and not padded_out:
        out = a.empty((H, W, D), agg.dtype)
        a.launch(_copy_hypotheses, H * W, [agg, out, wp.float64(0.0)])
        agg = out
    return agg


def _is_uint8(x: Any) -> bool:
    return getattr(x, "dtype", None) in (wp.uint8, np.uint8)


def _aggregate(a: Inputs, cost_v: wp.array, agg_v: wp.array, H: int, W: int, nb: int, p1: float, p2: float,
               paths: int) -> None:
    """The axis launches of `sgm` over flat vector views of the cost and the aggregate."""
    vec = SGM_VEC[a.scalar]
    # Two rows of nb * 8 scalars per scanline, each between +inf sentinels, viewed as vectors that may
    # start at any scalar (stride: one scalar).
    row = nb * SGM_LANES + 2
    buf = wp.full(((W + H - 1) * 2 * row,), float("inf"), dtype=a.scalar, device=a.device)
    item = 4 if a.scalar == wp.float32 else 8
    win_v = wp.array(ptr=buf.ptr, dtype=vec, shape=(buf.shape[0] - SGM_LANES + 1,), strides=(item,), device=a.device)
    for j, (dy, dx) in enumerate(SGM_AXES[: paths // 2]):
        lines = H if dy == 0 else (W if dx == 0 else W + H - 1)
        a.launch(_sgm_axis, lines, [cost_v, agg_v, win_v, H, W, dy, dx, a.s(p1), a.s(p2), int(j == 0)],
                 min_chunk=8)
