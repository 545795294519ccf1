"""kernels/volume/proposal.py against its Dr.Jit oracles (research/oracles/proposal.py): the interval weights
and the interlevel loss with their VJPs, in float64 (float32 is reported by oracle_conformance)."""

from __future__ import annotations

import numpy as np
import pytest

from kernels.volume import proposal as kp
from research.oracles.proposal import interlevel_loss_oracle, interval_weights_oracle
from tests.oracles.conftest import close64


@pytest.mark.parametrize("seed, rays, n", [(0, 40, 24), (1, 3, 1)])
def test_float64_weights_and_vjp_match_the_oracle(seed, rays, n):
    rng = np.random.default_rng(seed)
    sigma, delta = rng.uniform(0.0, 8.0, (rays, n)), rng.uniform(0.001, 0.3, (rays, n))
    cot = rng.normal(size=(rays, n))
    want_w, want_g = interval_weights_oracle(sigma, delta, cot)
    close64("w", kp.interval_weights(sigma, delta), want_w)
    close64("dL/dsigma", kp.interval_weights_backward(sigma, delta, cot), want_g)


@pytest.mark.parametrize("seed, rays, m, k, scale", [(0, 30, 20, 12, 0.7), (1, 5, 9, 31, 0.9)])
def test_float64_interlevel_loss_and_vjp_match_the_oracle(seed, rays, m, k, scale):
    rng = np.random.default_rng(seed)
    edges = np.sort(rng.uniform(0.0, 1.0, (rays, m + 1)), axis=1)
    prop_edges = np.sort(rng.uniform(0.0, 1.0, (rays, k + 1)), axis=1)
    weights = rng.dirichlet(np.ones(m), rays)
    prop = rng.dirichlet(np.ones(k), rays) * scale  # below the main mass: most hinges are active
    cot = rng.normal(size=rays)
    want_loss, want_g = interlevel_loss_oracle(edges, weights, prop_edges, prop, cot)
    hinges = np.count_nonzero(want_g)
    assert 0 < hinges < want_g.size, "the inputs should leave some proposal weights without a gradient"
    close64("L_r", kp.interlevel_loss(edges, weights, prop_edges, prop), want_loss)
    close64("dL/dq", kp.interlevel_loss_backward(edges, weights, prop_edges, prop, cot), want_g)
