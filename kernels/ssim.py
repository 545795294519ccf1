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
(kernels.launch.launch_split). Generic over float32 and float64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels.launch import launch_split

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


@wp.kernel
def _moments_kernel(x: wp.array3d(dtype=Any), y: wp.array3d(dtype=Any), out: wp.array4d(dtype=Any), offset: int):
    i = wp.tid() + offset
    h = x.shape[0]
    w = x.shape[1]
    c = x.shape[2]
    ch = i % c
    col = (i / c) % w
    row = i / (c * w)
    if row >= h:
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
    i = wp.tid() + offset
    h = src.shape[1]
    w = src.shape[2]
    c = src.shape[3]
    ch = i % c
    col = (i / c) % w
    row = i / (c * w)
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
    i = wp.tid() + offset
    w = out.shape[1]
    c = out.shape[2]
    ch = i % c
    col = (i / c) % w
    row = i / (c * w)
    two = mom.dtype(2.0)
    mx = mom[0, row, col, ch]
    my = mom[1, row, col, ch]
    sxx = mom[2, row, col, ch] - mx * mx
    syy = mom[3, row, col, ch] - my * my
    sxy = mom[4, row, col, ch] - mx * my
    out[row, col, ch] = (two * mx * my + c1) * (two * sxy + c2) / ((mx * mx + my * my + c1) * (sxx + syy + c2))


@wp.kernel
def _ssim_partials_kernel(mom: wp.array4d(dtype=Any), g_map: wp.array3d(dtype=Any), c1: Any, c2: Any,
                          out: wp.array4d(dtype=Any), offset: int):
    # out[m] = g_map * dS/d(moment m), for m = mu_x, mu_y, e_xx, e_yy, e_xy.
    i = wp.tid() + offset
    w = g_map.shape[1]
    c = g_map.shape[2]
    ch = i % c
    col = (i / c) % w
    row = i / (c * w)
    two = mom.dtype(2.0)
    mx = mom[0, row, col, ch]
    my = mom[1, row, col, ch]
    sxx = mom[2, row, col, ch] - mx * mx
    syy = mom[3, row, col, ch] - my * my
    sxy = mom[4, row, col, ch] - mx * my
    a1 = two * mx * my + c1
    a2 = two * sxy + c2
    b1 = mx * mx + my * my + c1
    b2 = sxx + syy + c2
    gs = g_map[row, col, ch] * a1 * a2 / (b1 * b2)
    out[0, row, col, ch] = gs * (two * my / a1 - two * my / a2 - two * mx / b1 + two * mx / b2)
    out[1, row, col, ch] = gs * (two * mx / a1 - two * mx / a2 - two * my / b1 + two * my / b2)
    out[2, row, col, ch] = -gs / b2
    out[3, row, col, ch] = -gs / b2
    out[4, row, col, ch] = two * gs / a2


@wp.kernel
def _ssim_input_grads_kernel(x: wp.array3d(dtype=Any), y: wp.array3d(dtype=Any), gm: wp.array4d(dtype=Any),
                             dx: wp.array3d(dtype=Any), dy: wp.array3d(dtype=Any), offset: int):
    i = wp.tid() + offset
    w = x.shape[1]
    c = x.shape[2]
    ch = i % c
    col = (i / c) % w
    row = i / (c * w)
    two = x.dtype(2.0)
    a = x[row, col, ch]
    b = y[row, col, ch]
    dx[row, col, ch] = gm[0, row, col, ch] + two * a * gm[2, row, col, ch] + b * gm[4, row, col, ch]
    dy[row, col, ch] = gm[1, row, col, ch] + two * b * gm[3, row, col, ch] + a * gm[4, row, col, ch]


def _declare_float_overloads(kernel: Any) -> None:
    for dt in (wp.float32, wp.float64):
        types = {}
        for arg in kernel.adj.args:
            if wp.types.is_array(arg.type) and arg.type.dtype is Any:
                types[arg.label] = wp.array(dtype=dt, ndim=arg.type.ndim)
            elif arg.type is Any:
                types[arg.label] = dt
        wp.overload(kernel, types)


for _k in (_moments_kernel, _blur_kernel, _ssim_map_kernel, _ssim_partials_kernel, _ssim_input_grads_kernel):
    _declare_float_overloads(_k)


# ============================================================================ entry points


def _as_image(name: str, img: Any, device: wp.Device, like: wp.array | None = None) -> wp.array:
    if isinstance(img, wp.array):
        if img.device != device:
            raise ValueError(f"{name}: expected an array on device {device}, got {img.device}")
        arr = img.numpy()
    else:
        arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] < 1:
        raise ValueError(f"{name}: expected an image of shape (H, W, C), got {arr.shape}")
    if arr.dtype not in (np.float32, np.float64):
        raise ValueError(f"{name}: expected float32 or float64, got {arr.dtype}")
    if like is not None:
        want = np.dtype(wp.dtype_to_numpy(like.dtype))
        if tuple(arr.shape) != tuple(like.shape):
            raise ValueError(f"{name}: expected shape {tuple(like.shape)}, got {arr.shape}")
        if arr.dtype != want:
            raise ValueError(f"{name}: expected dtype {want}, got {arr.dtype}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return img if isinstance(img, wp.array) else wp.array(np.ascontiguousarray(arr), device=device)


def _launch(kernel, dim: int, inputs: list, device: wp.Device) -> None:
    if dim > 0:
        launch_split(kernel, dim, inputs, device=device)


def _blur(maps: wp.array, taps: wp.array, device: wp.Device) -> wp.array:
    tmp = wp.empty_like(maps)
    out = wp.empty_like(maps)
    per_map = maps.size // maps.shape[0]
    _launch(_blur_kernel, per_map, [maps, taps, 2, tmp], device)
    _launch(_blur_kernel, per_map, [tmp, taps, 1, out], device)
    return out


@dataclass
class SSIMState:
    x: wp.array
    y: wp.array
    moments: wp.array  # (5, H, W, C) filtered mu_x, mu_y, e_xx, e_yy, e_xy
    map: wp.array  # (H, W, C)
    data_range: float

    def mean(self) -> float:
        return float(self.map.numpy().mean(dtype=np.float64))


def _constants(data_range: float, dt: Any) -> tuple[Any, Any]:
    if not (isinstance(data_range, (int, float)) and math.isfinite(data_range) and data_range > 0):
        raise ValueError(f"data_range: expected a positive finite number, got {data_range!r}")
    return dt((K1 * data_range) ** 2), dt((K2 * data_range) ** 2)


def ssim_map(x: Any, y: Any, *, data_range: float = 1.0, device: str | wp.Device = "cpu") -> SSIMState:
    """Per-pixel SSIM of images x and y (H, W, C), same dtype; see the module docstring."""
    device = wp.get_device(device)
    xa = _as_image("x", x, device)
    ya = _as_image("y", y, device, like=xa)
    c1, c2 = _constants(data_range, xa.dtype)
    h, w, c = xa.shape
    if min(h, w) < 1:
        raise ValueError(f"x: expected a non-empty image, got shape {xa.shape}")
    taps = wp.array(gaussian_window(), dtype=xa.dtype, device=device)
    mom = wp.empty((_MOMENTS, h, w, c), dtype=xa.dtype, device=device)
    _launch(_moments_kernel, h * w * c, [xa, ya, mom], device)
    mom = _blur(mom, taps, device)
    out = wp.empty((h, w, c), dtype=xa.dtype, device=device)
    _launch(_ssim_map_kernel, h * w * c, [mom, c1, c2, out], device)
    return SSIMState(xa, ya, mom, out, float(data_range))


def ssim_map_backward(state: SSIMState, grad_map: Any) -> tuple[wp.array, wp.array]:
    """VJP of `ssim_map`: (dL/dx, dL/dy) for dL/dmap = grad_map."""
    device = state.x.device
    g = _as_image("grad_map", grad_map, device, like=state.map)
    c1, c2 = _constants(state.data_range, state.x.dtype)
    h, w, c = state.x.shape
    taps = wp.array(gaussian_window(), dtype=state.x.dtype, device=device)
    partials = wp.empty_like(state.moments)
    _launch(_ssim_partials_kernel, h * w * c, [state.moments, g, c1, c2, partials], device)
    partials = _blur(partials, taps, device)
    dx = wp.empty_like(state.x)
    dy = wp.empty_like(state.x)
    _launch(_ssim_input_grads_kernel, h * w * c, [state.x, state.y, partials, dx, dy], device)
    return dx, dy


def ssim(x: Any, y: Any, *, data_range: float = 1.0, device: str | wp.Device = "cpu") -> tuple[float, wp.array]:
    """Mean SSIM of x against y, and its gradient with respect to x."""
    state = ssim_map(x, y, data_range=data_range, device=device)
    n = state.map.size
    grad = np.full(state.map.shape, 1.0 / n, dtype=wp.dtype_to_numpy(state.map.dtype))
    dx, _ = ssim_map_backward(state, grad)
    return state.mean(), dx
