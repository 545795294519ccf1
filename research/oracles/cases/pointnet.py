"""PointNet's max-pool and PointNet++'s grouping (kernels/pointnet.py) against their Dr.Jit oracles
(research/oracles/pointnet.py), forward and VJPs.

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: pointnet_sets, the sets of 32 rows (max-pool, 128 channels) or the centres of 32
# neighbours (grouping, in clouds of 1,024 points).
SIZES = {
    "full": dict(pointnet_sets=4096),
    "quick": dict(pointnet_sets=512),
    "smoke": dict(pointnet_sets=16),
}
ROWS, CHANNELS, CLOUD = 32, 128, 1024


def case_max_pool(dt, S, seed):
    from kernels import pointnet as kpn
    from research.oracles.pointnet import max_pool_oracle

    rng = Rounded(seed)
    g = S["pointnet_sets"]
    # Each column a shuffled ladder 0.01 k above a random offset: no two rows tie (float32 normal draws
    # would tie at the maximum somewhere among 500k columns, where the first-argmax rule and Dr.Jit's
    # maximum route the cotangent differently).
    ladder = 0.01 * np.argsort(rng.uniform(size=(g, ROWS, CHANNELS)), axis=1)
    x = (rng.normal(size=(g, 1, CHANNELS)) + ladder).astype(np.float32).astype(np.float64)
    cot = rng.normal(size=(g, CHANNELS))

    def drlab(t):
        r = kpn.max_pool(x.astype(t))
        return [r.value], [kpn.max_pool_backward(r, cot.astype(t), ROWS)["x"]]

    def oracle(t):
        y, dx = max_pool_oracle(x.astype(dt).astype(t), cot.astype(dt).astype(t))
        return [y], [dx]

    return f"{g} sets x {ROWS} rows x {CHANNELS} channels", drlab, oracle


def case_group_local(dt, S, seed):
    from kernels import pointnet as kpn
    from research.oracles.pointnet import group_local_oracle

    rng = Rounded(seed)
    s = S["pointnet_sets"]
    b = max(1, s // 256)
    s_per = s // b
    points = rng.uniform(-1.0, 1.0, (b, CLOUD, 3))
    draw = np.random.default_rng(seed + 1)
    centers = draw.integers(0, CLOUD, (b, s_per)).astype(np.int32)
    neighbors = draw.integers(0, CLOUD, (b, s_per, ROWS)).astype(np.int32)
    cot = rng.normal(size=(b, s_per, ROWS, 3))
    radius = 0.2

    def drlab(t):
        p = points.astype(t)
        return ([kpn.group_local(p, centers, neighbors, radius)],
                [kpn.group_local_backward(p, centers, neighbors, radius, cot.astype(t))["points"]])

    def oracle(t):
        u, dp = group_local_oracle(points.astype(dt).astype(t), centers, neighbors, radius, cot.astype(dt).astype(t))
        return [u], [dp]

    return f"{b} clouds x {s_per} centres x {ROWS} neighbours", drlab, oracle


CASES = [
    Case("max-pool", case_max_pool),
    Case("grouping in local coordinates", case_group_local),
]
