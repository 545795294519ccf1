"""The AD-census cost's per-image passes: the clipped x-gradient, census with a tolerance, BT ranges, rho.

For a channel of an image I in [0, 1] (rows and columns clamped at the border),

    g(x, y) = sum_{dy in -1..1} w_dy (I(x + 1, y + dy) - I(x - 1, y + dy)),  w = (1, 2, 1),
    G(x, y) = (clip(g, -cap, cap) + cap) / (2 cap)  in [0, 1]                  (_sobel_x, sobel_x_clipped)

(StereoSGBM's prefilter, the x-Sobel filter). The census bit of a neighbour q of p with a tolerance
eps >= 0 is [I(q) < I(p) - eps], in kernels.stereo.costs' bit order (_census_eps). The
Birchfield-Tomasi terms need each pixel's half-pixel range (I_min, I_max) per channel
(_half_ranges, kernels.stereo.bt's _half_range). The robust squashing is

    w rho(c, lambda) = w (1 - exp(-c / lambda)),   1 / lambda rounded to c's type once   (_robust_term),

tabulated for every census distance h (_rho_table). _reverse_planar copies a right image with
every row mirrored and the channels planar, so that R(x - d) over consecutive d is a run of
consecutive scalars (kernels.stereo.adcensus_kernels reads it as vectors). The module options are
kernels.stereo.adcensus_kernels' (no contraction into FMA: the same values on every host).
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels import cpu_target
from kernels._arrays import Inputs, check_float, declare_float_overloads
from kernels.stereo._common import pixel
from kernels.stereo.bt import _half_range

# The host's vector width (-march=native, or DRLAB_CPU_TARGET's CPU: kernels/cpu_target.py);
# fuse_fp off: no multiply-add is ever contracted into an FMA, so every value is the same on hosts with and
# without FMA units.
wp.set_module_options({"enable_backward": False, "optimization_level": 3, "fuse_fp": False,
                       "cpu_compiler_flags": cpu_target.module_flags("-mllvm=-inline-threshold=9000")})


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


for _kernel in (_sobel_x, _census_eps, _half_ranges, _rho_table, _reverse_planar):
    declare_float_overloads(_kernel)


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
