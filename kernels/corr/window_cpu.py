"""The dense lookup's window sampling (3)-(4) on the CPU, in C++ with the window's side fixed at compile time.

The C++ is in kernels/native/window_sample.cpp, window_lanes.cpp and window_prefetch.cpp, loaded by
`kernels.native.source` with the side (and the lanes) as template parameters.

Same math and the same operations as `_common.sample_window`, on the same values,
so the same outputs bit for bit. For pixel p at level l with window origin
(j0, i0) and fractions (fx, fy) (`_common.pixel_window`), gx = 1 - fx, gy = 1 - fy,
and tap rows t = 0 .. 2r+1 of S = V^l[p] (taps outside S reading 0):

    row sample   R[t, a] = gx S[j0 + t, i0 + a] + fx S[j0 + t, i0 + a + 1],      a = 0 .. 2r
    output       out[l (2r+1)^2 + a (2r+1) + b, p] = gy R[b, a] + fy R[b + 1, a],  b = 0 .. 2r

each product and each sum a separate C++ statement (so the compiler fuses no
multiply-add, exactly as Warp's generated code computes `sample_window`).

Why C++. Warp's generated code reads every tap through a runtime-strided, 3-index
array access that also wraps negative indices, and with the side a runtime value
keeps the window's loops generic: about 29 instructions an output sample at radius
4, and each output sample a scattered scalar store (out is channel-major).

Here a thread takes a block of LANES = 4 consecutive pixels, one pixel a vector
lane (kernels/native/window_lanes.cpp, clang's vector extension: the same statements on vectors of 4
samples), so each output channel's 4 samples leave in one vector store. The tap
rows are read through plain pointers: a block whose windows all lie inside their
slices (most of levels 0-1) reads them without tests; otherwise (most of levels
2-3) each tap row and tap column is tested once a lane and clamped positions are
read, the outside taps set to 0. A last block of fewer than 4 pixels runs the
one-pixel version (window_sample.cpp). `sample_levels_cpu(radius, scalar)` builds one
kernel per radius and float type (its own Warp module, compiled on first use) with
the side a literal, so the compiler unrolls and schedules the window's loops.
While a block is sampled, the next block's tap rows are prefetched
(`__builtin_prefetch`, a hint): at levels 0-1 (volumes of 32 and 8 MB at 46x62
features) each window otherwise waits about one cache-miss latency.

The kernel samples up to four levels a launch, as `_common.sample_levels` does
(its arguments minus `radius`, over `blocks(H W)` threads); it is launched on the
CPU only (CUDA keeps `_common.sample_levels`). The adjoint is unchanged
(`_common.sample_windows_adjoint`). `sample_patches_cpu` is the same 4-lane window
reading each pixel's on-the-fly patch (its origin 0, 0) instead of a level slice: the
on-the-fly forward's sampling on the CPU (`_common.sample_windows` with `from_patch` = 1).
"""

from typing import Any

import warp as wp

from kernels.native import built_once, source
from kernels.corr._common import pixel_window

# LANES consecutive pixels at once, a pixel a vector lane (kernels/native/window_lanes.cpp: clang's vector
# extension; compiled for the CPU only, by Warp's clang).
LANES = 4  # 4 measured 1.2x faster than 8 and 1.6x faster than 2 (one thread, interleaved)

_kernels: dict[tuple[int, Any], Any] = {}
_windows: dict[tuple[int, Any], Any] = {}


def window_func(radius: int, scalar: Any) -> Any:
    """The one-pixel C++ window (kernels/native/window_sample.cpp) for this radius and float type, a Warp native
    function (s, p, row0, col0, fx, fy, out, channel0, h, w) with `_common.sample_window`'s arguments less
    the side; built once (also used by `patch_cpu`, on the on-the-fly path's patches)."""
    return built_once(_windows, (radius, scalar), lambda: _window(radius, scalar))


def _window(radius: int, scalar: Any) -> Any:
    # No `from __future__ import annotations` in this module: Warp reads the stub's and the
    # kernel's annotations as objects, and these name the closure's types.
    side = 2 * radius + 1
    array3 = wp.array3d(dtype=scalar)

    def window(s: array3, p: int, row0: int, col0: int, fx: scalar, fy: scalar, out: array3, channel0: int,
               h: int, w: int): ...

    # A name of its own per radius and type: Warp keys native functions by name.
    window.__name__ = window.__qualname__ = f"sample_window_cpu_r{radius}_{scalar.__name__}"
    window = wp.func_native(source("window_sample.cpp", SIDE=side))(window)
    return window


def _build(radius: int, scalar: Any) -> Any:
    side = 2 * radius + 1
    array3 = wp.array3d(dtype=scalar)
    window = window_func(radius, scalar)

    def prefetch(s: array3, p: int, row0: int, col0: int): ...

    prefetch.__name__ = prefetch.__qualname__ = f"prefetch_window_cpu_r{radius}_{scalar.__name__}"
    prefetch = wp.func_native(source("window_prefetch.cpp", SIDE=side))(prefetch)

    def lanes(s: array3, p0: int, coords: array3, scale: scalar, out: array3, channel0: int): ...

    lanes.__name__ = lanes.__qualname__ = f"sample_lanes_cpu_r{radius}_{scalar.__name__}"
    lanes = wp.func_native(source("window_lanes.cpp", SIDE=side, LANES=LANES, FROM_PATCH=False))(lanes)

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3})
    def sample_levels_cpu(v0: array3, v1: array3, v2: array3, v3: array3, n_levels: int, coords: array3,
                          out: array3, scale0: scalar, channel0: int, offset: int):
        # thread = a block of LANES consecutive pixels (the last block may hold fewer)
        p0 = (wp.tid() + offset) * LANES
        n_pixels = coords.shape[1] * coords.shape[2]
        half = scalar(0.5)
        scale = scale0
        for k in range(n_levels):  # one call site: the window's code once, not once a level
            v = v0
            if k == 1:
                v = v1
            if k == 2:
                v = v2
            if k == 3:
                v = v3
            for q in range(p0 + LANES, wp.min(p0 + 2 * LANES, n_pixels)):  # the next block's rows
                hq, wq, iq, fxq, jq, fyq = pixel_window(coords, q, scale, radius)
                prefetch(v, q, jq, iq)
            channel = channel0 + k * side * side
            if p0 + LANES <= n_pixels:
                lanes(v, p0, coords, scale, out, channel)
            else:
                for p in range(p0, n_pixels):
                    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
                    window(v, p, j0, i0, fx, fy, out, channel, h, w)
            scale = scale * half

    return sample_levels_cpu


def sample_levels_cpu(radius: int, scalar: Any) -> Any:
    """The CPU kernel sampling up to four levels for this radius and float type (built once, cached).

    Arguments: (v0, v1, v2, v3, n_levels, coords, out, scale0, channel0, offset), those of
    `_common.sample_levels` without `radius`; launched over `blocks(H W)` threads (blocks of LANES
    pixels), not one a pixel.
    """
    return built_once(_kernels, (radius, scalar), lambda: _build(radius, scalar))


def blocks(n_pixels: int) -> int:
    """Threads of a `sample_levels_cpu` launch over n_pixels pixels: one a block of LANES."""
    return -(-n_pixels // LANES)


# The on-the-fly lookup's windows, sampled from each pixel's (2r + 2)^2 patch of taps (origin 0, 0)
# instead of its level slice at the window's origin; the fractions are the same.
_patch_kernels: dict[tuple[int, Any], Any] = {}


def _build_patches(radius: int, scalar: Any) -> Any:
    side = 2 * radius + 1
    array3 = wp.array3d(dtype=scalar)
    window = window_func(radius, scalar)

    def lanes(s: array3, p0: int, coords: array3, scale: scalar, out: array3, channel0: int): ...

    lanes.__name__ = lanes.__qualname__ = f"sample_patch_lanes_cpu_r{radius}_{scalar.__name__}"
    lanes = wp.func_native(source("window_lanes.cpp", SIDE=side, LANES=LANES, FROM_PATCH=True))(lanes)

    @wp.kernel(module="unique", module_options={"enable_backward": False, "optimization_level": 3})
    def sample_patches_cpu(patch: array3, coords: array3, out: array3, scale: scalar, channel0: int, offset: int):
        # thread = a block of LANES consecutive pixels (the last block may hold fewer)
        p0 = (wp.tid() + offset) * LANES
        n_pixels = coords.shape[1] * coords.shape[2]
        if p0 + LANES <= n_pixels:
            lanes(patch, p0, coords, scale, out, channel0)
        else:
            for p in range(p0, n_pixels):
                h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
                window(patch, p, 0, 0, fx, fy, out, channel0, h, w)

    return sample_patches_cpu


def sample_patches_cpu(radius: int, scalar: Any) -> Any:
    """The CPU kernel sampling every pixel's window from its patch (the on-the-fly lookup's (3)), for this
    radius and float type: `_common.sample_windows` with `from_patch` = 1, LANES pixels a thread as
    `sample_levels_cpu` (bit-identical). Arguments (patch, coords, out, scale, channel0, offset), over
    `blocks(H W)` threads; built once, cached."""
    return built_once(_patch_kernels, (radius, scalar), lambda: _build_patches(radius, scalar))
