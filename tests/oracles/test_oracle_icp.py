"""kernels/icp.py against its Dr.Jit oracle (research/oracles/icp.py): residual rows, the hand-written pose
Jacobians and robust weights against Dr.Jit's reverse mode, and the normal equations against explicit sums
and against the AD gradient of the robust cost, in float64 (float32 is reported by oracle_conformance)."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import icp
from research.oracles.icp import icp_oracle
from tests.oracles.conftest import close64

SCALE = {"none": 1.0, "huber": 0.3, "gm": 0.05}


def _correspondences(seed: int, n: int, plane: bool):
    """Source of spread 2, targets 0.1 away, every fifth an outlier about 2 away (past Huber's c = 0.3)."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3)) * 2.0
    offset = rng.normal(size=(n, 3)) * 0.1
    offset[::5] = rng.normal(size=offset[::5].shape) * 2.0
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return p, p + offset, nrm if plane else None


@pytest.mark.parametrize("robust", ["none", "huber", "gm"])
@pytest.mark.parametrize("plane", [False, True], ids=["point", "plane"])
@pytest.mark.parametrize("seed, n", [(0, 400), (1, 1)])
def test_float64_rows_weights_and_normal_equations_match_the_oracle(seed, n, plane, robust):
    source, target, normals = _correspondences(seed, n, plane)
    scale = SCALE[robust]
    got = icp.icp_residuals(source, target, normals, robust=robust, scale=scale)
    ne = icp.normal_equations(source, target, normals, robust=robust, scale=scale, block=64)
    want = icp_oracle(source, target, normals, robust=robust, scale=scale)
    if robust == "huber" and n > 1:  # both of Huber's branches are exercised
        assert 0 < np.sum(want["weights"] < 1.0) < n
    for name in ("residuals", "jacobians", "weights", "rho"):
        close64(name, getattr(got, name), want[name])
    close64("H", ne.H, want["H"])
    close64("g", ne.g, want["g"])
    close64("cost", ne.cost, want["cost"])
    close64("g vs d cost / d xi", ne.g, want["grad_cost"])
