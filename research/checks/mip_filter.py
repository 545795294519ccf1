"""Finite-difference check (float64) of Mip-Splatting's 3D filter backward (kernels/splat/filter3d.py).

Registered for `drlab gradcheck mip_filter`. Inputs: log-scales from very thin (sigma / s = 10) to
much wider than the filter (sigma / s = 0.01), opacity logits from -4 to 4 (o from 0.02 to 0.98, so
1 - q is not tiny), sigma > 0. sigma is held fixed (the filter's contract: it is recomputed from the
cameras without a gradient), so the check is with respect to the log-scales and the opacity logits.
"""

from __future__ import annotations

import numpy as np

from kernels.splat.filter3d import filter_3d, filter_3d_backward
from research.gradcheck import GradcheckResult, check_vjp, register_check


def check_filter(seed: int, n: int = 24) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    sigma = rng.uniform(0.01, 0.05, n)
    log_scales = np.log(sigma[:, None] * np.exp(rng.uniform(np.log(0.1), np.log(100.0), (n, 3))))
    logits = rng.uniform(-4.0, 4.0, n)

    def f(log_scales, opacity_logits):
        ls, al = filter_3d(log_scales, opacity_logits, sigma)
        return {"log_scales": ls, "opacity_logits": al}

    def vjp(inp, cot):
        d_s, d_l = filter_3d_backward(inp["log_scales"], inp["opacity_logits"], sigma, cot["log_scales"],
                                      cot["opacity_logits"])
        return {"log_scales": d_s, "opacity_logits": d_l}

    return check_vjp(f, vjp, {"log_scales": log_scales, "opacity_logits": logits}, seed=seed,
                     name=f"mip_filter.filter3d[seed={seed}]")


@register_check("mip_filter.filter3d")
def filter_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for r in check_filter(seed)]
