"""The census transform (Zabih & Woodfill, ECCV 1994) as kernels compiled for one window size each.

For a (2 ry + 1) x (2 rx + 1) window, pixel p's bit string has one bit per neighbour q != p, in
raster order (dy, then dx, from -r to r), most significant first:

    census(p) = sum_i [I(q_i) < I(p)] 2^(n - 1 - i),   n = (2 ry + 1)(2 rx + 1) - 1 <= 64,

with neighbour coordinates clamped to the image (kernels.stereo.costs states the same). The radii
are compile-time constants of each kernel (`census_kernel(ry, rx)` builds and caches one per window
size), so the window loops unroll into straight-line code, and pixels whose window lies inside the
image skip the clamps. One thread per pixel, thread i = y W + x. Float32 images on the CPU take
census_rows_f32 instead (a row per thread in C++, 16 pixels a vector; the same strings, below).
"""

from __future__ import annotations

import typing

import warp as wp

from kernels._arrays import declare_float_overloads
from kernels.native import source
from kernels.stereo._common import pixel

_KERNELS: dict[tuple[int, int], typing.Any] = {}


def census_kernel(ry: int, rx: int) -> typing.Any:
    """The census transform kernel for radii (ry, rx): (img (H, W) float, out (H, W) uint64, offset)."""
    key = (int(ry), int(rx))
    if key in _KERNELS:
        return _KERNELS[key]
    RY, RX = key
    N = (2 * RY + 1) * (2 * RX + 1) - 1

    @wp.kernel(enable_backward=False, module="unique")
    def census(img: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=wp.uint64), offset: int):
        H = img.shape[0]
        W = img.shape[1]
        y, x = pixel(wp.tid() + offset, W)
        c = img[y, x]
        bits = wp.uint64(0)
        if y >= RY and y < H - RY and x >= RX and x < W - RX:
            # Each bit on its own (no chain of shifts): neighbour (dy, dx) is bit number n - 1 - i, with i
            # its raster index, one less past the centre. Branch-free: on texture the comparison is a coin
            # toss that a branch would mispredict.
            for dy in range(wp.static(-RY), wp.static(RY + 1)):
                for dx in range(wp.static(-RX), wp.static(RX + 1)):
                    if dy != 0 or dx != 0:
                        i = (dy + RY) * (2 * RX + 1) + dx + RX
                        if dy > 0 or (dy == 0 and dx > 0):
                            i = i - 1
                        bit = wp.uint64(wp.where(img[y + dy, x + dx] < c, 1, 0))
                        bits = bits | (bit << wp.uint64(N - 1 - i))
        else:
            for dy in range(wp.static(-RY), wp.static(RY + 1)):
                yy = wp.clamp(y + dy, 0, H - 1)
                for dx in range(wp.static(-RX), wp.static(RX + 1)):
                    if dy != 0 or dx != 0:
                        q = img[yy, wp.clamp(x + dx, 0, W - 1)]
                        bits = (bits << wp.uint64(1)) | wp.uint64(wp.where(q < c, 1, 0))
        out[y, x] = bits

    declare_float_overloads(census)
    _KERNELS[key] = census
    return census


# The same transform for float32 images on the CPU, one thread per row, in C++ (wp.func_native,
# kernels/native/census_row.cpp): where the window lies inside the image, 16 pixels at once (clang vector lanes: one
# unaligned row load per neighbour, the bits set as above); elsewhere (border rows and columns, a row's last pixels)
# pixel by pixel with clamped coordinates and the chain of shifts. Comparisons and bit operations only, so the
# strings are those of census_kernel exactly.
@wp.func_native(source("census_row.cpp"))
def _census_row(img: wp.array2d(dtype=wp.float32), out: wp.array2d(dtype=wp.uint64), y: int, ry: int,
                rx: int) -> int: ...


@wp.kernel(enable_backward=False)
def census_rows_f32(img: wp.array2d(dtype=wp.float32), out: wp.array2d(dtype=wp.uint64), ry: int, rx: int,
                    offset: int):
    """census_kernel(ry, rx)'s strings of float32 images on the CPU, one thread per row (_census_row)."""
    _census_row(img, out, wp.tid() + offset, ry, rx)
