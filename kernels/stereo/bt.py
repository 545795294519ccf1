"""Birchfield-Tomasi matching cost (Birchfield & Tomasi, PAMI 1998), grey or colour, over a window.

The sampling-insensitive dissimilarity compares a pixel with the linearly interpolated intensity
range of its match's half-pixel neighbourhood, so a half-pixel misalignment of the sampling grids
costs nothing. For one channel I of the left image at x and of the right image at u = x - d (row y),

    I^-(x) = (I(x) + I(x - 1)) / 2,   I^+(x) = (I(x) + I(x + 1)) / 2   (neighbours clamped to the row),
    I_min(x) = min(I^-(x), I^+(x), I(x)),   I_max(x) = max(I^-(x), I^+(x), I(x)),
    e_LR = max(0, I_L(x) - I_Rmax(u), I_Rmin(u) - I_L(x)),
    e_RL = max(0, I_R(u) - I_Lmax(x), I_Lmin(x) - I_R(u)),
    bt(x, y, d) = min(e_LR, e_RL).

Colour images (H, W, C) contribute the mean of the per-channel values (the colour term of OpenCV's
StereoSGBM sums channels; the mean keeps the cost in the images' intensity units whatever C is).
The cost is the window mean, over the (2r+1)^2 window N cut to the image and to the columns whose
match exists (u - d in [0, W)), exactly as SAD's (kernels.stereo.costs):

    C_BT(x, y, d) = 1/|N| sum_{(u', v) in N} bt(u', v, d).

Out of range (x - d outside [0, W)): the range of all pixel values (max - min over both images),
an upper bound of every in-range cost.

Three launches, each one thread per pixel writing only its own cells: the per-pixel bt volume
(0 out of range), the sum over the window's rows, then over its columns divided by |N|. Work per
cell is O(r); the window is small.
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels._arrays import Inputs, check_int, declare_float_overloads
from kernels.stereo._common import check_range, grey_or_colour_pair, pixel

wp.set_module_options({"enable_backward": False})


@wp.func
def _half_range(img: wp.array3d(dtype=typing.Any), y: int, x: int, c: int):
    """(I_min, I_max) of the half-pixel neighbourhood of I(x, y) in channel c."""
    W = img.shape[1]
    v = img[y, x, c]
    h = img.dtype(0.5)
    vm = h * (v + img[y, wp.max(x - 1, 0), c])
    vp = h * (v + img[y, wp.min(x + 1, W - 1), c])
    return wp.min(wp.min(vm, vp), v), wp.max(wp.max(vm, vp), v)


@wp.kernel
def _bt_pixel(left: wp.array3d(dtype=typing.Any), right: wp.array3d(dtype=typing.Any),
              out: wp.array3d(dtype=typing.Any), dmin: int, offset: int):
    W = left.shape[1]
    C = left.shape[2]
    y, x = pixel(wp.tid() + offset, W)
    zero = out.dtype(0.0)
    inv_c = out.dtype(1.0) / out.dtype(C)
    for k in range(out.shape[2]):
        u = x - (dmin + k)
        acc = zero
        if u >= 0 and u < W:
            for c in range(C):
                lv = left[y, x, c]
                rv = right[y, u, c]
                lmin, lmax = _half_range(left, y, x, c)
                rmin, rmax = _half_range(right, y, u, c)
                e_lr = wp.max(wp.max(zero, lv - rmax), rmin - lv)
                e_rl = wp.max(wp.max(zero, rv - lmax), lmin - rv)
                acc += wp.min(e_lr, e_rl)
        out[y, x, k] = acc * inv_c


@wp.kernel
def _sum_rows(src: wp.array3d(dtype=typing.Any), dst: wp.array3d(dtype=typing.Any), radius: int, offset: int):
    # dst[y, x, k] = sum over v in [y - r, y + r] cut to the image of src[v, x, k].
    H = src.shape[0]
    y, x = pixel(wp.tid() + offset, src.shape[1])
    v0 = wp.max(y - radius, 0)
    v1 = wp.min(y + radius, H - 1)
    for k in range(src.shape[2]):
        s = src.dtype(0.0)
        for v in range(v0, v1 + 1):
            s += src[v, x, k]
        dst[y, x, k] = s


@wp.kernel
def _mean_cols(src: wp.array3d(dtype=typing.Any), dst: wp.array3d(dtype=typing.Any), dmin: int, radius: int,
               invalid: wp.float64, offset: int):
    # dst[y, x, k] = sum over the window's in-range columns of src[y, ., k], divided by |N|.
    H = src.shape[0]
    W = src.shape[1]
    y, x = pixel(wp.tid() + offset, W)
    rows = wp.min(y + radius, H - 1) - wp.max(y - radius, 0) + 1
    for k in range(src.shape[2]):
        d = dmin + k
        if x - d < 0 or x - d >= W:
            dst[y, x, k] = dst.dtype(invalid)
        else:
            lo = wp.max(wp.max(x - radius, 0), d)
            hi = wp.min(wp.min(x + radius, W - 1), W - 1 + d)
            s = src.dtype(0.0)
            for u in range(lo, hi + 1):
                s += src[y, u, k]
            dst[y, x, k] = s / src.dtype(rows * (hi - lo + 1))


for _kernel in (_bt_pixel, _sum_rows, _mean_cols):
    declare_float_overloads(_kernel)


def bt_cost(left: Any, right: Any, dmin: int, dmax: int, radius: int = 2, *, device: Any = None) -> Any:
    """Window mean of the Birchfield-Tomasi dissimilarity: volume (H, W, dmax - dmin) (module docstring).

    `left`, `right`: grey (H, W) or colour (H, W, C) float images of one shape and dtype.
    """
    a = Inputs(device, left, right)
    l_img, r_img, ndim = grey_or_colour_pair(a, left, right)
    H, W = l_img.shape[:2]
    dmin, D = check_range(dmin, dmax, W)
    r = check_int("radius", radius, minimum=0)
    lh, rh = l_img.numpy(), r_img.numpy()
    invalid = float(max(lh.max(), rh.max())) - float(min(lh.min(), rh.min()))
    if ndim == 2:  # a view with one channel
        l_img, r_img = l_img.contiguous().reshape((H, W, 1)), r_img.contiguous().reshape((H, W, 1))
    raw = a.empty((H, W, D))
    a.launch(_bt_pixel, H * W, [l_img, r_img, raw, dmin], min_chunk=256)
    rows = a.empty((H, W, D))
    a.launch(_sum_rows, H * W, [raw, rows, r], min_chunk=256)
    out = raw  # raw is no longer read: its memory takes the result
    a.launch(_mean_cols, H * W, [rows, out, dmin, r, wp.float64(invalid)], min_chunk=256)
    return a.out(out)
