"""Stereo cost volumes against their Dr.Jit oracles (research/oracles/stereo.py): SAD (r 2) and ZNCC (r 3)
volumes; feature correlation (volume, d features); soft-argmin (disparity, d cost).

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: img, the side of the pair; disp, the disparities; feat, the channels.
SIZES = {
    "full": dict(img=256, disp=64, feat=32),
    "quick": dict(img=128, disp=32, feat=16),
    "smoke": dict(img=24, disp=8, feat=4),
}


def case_window_cost(kind):
    def case(dt, S, seed):
        from kernels import stereo as kst
        from research.oracles.stereo import window_cost_oracle

        rng = Rounded(seed)
        n, D = S["img"], S["disp"]
        left = rng.uniform(0, 1, (n, n))
        right = np.roll(left, -5, axis=1) + rng.normal(0, 0.05, (n, n))
        r = 2 if kind == "sad" else 3
        fn = kst.sad_cost if kind == "sad" else kst.zncc_cost

        def drlab(t):
            return [fn(left.astype(t), right.astype(t), 0, D, r)], []

        def oracle(t):
            return [window_cost_oracle(left.astype(dt).astype(t), right.astype(dt).astype(t), 0, D, r, kind)], []

        return f"{n}x{n}x{D}, r {r}", drlab, oracle
    return case


def case_feature_corr(dt, S, seed):
    from kernels import stereo as kst
    from research.oracles.stereo import feature_correlation_oracle

    rng = Rounded(seed)
    n, D, C = S["img"], S["disp"], S["feat"]
    fl, fr, g = rng.normal(size=(C, n, n)), rng.normal(size=(C, n, n)), rng.normal(size=(n, n, D))

    def drlab(t):
        b = kst.feature_correlation_backward(fl.astype(t), fr.astype(t), g.astype(t), -2)
        return [kst.feature_correlation(fl.astype(t), fr.astype(t), -2, D - 2)], [b["feat_left"], b["feat_right"]]

    def oracle(t):
        c, (a, b) = feature_correlation_oracle(*(v.astype(dt).astype(t) for v in (fl, fr)), -2, D - 2,
                                               g.astype(dt).astype(t))
        return [c], [a, b]

    return f"C {C}, {n}x{n}x{D}", drlab, oracle


def case_soft_argmin(dt, S, seed):
    from kernels import stereo as kst
    from research.oracles.stereo import soft_argmin_oracle

    rng = Rounded(seed)
    n, D = S["img"], S["disp"]
    cost, g = rng.uniform(0, 3, (n, n, D)), rng.normal(size=(n, n))

    def drlab(t):
        return [kst.soft_argmin(cost.astype(t), -1, 0.5)], [kst.soft_argmin_backward(cost.astype(t), -1, g.astype(t),
                                                                                       0.5)["cost"]]

    def oracle(t):
        d, gc = soft_argmin_oracle(cost.astype(dt).astype(t), -1, g.astype(dt).astype(t), 0.5)
        return [d], [gc]

    return f"{n}x{n}x{D}, T 0.5", drlab, oracle


CASES = [
    Case("SAD volume", case_window_cost("sad")),
    Case("ZNCC volume", case_window_cost("zncc")),
    Case("feature correlation", case_feature_corr),
    Case("soft-argmin", case_soft_argmin),
]
