"""Dr.Jit oracles for the proposal sampler's differentiable parts (kernels/volume/proposal.py).

Interval weights, written from NeRF's quadrature as a product of survivals rather than drlab's
running sum of optical depths: for densities sigma_k and lengths delta_k of a ray's intervals,

    alpha_k = 1 - exp(-sigma_k delta_k),   T_k = prod_{j<k} (1 - alpha_j),   w_k = T_k alpha_k.

Interlevel loss (mip-NeRF 360, eq. 13-14), written with an explicit overlap matrix: for main
intervals [e_i, e_{i+1}] with weights w_i (constants) and proposal intervals [h_j, h_{j+1}] with
weights q_j, O_ij = [h_j < e_{i+1} and h_{j+1} > e_i],

    bound_i = sum_j O_ij q_j,   L_r = sum_i max(0, w_i - bound_i)^2 / (w_i + eps).

The VJPs are Dr.Jit's reverse-mode derivatives of <cotangent, output> (sigma's, with delta held
fixed; the proposal weights', with the main weights and all edges held fixed).
"""

from __future__ import annotations

import numpy as np

from research.oracles import backend, check_array


def interval_weights_oracle(sigma: np.ndarray, delta: np.ndarray, grad_w: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
    """(w (R, K), dL/dsigma (R, K)) for L = sum(grad_w * w), in sigma's dtype."""
    check_array("sigma", sigma, (None, None))
    check_array("delta", delta, sigma.shape)
    check_array("grad_w", grad_w, sigma.shape)
    for name, x in (("sigma", sigma), ("delta", delta)):
        if np.any(x < 0):
            raise ValueError(f"{name}: expected values >= 0")
    be = backend(sigma.dtype)
    dr = be.dr
    n_rays, n = sigma.shape
    S = be.leaf(sigma)
    rays = be.arange(n_rays)
    survive = be.Float(1.0)
    weights = []
    for k in range(n):
        alpha = 1.0 - dr.exp(-dr.gather(be.Float, S, rays * n + k) * be.const(np.ascontiguousarray(delta[:, k])))
        weights.append(survive * alpha)
        survive = survive * (1.0 - alpha)
    dr.eval(*weights)
    dr.backward(be.dot(weights, [np.ascontiguousarray(grad_w[:, k]) for k in range(n)]))
    return np.stack([be.numpy(v, (n_rays,)) for v in weights], axis=1), be.grad(S, sigma.shape)


def interlevel_loss_oracle(edges: np.ndarray, weights: np.ndarray, proposal_edges: np.ndarray,
                           proposal_weights: np.ndarray, grad_loss: np.ndarray, eps: float = 1e-7
                           ) -> tuple[np.ndarray, np.ndarray]:
    """(L_r (R,), dL/dq (R, K)) for L = sum(grad_loss * L_r), in proposal_weights' dtype."""
    check_array("proposal_weights", proposal_weights, (None, None))
    n_rays, n_prop = proposal_weights.shape
    check_array("proposal_edges", proposal_edges, (n_rays, n_prop + 1))
    check_array("edges", edges, (n_rays, None))
    check_array("weights", weights, (n_rays, edges.shape[1] - 1))
    check_array("grad_loss", grad_loss, (n_rays,))
    be = backend(proposal_weights.dtype)
    dr = be.dr
    Q = be.leaf(proposal_weights)
    rays = be.arange(n_rays)
    q = [dr.gather(be.Float, Q, rays * n_prop + j) for j in range(n_prop)]
    loss = be.Float(0.0)
    for i in range(weights.shape[1]):
        overlap = (proposal_edges[:, :-1] < edges[:, i + 1:i + 2]) & (proposal_edges[:, 1:] > edges[:, i:i + 1])
        bound = be.Float(0.0)
        for j in range(n_prop):
            bound = bound + be.const(overlap[:, j].astype(proposal_weights.dtype)) * q[j]
        w = be.const(np.ascontiguousarray(weights[:, i]))
        loss = loss + dr.square(dr.maximum(w - bound, 0.0)) / (w + eps)
        dr.eval(loss)
    dr.backward(be.dot([loss], [grad_loss]))
    return be.numpy(loss, (n_rays,)), be.grad(Q, proposal_weights.shape)
