"""Post-processing of a disparity map: the row fill of invalid pixels, then a 3x3 median.

`fill_median3(disp, valid)` returns M = median3(F), where F is KITTI's background fill along rows
(research.stereo.matching.fill_invalid): with l(x) and r(x) the disparities of the nearest valid pixels at or
left of x and at or right of x in the same row (+inf where there is none),

    F(x, y) = disp(x, y)                      where valid(x, y),
              min(l(x), r(x))                 elsewhere, or 0 when both are +inf (a row with no valid pixel),

and median3(F)(x, y) = the median of the 9 values F(x + i, y + j), i, j in {-1, 0, 1}, with coordinates
clamped to the image (scipy.ndimage.median_filter(F, size=3, mode="nearest")). Both steps only select
values (minima, order statistics), so the result equals that composition exactly, whatever the float
type. One thread per row fills it (a left-to-right pass for l, a right-to-left pass for r); one thread
per row then takes each pixel's median of 9 by a fixed sequence of minima and maxima: sort each of the
three rows of the 3x3 neighbourhood; the median of the 9 is then the median of (the largest of the three
minima, the median of the three medians, the smallest of the three maxima). Away from the left and right
columns that runs on vectors of 16 float32 (8 float64) consecutive pixels, lane by lane the same minima
and maxima.
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels import cpu_target
from kernels._arrays import Inputs, declare_float_overloads
from kernels.stereo._common import pixel

wp.set_module_options({"enable_backward": False, "optimization_level": 3,
                       "cpu_compiler_flags": cpu_target.module_flags("-mllvm=-inline-threshold=9000")})


@wp.kernel
def _fill_rows(disp: wp.array2d(dtype=typing.Any), valid: wp.array2d(dtype=wp.uint8),
               out: wp.array2d(dtype=typing.Any), offset: int):
    y = wp.tid() + offset
    W = disp.shape[1]
    inf = disp.dtype(wp.inf)
    zero = disp.dtype(0.0)
    last = inf
    for x in range(W):  # l(x): the nearest valid value at or left of x
        last = wp.where(valid[y, x] != wp.uint8(0), disp[y, x], last)
        out[y, x] = last
    last = inf
    for i in range(W):  # r(x), then F (at a valid pixel l = r = its own value)
        x = W - 1 - i
        last = wp.where(valid[y, x] != wp.uint8(0), disp[y, x], last)
        f = wp.min(out[y, x], last)
        out[y, x] = wp.where(f == inf, zero, f)


@wp.func
def _cx(a: typing.Any, b: typing.Any):
    """(min, max) of two values (or of two vectors, lane by lane): one compare-exchange."""
    return wp.min(a, b), wp.max(a, b)


@wp.func
def _med9(p0: typing.Any, p1: typing.Any, p2: typing.Any, p3: typing.Any, p4: typing.Any, p5: typing.Any,
          p6: typing.Any, p7: typing.Any, p8: typing.Any):
    """The median of 9 values (lane by lane for vectors): sort the triples (p0 p1 p2), (p3 p4 p5), (p6 p7 p8);
    the median is then the median of (the largest of their minima, the median of their medians, the smallest of
    their maxima)."""
    q1, q2 = _cx(p1, p2)
    q4, q5 = _cx(p4, p5)
    q7, q8 = _cx(p7, p8)
    q0, q1 = _cx(p0, q1)
    q3, q4 = _cx(p3, q4)
    q6, q7 = _cx(p6, q7)
    q1, q2 = _cx(q1, q2)
    q4, q5 = _cx(q4, q5)
    q7, q8 = _cx(q7, q8)
    lo = wp.max(wp.max(q0, q3), q6)  # the largest minimum
    hi = wp.min(wp.min(q2, q5), q8)  # the smallest maximum
    a, b = _cx(q1, q4)  # the median of the medians q1, q4, q7
    b = wp.min(b, q7)
    mid = wp.max(a, b)
    a, b = _cx(lo, mid)  # the median of lo, mid, hi
    b = wp.min(b, hi)
    return wp.max(a, b)


@wp.func
def _median_at(img: wp.array2d(dtype=typing.Any), ym: int, y: int, yp: int, x: int):
    """The 3x3 median at column x of rows (ym, y, yp), columns clamped."""
    W = img.shape[1]
    xm = wp.max(x - 1, 0)
    xp = wp.min(x + 1, W - 1)
    return _med9(img[ym, xm], img[ym, x], img[ym, xp], img[y, xm], img[y, x], img[y, xp], img[yp, xm], img[yp, x],
                 img[yp, xp])


@wp.kernel
def _median3(img: wp.array2d(dtype=typing.Any), img_v: wp.array(dtype=typing.Any), out: wp.array2d(dtype=typing.Any),
             out_v: wp.array(dtype=typing.Any), lanes: int, offset: int):
    # One thread per row y. Columns 1 .. W - 2 whose 3 x (lanes + 2) neighbourhood needs no clamping go through in
    # vectors of `lanes` consecutive pixels (img_v, out_v: unaligned vector views of the flat arrays); the first
    # column and the rest of the row one pixel at a time.
    y = wp.tid() + offset
    H = img.shape[0]
    W = img.shape[1]
    ym = wp.max(y - 1, 0) * W
    yc = y * W
    yp = wp.min(y + 1, H - 1) * W
    x0 = int(1)
    while x0 + lanes <= W - 1:
        out_v[yc + x0] = _med9(img_v[ym + x0 - 1], img_v[ym + x0], img_v[ym + x0 + 1],
                               img_v[yc + x0 - 1], img_v[yc + x0], img_v[yc + x0 + 1],
                               img_v[yp + x0 - 1], img_v[yp + x0], img_v[yp + x0 + 1])
        x0 += lanes
    out[y, 0] = _median_at(img, ym / W, y, yp / W, 0)
    for x in range(wp.max(x0, 1), W):
        out[y, x] = _median_at(img, ym / W, y, yp / W, x)


LANES = {wp.float32: 16, wp.float64: 8}
VEC = {s: wp.types.vector(length=n, dtype=s) for s, n in LANES.items()}
declare_float_overloads(_fill_rows)
declare_float_overloads(_median3, VEC)


def _vector_view(flat: wp.array, lanes: int) -> wp.array:
    """Vectors of `lanes` consecutive scalars of `flat` starting at any scalar (unaligned, strides of one scalar);
    empty when `flat` holds fewer than `lanes` scalars."""
    item = wp.types.type_size_in_bytes(flat.dtype)
    return wp.array(ptr=flat.ptr, dtype=VEC[flat.dtype], shape=(max(flat.shape[0] - lanes + 1, 0),),
                    strides=(item,), device=flat.device)


def fill_median3(disp: Any, valid: Any, *, device: Any = None) -> Any:
    """median3(F) of the module docstring: `disp` (H, W) float32 or float64, `valid` (H, W) bool or uint8;
    the result has `disp`'s float type and array kind."""
    a = Inputs(device, disp, valid)
    if len(getattr(disp, "shape", ())) != 2:
        raise ValueError(f"disp: expected an (H, W) disparity map, got shape {tuple(getattr(disp, 'shape', ()))}")
    # Invalid pixels may hold anything (they are replaced), so only the valid ones must be finite: checked by the
    # caller's pipeline; here the values are taken as they are.
    d = a.floats("disp", disp, ndim=2, finite=False, nonempty=True)
    v = a.mask("valid", valid, d.shape)
    H, W = d.shape
    filled = a.empty((H, W))
    a.launch(_fill_rows, H, [d, v, filled], min_chunk=16)
    out = a.empty((H, W))
    lanes = LANES[a.scalar]
    views = [_vector_view(x.reshape((H * W,)), lanes) for x in (filled, out)]
    a.launch(_median3, H, [filled, views[0], out, views[1], lanes], min_chunk=8)
    return a.out(out)
