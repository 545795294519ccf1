"""Volume-rendering compositing along rays, forward and hand-written backward.

Quadrature of the volume-rendering integral (Max 1995; NeRF, Mildenhall et al. 2020, eq. 3).
Ray r owns the packed samples k = o_r .. o_{r+1}-1 (``ray_offsets``), in front-to-back order,
each with density sigma_k >= 0, colour c_k (3), interval length delta_k >= 0 and depth z_k:

    alpha_k = 1 - exp(-sigma_k delta_k)
    T_k     = prod_{j<k} (1 - alpha_j) = exp(-sum_{j<k} sigma_j delta_j)      (T_0 = 1)
    w_k     = T_k alpha_k
    C       = sum_k w_k c_k + T_N b          colour over the background b
    D       = sum_k w_k z_k                  expected depth (z-depth when z_k is)
    A       = 1 - T_N = sum_k w_k            accumulated opacity

Early ray termination (instant-ngp, Mueller et al. 2022): the loop stops before sample k as
soon as T_k < t_threshold; the samples processed are counted (``n_used``) and T_N is the
transmittance after the last one. ``t_threshold = 0`` disables termination.

Backward (hand-written; Warp's tape is wrong through this loop, notes/warp.md). For output
cotangents (g_C, g_D, g_A) and f_k = g_C . c_k + g_D z_k, the scalar
L = g_C . C + g_D D + g_A A has

    dL/dc_k     = g_C w_k
    dL/dsigma_k = delta_k [ T_{k+1} f_k - S_k + T_N (g_A - g_C . b) ],   S_k = sum_{j>k} w_j f_j

(dw_j/dsigma_k is delta_k T_{k+1} for j = k and -delta_k w_j for j > k; dT_N/dsigma_k =
-delta_k T_N.) The backward kernel is a second pass over each ray that starts from the
forward's final values, as instant-ngp does: the total sum_j w_j f_j = g_C . (C - T_N b) + g_D D
comes from the forward outputs, and S_k = total - sum_{j<=k} w_j f_j is obtained by
subtracting the running prefix while T_k is rebuilt front to back from the factors
exp(-sigma_k delta_k) that the forward stored (``CompositeResult.factor``): the same products
as the forward, so T_k and w_k agree bit for bit, and no exponential is evaluated twice (that
was more than half the backward kernel's time on the CPU: 36 -> 16 ms at 65536 x 128
samples). Samples after the termination point get zero gradient; a ray with no samples returns
the background with zero gradient.

One thread per ray: every thread writes only its own ray's outputs and its own samples'
gradients, so both kernels run through kernels.launch.launch_split on the CPU.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels.launch import launch_split
from kernels.volume import _util as U
from kernels.volume.workspace import Workspace

wp.set_module_options({"enable_backward": False})

DEFAULT_T_THRESHOLD = 1e-4


@wp.kernel
def _composite_forward_kernel(
    sigma: wp.array(dtype=typing.Any),
    rgb: wp.array2d(dtype=typing.Any),
    delta: wp.array(dtype=typing.Any),
    z: wp.array(dtype=typing.Any),
    ray_offsets: wp.array(dtype=wp.int32),
    background: wp.array2d(dtype=typing.Any),
    background_per_ray: int,
    t_threshold: typing.Any,
    out_rgb: wp.array2d(dtype=typing.Any),
    out_depth: wp.array(dtype=typing.Any),
    out_opacity: wp.array(dtype=typing.Any),
    out_transmittance: wp.array(dtype=typing.Any),
    out_n_used: wp.array(dtype=wp.int32),
    out_factor: wp.array(dtype=typing.Any),
    offset: int,
):
    r = wp.tid() + offset
    one = sigma.dtype(1.0)
    thr = t_threshold
    T = one
    cr = sigma.dtype(0.0)
    cg = sigma.dtype(0.0)
    cb = sigma.dtype(0.0)
    d = sigma.dtype(0.0)
    n = int(0)
    for k in range(ray_offsets[r], ray_offsets[r + 1]):
        if T < thr:
            break
        e = wp.exp(-sigma[k] * delta[k])
        out_factor[k] = e
        w = T * (one - e)
        cr += w * rgb[k, 0]
        cg += w * rgb[k, 1]
        cb += w * rgb[k, 2]
        d += w * z[k]
        T = T * e
        n += 1
    b = r * background_per_ray
    out_rgb[r, 0] = cr + T * background[b, 0]
    out_rgb[r, 1] = cg + T * background[b, 1]
    out_rgb[r, 2] = cb + T * background[b, 2]
    out_depth[r] = d
    out_opacity[r] = one - T
    out_transmittance[r] = T
    out_n_used[r] = n


@wp.kernel
def _composite_backward_kernel(
    factor: wp.array(dtype=typing.Any),
    rgb: wp.array2d(dtype=typing.Any),
    delta: wp.array(dtype=typing.Any),
    z: wp.array(dtype=typing.Any),
    ray_offsets: wp.array(dtype=wp.int32),
    background: wp.array2d(dtype=typing.Any),
    background_per_ray: int,
    out_rgb: wp.array2d(dtype=typing.Any),
    out_depth: wp.array(dtype=typing.Any),
    out_transmittance: wp.array(dtype=typing.Any),
    out_n_used: wp.array(dtype=wp.int32),
    grad_rgb: wp.array2d(dtype=typing.Any),
    grad_depth: wp.array(dtype=typing.Any),
    grad_opacity: wp.array(dtype=typing.Any),
    grad_sigma: wp.array(dtype=typing.Any),
    grad_sample_rgb: wp.array2d(dtype=typing.Any),
    offset: int,
):
    r = wp.tid() + offset
    zero = factor.dtype(0.0)
    one = factor.dtype(1.0)
    b = r * background_per_ray
    gr = grad_rgb[r, 0]
    gg = grad_rgb[r, 1]
    gb = grad_rgb[r, 2]
    gd = grad_depth[r]
    T_final = out_transmittance[r]
    g_bg = gr * background[b, 0] + gg * background[b, 1] + gb * background[b, 2]
    total = (gr * (out_rgb[r, 0] - T_final * background[b, 0]) + gg * (out_rgb[r, 1] - T_final * background[b, 1])
             + gb * (out_rgb[r, 2] - T_final * background[b, 2]) + gd * out_depth[r])
    tail = T_final * (grad_opacity[r] - g_bg)
    start = ray_offsets[r]
    stop = start + out_n_used[r]
    T = one
    prefix = zero
    for k in range(start, stop):
        e = factor[k]  # exp(-sigma_k delta_k), stored by the forward: bit for bit its T_k and w_k
        w = T * (one - e)
        f = gr * rgb[k, 0] + gg * rgb[k, 1] + gb * rgb[k, 2] + gd * z[k]
        prefix += w * f
        T = T * e
        grad_sigma[k] = delta[k] * (T * f - (total - prefix) + tail)
        grad_sample_rgb[k, 0] = gr * w
        grad_sample_rgb[k, 1] = gg * w
        grad_sample_rgb[k, 2] = gb * w
    for k in range(stop, ray_offsets[r + 1]):
        grad_sigma[k] = zero
        grad_sample_rgb[k, 0] = zero
        grad_sample_rgb[k, 1] = zero
        grad_sample_rgb[k, 2] = zero


@dataclass
class CompositeResult:
    """Per-ray outputs of `composite_forward` (all wp.arrays on the input's device)."""

    rgb: wp.array  # (R, 3) colour over the background
    depth: wp.array  # (R,) expected depth sum_k w_k z_k
    opacity: wp.array  # (R,) 1 - T_N
    transmittance: wp.array  # (R,) T_N, transmittance after the last processed sample
    n_used: wp.array  # (R,) int32, samples processed before early termination
    # (N,) exp(-sigma_k delta_k) of every processed sample (entries past termination are not written).
    # The backward reads it rather than recomputing the exponential.
    factor: wp.array


def _result_layout(n_rays: int, n_samples: int, dtype: Any) -> dict[str, tuple[tuple[int, ...], Any]]:
    """Shape and dtype of every CompositeResult field."""
    return {"rgb": ((n_rays, 3), dtype), "depth": ((n_rays,), dtype), "opacity": ((n_rays,), dtype),
            "transmittance": ((n_rays,), dtype), "n_used": ((n_rays,), wp.int32), "factor": ((n_samples,), dtype)}


def composite_buffers(workspace: Workspace, n_rays: int, n_samples: int, dtype: Any) -> CompositeResult:
    """`out` buffers for composite_forward: views into `workspace` (names "composite.<field>")."""
    return CompositeResult(**{k: workspace.array(f"composite.{k}", shape, t)
                              for k, (shape, t) in _result_layout(n_rays, n_samples, dtype).items()})


def composite_grad_buffers(workspace: Workspace, n_samples: int, dtype: Any) -> tuple[wp.array, wp.array]:
    """`out` buffers for composite_backward: (grad_sigma (N,), grad_rgb (N, 3)) views into `workspace`."""
    return (workspace.array("composite.grad_sigma", (n_samples,), dtype),
            workspace.array("composite.grad_rgb", (n_samples, 3), dtype))


def dense_offsets(n_rays: int, n_samples: int) -> np.ndarray:
    """ray_offsets for R rays with S samples each: [0, S, 2S, ..., RS] (int32)."""
    U.check_positive_int("n_rays", n_rays)
    U.check_positive_int("n_samples", n_samples)
    return (np.arange(n_rays + 1, dtype=np.int64) * n_samples).astype(np.int32)


def _background(background: Any, n_rays: int, dtype: Any, device: wp.Device) -> tuple[wp.array, int]:
    if isinstance(background, wp.array):
        bg = background
    else:
        bg = np.asarray(background, dtype=U.NP_TYPES[dtype])
        if bg.shape == (3,):
            bg = bg[None, :]
    if tuple(bg.shape) == (1, 3):
        per_ray = 0
    elif tuple(bg.shape) == (n_rays, 3):
        per_ray = 1
    else:
        raise ValueError(f"background: expected shape (3,) or (R, 3) = ({n_rays}, 3), got {tuple(bg.shape)}")
    U.check_finite("background", bg)
    return U.to_warp("background", bg, dtype, device), per_ray


def _validate(sigma, rgb, delta, z, ray_offsets, device, values: bool = True) -> tuple[Any, int, int]:
    dtype = U.common_dtype([("sigma", sigma), ("rgb", rgb), ("delta", delta), ("z", z)])
    if len(sigma.shape) != 1:
        raise ValueError(f"sigma: expected shape (N,) (packed samples), got {tuple(sigma.shape)}")
    n = sigma.shape[0]
    U.check_shape("rgb", rgb, (n, 3))
    U.check_shape("delta", delta, (n,))
    U.check_shape("z", z, (n,))
    offsets = U.check_ray_offsets("ray_offsets", ray_offsets, None, n)
    if values:
        U.check_nonnegative("sigma", sigma)
        U.check_finite("rgb", rgb)
        U.check_nonnegative("delta", delta)
        U.check_finite("z", z)
    return dtype, n, offsets.size - 1


def composite_forward(
    sigma: U.ArrayLike,
    rgb: U.ArrayLike,
    delta: U.ArrayLike,
    z: U.ArrayLike,
    ray_offsets: U.ArrayLike,
    background: Any = (0.0, 0.0, 0.0),
    t_threshold: float = DEFAULT_T_THRESHOLD,
    device: str | wp.Device | None = None,
    out: CompositeResult | None = None,
) -> CompositeResult:
    """Composite packed samples front to back (module docstring); one thread per ray.

    sigma (N,), rgb (N, 3), delta (N,), z (N,) in float32 or float64 (one dtype), ray_offsets
    (R+1,) integer, background (3,) or (R, 3). NumPy inputs are copied to `device` (default
    the CPU); wp.arrays must already be there. `out`, if given, receives the outputs (and is
    returned): reusing buffers saves the page faults of fresh ones (kernels.volume.workspace).
    """
    device = U.default_device(device)
    dtype, n, n_rays = _validate(sigma, rgb, delta, z, ray_offsets, device)
    if not (np.isfinite(t_threshold) and 0.0 <= t_threshold < 1.0):
        raise ValueError(f"t_threshold: expected a value in [0, 1), got {t_threshold}")
    bg, per_ray = _background(background, n_rays, dtype, device)
    args = [U.to_warp("sigma", sigma, dtype, device), U.to_warp("rgb", rgb, dtype, device),
            U.to_warp("delta", delta, dtype, device), U.to_warp("z", z, dtype, device),
            U.to_int32("ray_offsets", ray_offsets, device), bg, per_ray, dtype(t_threshold)]
    layout = _result_layout(n_rays, n, dtype)
    if out is None:
        res = CompositeResult(**{k: wp.empty(shape, dtype=t, device=device) for k, (shape, t) in layout.items()})
    else:
        res = CompositeResult(**{k: U.check_out(f"out.{k}", getattr(out, k), shape, t, device)
                                 for k, (shape, t) in layout.items()})
    if n_rays:
        launch_split(_composite_forward_kernel, n_rays,
                     args + [res.rgb, res.depth, res.opacity, res.transmittance, res.n_used, res.factor],
                     device=device, min_chunk=256)
    return res


def composite_backward(
    sigma: U.ArrayLike,
    rgb: U.ArrayLike,
    delta: U.ArrayLike,
    z: U.ArrayLike,
    ray_offsets: U.ArrayLike,
    result: CompositeResult,
    grad_rgb: U.ArrayLike | None = None,
    grad_depth: U.ArrayLike | None = None,
    grad_opacity: U.ArrayLike | None = None,
    background: Any = (0.0, 0.0, 0.0),
    device: str | wp.Device | None = None,
    out: tuple[wp.array, wp.array] | None = None,
) -> tuple[wp.array, wp.array]:
    """Gradients (d sigma (N,), d rgb (N, 3)) of <grad_rgb, C> + <grad_depth, D> + <grad_opacity, A>.

    `result` is what `composite_forward` returned for the same inputs and background; missing
    cotangents count as zero. Shapes and dtypes are checked again, the sample values are not
    (composite_forward checked them, and stored in `result` what the backward needs of sigma);
    the cotangents are. `out`, if given, is the pair of buffers (N,) and (N, 3) to write the
    gradients into (and is returned); every entry is written.
    """
    device = U.default_device(device)
    dtype, n, n_rays = _validate(sigma, rgb, delta, z, ray_offsets, device, values=False)
    if result.rgb.shape != (n_rays, 3) or result.rgb.dtype != dtype or result.factor.shape != (n,) \
            or result.factor.dtype != dtype:
        raise ValueError(f"result: expected the CompositeResult of {n_rays} rays in {U.NP_TYPES[dtype].__name__}")
    bg, per_ray = _background(background, n_rays, dtype, device)
    grads = []
    for name, g, shape in (("grad_rgb", grad_rgb, (n_rays, 3)), ("grad_depth", grad_depth, (n_rays,)),
                           ("grad_opacity", grad_opacity, (n_rays,))):
        if g is None:
            grads.append(wp.zeros(shape, dtype=dtype, device=device))
            continue
        U.check_shape(name, g, shape)
        if U.float_dtype(name, g) != dtype:
            raise ValueError(f"{name}: expected dtype {U.NP_TYPES[dtype].__name__}")
        U.check_finite(name, g)
        grads.append(U.to_warp(name, g, dtype, device))
    if out is None:
        grad_sigma = wp.empty(n, dtype=dtype, device=device)
        grad_sample_rgb = wp.empty((n, 3), dtype=dtype, device=device)
    else:
        if not isinstance(out, (tuple, list)) or len(out) != 2:
            raise ValueError("out: expected a pair (grad_sigma (N,), grad_rgb (N, 3)) of wp.arrays")
        grad_sigma = U.check_out("out[0]", out[0], (n,), dtype, device)
        grad_sample_rgb = U.check_out("out[1]", out[1], (n, 3), dtype, device)
    if n_rays:
        launch_split(_composite_backward_kernel, n_rays,
                     [result.factor, U.to_warp("rgb", rgb, dtype, device),
                      U.to_warp("delta", delta, dtype, device), U.to_warp("z", z, dtype, device),
                      U.to_int32("ray_offsets", ray_offsets, device), bg, per_ray,
                      result.rgb, result.depth, result.transmittance, result.n_used,
                      *grads, grad_sigma, grad_sample_rgb],
                     device=device, min_chunk=256)
    return grad_sigma, grad_sample_rgb
