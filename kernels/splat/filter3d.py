"""Mip-Splatting's 3D smoothing filter: each Gaussian convolved with an isotropic 3D Gaussian, and its adjoint.

Yu et al., "Mip-Splatting: Alias-free 3D Gaussian Splatting" (CVPR 2024), section 5.1: a splat can
never be seen at more than its maximal sampling rate nu_i = max_n f_n / d_n,i (pixels per world unit
over the training cameras n that see it at depth d_n,i), so it is low-passed in 3D at that rate:

    Sigma'_i = Sigma_i + sigma_i^2 I,    sigma_i^2 = s / nu_i^2,
    o'_i = o_i sqrt(det Sigma_i / det Sigma'_i),

the factor keeping the splat's integral. With Sigma = R S^2 R^T and I = R I R^T the filtered
covariance keeps the rotation and widens every axis: s'_k = sqrt(s_k^2 + sigma^2). In the
renderer's parameters (log-scales l, opacity logit a; o = sigmoid(a)):

    l'_k = (1/2) log(exp(2 l_k) + sigma^2),
    c = prod_k exp(l_k - l'_k) = sqrt(det Sigma / det Sigma'),   q = sigmoid(a) c,
    a' = logit(q) = log q - log(1 - q).

Adjoint, with sigma held fixed (Mip-Splatting recomputes it from the cameras, without a gradient)
and A_k = exp(2 l_k) / (exp(2 l_k) + sigma^2) = dl'_k/dl_k:

    dL/dl_k = A_k dL/dl'_k + (1 - A_k) / (1 - q) dL/da',     dL/da = (1 - o) / (1 - q) dL/da',

since dq/da = o (1 - o) c, dq/dl_k = q (1 - A_k) and da'/dq = 1 / (q (1 - q)). q < o < 1, so no
division by zero. One thread per splat; generic over float32 and float64. research/splats/mip.py
computes sigma from the training cameras and applies the filter in training (kernels/reference/
splat_filter3d.py is the NumPy forward).
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels import _arrays as A

wp.set_module_options({"enable_backward": False})


@wp.func
def _filtered_log_scale(l: Any, var: Any):
    """(l', A) = ((1/2) log(exp(2 l) + sigma^2), exp(2 l) / (exp(2 l) + sigma^2))."""
    s2 = wp.exp(l + l)
    return type(l)(0.5) * wp.log(s2 + var), s2 / (s2 + var)


@wp.func
def _log_compensation(log_scales: wp.array2d(dtype=typing.Any), i: int, var: typing.Any):
    """log c = sum_k (l_k - l'_k): the log of the opacity factor sqrt(det Sigma / det Sigma')."""
    log_c = type(var)(0.0)
    for k in range(3):
        lk, _ak = _filtered_log_scale(log_scales[i, k], var)
        log_c += log_scales[i, k] - lk
    return log_c


@wp.kernel
def _filter_kernel(log_scales: wp.array2d(dtype=typing.Any), logits: wp.array(dtype=typing.Any),
                   sigma: wp.array(dtype=typing.Any), out_scales: wp.array2d(dtype=typing.Any),
                   out_logits: wp.array(dtype=typing.Any), offset: int):
    i = wp.tid() + offset
    one = type(sigma[i])(1.0)
    var = sigma[i] * sigma[i]
    for k in range(3):
        lk, _ak = _filtered_log_scale(log_scales[i, k], var)
        out_scales[i, k] = lk
    q = wp.exp(_log_compensation(log_scales, i, var)) / (one + wp.exp(-logits[i]))
    out_logits[i] = wp.log(q) - wp.log(one - q)


@wp.kernel
def _filter_backward_kernel(log_scales: wp.array2d(dtype=typing.Any), logits: wp.array(dtype=typing.Any),
                            sigma: wp.array(dtype=typing.Any), g_scales: wp.array2d(dtype=typing.Any),
                            g_logits: wp.array(dtype=typing.Any), d_scales: wp.array2d(dtype=typing.Any),
                            d_logits: wp.array(dtype=typing.Any), offset: int):
    i = wp.tid() + offset
    one = type(sigma[i])(1.0)
    var = sigma[i] * sigma[i]
    o = one / (one + wp.exp(-logits[i]))
    q = wp.exp(_log_compensation(log_scales, i, var)) * o
    ga = g_logits[i] / (one - q)
    for k in range(3):
        _lk, ak = _filtered_log_scale(log_scales[i, k], var)
        d_scales[i, k] = ak * g_scales[i, k] + (one - ak) * ga
    d_logits[i] = (one - o) * ga


A.declare_float_overloads(_filter_kernel)
A.declare_float_overloads(_filter_backward_kernel)


def _inputs(log_scales: Any, opacity_logits: Any, sigma: Any, device: Any) -> tuple[A.Inputs, list[wp.array]]:
    a = A.Inputs(device, log_scales, opacity_logits, sigma)
    ls = a.floats("log_scales", log_scales, ndim=2)
    n = int(ls.shape[0])
    A.check_shape("log_scales", log_scales, (n, 3))
    al = a.floats("opacity_logits", opacity_logits, (n,))
    sg = a.floats("sigma", sigma, (n,))
    A.check_at_least("sigma", sigma, 0.0)
    return a, [ls, al, sg]


def filter_3d(log_scales: Any, opacity_logits: Any, sigma: Any, *, device: Any = None) -> tuple[Any, Any]:
    """(l', a'): the log-scales (N, 3) and opacity logits (N,) of the splats low-passed by isotropic 3D
    Gaussians of standard deviation `sigma` (N,) >= 0 (module docstring); in the inputs' kind."""
    a, (ls, al, sg) = _inputs(log_scales, opacity_logits, sigma, device)
    n = int(ls.shape[0])
    out_s, out_l = a.empty((n, 3)), a.empty((n,))
    if n:
        a.launch(_filter_kernel, n, [ls, al, sg, out_s, out_l])
    return a.out(out_s), a.out(out_l)


def filter_3d_backward(log_scales: Any, opacity_logits: Any, sigma: Any, grad_log_scales: Any,
                       grad_opacity_logits: Any, *, device: Any = None) -> tuple[Any, Any]:
    """(dL/dl, dL/da) from dL/dl' (N, 3) and dL/da' (N,) of `filter_3d` at the same inputs, sigma fixed."""
    a, (ls, al, sg) = _inputs(log_scales, opacity_logits, sigma, device)
    n = int(ls.shape[0])
    gs = a.floats("grad_log_scales", grad_log_scales, (n, 3))
    gl = a.floats("grad_opacity_logits", grad_opacity_logits, (n,))
    d_s, d_l = a.empty((n, 3)), a.empty((n,))
    if n:
        a.launch(_filter_backward_kernel, n, [ls, al, sg, gs, gl, d_s, d_l])
    return a.out(d_s), a.out(d_l)
