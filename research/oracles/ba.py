"""Dr.Jit oracle for bundle adjustment's reprojection (kernels/ba.py): residuals, depths and the Jacobians.

Written from the pinhole model of kernels/ba.py's docstring: for observation k of point p in camera
[R | t] with intrinsics (fx, fy, cx, cy) and measured pixel (u, v),

    X = exp(xi^) (R p + t),   r = (fx X_x / X_z + cx - u,  fy X_y / X_z + cy - v),   Z = X_z,

with the left se(3) perturbation xi = (rho, phi) of world-to-camera taken to first order at xi = 0,
exp(xi^) X = X + rho + phi x X (its derivative there is exp's). drlab writes the Jacobians out by hand;
here each observation has its own leaves xi (6) and p (3), and one Dr.Jit reverse pass per output
(r_u, r_v, Z) gives that output's row of d/dxi and d/dp for every observation at once.
"""

from __future__ import annotations

import numpy as np

from research.oracles import backend, check_array


def reproject_oracle(poses: np.ndarray, points: np.ndarray, observations: np.ndarray, cam_idx: np.ndarray,
                     pt_idx: np.ndarray, intrinsics) -> dict[str, np.ndarray]:
    """{"residuals" (M, 2), "depth" (M,), "jac_pose" (M, 2, 6), "jac_point" (M, 2, 3), "jac_depth" (M, 9)}
    in points' dtype (kernels.ba.Reprojection's fields)."""
    check_array("poses", poses, (None, None, 4))
    if poses.shape[1] not in (3, 4):
        raise ValueError(f"poses: expected shape (C, 3, 4) or (C, 4, 4), got {poses.shape}")
    check_array("points", points, (None, 3))
    check_array("observations", observations, (None, 2))
    m = observations.shape[0]
    cam_idx, pt_idx = np.asarray(cam_idx), np.asarray(pt_idx)
    if cam_idx.shape != (m,) or pt_idx.shape != (m,):
        raise ValueError(f"cam_idx, pt_idx: expected shape ({m},) each, got {cam_idx.shape} and {pt_idx.shape}")
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    if not (fx > 0 and fy > 0):
        raise ValueError(f"intrinsics: expected fx, fy > 0, got {fx}, {fy}")
    be = backend(points.dtype)
    dr = be.dr
    R, t = poses[cam_idx, :3, :3], poses[cam_idx, :3, 3]  # per observation
    p_obs = points[pt_idx]

    def outputs(xi, p):
        """(r_u, r_v, Z) of every observation as Dr.Jit arrays."""
        col = lambda a, j: be.const(np.ascontiguousarray(a[..., j]))  # noqa: E731
        pj = [dr.gather(be.Float, p, be.arange(m) * 3 + j) for j in range(3)]
        x = [sum(col(R[:, i], j) * pj[j] for j in range(3)) + col(t, i) for i in range(3)]
        rho = [dr.gather(be.Float, xi, be.arange(m) * 6 + j) for j in range(3)]
        phi = [dr.gather(be.Float, xi, be.arange(m) * 6 + 3 + j) for j in range(3)]
        cross = [phi[1] * x[2] - phi[2] * x[1], phi[2] * x[0] - phi[0] * x[2], phi[0] * x[1] - phi[1] * x[0]]
        X = [x[i] + rho[i] + cross[i] for i in range(3)]
        return (fx * X[0] / X[2] + cx - col(observations, 0), fy * X[1] / X[2] + cy - col(observations, 1), X[2])

    values, rows_pose, rows_point = [], [], []
    for which in range(3):
        xi, p = be.leaf(np.zeros((m, 6))), be.leaf(p_obs)
        out = outputs(xi, p)[which]
        dr.eval(out)
        dr.backward(dr.sum(out))
        values.append(be.numpy(out, (m,)))
        rows_pose.append(be.grad(xi, (m, 6)))
        rows_point.append(be.grad(p, (m, 3)))
    return {"residuals": np.stack(values[:2], axis=1), "depth": values[2],
            "jac_pose": np.stack(rows_pose[:2], axis=1), "jac_point": np.stack(rows_point[:2], axis=1),
            "jac_depth": np.concatenate([rows_pose[2], rows_point[2]], axis=1)}
