"""Gradient checks of the bundle-adjustment Jacobians (kernels/ba.py chained in research/vo/ba.py), float64.

f(xi, points, observations) = (reprojection residuals, point depths Z) of T_c = exp(xi_c^) T_c0
(research.vo.ba); its VJP is J^T c with the Warp kernel's Jacobians chained with the SE(3) left Jacobian. The inputs
are random non-degenerate: poses looking at a point cloud in front of every camera (depths 2..5),
non-zero pose vectors xi (so the left Jacobian is exercised away from identity, with |phi| up to
about 0.3 rad), several observations per point and per camera, and one camera whose phi is below the
Taylor-series switch of the left Jacobian (|phi| < 0.1).
"""

from __future__ import annotations

import numpy as np

from research.gradcheck import GradcheckResult, check_vjp, register_check


def ba_problem(seed: int, n_cams: int = 3, n_points: int = 7):
    """A small random problem: (inputs for check_vjp, fixed arrays)."""
    from research.cameras import look_at

    rng = np.random.default_rng(seed)
    centre = rng.normal(0.0, 0.2, 3)
    poses0 = []
    for c in range(n_cams):
        eye = centre + rng.normal(0.0, 1.0, 3) + np.array([0.0, 0.0, -3.5])
        poses0.append(np.linalg.inv(look_at(eye, centre, np.array([0.0, -1.0, 0.0]))))
    poses0 = np.stack(poses0)
    points = centre + rng.uniform(-0.8, 0.8, (n_points, 3))
    cam_idx, pt_idx = np.meshgrid(np.arange(n_cams), np.arange(n_points), indexing="ij")
    cam_idx, pt_idx = cam_idx.ravel().astype(np.int32), pt_idx.ravel().astype(np.int32)
    xi = np.concatenate([rng.normal(0.0, 0.05, (n_cams, 3)), rng.normal(0.0, 0.15, (n_cams, 3))], axis=1)
    xi[-1, 3:] = rng.normal(0.0, 0.02, 3)  # below the left Jacobian's series switch (|phi| < 0.1)
    K = (80.0 + 20 * rng.uniform(), 75.0 + 20 * rng.uniform(), 32.0 + rng.uniform(), 30.0 + rng.uniform())
    obs = rng.uniform(0.0, 64.0, (cam_idx.size, 2))
    return {"xi": xi, "points": points, "observations": obs}, (cam_idx, pt_idx, poses0, K)


def check_ba(seed: int) -> list[GradcheckResult]:
    from research.vo.ba import residuals_and_jacobian

    inputs, (cam_idx, pt_idx, poses0, K) = ba_problem(seed)

    def f(xi, points, observations):
        lin = residuals_and_jacobian(xi, points, observations, cam_idx, pt_idx, poses0, K, jacobians=False)
        return lin.r, lin.z

    def vjp(inp, cot):
        lin = residuals_and_jacobian(inp["xi"], inp["points"], inp["observations"], cam_idx, pt_idx, poses0, K)
        c_r, c_z = cot
        gxi = np.zeros_like(inp["xi"])
        np.add.at(gxi, cam_idx, np.einsum("ka,kab->kb", c_r, lin.jr_pose) + c_z[:, None] * lin.jz_pose)
        gp = np.zeros_like(inp["points"])
        np.add.at(gp, pt_idx, np.einsum("ka,kab->kb", c_r, lin.jr_point) + c_z[:, None] * lin.jz_point)
        return {"xi": gxi, "points": gp, "observations": -c_r}

    return check_vjp(f, vjp, inputs, seed=seed, name=f"ba.reprojection[seed={seed}]")


@register_check("ba.reprojection")
def ba_checks() -> list[GradcheckResult]:
    return check_ba(0) + check_ba(1)
