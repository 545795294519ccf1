"""Mip-Splatting's 3D filter (kernels/splat/filter3d.py) against its Dr.Jit oracle (research/oracles/mip.py):
the filtered log-scales and opacity logits and the VJPs of the log-scales and logits (sigma fixed).

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

from research.oracles.cases import Case, Rounded

# Sizes per mode: mip_splats, the Gaussians.
SIZES = {
    "full": dict(mip_splats=200_000),
    "quick": dict(mip_splats=20_000),
    "smoke": dict(mip_splats=200),
}


def case_filter(dt, S, seed):
    from kernels.splat import filter3d as kf
    from research.oracles.mip import filter_3d_oracle

    rng = Rounded(seed)
    n = S["mip_splats"]
    # Scales from below to above the filter's width, opacities from 0.05 to 0.95.
    log_scales, logits = rng.uniform(-5.0, -1.5, (n, 3)), rng.uniform(-3.0, 3.0, n)
    sigma = rng.uniform(0.005, 0.05, n)
    g_scales, g_logits = rng.normal(size=(n, 3)), rng.normal(size=n)

    def drlab(t):
        args = (log_scales.astype(t), logits.astype(t), sigma.astype(t))
        return list(kf.filter_3d(*args)), list(kf.filter_3d_backward(*args, g_scales.astype(t), g_logits.astype(t)))

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        values, vjps = filter_3d_oracle(c(log_scales), c(logits), c(sigma), c(g_scales), c(g_logits))
        return list(values), list(vjps)

    return f"{n} Gaussians", drlab, oracle


CASES = [
    Case("3D smoothing filter", case_filter),
]
