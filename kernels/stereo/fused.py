"""The default matching back end in one call: SGM, both views' winners and the left-right check.

`sgm_disparity(cost, dmin, p1, p2, paths)` returns what these calls return in sequence,

    S = sgm(cost, p1, p2, paths)
    d_L, v_L, d_R, v_R = wta_left_right(S, dmin, subpixel=..., uniqueness=u)
    v = left_right_check(d_L, d_R, max_diff, valid_left=v_L, valid_right=v_R)

(kernels.stereo.sgm and kernels.stereo.disparity state the math), bit for bit, with fewer passes
over the volume on the CPU: for a uint8 cost volume (compact mode, integer P1 and P2)
S comes from the two-sweep SGM of kernels.stereo.sweep, kept padded to whole vectors, and one
thread per row then finds both views' winners and checks them:

* every cell's key K(x, k) = S(x, y, k) 2^16 + k (uint32; S <= 65535 and k < D <= W <= 65535) is
  computed in vectors of 32 hypotheses; min_k K(x, k) gives the left winner k* (its low half) and
  its cost (its high half), the first minimum on ties, as `wta` keeps;
* the right pixel x_r = x - d_k collects min K over the cells (x_r + d_k, k): in a row buffer that
  holds x_r at index M + W - 1 - x_r, the hypotheses k of pixel x land at M + W - 1 - x + dmin + k,
  consecutive in k, so one unaligned vector minimum per block of hypotheses updates them all (the
  first minimum on ties again, as `wta_right` keeps); M = W leaves room for the cells whose x_r
  lies outside the image, which are never read;
* then, per pixel, the range and uniqueness tests, the sub-pixel parabola and the left-right
  check, as the separate entry points compute them (the same expressions, in the same types).

A float volume on the CPU gets the float sweeps (S padded to 16 float32 or 8 float64 lanes, the
padding raised to +inf) and `_rows_float`: vector minima give each left pixel's smallest S and each
right pixel's (in the same reversed row buffer, +inf where no cell is in range); a scan in
increasing k then finds the first hypothesis holding it (the first minimum again; costs are finite,
so the scan always ends), whose own value is the winner's cost. A CUDA device runs the three calls
above.
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels._arrays import Inputs, check_float
from kernels.stereo import disparity, sweep
from kernels.stereo._common import check_dmin
from kernels.stereo.disparity import _consistent, _left_pixel, _right_pixel
from kernels.stereo.sgm import _sweep_cpu, checked, sgm

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

KEY_LANES = 32
KEY_VEC = wp.types.vector(length=KEY_LANES, dtype=wp.uint32)
KEY_QUARTER = wp.types.vector(length=KEY_LANES // 4, dtype=wp.uint32)
KEY_NONE = 0xFFFFFFFF
KEY_NONE_U32 = wp.constant(wp.uint32(KEY_NONE))


@wp.func
def _fold_block(v: typing.Any, j: int, nb: int, tail: typing.Any, lm_v: wp.array(dtype=typing.Any), y: int,
                rm_v: wp.array(dtype=typing.Any), o: int):
    """Block j of a pixel's nb blocks of hypotheses (keys or costs, the last raised by `tail` past D)
    into the pixel's lane minima lm_v[y] and the right pixels' running minima at rm_v[o]."""
    if j == nb - 1:
        v = wp.max(v, tail)
    if j == 0:
        lm_v[y] = v
    else:
        lm_v[y] = wp.min(lm_v[y], v)
    rm_v[o] = wp.min(rm_v[o], v)


@wp.func
def _check_row(disp_l: wp.array2d(dtype=typing.Any), valid_l: wp.array2d(dtype=wp.uint8),
               disp_r: wp.array2d(dtype=typing.Any), valid_r: wp.array2d(dtype=wp.uint8),
               valid: wp.array2d(dtype=wp.uint8), y: int, check: int, max_diff: wp.float64):
    """Row y's validity: the left winners' own, and the left-right check unless check == 0."""
    for x in range(disp_l.shape[1]):
        ok = int(valid_l[y, x])
        if check != 0:
            ok = _consistent(disp_l, valid_l, disp_r, valid_r, y, x, max_diff)
        valid[y, x] = wp.uint8(ok)


@wp.kernel
def _rows(agg_v: wp.array(dtype=sweep.AGG_U16_VEC), agg: wp.array3d(dtype=wp.uint16), rk: wp.array(dtype=wp.uint32),
          rk_v: wp.array(dtype=KEY_VEC), lk_v: wp.array(dtype=KEY_VEC), lk4_v: wp.array(dtype=KEY_QUARTER),
          lanes_k: KEY_VEC, tail: KEY_VEC, D: int, dmin: int, subpixel: int, uniqueness: wp.float64, check: int,
          max_diff: wp.float64, disp_l: wp.array2d(dtype=wp.float32), valid_l: wp.array2d(dtype=wp.uint8),
          disp_r: wp.array2d(dtype=wp.float32), valid_r: wp.array2d(dtype=wp.uint8), valid: wp.array2d(dtype=wp.uint8),
          offset: int):
    # One thread per row y; agg (H, W, nb * 32) is S padded to whole vectors (its first D hypotheses
    # are real), agg_v its flat vector view. rk holds this row's right-view keys from y * RW, rk_v
    # views it as vectors starting at any scalar; lk_v[y] is this row's scratch vector.
    y = wp.tid() + offset
    W = agg.shape[1]
    nb = agg.shape[2] / KEY_LANES
    RW = rk.shape[0] / agg.shape[0]
    r0 = y * RW
    M = W
    for i in range(RW):
        rk[r0 + i] = KEY_NONE_U32
    for x in range(W):
        base = (y * W + x) * nb
        ro = r0 + M + W - 1 - x + dmin
        for j in range(nb):
            key = KEY_VEC(agg_v[base + j]) * wp.uint32(65536) + lanes_k + KEY_VEC(wp.uint32(KEY_LANES * j))
            _fold_block(key, j, nb, tail, lk_v, y, rk_v, ro + KEY_LANES * j)
        kl = sweep._lanes_min(lk4_v, 4 * y)
        best = int(kl % wp.uint32(65536))
        out, ok = _left_pixel(agg, disp_l, y, x, best, wp.float32(kl / wp.uint32(65536)), D, dmin, subpixel,
                              uniqueness)
        disp_l[y, x] = out
        valid_l[y, x] = wp.uint8(ok)
    for xr in range(W):
        kr = rk[r0 + M + W - 1 - xr]
        best = int(-1)
        cbest = wp.float32(0.0)
        if kr != KEY_NONE_U32:
            best = int(kr % wp.uint32(65536))
            cbest = wp.float32(kr / wp.uint32(65536))
        out, ok = _right_pixel(agg, disp_r, y, xr, best, cbest, D, dmin, subpixel)
        disp_r[y, xr] = out
        valid_r[y, xr] = wp.uint8(ok)
    _check_row(disp_l, valid_l, disp_r, valid_r, valid, y, check, max_diff)


@wp.kernel
def _rows_float(agg_v: wp.array(dtype=typing.Any), agg: wp.array3d(dtype=typing.Any), rv: wp.array(dtype=typing.Any),
                rv_v: wp.array(dtype=typing.Any), lm_v: wp.array(dtype=typing.Any), lm4_v: wp.array(dtype=typing.Any),
                tail: typing.Any, lanes: int, D: int, dmin: int, subpixel: int, uniqueness: wp.float64, check: int,
                max_diff: wp.float64, disp_l: wp.array2d(dtype=typing.Any), valid_l: wp.array2d(dtype=wp.uint8),
                disp_r: wp.array2d(dtype=typing.Any), valid_r: wp.array2d(dtype=wp.uint8),
                valid: wp.array2d(dtype=wp.uint8), offset: int):
    # _rows for a float S (padded to whole vectors of `lanes`): the vectors give each pixel's and each
    # right pixel's smallest cost (rv holds the right pixels' running minima, reversed as in _rows, +inf
    # where none), then a scan in increasing k finds the first hypothesis holding it.
    y = wp.tid() + offset
    W = agg.shape[1]
    nb = agg.shape[2] / lanes
    RW = rv.shape[0] / agg.shape[0]
    r0 = y * RW
    M = W
    inf = agg.dtype(wp.inf)
    for i in range(RW):
        rv[r0 + i] = inf
    for x in range(W):
        base = (y * W + x) * nb
        ro = r0 + M + W - 1 - x + dmin
        for j in range(nb):
            _fold_block(agg_v[base + j], j, nb, tail, lm_v, y, rv_v, ro + lanes * j)
        cbest = sweep._lanes_min(lm4_v, 4 * y)
        best = int(0)
        while agg[y, x, best] != cbest:
            best += 1
        cbest = agg[y, x, best]  # the first minimum's own value (-0.0 and 0.0 compare equal)
        out, ok = _left_pixel(agg, disp_l, y, x, best, cbest, D, dmin, subpixel, uniqueness)
        disp_l[y, x] = out
        valid_l[y, x] = wp.uint8(ok)
    for xr in range(W):
        cr = rv[r0 + M + W - 1 - xr]
        best = int(-1)
        if cr != inf:
            # The first in-range k holding the minimum: x = xr + dmin + k >= 0.
            best = wp.max(0, -xr - dmin)
            while agg[y, xr + dmin + best, best] != cr:
                best += 1
            cr = agg[y, xr + dmin + best, best]
        out, ok = _right_pixel(agg, disp_r, y, xr, best, cr, D, dmin, subpixel)
        disp_r[y, xr] = out
        valid_r[y, xr] = wp.uint8(ok)
    _check_row(disp_l, valid_l, disp_r, valid_r, valid, y, check, max_diff)


for _s, _v in sweep.FLOAT_VEC.items():
    wp.overload(_rows_float, {"agg_v": wp.array(dtype=_v), "agg": wp.array3d(dtype=_s), "rv": wp.array(dtype=_s),
                              "rv_v": wp.array(dtype=_v), "lm_v": wp.array(dtype=_v),
                              "lm4_v": wp.array(dtype=sweep.QUARTER[_s]), "tail": _v,
                              "disp_l": wp.array2d(dtype=_s), "disp_r": wp.array2d(dtype=_s)})


def sgm_disparity(cost: Any, dmin: int, p1: float, p2: float, paths: int = 8, *, subpixel: bool = True,
                  uniqueness: float = 0.0, lr_max_diff: float | None = 1.0,
                  device: Any = None) -> tuple[Any, Any]:
    """SGM over `paths` directions, the left winner and, unless `lr_max_diff` is None, the left-right
    check with that tolerance: (disparity (H, W), validity mask (H, W)), as the module docstring says."""
    a = Inputs(device, cost)
    compact = getattr(cost, "dtype", None) in (wp.uint8, np.uint8)
    check = lr_max_diff is not None
    tol = check_float("lr_max_diff", lr_max_diff, nonnegative=True) if check else 0.0
    u = disparity._uniqueness(uniqueness)
    shape = getattr(cost, "shape", ())
    if not (a.device.is_cpu and len(shape) == 3 and 0 < shape[1] <= 65535):
        agg = sgm(cost, p1, p2, paths, device=device)
        if not check:
            return disparity.wta(agg, dmin, subpixel=subpixel, uniqueness=u, device=device)
        dl, vl, dr, vr = disparity.wta_left_right(agg, dmin, subpixel=subpixel, uniqueness=u, device=device)
        return dl, disparity.left_right_check(dl, dr, tol, valid_left=vl, valid_right=vr, device=device)
    c, paths, p1, p2 = checked(a, cost, p1, p2, paths)
    H, W, D = c.shape
    dmin = check_dmin(dmin, D, W)
    agg = _sweep_cpu(a, c, H, W, D, p1, p2, paths, compact, padded_out=True)
    lanes = sweep.lanes_of(compact, a.scalar)
    Dp = agg.shape[2]
    nb = Dp // lanes
    RW = 3 * W + 2 * lanes
    disp_l, disp_r = a.empty((H, W)), a.empty((H, W))
    valid_l, valid_r, valid = (a.empty((H, W), wp.uint8) for _ in range(3))
    flags = [D, dmin, int(bool(subpixel)), wp.float64(u), int(check), wp.float64(tol), disp_l, valid_l, disp_r,
             valid_r, valid]
    if compact:
        agg_v = wp.array(ptr=agg.ptr, dtype=sweep.AGG_U16_VEC, shape=(H * W * nb,), device=a.device)
        rk = wp.empty((H * RW,), dtype=wp.uint32, device=a.device)
        rk_v = wp.array(ptr=rk.ptr, dtype=KEY_VEC, shape=(H * RW - lanes + 1,), strides=(4,), device=a.device)
        lk_v = wp.empty((H,), dtype=KEY_VEC, device=a.device)
        lk4_v = wp.array(ptr=lk_v.ptr, dtype=KEY_QUARTER, shape=(4 * H,), device=a.device)
        lanes_k = KEY_VEC(*range(KEY_LANES))
        tail = KEY_VEC(*[0 if (nb - 1) * KEY_LANES + i < D else KEY_NONE for i in range(KEY_LANES)])
        a.launch(_rows, H, [agg_v, agg, rk, rk_v, lk_v, lk4_v, lanes_k, tail, *flags], min_chunk=4)
    else:
        vec = sweep.FLOAT_VEC[a.scalar]
        item = wp.types.type_size_in_bytes(a.scalar)
        agg_v = wp.array(ptr=agg.ptr, dtype=vec, shape=(H * W * nb,), device=a.device)
        rv = wp.empty((H * RW,), dtype=a.scalar, device=a.device)
        rv_v = wp.array(ptr=rv.ptr, dtype=vec, shape=(H * RW - lanes + 1,), strides=(item,), device=a.device)
        lm_v = wp.empty((H,), dtype=vec, device=a.device)
        lm4_v = wp.array(ptr=lm_v.ptr, dtype=sweep.QUARTER[a.scalar], shape=(4 * H,), device=a.device)
        tail = vec(*[-np.inf if (nb - 1) * lanes + i < D else np.inf for i in range(lanes)])
        a.launch(_rows_float, H, [agg_v, agg, rv, rv_v, lm_v, lm4_v, tail, lanes, *flags], min_chunk=4)
    return a.out(disp_l), a.out_mask(valid)
