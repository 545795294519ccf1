"""What every stage of kernels.stereo shares: the pixel of a flat thread index, and disparity ranges.

A launch over an image of width W runs one thread per pixel, thread i = y W + x. A disparity
range [dmin, dmax) over an image W pixels wide holds D = dmax - dmin hypotheses d_k = dmin + k;
it is usable when it is non-empty, holds at most W hypotheses, and lies within (-W, W], so that
some pixel (x, y) has its match (x - d_k, y) inside the image.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from kernels._arrays import Inputs, check_int


@wp.func
def pixel(i: int, width: int):
    """(y, x) of the flat pixel index i = y * width + x."""
    y = i / width
    return y, i - y * width


def check_range(dmin: Any, dmax: Any, width: int) -> tuple[int, int]:
    """Validate the disparity range [dmin, dmax) against an image `width` pixels wide: (dmin, D)."""
    dmin = check_int("dmin", dmin)
    dmax = check_int("dmax", dmax)
    if dmax <= dmin:
        raise ValueError(f"dmax: the disparity range [dmin, dmax) = [{dmin}, {dmax}) is empty")
    if dmax - dmin > width:
        raise ValueError(f"dmax: the disparity range [{dmin}, {dmax}) holds {dmax - dmin} hypotheses, "
                         f"more than the image width {width}")
    if dmin <= -width or dmax > width:
        raise ValueError(f"dmin, dmax: the range [{dmin}, {dmax}) must lie within (-{width}, {width}] "
                         "so that some pixel has a match")
    return dmin, dmax - dmin


def check_dmin(dmin: Any, hypotheses: int, width: int, volume: str = "cost") -> int:
    """Validate dmin for the argument `volume` holding `hypotheses` hypotheses over an image `width`
    pixels wide; returns it. A volume with too many hypotheses is the volume's error, not dmax's
    (these entry points have no dmax)."""
    dmin = check_int("dmin", dmin)
    if hypotheses > width:
        raise ValueError(f"{volume}: holds {hypotheses} disparity hypotheses [dmin, dmin + D), more than the "
                         f"image width {width}")
    return check_range(dmin, dmin + hypotheses, width)[0]


def image_pair(a: Inputs, left: Any, right: Any, ndim: int = 2, names: tuple[str, str] = ("left", "right")
               ) -> tuple[wp.array, wp.array]:
    """Two non-empty, finite float arrays of one shape (`ndim` dimensions) and dtype, as wp.arrays."""
    first = a.floats(names[0], left, ndim=ndim, nonempty=True)
    return first, a.floats(names[1], right, first.shape)


def grey_or_colour_pair(a: Inputs, left: Any, right: Any) -> tuple[wp.array, wp.array, int]:
    """`image_pair` of grey (H, W) or colour (H, W, C) images, and their number of dimensions (2 or 3)."""
    ndim = len(getattr(left, "shape", ()))
    if ndim not in (2, 3):
        raise ValueError(f"left: expected a grey (H, W) or colour (H, W, C) image, got shape "
                         f"{tuple(getattr(left, 'shape', ()))}")
    return (*image_pair(a, left, right, ndim), ndim)


def compact_volume(a: Inputs, name: str, x: Any, dtype: Any) -> wp.array:
    """An integer volume (H, W, D) of `dtype` (wp.uint8 or wp.uint16; compact mode) as a wp.array on the call's
    device; its results are float32 (a.scalar)."""
    a._array(name, x)
    np_dtype = {wp.uint8: np.uint8, wp.uint16: np.uint16}[dtype]
    if getattr(x, "dtype", None) not in (dtype, np_dtype):
        raise ValueError(f"{name}: expected a float or a {np.dtype(np_dtype).name} volume, got dtype {x.dtype}")
    if len(x.shape) != 3 or min(x.shape) == 0:
        raise ValueError(f"{name}: expected a non-empty (H, W, D) volume, got shape {tuple(x.shape)}")
    if a.scalar is None:
        a.scalar = wp.float32
    if isinstance(x, wp.array):
        return x
    return wp.array(np.ascontiguousarray(x), dtype=dtype, device=a.device)
