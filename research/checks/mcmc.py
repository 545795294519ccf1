"""Finite-difference check (float64) of the 3DGS-MCMC regularisers' gradients (research/splats/mcmc.py).

Registered for `drlab gradcheck mcmc`. The regulariser opacity_reg mean(sigmoid(logits)) +
scale_reg mean(exp(log_scales)) is the only MCMC term with a gradient (relocation and the position
noise are applied outside the gradient, as in the paper and gsplat). Inputs: logits in [-4, 4],
log-scales in [-5, 0], non-round weights, so that neither term dominates and every derivative is far
from zero.
"""

from __future__ import annotations

import numpy as np

from research.gradcheck import GradcheckResult, check_vjp, register_check
from research.splats.mcmc import regularizer


def check_regularizer(seed: int, n: int = 20) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    logits = rng.uniform(-4.0, 4.0, n)
    log_scales = rng.uniform(-5.0, 0.0, (n, 3))
    w_o, w_s = 0.013, 0.37

    def f(opacity_logits, log_scales):
        return {"loss": np.array([regularizer(opacity_logits, log_scales, w_o, w_s)[0]])}

    def vjp(inp, cot):
        _, d_logits, d_log_scales = regularizer(inp["opacity_logits"], inp["log_scales"], w_o, w_s)
        c = cot["loss"][0]
        return {"opacity_logits": c * d_logits, "log_scales": c * d_log_scales}

    return check_vjp(f, vjp, {"opacity_logits": logits, "log_scales": log_scales}, seed=seed,
                     name=f"mcmc.regularizer[seed={seed}]")


@register_check("mcmc.regularizer")
def regularizer_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for r in check_regularizer(seed)]
