"""kernels/ba.py against its Dr.Jit oracle (research/oracles/ba.py): residuals, depths and the hand-written
pose, point and depth Jacobians against Dr.Jit's reverse mode, in float64 (float32 is reported by
oracle_conformance)."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import ba
from research.oracles.ba import reproject_oracle
from research.poses.se3 import se3_exp
from tests.oracles.conftest import close64


@pytest.mark.parametrize("seed, cameras, points, m, rows", [(0, 5, 40, 300, 4), (1, 1, 3, 4, 3)])
def test_float64_reprojection_and_jacobians_match_the_oracle(seed, cameras, points, m, rows):
    rng = np.random.default_rng(seed)
    poses = np.stack([se3_exp(rng.normal(0.0, 0.4, 6)) for _ in range(cameras)])[:, :rows]
    poses[:, 2, 3] += 5.0
    pts = rng.normal(size=(points, 3))
    cam_idx, pt_idx = rng.integers(0, cameras, m).astype(np.int32), rng.integers(0, points, m).astype(np.int32)
    obs = rng.uniform(0.0, 96.0, (m, 2))
    intr = (80.0, 83.0, 47.5, 40.5)
    got = ba.reproject(poses, pts, obs, cam_idx, pt_idx, intr)
    want = reproject_oracle(poses, pts, obs, cam_idx, pt_idx, intr)
    for name in ("residuals", "depth", "jac_pose", "jac_point", "jac_depth"):
        close64(name, getattr(got, name), want[name])
