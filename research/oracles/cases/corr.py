"""RAFT correlation lookups against their Dr.Jit oracle (research/oracles/corr.py): dense (volume,
pyramid, lookup) and on-the-fly paths (lookup, d f1, d f2, d coords).

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: corr = (channels, height, width, levels, radius).
SIZES = {
    "full": dict(corr=(64, 46, 62, 4, 4)),
    "quick": dict(corr=(32, 23, 31, 3, 3)),
    "smoke": dict(corr=(4, 8, 10, 2, 1)),
}


def case_corr(path):
    def case(dt, S, seed):
        from kernels import corr
        from research.oracles.corr import lookup_oracle

        C, H, W, L, r = S["corr"]
        rng = Rounded(seed)
        f1, f2 = rng.normal(size=(C, H, W)), rng.normal(size=(C, H, W))
        coords = np.stack([rng.uniform(-4, W + 4, (H, W)), rng.uniform(-4, H + 4, (H, W))])
        g = rng.normal(size=(L * (2 * r + 1) ** 2, H, W))

        def drlab(t):
            a, b, c, gg = (v.astype(t) for v in (f1, f2, coords, g))
            if path == "dense":
                pyr = corr.correlation_pyramid(corr.correlation_volume(a, b), L)
                out = corr.lookup(pyr, c, r)
                lb = corr.lookup_backward(pyr, c, r, gg)
                fg = corr.correlation_volume_backward(a, b, next(iter(corr.correlation_pyramid_backward(
                    lb["pyramid"]).values())))
                return [out], [fg["f1"], fg["f2"], lb["coords"]]
            fp = corr.pool_features(b, L)
            out = corr.lookup_onthefly(a, fp, c, r)
            bk = corr.lookup_onthefly_backward(a, fp, c, r, gg)
            f2g = next(iter(corr.pool_features_backward(bk["f2_pyramid"]).values()))
            return [out], [bk["f1"], f2g, bk["coords"]]

        def oracle(t):
            out, gr = lookup_oracle(*(v.astype(dt).astype(t) for v in (f1, f2, coords)), L, r, g.astype(dt).astype(t))
            return [out], [gr["f1"], gr["f2"], gr["coords"]]

        return f"{H}x{W}, C {C}, {L} levels, r {r}", drlab, oracle
    return case


CASES = [
    Case("RAFT lookup, dense", case_corr("dense")),
    Case("RAFT lookup, on the fly", case_corr("onthefly")),
]
