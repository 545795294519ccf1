"""The proposal sampler's differentiable parts (kernels/volume/proposal.py) against their Dr.Jit oracles
(research/oracles/proposal.py): the interval weights and the interlevel loss, with their VJPs.

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: proposal_rays; each ray has 48 proposal and 32 main intervals (nerfstudio's 48 / 48 ... 32).
SIZES = {
    "full": dict(proposal_rays=4096),
    "quick": dict(proposal_rays=1024),
    "smoke": dict(proposal_rays=16),
}
PROPOSAL, MAIN = 48, 32


def _edges(rng: Rounded, rays: int, n: int) -> np.ndarray:
    """Sorted edges in s in [0, 1] (non-decreasing along each ray)."""
    return np.sort(rng.uniform(0.0, 1.0, (rays, n + 1)), axis=1)


def case_weights(dt, S, seed):
    from kernels.volume import proposal as kp
    from research.oracles.proposal import interval_weights_oracle

    rng = Rounded(seed)
    r = S["proposal_rays"]
    sigma, delta = rng.uniform(0.0, 6.0, (r, PROPOSAL)), rng.uniform(0.005, 0.1, (r, PROPOSAL))
    cot = rng.normal(size=(r, PROPOSAL))

    def drlab(t):
        s, d = sigma.astype(t), delta.astype(t)
        return [kp.interval_weights(s, d)], [kp.interval_weights_backward(s, d, cot.astype(t))]

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        w, g = interval_weights_oracle(c(sigma), c(delta), c(cot))
        return [w], [g]

    return f"{r} rays x {PROPOSAL}", drlab, oracle


def case_interlevel(dt, S, seed):
    from kernels.volume import proposal as kp
    from research.oracles.proposal import interlevel_loss_oracle

    rng = Rounded(seed)
    r = S["proposal_rays"]
    edges, prop_edges = _edges(rng, r, MAIN), _edges(rng, r, PROPOSAL)
    # Main weights summing to about 1, proposal weights to about 0.7: most hinges active, some not.
    weights = rng.uniform(0.0, 2.0 / MAIN, (r, MAIN))
    prop = rng.uniform(0.0, 1.4 / PROPOSAL, (r, PROPOSAL))
    cot = rng.normal(size=r)

    def drlab(t):
        args = tuple(v.astype(t) for v in (edges, weights, prop_edges, prop))
        return [kp.interlevel_loss(*args)], [kp.interlevel_loss_backward(*args, cot.astype(t))]

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        loss, g = interlevel_loss_oracle(c(edges), c(weights), c(prop_edges), c(prop), c(cot))
        return [loss], [g]

    return f"{r} rays, {MAIN} main / {PROPOSAL} proposal intervals", drlab, oracle


CASES = [
    Case("interval weights", case_weights),
    Case("interlevel loss", case_interlevel),
]
