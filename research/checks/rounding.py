"""Forward error bounds of floating-point sums and products, for tests that compare results which
round differently (another BLAS kernel, another layout, another summation order).

Standard model (Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., sec. 2.2 and 3.1):
every operation rounds as fl(a op b) = (a op b)(1 + d), |d| <= u, with u the unit roundoff
(2^-24 in float32, 2^-53 in float64). A dot product of length k summed in ANY order, with or without
fused multiply-adds, then satisfies

    |fl(x . y) - x . y| <= gamma_k |x| . |y|,      gamma_k = k u / (1 - k u),

so a matrix product C = A B computed by any BLAS kernel obeys |fl(C) - C| <= gamma_k |A| |B|
elementwise, and two such products of the same matrices differ by at most twice that. Adding a
bias afterwards adds one more rounding (gamma_{k+1}, with |b| in the bound). ReLU is exact and
1-Lipschitz, so it carries an error through unchanged.
"""

from __future__ import annotations

import numpy as np


def unit_roundoff(dtype) -> float:
    """u = eps / 2 of a NumPy float dtype."""
    return float(np.finfo(dtype).eps) / 2.0


def gamma(k: int, dtype) -> float:
    """gamma_k = k u / (1 - k u) (requires k u < 1)."""
    ku = k * unit_roundoff(dtype)
    if ku >= 1.0:
        raise ValueError(f"k: gamma_k needs k u < 1, got k = {k} for {np.dtype(dtype).name}")
    return ku / (1.0 - ku)


def affine_bound(a: np.ndarray, w: np.ndarray, b: np.ndarray | None, dtype) -> np.ndarray:
    """Elementwise bound on |fl(a @ w.T + b) - (a @ w.T + b)| for a (N, k), w (m, k), b (m,), the
    product by any BLAS kernel then one rounded add: gamma_{k+1} (|a| |w|^T + |b|), in float64."""
    k = a.shape[-1] + (0 if b is None else 1)
    mag = np.abs(a.astype(np.float64)) @ np.abs(w.astype(np.float64)).T
    if b is not None:
        mag = mag + np.abs(b.astype(np.float64))
    return gamma(k, dtype) * mag


def mlp_forward_bound(x: np.ndarray, weights: list[np.ndarray], biases: list[np.ndarray], dtype) -> np.ndarray:
    """Elementwise bound on |y_computed - y_exact| of a ReLU MLP y = W_L relu(... relu(W_0 x + b_0) ...) + b_L
    computed in `dtype` (each layer one product then one add), propagated layer by layer:
    e_{l+1} = e_l |W_l|^T + gamma_{k+1} ((|a_l| + e_l) |W_l|^T + |b_l|), a_l the exact activations
    (|computed a_l| <= |a_l| + e_l, so the bound is rigorous, not first-order). The bound itself is
    evaluated in float64, whose own rounding is ~1e-16 of it."""
    a = x.astype(np.float64)
    err = np.zeros_like(a)
    last = len(weights) - 1
    for l, (w, b) in enumerate(zip(weights, biases)):
        w64 = w.astype(np.float64)
        err = err @ np.abs(w64).T + affine_bound(np.abs(a) + err, w64, b, dtype)
        z = a @ w64.T + b.astype(np.float64)
        a = z if l == last else np.maximum(z, 0.0)
    return err
