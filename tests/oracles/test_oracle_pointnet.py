"""kernels/pointnet.py against its Dr.Jit oracles (research/oracles/pointnet.py): the max-pool and the grouping
in local coordinates, values and VJPs, in float64 (float32 is reported by oracle_conformance)."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import pointnet as kpn
from research.oracles.pointnet import group_local_oracle, max_pool_oracle
from tests.oracles.conftest import close64


@pytest.mark.parametrize("seed, shape", [(0, (6, 9, 11)), (1, (1, 1, 4))])
def test_float64_max_pool_matches_the_oracle(seed, shape):
    rng = np.random.default_rng(seed)
    x, cot = rng.normal(size=shape), rng.normal(size=(shape[0], shape[2]))
    res = kpn.max_pool(x)
    want_y, want_dx = max_pool_oracle(x, cot)
    close64("y", res.value, want_y)
    close64("dL/dx", kpn.max_pool_backward(res, cot, shape[1])["x"], want_dx)


@pytest.mark.parametrize("seed, b, n, s, k", [(0, 2, 50, 7, 6), (1, 1, 4, 3, 5)])
def test_float64_group_local_matches_the_oracle(seed, b, n, s, k):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(b, n, 3))
    centers = rng.integers(0, n, (b, s)).astype(np.int32)
    neighbors = rng.integers(0, n, (b, s, k)).astype(np.int32)  # repeats included: the scatter sums them
    cot = rng.normal(size=(b, s, k, 3))
    want_u, want_dp = group_local_oracle(points, centers, neighbors, 0.35, cot)
    close64("u", kpn.group_local(points, centers, neighbors, 0.35), want_u)
    close64("dL/dpoints", kpn.group_local_backward(points, centers, neighbors, 0.35, cot)["points"], want_dp)
