"""Proposal sampling (mip-NeRF 360, nerfacc's PropNetEstimator): weights, inverse-CDF resampling, interlevel loss.

Every ray carries intervals [e_k, e_{k+1}] given by edges e (R, K+1) in the normalised ray
coordinate s (kernels.volume.contract: s-space) or in t; all three operations work on dense
(R, K) layouts, one thread per ray.

Interval weights (the compositing weights of NeRF's quadrature). For densities sigma_k and
interval lengths delta_k, tau_k = sigma_k delta_k,

    w_k = T_k (1 - exp(-tau_k)),    T_k = exp(-sum_{j<k} tau_j).

Backward for a cotangent g of w: dw_i/dtau_k = 0 for i < k, T_k exp(-tau_k) = T_{k+1} for i = k and
-w_i for i > k, so

    dL/dsigma_k = delta_k (g_k T_{k+1} - sum_{i>k} g_i w_i),

a suffix sum (one reverse pass per ray). delta_k may be large (the last interval of an unbounded
ray); an infinite delta is refused.

Inverse-CDF resampling (mip-NeRF 360's `sample_intervals`, nerfacc's `importance_sampling`). The
proposal's weights plus a padding p > 0 per interval (nerfstudio's histogram_padding, 0.01)
define a piecewise-constant density over [e_0, e_K]; its CDF F is piecewise linear with
F(e_k) = c_k = sum_{i<k} (w_i + p) / sum_i (w_i + p). The M + 1 new edges are

    e'_j = F^{-1}(u_j),   u_j = (j + xi_j) / (M + 1),   j = 0 .. M,

with xi_j ~ U[0, 1) drawn from (seed, ray) when jittered, else 1/2 (stratified: u_j < u_{j+1}, so the
edges are non-decreasing), and F^{-1}(u) = e_k + (u - c_k) / (c_{k+1} - c_k) (e_{k+1} - e_k) on the
interval with c_k <= u < c_{k+1}. There is no gradient: as in nerfacc and mip-NeRF 360 the
resampled positions are constants (stop-gradient), and the proposal network learns from the
interlevel loss alone.

Interlevel loss (mip-NeRF 360, eq. 13-14). For the main intervals [e_i, e_{i+1}] with weights w_i
(held constant: stop-gradient, as in the paper) and the proposal's intervals [h_j, h_{j+1}] with
weights q_j, the bound is the proposal weight of every interval that overlaps,

    bound_i = sum_j q_j [h_j < e_{i+1} and h_{j+1} > e_i],
    L_r = sum_i max(0, w_i - bound_i)^2 / (w_i + eps),       eps = 1e-7 (nerfstudio),

per ray; the caller averages over rays. Backward to the proposal weights, for a cotangent G_r of L_r:

    dL/dq_j = G_r sum_i [overlap(i, j)] (-2 max(0, w_i - bound_i) / (w_i + eps)),

one-sided where w_i = bound_i (the hinge), zero when the bound holds. Both edge arrays must be in
the same coordinate (s or t) and non-decreasing. kernels/reference/volume_unbounded.py holds the
NumPy forwards.
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A

wp.set_module_options({"enable_backward": False})

INTERLEVEL_EPS = 1e-7
DEFAULT_PADDING = 0.01


@wp.kernel
def _weights_kernel(sigma: wp.array2d(dtype=typing.Any), delta: wp.array2d(dtype=typing.Any),
                    out: wp.array2d(dtype=typing.Any), offset: int):
    r = wp.tid() + offset
    acc = sigma.dtype(0.0)  # sum_{j<k} tau_j
    for k in range(sigma.shape[1]):
        tau = sigma[r, k] * delta[r, k]
        out[r, k] = wp.exp(-acc) * (sigma.dtype(1.0) - wp.exp(-tau))
        acc += tau


@wp.kernel
def _weights_vjp_kernel(sigma: wp.array2d(dtype=typing.Any), delta: wp.array2d(dtype=typing.Any),
                        grad_w: wp.array2d(dtype=typing.Any), grad_sigma: wp.array2d(dtype=typing.Any),
                        offset: int):
    r = wp.tid() + offset
    n = sigma.shape[1]
    total = sigma.dtype(0.0)
    for k in range(n):
        total += sigma[r, k] * delta[r, k]
    # Backwards from the last interval: acc_after = sum_{j<=k} tau_j (so T_{k+1} = exp(-acc_after)),
    # suffix = sum_{i>k} g_i w_i.
    acc_after = total
    suffix = sigma.dtype(0.0)
    for kk in range(n):
        k = n - 1 - kk
        tau = sigma[r, k] * delta[r, k]
        t_next = wp.exp(-acc_after)
        acc_before = acc_after - tau
        grad_sigma[r, k] = delta[r, k] * (grad_w[r, k] * t_next - suffix)
        w = wp.exp(-acc_before) * (sigma.dtype(1.0) - wp.exp(-tau))
        suffix += grad_w[r, k] * w
        acc_after = acc_before


@wp.kernel
def _resample_kernel(edges: wp.array2d(dtype=typing.Any), weights: wp.array2d(dtype=typing.Any),
                     padding: typing.Any, jitter: int, seed: int, out: wp.array2d(dtype=typing.Any), offset: int):
    r = wp.tid() + offset
    n_bins = weights.shape[1]
    n_out = out.shape[1]  # M + 1 edges
    total = weights.dtype(0.0)
    for k in range(n_bins):
        total += weights[r, k] + padding
    state = wp.rand_init(seed, r)
    k = int(0)
    c_lo = weights.dtype(0.0)  # c_k
    c_hi = (weights[r, 0] + padding) / total  # c_{k+1}
    for j in range(n_out):
        xi = weights.dtype(0.5)
        if jitter != 0:
            xi = weights.dtype(wp.randf(state))
        u = (weights.dtype(j) + xi) / weights.dtype(n_out)
        while u >= c_hi and k < n_bins - 1:
            k += 1
            c_lo = c_hi
            c_hi = c_lo + (weights[r, k] + padding) / total
        f = wp.clamp((u - c_lo) / (c_hi - c_lo), weights.dtype(0.0), weights.dtype(1.0))
        out[r, j] = edges[r, k] + f * (edges[r, k + 1] - edges[r, k])


@wp.func
def _bound(i: int, r: int, e: wp.array2d(dtype=typing.Any), h: wp.array2d(dtype=typing.Any),
           q: wp.array2d(dtype=typing.Any)):
    b = q.dtype(0.0)
    for j in range(q.shape[1]):
        if h[r, j] < e[r, i + 1] and h[r, j + 1] > e[r, i]:
            b += q[r, j]
    return b


@wp.kernel
def _interlevel_kernel(e: wp.array2d(dtype=typing.Any), w: wp.array2d(dtype=typing.Any),
                       h: wp.array2d(dtype=typing.Any), q: wp.array2d(dtype=typing.Any), eps: typing.Any,
                       out: wp.array(dtype=typing.Any), offset: int):
    r = wp.tid() + offset
    loss = w.dtype(0.0)
    for i in range(w.shape[1]):
        excess = wp.max(w[r, i] - _bound(i, r, e, h, q), w.dtype(0.0))
        loss += excess * excess / (w[r, i] + eps)
    out[r] = loss


@wp.kernel
def _interlevel_vjp_kernel(e: wp.array2d(dtype=typing.Any), w: wp.array2d(dtype=typing.Any),
                           h: wp.array2d(dtype=typing.Any), q: wp.array2d(dtype=typing.Any), eps: typing.Any,
                           grad_loss: wp.array(dtype=typing.Any), grad_q: wp.array2d(dtype=typing.Any),
                           offset: int):
    r = wp.tid() + offset
    for j in range(q.shape[1]):
        grad_q[r, j] = q.dtype(0.0)
    for i in range(w.shape[1]):
        excess = wp.max(w[r, i] - _bound(i, r, e, h, q), w.dtype(0.0))
        if excess > w.dtype(0.0):
            gb = -w.dtype(2.0) * excess / (w[r, i] + eps) * grad_loss[r]
            for j in range(q.shape[1]):
                if h[r, j] < e[r, i + 1] and h[r, j + 1] > e[r, i]:
                    grad_q[r, j] = grad_q[r, j] + gb


for _k in (_weights_kernel, _weights_vjp_kernel, _resample_kernel, _interlevel_kernel, _interlevel_vjp_kernel):
    A.declare_float_overloads(_k)


def _check_sorted(name: str, x: Any) -> None:
    if A.values_checked():
        h = A.host_view(x)
        if h is not None and h.size and np.any(np.diff(h, axis=1) < 0):
            raise ValueError(f"{name}: expected non-decreasing edges along each ray")


def _weights_inputs(sigma: Any, delta: Any, device: Any) -> tuple[A.Inputs, wp.array, wp.array]:
    a = A.Inputs(device, sigma, delta)
    s = a.floats("sigma", sigma, ndim=2)
    A.check_at_least("sigma", sigma, 0.0)
    d = a.floats("delta", delta, tuple(s.shape))
    A.check_at_least("delta", delta, 0.0)
    return a, s, d


def interval_weights(sigma: Any, delta: Any, *, device: Any = None) -> Any:
    """w (R, K) of densities sigma (R, K) >= 0 on intervals of lengths delta (R, K) >= 0, finite (module
    docstring); in the kind of `sigma`."""
    a, s, d = _weights_inputs(sigma, delta, device)
    out = a.empty(tuple(s.shape))
    a.launch(_weights_kernel, s.shape[0], [s, d, out])
    return a.out(out)


def interval_weights_backward(sigma: Any, delta: Any, grad_w: Any, *, device: Any = None) -> Any:
    """dL/dsigma (R, K) from dL/dw (R, K) of `interval_weights(sigma, delta)` (delta held fixed)."""
    a, s, d = _weights_inputs(sigma, delta, device)
    g = a.floats("grad_w", grad_w, tuple(s.shape))
    out = a.empty(tuple(s.shape))
    a.launch(_weights_vjp_kernel, s.shape[0], [s, d, g, out])
    return a.out(out)


def resample(edges: Any, weights: Any, n_intervals: int, *, padding: float = DEFAULT_PADDING, jitter: bool = False,
             seed: int = 0, device: Any = None) -> Any:
    """M + 1 = n_intervals + 1 new edges (R, M + 1) per ray by inverse-CDF sampling of the padded weights
    (R, K) on `edges` (R, K + 1), non-decreasing (module docstring; no gradient); in the kind of `edges`."""
    a = A.Inputs(device, edges, weights)
    e = a.floats("edges", edges, ndim=2)
    if e.shape[1] < 2:
        raise ValueError(f"edges: expected at least 2 edges per ray, got shape {tuple(e.shape)}")
    w = a.floats("weights", weights, (e.shape[0], e.shape[1] - 1))
    A.check_at_least("weights", weights, 0.0)
    _check_sorted("edges", edges)
    m = A.check_int("n_intervals", n_intervals, minimum=1)
    padding = A.check_float("padding", padding, positive=True)
    out = a.empty((e.shape[0], m + 1))
    a.launch(_resample_kernel, e.shape[0], [e, w, a.s(padding), int(bool(jitter)), int(seed), out])
    return a.out(out)


def _interlevel_inputs(edges: Any, weights: Any, proposal_edges: Any, proposal_weights: Any, eps: float,
                       device: Any) -> tuple[A.Inputs, list]:
    a = A.Inputs(device, proposal_weights, edges, weights, proposal_edges)
    q = a.floats("proposal_weights", proposal_weights, ndim=2)
    n_rays = q.shape[0]
    h = a.floats("proposal_edges", proposal_edges, (n_rays, q.shape[1] + 1))
    e = a.floats("edges", edges, (n_rays, None))
    if e.shape[1] < 2:
        raise ValueError(f"edges: expected at least 2 edges per ray, got shape {tuple(e.shape)}")
    w = a.floats("weights", weights, (n_rays, e.shape[1] - 1))
    for name, x in (("weights", weights), ("proposal_weights", proposal_weights)):
        A.check_at_least(name, x, 0.0)
    _check_sorted("edges", edges)
    _check_sorted("proposal_edges", proposal_edges)
    return a, [e, w, h, q, a.s(A.check_float("eps", eps, positive=True))]


def interlevel_loss(edges: Any, weights: Any, proposal_edges: Any, proposal_weights: Any, *,
                    eps: float = INTERLEVEL_EPS, device: Any = None) -> Any:
    """L_r (R,): the interlevel loss of each ray (module docstring), in the kind of `proposal_weights`.

    edges (R, M + 1), weights (R, M): the main intervals; proposal_edges (R, K + 1), proposal_weights
    (R, K): the proposal's."""
    a, args = _interlevel_inputs(edges, weights, proposal_edges, proposal_weights, eps, device)
    out = a.empty(args[0].shape[0])
    a.launch(_interlevel_kernel, args[0].shape[0], [*args, out])
    return a.out(out)


def interlevel_loss_backward(edges: Any, weights: Any, proposal_edges: Any, proposal_weights: Any, grad_loss: Any,
                             *, eps: float = INTERLEVEL_EPS, device: Any = None) -> Any:
    """dL/dq (R, K) from dL/dL_r (R,) of `interlevel_loss` (the main weights held constant)."""
    a, args = _interlevel_inputs(edges, weights, proposal_edges, proposal_weights, eps, device)
    g = a.floats("grad_loss", grad_loss, (args[0].shape[0],))
    out = a.empty(tuple(args[3].shape))
    a.launch(_interlevel_vjp_kernel, args[0].shape[0], [*args, g, out])
    return a.out(out)
