"""Bundle adjustment's reprojection (kernels/ba.py) against its Dr.Jit oracle (research/oracles/ba.py): the
residuals and depths (forward) and the pose, point and depth Jacobians (in the VJP columns: they are the
derivatives drlab writes by hand, here against Dr.Jit's reverse mode).

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: ba_observations, of 2,000 points in 20 cameras.
SIZES = {
    "full": dict(ba_observations=200_000),
    "quick": dict(ba_observations=20_000),
    "smoke": dict(ba_observations=200),
}
CAMERAS, POINTS = 20, 2000


def case_reproject(dt, S, seed):
    from kernels import ba
    from research.oracles.ba import reproject_oracle
    from research.poses.se3 import se3_exp

    rng = Rounded(seed)
    m = S["ba_observations"]
    poses = np.stack([se3_exp(rng.normal(0.0, 0.3, 6)) for _ in range(CAMERAS)])
    poses[:, 2, 3] += 6.0  # the points, near the origin, in front of every camera
    poses = poses.astype(np.float32).astype(np.float64)
    points = rng.normal(size=(POINTS, 3))
    draw = np.random.default_rng(seed + 1)
    cam_idx = draw.integers(0, CAMERAS, m).astype(np.int32)
    pt_idx = draw.integers(0, POINTS, m).astype(np.int32)
    obs = rng.uniform(0.0, 640.0, (m, 2))
    intr = (500.0, 510.0, 320.5, 239.5)
    jac = ("jac_pose", "jac_point", "jac_depth")

    def drlab(t):
        r = ba.reproject(poses.astype(t), points.astype(t), obs.astype(t), cam_idx, pt_idx, intr)
        return [r.residuals, r.depth], [getattr(r, k) for k in jac]

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        o = reproject_oracle(c(poses), c(points), c(obs), cam_idx, pt_idx, intr)
        return [o["residuals"], o["depth"]], [o[k] for k in jac]

    return f"{m} observations, {CAMERAS} cameras", drlab, oracle


CASES = [
    Case("reprojection and Jacobians", case_reproject),
]
