"""The chamfer distance against its Dr.Jit oracle (research/oracles/points.py, brute force over all
pairs): value, d x, d y (kernels/points/chamfer.py).

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: points // 16 points per cloud (the oracle visits all pairs).
SIZES = {
    "full": dict(points=65536),
    "quick": dict(points=8192),
    "smoke": dict(points=200),
}


def case_chamfer(dt, S, seed):
    from kernels import points as kp
    from research.oracles.points import chamfer_oracle

    rng = Rounded(seed)
    n = max(S["points"] // 16, 16)  # the oracle visits all n x n pairs
    x, y = rng.normal(size=(n, 3)), rng.normal(0.3, 0.8, (n, 3))
    g = float(rng.normal(size=1)[0])

    def drlab(t):
        res = kp.chamfer_distance(x.astype(t), y.astype(t))
        grads = kp.chamfer_backward(x.astype(t), y.astype(t), res, g)
        return [np.array([res.value])], [grads["x"], grads["y"]]

    def oracle(t):
        value, (gx, gy) = chamfer_oracle(x.astype(dt).astype(t), y.astype(dt).astype(t), g)
        return [np.array([value])], [gx, gy]

    return f"{n} x {n} points", drlab, oracle


CASES = [
    Case("chamfer distance (both clouds' gradients)", case_chamfer),
]
