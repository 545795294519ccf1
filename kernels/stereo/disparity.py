"""From a cost volume (H, W, D) to disparity, its validity and depth.

* Winner-take-all: k* = argmin_k C(p, k) (the first minimum), refined by the parabola through
  (k* - 1, k*, k* + 1) when both neighbours exist:
  d = d_{k*} + (c_- - c_+) / (2 (c_- - 2 c_0 + c_+)) (no refinement when the curvature is not
  positive). The pixel is invalid when its winner is out of range, or, with a uniqueness ratio
  u > 0, when some k with |k - k*| > 1 has C(p, k) (1 - u) < C(p, k*) (as OpenCV's
  uniquenessRatio). The right view's disparity comes from the same volume (Hirschmueller, PAMI
  2008, sec. 3.4): d_R(x_r) = argmin_k C(x_r + d_k, y, k), with the same refinement.
  These three also take the uint16 aggregate of kernels.stereo.sgm's compact mode (its integer
  costs are converted to float32 exactly, so the result equals that of the same volume in float32).
  `wta_left_right` returns both from one sequential pass over each row of the volume (one thread
  per row), the same values as `wta` and `wta_right`, without `wta_right`'s diagonal reads.
* Soft-argmin (Kendall et al., GC-Net, ICCV 2017) with temperature T:

      sigma_k = softmax_k(-C(p, k) / T),   d = sum_k d_k sigma_k,
      dd/dC(p, k) = sigma_k (d - d_k) / T.

  It runs over all D cells, in range or not (pass a volume whose out-of-range cells are costly,
  as the costs of kernels.stereo.costs are). The exponentials are taken relative to the smallest
  cost, exp((min_i C(p, i) - C(p, k)) / T) <= 1, so large costs cannot overflow.
* Left-right consistency: the left pixel is valid when its own estimate is, the right pixel
  x_r = round(x - d_L) exists and is valid, and |d_L - d_R(x_r)| <= max_diff.
* Depth: Z = f b / d (f the focal length in pixels, b the baseline). A pixel with d <= 0, a
  non-finite d, an invalid input flag, or a non-finite quotient is invalid and gets Z = 0; the
  output never holds inf or NaN.
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels._arrays import Inputs, check_float, declare_float_overloads
from kernels.stereo._common import check_dmin, compact_volume, pixel

wp.set_module_options({"enable_backward": False})


# =========================================================================== kernels


@wp.func
def _parabola(cm: typing.Any, c0: typing.Any, cp: typing.Any):
    denom = cm - c0 - c0 + cp
    off = c0 - c0
    if denom > off:
        off = (cm - cp) / (denom + denom)
    return off


@wp.func
def _wta_pixel(cost: wp.array3d(dtype=typing.Any), disp: wp.array2d(dtype=typing.Any), y: int, x: int, dmin: int,
               subpixel: int, uniqueness: wp.float64):
    """(disparity, valid) of the left pixel (x, y): the first minimum, its checks and its parabola, in
    `disp`'s float type (a uint16 volume's costs are converted exactly)."""
    D = cost.shape[2]
    best = int(0)
    cbest = disp.dtype(cost[y, x, 0])
    for k in range(1, D):
        c = disp.dtype(cost[y, x, k])
        if c < cbest:
            cbest = c
            best = k
    return _left_pixel(cost, disp, y, x, best, cbest, D, dmin, subpixel, uniqueness)


@wp.func
def _left_pixel(cost: wp.array3d(dtype=typing.Any), disp: wp.array2d(dtype=typing.Any), y: int, x: int, best: int,
                cbest: typing.Any, D: int, dmin: int, subpixel: int, uniqueness: wp.float64):
    """(disparity, valid) of the left pixel (x, y) whose first minimum is hypothesis `best`, of cost `cbest`
    in `disp`'s float type: the range test, the uniqueness test and the parabola, over the first D
    hypotheses of `cost` (a padded volume holds more)."""
    W = cost.shape[1]
    ok = int(1)
    d = dmin + best
    if x - d < 0 or x - d >= W:
        ok = 0
    if uniqueness > wp.float64(0.0):
        keep = disp.dtype(wp.float64(1.0) - uniqueness)
        for k in range(D):
            if (k < best - 1 or k > best + 1) and disp.dtype(cost[y, x, k]) * keep < cbest:
                ok = 0
    out = disp.dtype(d)
    if subpixel != 0 and best > 0 and best + 1 < D:
        out = out + _parabola(disp.dtype(cost[y, x, best - 1]), cbest, disp.dtype(cost[y, x, best + 1]))
    return out, ok


@wp.func
def _right_pixel(cost: wp.array3d(dtype=typing.Any), disp: wp.array2d(dtype=typing.Any), y: int, xr: int, best: int,
                 cbest: typing.Any, D: int, dmin: int, subpixel: int):
    """(disparity, valid) of the right pixel xr whose first minimum is hypothesis `best` (-1: none in range),
    over the first D hypotheses of `cost` (a padded volume holds more)."""
    W = cost.shape[1]
    out = disp.dtype(0.0)
    ok = int(0)
    if best >= 0:
        ok = 1
        out = disp.dtype(dmin + best)
        xm = xr + dmin + best - 1
        xp = xr + dmin + best + 1
        if subpixel != 0 and best > 0 and best + 1 < D and xm >= 0 and xp < W:
            out = out + _parabola(disp.dtype(cost[y, xm, best - 1]), cbest, disp.dtype(cost[y, xp, best + 1]))
    return out, ok


@wp.kernel
def _wta(cost: wp.array3d(dtype=typing.Any), disp: wp.array2d(dtype=typing.Any), valid: wp.array2d(dtype=wp.uint8),
         dmin: int, subpixel: int, uniqueness: wp.float64, offset: int):
    y, x = pixel(wp.tid() + offset, cost.shape[1])
    d, ok = _wta_pixel(cost, disp, y, x, dmin, subpixel, uniqueness)
    disp[y, x] = d
    valid[y, x] = wp.uint8(ok)


@wp.kernel
def _wta_right(cost: wp.array3d(dtype=typing.Any), disp: wp.array2d(dtype=typing.Any),
               valid: wp.array2d(dtype=wp.uint8), dmin: int, subpixel: int, offset: int):
    # Right pixel xr: hypothesis k lives in the left volume at x = xr + d_k.
    W = cost.shape[1]
    D = cost.shape[2]
    y, xr = pixel(wp.tid() + offset, W)
    best = int(-1)
    cbest = disp.dtype(0.0)
    for k in range(D):
        x = xr + dmin + k
        if x >= 0 and x < W:
            c = disp.dtype(cost[y, x, k])
            if best < 0 or c < cbest:
                cbest = c
                best = k
    d, ok = _right_pixel(cost, disp, y, xr, best, cbest, D, dmin, subpixel)
    disp[y, xr] = d
    valid[y, xr] = wp.uint8(ok)


@wp.kernel
def _wta_rows(cost: wp.array3d(dtype=typing.Any), disp_l: wp.array2d(dtype=typing.Any),
              valid_l: wp.array2d(dtype=wp.uint8), disp_r: wp.array2d(dtype=typing.Any),
              valid_r: wp.array2d(dtype=wp.uint8), best_r: wp.array2d(dtype=wp.int32), dmin: int, subpixel: int,
              uniqueness: wp.float64, offset: int):
    # One thread per row: both views' winners from one sequential pass over the row's cells. The
    # right pixel xr = x - d_k meets its hypotheses k in increasing order as x increases, so keeping
    # the first strict minimum gives _wta_right's first minimum. disp_r holds the running minimum
    # cost until the last loop turns it into the disparity.
    y = wp.tid() + offset
    W = cost.shape[1]
    D = cost.shape[2]
    for xr in range(W):
        best_r[y, xr] = -1
    for x in range(W):
        for k in range(D):
            xr = x - dmin - k
            if xr >= 0 and xr < W:
                c = disp_r.dtype(cost[y, x, k])
                if best_r[y, xr] < 0 or c < disp_r[y, xr]:
                    disp_r[y, xr] = c
                    best_r[y, xr] = k
        d, ok = _wta_pixel(cost, disp_l, y, x, dmin, subpixel, uniqueness)
        disp_l[y, x] = d
        valid_l[y, x] = wp.uint8(ok)
    for xr in range(W):
        d, ok = _right_pixel(cost, disp_r, y, xr, best_r[y, xr], disp_r[y, xr], cost.shape[2], dmin, subpixel)
        disp_r[y, xr] = d
        valid_r[y, xr] = wp.uint8(ok)


@wp.func
def _softmax_sums(cost: wp.array3d(dtype=typing.Any), y: int, x: int, dmin: int, inv_t: typing.Any):
    """(c_min, z, num) at pixel (x, y): z = sum_k e_k, num = sum_k d_k e_k, e_k = exp((c_min - C_k) / T)."""
    cmin = cost[y, x, 0]
    for k in range(1, cost.shape[2]):
        cmin = wp.min(cmin, cost[y, x, k])
    z = cost.dtype(0.0)
    num = cost.dtype(0.0)
    for k in range(cost.shape[2]):
        e = wp.exp((cmin - cost[y, x, k]) * inv_t)
        z += e
        num += e * cost.dtype(dmin + k)
    return cmin, z, num


@wp.kernel
def _soft_argmin_forward(cost: wp.array3d(dtype=typing.Any), disp: wp.array2d(dtype=typing.Any), dmin: int,
                         temperature: wp.float64, offset: int):
    y, x = pixel(wp.tid() + offset, cost.shape[1])
    _cmin, z, num = _softmax_sums(cost, y, x, dmin, cost.dtype(wp.float64(1.0) / temperature))
    disp[y, x] = num / z


@wp.kernel
def _soft_argmin_backward(cost: wp.array3d(dtype=typing.Any), grad_disp: wp.array2d(dtype=typing.Any),
                          grad_cost: wp.array3d(dtype=typing.Any), dmin: int, temperature: wp.float64, offset: int):
    # dd/dC_k = sigma_k (d - d_k) / T, with sigma and d recomputed from the cost as the forward does.
    y, x = pixel(wp.tid() + offset, cost.shape[1])
    inv_t = cost.dtype(wp.float64(1.0) / temperature)
    cmin, z, num = _softmax_sums(cost, y, x, dmin, inv_t)
    g = grad_disp[y, x] * inv_t / z
    d = num / z
    for k in range(cost.shape[2]):
        e = wp.exp((cmin - cost[y, x, k]) * inv_t)
        grad_cost[y, x, k] = g * e * (d - cost.dtype(dmin + k))


@wp.func
def _consistent(disp_l: wp.array2d(dtype=typing.Any), valid_l: wp.array2d(dtype=wp.uint8),
                disp_r: wp.array2d(dtype=typing.Any), valid_r: wp.array2d(dtype=wp.uint8), y: int, x: int,
                max_diff: wp.float64):
    """1 if the left pixel (x, y) passes the left-right check (module docstring), else 0."""
    W = disp_l.shape[1]
    dl = disp_l[y, x]
    ok = int(0)
    if valid_l[y, x] != wp.uint8(0):
        xr = int(wp.floor(wp.float64(x) - wp.float64(dl) + wp.float64(0.5)))
        if xr >= 0 and xr < W:
            if valid_r[y, xr] != wp.uint8(0):
                if wp.abs(wp.float64(dl) - wp.float64(disp_r[y, xr])) <= max_diff:
                    ok = 1
    return ok


@wp.kernel
def _left_right_check(disp_l: wp.array2d(dtype=typing.Any), valid_l: wp.array2d(dtype=wp.uint8),
                      disp_r: wp.array2d(dtype=typing.Any), valid_r: wp.array2d(dtype=wp.uint8),
                      out: wp.array2d(dtype=wp.uint8), max_diff: wp.float64, offset: int):
    y, x = pixel(wp.tid() + offset, disp_l.shape[1])
    out[y, x] = wp.uint8(_consistent(disp_l, valid_l, disp_r, valid_r, y, x, max_diff))


@wp.kernel
def _depth(disp: wp.array2d(dtype=typing.Any), valid: wp.array2d(dtype=wp.uint8), depth: wp.array2d(dtype=typing.Any),
           valid_out: wp.array2d(dtype=wp.uint8), fb: wp.float64, offset: int):
    y, x = pixel(wp.tid() + offset, disp.shape[1])
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


for _kernel in (_wta, _wta_right, _wta_rows, _soft_argmin_forward, _soft_argmin_backward, _left_right_check, _depth):
    declare_float_overloads(_kernel)
# Winners of a compact (uint16) aggregate, as float32 disparities.
for _kernel, _disp in ((_wta, ("disp",)), (_wta_right, ("disp",)), (_wta_rows, ("disp_l", "disp_r"))):
    wp.overload(_kernel, {"cost": wp.array3d(dtype=wp.uint16), **{n: wp.array2d(dtype=wp.float32) for n in _disp}})


# =========================================================================== entry points


def _volume(a: Inputs, cost: Any, dmin: Any, compact: bool = False) -> tuple[wp.array, int]:
    """The cost volume (H, W, D) and dmin, checked against each other; with `compact`, a uint16 volume
    (kernels.stereo.sgm's compact aggregate) is taken too, with float32 results."""
    if compact and getattr(cost, "dtype", None) in (wp.uint16, np.uint16):
        c = compact_volume(a, "cost", cost, wp.uint16)
    else:
        c = a.floats("cost", cost, ndim=3, nonempty=True)
    return c, check_dmin(dmin, c.shape[2], c.shape[1])


def _mask_or_ones(a: Inputs, name: str, m: Any, shape: tuple[int, ...]) -> wp.array:
    """A validity mask argument as uint8, all valid when None."""
    return wp.ones(shape, dtype=wp.uint8, device=a.device) if m is None else a.mask(name, m, shape)


def _uniqueness(uniqueness: float) -> float:
    """The uniqueness ratio, checked: in [0, 1)."""
    u = check_float("uniqueness", uniqueness, nonnegative=True)
    if u >= 1.0:
        raise ValueError(f"uniqueness: expected a ratio in [0, 1), got {uniqueness!r}")
    return u


def wta(cost: Any, dmin: int, *, subpixel: bool = True, uniqueness: float = 0.0,
        device: Any = None) -> tuple[Any, Any]:
    """Winner-take-all left disparity (H, W) and its validity mask (see the module docstring)."""
    a = Inputs(device, cost)
    c, dmin = _volume(a, cost, dmin, compact=True)
    u = _uniqueness(uniqueness)
    H, W, _ = c.shape
    disp = a.empty((H, W))
    valid = a.empty((H, W), wp.uint8)
    a.launch(_wta, H * W, [c, disp, valid, dmin, int(bool(subpixel)), wp.float64(u)], min_chunk=256)
    return a.out(disp), a.out_mask(valid)


def wta_right(cost: Any, dmin: int, *, subpixel: bool = True, device: Any = None) -> tuple[Any, Any]:
    """The right view's winner-take-all disparity (H, W) from the left volume, and its validity mask."""
    a = Inputs(device, cost)
    c, dmin = _volume(a, cost, dmin, compact=True)
    H, W, _ = c.shape
    disp = a.empty((H, W))
    valid = a.empty((H, W), wp.uint8)
    a.launch(_wta_right, H * W, [c, disp, valid, dmin, int(bool(subpixel))], min_chunk=256)
    return a.out(disp), a.out_mask(valid)


def wta_left_right(cost: Any, dmin: int, *, subpixel: bool = True, uniqueness: float = 0.0,
                   device: Any = None) -> tuple[Any, Any, Any, Any]:
    """`wta` and `wta_right` of one volume in one pass over it: (disp_left, valid_left, disp_right, valid_right),
    each equal to what the two entry points return."""
    a = Inputs(device, cost)
    c, dmin = _volume(a, cost, dmin, compact=True)
    u = _uniqueness(uniqueness)
    H, W, _ = c.shape
    disp_l, disp_r = a.empty((H, W)), a.empty((H, W))
    valid_l, valid_r = a.empty((H, W), wp.uint8), a.empty((H, W), wp.uint8)
    best_r = a.empty((H, W), wp.int32)
    a.launch(_wta_rows, H, [c, disp_l, valid_l, disp_r, valid_r, best_r, dmin, int(bool(subpixel)), wp.float64(u)],
             min_chunk=4)
    return a.out(disp_l), a.out_mask(valid_l), a.out(disp_r), a.out_mask(valid_r)


def soft_argmin(cost: Any, dmin: int, temperature: float = 1.0, *, device: Any = None) -> Any:
    """sum_k d_k softmax_k(-cost / temperature): disparity (H, W)."""
    a = Inputs(device, cost)
    c, dmin = _volume(a, cost, dmin)
    t = check_float("temperature", temperature, positive=True)
    H, W, _ = c.shape
    disp = a.empty((H, W))
    a.launch(_soft_argmin_forward, H * W, [c, disp, dmin, wp.float64(t)], min_chunk=256)
    return a.out(disp)


def soft_argmin_backward(cost: Any, dmin: int, grad_disp: Any, temperature: float = 1.0, *,
                         device: Any = None) -> dict[str, Any]:
    """The gradient of a loss given grad_disp = dLoss/ddisp (H, W).

    Returns a dict {"cost": dLoss/dcost} (H, W, D) in the kind of `cost` (a NumPy array, or a
    wp.array on the device).
    """
    a = Inputs(device, cost, grad_disp)
    c, dmin = _volume(a, cost, dmin)
    t = check_float("temperature", temperature, positive=True)
    H, W, _ = c.shape
    g = a.floats("grad_disp", grad_disp, (H, W))
    grad = a.empty(c.shape)
    a.launch(_soft_argmin_backward, H * W, [c, g, grad, dmin, wp.float64(t)], min_chunk=256)
    return {"cost": a.out(grad)}


def left_right_check(disp_left: Any, disp_right: Any, max_diff: float = 1.0, *, valid_left: Any = None,
                     valid_right: Any = None, device: Any = None) -> Any:
    """Validity mask (H, W) of the left disparity after the left-right consistency check."""
    a = Inputs(device, disp_left, disp_right, valid_left, valid_right)
    dl = a.floats("disp_left", disp_left, ndim=2, nonempty=True)
    dr = a.floats("disp_right", disp_right, dl.shape)
    tol = check_float("max_diff", max_diff, nonnegative=True)
    shape = tuple(dl.shape)
    vl = _mask_or_ones(a, "valid_left", valid_left, shape)
    vr = _mask_or_ones(a, "valid_right", valid_right, shape)
    out = a.empty(shape, wp.uint8)
    a.launch(_left_right_check, dl.size, [dl, vl, dr, vr, out, wp.float64(tol)])
    return a.out_mask(out)


def depth_from_disparity(disp: Any, focal: float, baseline: float, *, valid: Any = None,
                         device: Any = None) -> tuple[Any, Any]:
    """Z = focal * baseline / d: depth (H, W) with 0 where invalid, and the validity mask."""
    a = Inputs(device, disp, valid)
    d = a.floats("disp", disp, ndim=2, nonempty=True, finite=False)  # non-finite disparities are marked invalid
    f = check_float("focal", focal, positive=True)
    b = check_float("baseline", baseline, positive=True)
    shape = tuple(d.shape)
    v = _mask_or_ones(a, "valid", valid, shape)
    depth = a.empty(shape)
    valid_out = a.empty(shape, wp.uint8)
    a.launch(_depth, d.size, [d, v, depth, valid_out, wp.float64(f * b)])
    return a.out(depth), a.out_mask(valid_out)
