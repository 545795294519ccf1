"""Structural similarity (SSIM) and its hand-written adjoint, for image losses.

Follows Wang et al., "Image Quality Assessment: From Error Visibility to
Structural Similarity" (IEEE TIP 2004), in the form the 3DGS training loss uses
(Kerbl et al. 2023, after Zhao et al.'s pytorch-ssim): every channel of
images x, y (H, W, C) is filtered with the 11 x 11 Gaussian window g (sigma 1.5,
normalised to sum 1) as a 'same'-size correlation with ZERO padding,

    mu_x = g * x,  mu_y = g * y,  e_xx = g * x^2,  e_yy = g * y^2,  e_xy = g * (x y),
    s_xx = e_xx - mu_x^2,  s_yy = e_yy - mu_y^2,  s_xy = e_xy - mu_x mu_y,

    SSIM = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_xx + s_yy + C2)),

with C1 = (0.01 L)^2, C2 = (0.03 L)^2 for data range L (default 1). `ssim_map`
returns the per-pixel map; the loss uses its mean.

Backward. With A1 = 2 mu_x mu_y + C1, A2 = 2 s_xy + C2, B1 = mu_x^2 + mu_y^2 + C1,
B2 = s_xx + s_yy + C2 and S = A1 A2 / (B1 B2), as a function of the five filtered
maps,
    dS/dmu_x = S (2 mu_y / A1 - 2 mu_y / A2 - 2 mu_x / B1 + 2 mu_x / B2),
    dS/de_xx = -S / B2,   dS/de_xy = 2 S / A2       (and symmetrically in y).
The window is symmetric and zero-padded, so the filter is its own adjoint: with
G_m = g * (c dS/dm) for a cotangent map c,
    dL/dx = G_mu_x + 2 x G_e_xx + y G_e_xy,    dL/dy = G_mu_y + 2 y G_e_yy + x G_e_xy.
The filter is separable and runs as a horizontal then a vertical pass. Every
kernel writes only its own pixel, so all of them run split over CPU threads
(kernels.launch.launch_split, through kernels/_arrays.py). Generic over float32 and float64.

CPU fast path (kernels.fast_paths): in float32 on the CPU the two passes run a row at a time in C++
(kernels/native/ssim_blur_row.cpp), each output row a sum of shifted source rows, which the compiler
runs in vector lanes; every output pixel gets the same terms in the same order, each product and sum
its own statement as in `_blur_kernel`, so the blurred maps are bit-identical to the plain kernel's
(tests/kernels/test_ssim.py checks it). It is what makes the 3DGS loss cheap on the CPU: the plain
per-pixel Warp kernel spends most of a 200x200 training iteration's time in this filter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A, fast_paths
from kernels.native import source

wp.set_module_options({"enable_backward": False})

WINDOW = 11
SIGMA = 1.5
K1 = 0.01
K2 = 0.03
_HALF = WINDOW // 2
_MOMENTS = 5  # mu_x, mu_y, e_xx, e_yy, e_xy


def gaussian_window(size: int = WINDOW, sigma: float = SIGMA) -> np.ndarray:
    """The normalised 1-D Gaussian taps; the 2-D window is their outer product."""
    k = np.arange(size) - size // 2
    w = np.exp(-(k**2) / (2.0 * sigma**2))
    return w / w.sum()


@wp.func
def _pixel(i: int, w: int, c: int):
    """(row, col, channel) of flat index i over an (H, W, C) image, channel fastest."""
    return i / (c * w), (i / c) % w, i % c


@wp.func
def _ssim_terms(mom: wp.array4d(dtype=Any), row: int, col: int, ch: int, c1: Any, c2: Any):
    """(mu_x, mu_y, A1, A2, B1, B2) at one pixel and channel from the filtered moments (module docstring)."""
    two = mom.dtype(2.0)
    mx = mom[0, row, col, ch]
    my = mom[1, row, col, ch]
    sxx = mom[2, row, col, ch] - mx * mx
    syy = mom[3, row, col, ch] - my * my
    sxy = mom[4, row, col, ch] - mx * my
    return mx, my, two * mx * my + c1, two * sxy + c2, mx * mx + my * my + c1, sxx + syy + c2


@wp.kernel
def _moments_kernel(x: wp.array3d(dtype=Any), y: wp.array3d(dtype=Any), out: wp.array4d(dtype=Any), offset: int):
    row, col, ch = _pixel(wp.tid() + offset, x.shape[1], x.shape[2])
    if row >= x.shape[0]:
        return
    a = x[row, col, ch]
    b = y[row, col, ch]
    out[0, row, col, ch] = a
    out[1, row, col, ch] = b
    out[2, row, col, ch] = a * a
    out[3, row, col, ch] = b * b
    out[4, row, col, ch] = a * b


@wp.kernel
def _blur_kernel(src: wp.array4d(dtype=Any), taps: wp.array(dtype=Any), axis: int, dst: wp.array4d(dtype=Any),
                 offset: int):
    # One pixel and channel of all M maps: a 1-D correlation along `axis` (1 = rows, 2 = columns),
    # zero outside the image.
    row, col, ch = _pixel(wp.tid() + offset, src.shape[2], src.shape[3])
    h = src.shape[1]
    w = src.shape[2]
    lo = wp.max(0, _HALF - (col if axis == 2 else row))
    hi = wp.min(WINDOW, (w if axis == 2 else h) + _HALF - (col if axis == 2 else row))
    for m in range(src.shape[0]):
        acc = src.dtype(0.0)
        for k in range(lo, hi):
            if axis == 1:
                acc += taps[k] * src[m, row + k - _HALF, col, ch]
            else:
                acc += taps[k] * src[m, row, col + k - _HALF, ch]
        dst[m, row, col, ch] = acc


@wp.kernel
def _ssim_map_kernel(mom: wp.array4d(dtype=Any), c1: Any, c2: Any, out: wp.array3d(dtype=Any), offset: int):
    row, col, ch = _pixel(wp.tid() + offset, out.shape[1], out.shape[2])
    mx, my, a1, a2, b1, b2 = _ssim_terms(mom, row, col, ch, c1, c2)
    out[row, col, ch] = a1 * a2 / (b1 * b2)


@wp.kernel
def _ssim_partials_kernel(mom: wp.array4d(dtype=Any), g_map: wp.array3d(dtype=Any), c1: Any, c2: Any,
                          out: wp.array4d(dtype=Any), offset: int):
    # out[m] = g_map * dS/d(moment m), for m = mu_x, mu_y, e_xx, e_yy, e_xy.
    row, col, ch = _pixel(wp.tid() + offset, g_map.shape[1], g_map.shape[2])
    two = mom.dtype(2.0)
    mx, my, a1, a2, b1, b2 = _ssim_terms(mom, row, col, ch, c1, c2)
    gs = g_map[row, col, ch] * a1 * a2 / (b1 * b2)
    out[0, row, col, ch] = gs * (two * my / a1 - two * my / a2 - two * mx / b1 + two * mx / b2)
    out[1, row, col, ch] = gs * (two * mx / a1 - two * mx / a2 - two * my / b1 + two * my / b2)
    out[2, row, col, ch] = -gs / b2
    out[3, row, col, ch] = -gs / b2
    out[4, row, col, ch] = two * gs / a2


@wp.kernel
def _ssim_input_grads_kernel(x: wp.array3d(dtype=Any), y: wp.array3d(dtype=Any), gm: wp.array4d(dtype=Any),
                             dx: wp.array3d(dtype=Any), dy: wp.array3d(dtype=Any), offset: int):
    row, col, ch = _pixel(wp.tid() + offset, x.shape[1], x.shape[2])
    two = x.dtype(2.0)
    a = x[row, col, ch]
    b = y[row, col, ch]
    dx[row, col, ch] = gm[0, row, col, ch] + two * a * gm[2, row, col, ch] + b * gm[4, row, col, ch]
    dy[row, col, ch] = gm[1, row, col, ch] + two * b * gm[3, row, col, ch] + a * gm[4, row, col, ch]


for _k in (_moments_kernel, _blur_kernel, _ssim_map_kernel, _ssim_partials_kernel, _ssim_input_grads_kernel):
    A.declare_float_overloads(_k)


@wp.func_native(source("ssim_blur_row.cpp", HALF=_HALF))
def blur_row_f32(src: wp.array4d(dtype=wp.float32), taps: wp.array(dtype=wp.float32), axis: int,
                 dst: wp.array4d(dtype=wp.float32), m: int, row: int): ...


@wp.kernel
def _blur_rows_cpu_kernel(src: wp.array4d(dtype=wp.float32), taps: wp.array(dtype=wp.float32), axis: int,
                          dst: wp.array4d(dtype=wp.float32), offset: int):
    # One row of one map (the CPU fast path; module docstring).
    i = wp.tid() + offset
    if i >= src.shape[0] * src.shape[1]:
        return
    blur_row_f32(src, taps, axis, dst, i / src.shape[1], i % src.shape[1])


# ============================================================================ entry points


def _blur(a: A.Inputs, maps: wp.array, taps: wp.array) -> wp.array:
    """The window's correlation of every map (M, H, W, C): along the columns, then along the rows."""
    tmp = a.empty(maps.shape)
    out = a.empty(maps.shape)
    if maps.dtype == wp.float32 and fast_paths.on(a.device) and maps.is_contiguous:
        rows = maps.shape[0] * maps.shape[1]
        a.launch(_blur_rows_cpu_kernel, rows, [maps, taps, 2, tmp])
        a.launch(_blur_rows_cpu_kernel, rows, [tmp, taps, 1, out])
        return out
    per_map = maps.size // maps.shape[0]
    a.launch(_blur_kernel, per_map, [maps, taps, 2, tmp])
    a.launch(_blur_kernel, per_map, [tmp, taps, 1, out])
    return out


@dataclass
class SSIMState:
    """What `ssim_map` computed: `map` in the kind of x; x, y and the moments are wp.arrays (state)."""

    x: wp.array
    y: wp.array
    moments: wp.array  # (5, H, W, C) filtered mu_x, mu_y, e_xx, e_yy, e_xy
    map: Any  # (H, W, C)
    data_range: float
    as_numpy: bool

    def mean(self) -> float:
        m = self.map if isinstance(self.map, np.ndarray) else self.map.numpy()
        return float(m.mean(dtype=np.float64))

    def inputs(self) -> A.Inputs:
        return A.Inputs.like(self.x.device, self.x.dtype, self.as_numpy)


def _constants(a: A.Inputs, data_range: float) -> tuple[Any, Any]:
    data_range = A.check_float("data_range", data_range, positive=True)
    return a.s((K1 * data_range) ** 2), a.s((K2 * data_range) ** 2)


def ssim_map(x: Any, y: Any, *, data_range: float = 1.0, device: Any = None) -> SSIMState:
    """Per-pixel SSIM of images x and y (H, W, C), one float dtype; see the module docstring.

    NumPy or wp.array inputs (kernels/_arrays.py); the map comes back in the kind of x.
    """
    a = A.Inputs(device, x, y)
    xa = a.floats("x", x, ndim=3, nonempty=True)
    ya = a.floats("y", y, tuple(xa.shape))
    c1, c2 = _constants(a, data_range)
    h, w, c = xa.shape
    taps = wp.array(gaussian_window(), dtype=a.scalar, device=a.device)
    mom = a.empty((_MOMENTS, h, w, c))
    a.launch(_moments_kernel, h * w * c, [xa, ya, mom])
    mom = _blur(a, mom, taps)
    out = a.empty((h, w, c))
    a.launch(_ssim_map_kernel, h * w * c, [mom, c1, c2, out])
    return SSIMState(xa, ya, mom, a.out(out), float(data_range), a.as_numpy)


def ssim_map_backward(state: SSIMState, grad_map: Any) -> tuple[Any, Any]:
    """VJP of `ssim_map`: the tuple (dL/dx, dL/dy) for dL/dmap = grad_map, in the kind of x."""
    a = state.inputs()
    g = a.floats("grad_map", grad_map, tuple(state.x.shape))
    c1, c2 = _constants(a, state.data_range)
    h, w, c = state.x.shape
    taps = wp.array(gaussian_window(), dtype=a.scalar, device=a.device)
    partials = a.empty(state.moments.shape)
    a.launch(_ssim_partials_kernel, h * w * c, [state.moments, g, c1, c2, partials])
    partials = _blur(a, partials, taps)
    dx = a.empty(state.x.shape)
    dy = a.empty(state.x.shape)
    a.launch(_ssim_input_grads_kernel, h * w * c, [state.x, state.y, partials, dx, dy])
    return a.out(dx), a.out(dy)


def ssim(x: Any, y: Any, *, data_range: float = 1.0, device: Any = None) -> tuple[float, Any]:
    """Mean SSIM of x against y, and its gradient with respect to x (in the kind of x)."""
    state = ssim_map(x, y, data_range=data_range, device=device)
    grad = state.inputs().empty(state.x.shape)
    grad.fill_(state.x.dtype(1.0 / state.x.size))
    dx, _ = ssim_map_backward(state, grad)
    return state.mean(), dx
