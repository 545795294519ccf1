"""NumPy references of the unbounded-scene kernels (kernels/volume/contract.py, kernels/volume/proposal.py
state the maths): the contraction, the s-space spacing, interval weights, inverse-CDF resampling and the
interlevel loss. Plain float64 NumPy, written from the equations (vectorised, searchsorted and
cumulative sums where the kernels loop), not from the kernels.
"""

from __future__ import annotations

import numpy as np


def contract(points: np.ndarray, center=(0.0, 0.0, 0.0), radius: float = 1.0) -> np.ndarray:
    x = (np.asarray(points, np.float64) - np.asarray(center, np.float64)) / radius
    r = np.linalg.norm(x, axis=-1, keepdims=True)
    safe = np.maximum(r, 1.0)
    return np.where(r <= 1.0, x, (2.0 - 1.0 / safe) * x / safe)


def s_to_t(s: np.ndarray, near: float, far: float, tau: float = 1.0) -> np.ndarray:
    def g(t: float) -> float:
        return t / tau if t <= tau else 2.0 - tau / t

    u = np.asarray(s, np.float64) * g(far) + (1.0 - np.asarray(s, np.float64)) * g(near)
    with np.errstate(divide="ignore"):
        return np.where(u <= 1.0, tau * u, tau / np.maximum(2.0 - u, 0.0))


def interval_weights(sigma: np.ndarray, delta: np.ndarray) -> np.ndarray:
    tau = np.asarray(sigma, np.float64) * np.asarray(delta, np.float64)
    before = np.concatenate([np.zeros_like(tau[:, :1]), np.cumsum(tau, axis=1)[:, :-1]], axis=1)
    return np.exp(-before) * (1.0 - np.exp(-tau))


def resample(edges: np.ndarray, weights: np.ndarray, n_intervals: int, padding: float = 0.01,
             xi: np.ndarray | None = None) -> np.ndarray:
    """Edges (R, M + 1) at u_j = (j + xi_j) / (M + 1); xi (R, M + 1) defaults to 1/2 (no jitter)."""
    e = np.asarray(edges, np.float64)
    w = np.asarray(weights, np.float64) + padding
    cdf = np.concatenate([np.zeros((w.shape[0], 1)), np.cumsum(w, axis=1) / w.sum(axis=1, keepdims=True)], axis=1)
    m1 = n_intervals + 1
    xi = np.full((e.shape[0], m1), 0.5) if xi is None else np.asarray(xi, np.float64)
    u = (np.arange(m1) + xi) / m1
    out = np.empty((e.shape[0], m1))
    for r in range(e.shape[0]):
        out[r] = np.interp(u[r], cdf[r], e[r])  # F^{-1}: the piecewise-linear CDF inverted
    return out


def interlevel_loss(edges: np.ndarray, weights: np.ndarray, proposal_edges: np.ndarray,
                    proposal_weights: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    e, w = np.asarray(edges, np.float64), np.asarray(weights, np.float64)
    h, q = np.asarray(proposal_edges, np.float64), np.asarray(proposal_weights, np.float64)
    lo, hi = e[:, :-1, None], e[:, 1:, None]  # (R, M, 1)
    overlap = (h[:, None, :-1] < hi) & (h[:, None, 1:] > lo)  # (R, M, K)
    bound = (overlap * q[:, None, :]).sum(axis=2)
    return (np.maximum(w - bound, 0.0) ** 2 / (w + eps)).sum(axis=1)
