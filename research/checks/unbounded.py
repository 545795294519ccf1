"""Finite-difference checks (float64, rtol 1e-6) of the unbounded-scene backwards: mip-NeRF 360's
contraction (kernels/volume/contract.py), the interval weights and the interlevel loss
(kernels/volume/proposal.py).

Registered for `drlab gradcheck unbounded`. Inputs are random and kept away from the kinks:
  * contraction: points inside and outside the unit ball, none within 1e-2 of its sphere (where
    the second derivative jumps), with a centre and radius other than 0 and 1;
  * interval weights: densities in [0.05, 3], interval lengths in [0.05, 0.5] (T from 1 to ~1e-3);
  * interlevel loss: with respect to the proposal weights only (the main weights are held
    constant, the paper's stop-gradient), drawn again until every main interval's excess
    w - bound is either 0 with a margin of 1e-2 or at least 1e-2 (the hinge's kink is at 0).
The inverse-CDF resampling has no gradient (nerfacc and mip-NeRF 360 treat its positions as constants).
"""

from __future__ import annotations

import numpy as np

from kernels.reference import volume_unbounded as ref
from kernels.volume.contract import contract, contract_backward
from kernels.volume.proposal import (interlevel_loss, interlevel_loss_backward, interval_weights,
                                     interval_weights_backward, resample)
from research.gradcheck import GradcheckResult, check_vjp, register_check

CENTER = (0.3, -0.2, 0.1)
RADIUS = 1.7


def contract_points(seed: int, n: int = 40) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = np.concatenate([rng.uniform(0.05, 0.99, n // 2), np.exp(rng.uniform(np.log(1.01), np.log(50.0), n - n // 2))])
    return np.asarray(CENTER) + RADIUS * r[:, None] * d


def check_contract(seed: int) -> list[GradcheckResult]:
    points = contract_points(seed)
    return check_vjp(lambda points: contract(points, CENTER, RADIUS),
                     lambda inp, cot: {"points": contract_backward(inp["points"], cot, CENTER, RADIUS)},
                     {"points": points}, seed=seed, name=f"unbounded.contract[seed={seed}]")


def check_weights(seed: int, n_rays: int = 6, k: int = 9) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    sigma = rng.uniform(0.05, 3.0, (n_rays, k))
    delta = rng.uniform(0.05, 0.5, (n_rays, k))
    return check_vjp(lambda sigma: interval_weights(sigma, delta),
                     lambda inp, cot: {"sigma": interval_weights_backward(inp["sigma"], delta, cot)},
                     {"sigma": sigma}, seed=seed, name=f"unbounded.interval_weights[seed={seed}]")


def interlevel_inputs(seed: int, n_rays: int = 5, k: int = 10, m: int = 7, margin: float = 1e-2) -> dict:
    """Proposal edges/weights and main edges/weights (resampled from the proposal) with every excess kept
    away from the hinge (module docstring)."""
    rng = np.random.default_rng(seed)
    for _ in range(1000):
        h = np.sort(rng.uniform(0.0, 1.0, (n_rays, k + 1)), axis=1)
        h[:, 0], h[:, -1] = 0.0, 1.0
        q = rng.uniform(0.0, 0.25, (n_rays, k))
        e = resample(h, q, m, jitter=True, seed=seed)
        w = rng.uniform(0.0, 0.6, (n_rays, m))
        lo, hi = e[:, :-1, None], e[:, 1:, None]
        bound = (((h[:, None, :-1] < hi) & (h[:, None, 1:] > lo)) * q[:, None, :]).sum(axis=2)
        excess = w - bound
        if np.all((excess >= margin) | (excess <= -margin)) and np.any(excess > 0):
            return {"edges": e, "weights": w, "proposal_edges": h, "proposal_weights": q}
    raise RuntimeError("interlevel_inputs: no draw kept the hinge margin")


def check_interlevel(seed: int) -> list[GradcheckResult]:
    x = interlevel_inputs(seed)
    e, w, h = x["edges"], x["weights"], x["proposal_edges"]
    return check_vjp(lambda proposal_weights: interlevel_loss(e, w, h, proposal_weights),
                     lambda inp, cot: {"proposal_weights": interlevel_loss_backward(e, w, h, inp["proposal_weights"],
                                                                                    cot)},
                     {"proposal_weights": x["proposal_weights"]}, seed=seed,
                     name=f"unbounded.interlevel[seed={seed}]")


def check_interlevel_through_weights(seed: int) -> list[GradcheckResult]:
    """The proposal's chain as training runs it: densities -> interval weights -> interlevel loss; the
    densities drawn again until every excess is 1e-2 away from the hinge."""
    x = interlevel_inputs(seed, k=8)
    e, w, h = x["edges"], x["weights"], x["proposal_edges"]
    rng = np.random.default_rng(seed + 100)
    for _ in range(1000):
        delta = rng.uniform(0.05, 0.3, x["proposal_weights"].shape)
        sigma = rng.uniform(0.1, 2.0, delta.shape)
        excess = w - _bounds(e, h, ref.interval_weights(sigma, delta))
        if np.all(np.abs(excess) >= 1e-2) and np.any(excess > 0):
            break
    else:
        raise RuntimeError("check_interlevel_through_weights: no draw kept the hinge margin")

    def f(sigma):
        return interlevel_loss(e, w, h, interval_weights(sigma, delta))

    def vjp(inp, cot):
        q = interval_weights(inp["sigma"], delta)
        return {"sigma": interval_weights_backward(inp["sigma"], delta, interlevel_loss_backward(e, w, h, q, cot))}

    return check_vjp(f, vjp, {"sigma": sigma}, seed=seed, name=f"unbounded.interlevel_sigma[seed={seed}]")


def _bounds(e: np.ndarray, h: np.ndarray, q: np.ndarray) -> np.ndarray:
    lo, hi = e[:, :-1, None], e[:, 1:, None]
    return (((h[:, None, :-1] < hi) & (h[:, None, 1:] > lo)) * q[:, None, :]).sum(axis=2)


@register_check("unbounded.contract")
def contract_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for r in check_contract(seed)]


@register_check("unbounded.interval_weights")
def weights_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for r in check_weights(seed)]


@register_check("unbounded.interlevel")
def interlevel_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for r in check_interlevel(seed) + check_interlevel_through_weights(seed)]
