"""kernels/ba.py against its NumPy reference, finite differences (research.gradcheck and scipy), and the kind rule."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from scipy.optimize._numdiff import approx_derivative

from kernels import ba as kba
from kernels.reference import ba as ref
from research.checks import ba as cba
from research.gradcheck import assert_gradcheck


def _problem(seed=0, n_cams=3, n_points=7):
    inputs, (cam_idx, pt_idx, poses0, K) = cba.ba_problem(seed, n_cams, n_points)
    return inputs, cam_idx, pt_idx, poses0, K


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.usefixtures("warp_device")
def test_reproject_matches_reference(dtype):
    inputs, ci, pi, poses0, K = _problem(0)
    got = kba.reproject(poses0.astype(dtype), inputs["points"].astype(dtype), inputs["observations"].astype(dtype),
                        ci, pi, K)
    want_r, want_z = ref.reproject(poses0.astype(dtype).astype(np.float64), inputs["points"].astype(dtype).astype(
        np.float64), inputs["observations"].astype(dtype).astype(np.float64), ci, pi, K)
    assert isinstance(got.residuals, np.ndarray) and got.residuals.dtype == dtype
    tol = dict(rtol=1e-4, atol=1e-3) if dtype == np.float32 else dict(rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(got.residuals, want_r, **tol)
    np.testing.assert_allclose(got.depth, want_z, **tol)
    assert np.all(want_z > 1.0)  # the problem is non-degenerate: every point well in front of its camera


def test_reproject_kind_rule_and_3x4_poses():
    inputs, ci, pi, poses0, K = _problem(1)
    args = [wp.array(poses0[:, :3]), wp.array(inputs["points"]), wp.array(inputs["observations"])]
    got = kba.reproject(*args, wp.array(ci), wp.array(pi), K)
    assert isinstance(got.residuals, wp.array) and isinstance(got.jac_pose, wp.array)
    want = kba.reproject(poses0, inputs["points"], inputs["observations"], ci, pi, K)
    np.testing.assert_allclose(got.residuals.numpy(), want.residuals, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(got.jac_point.numpy(), want.jac_point, rtol=1e-13, atol=1e-12)


@pytest.mark.usefixtures("warp_device")
def test_ba_gradients():
    assert_gradcheck(cba.ba_checks())


def test_jacobian_matches_scipy_finite_differences():
    """The sparse Jacobian research.vo.bundle_adjust hands scipy equals scipy's own finite-difference one."""
    from research.vo import ba as vba

    inputs, ci, pi, poses0, K = _problem(2, n_cams=3, n_points=6)
    xi, pts, obs = inputs["xi"], inputs["points"], inputs["observations"]
    C, N, M = len(poses0), len(pts), len(obs)

    def fun(x):
        lin = vba.residuals_and_jacobian(x[:6 * C].reshape(C, 6), x[6 * C:].reshape(N, 3), obs, ci, pi, poses0, K,
                                         jacobians=False)
        return np.concatenate([lin.r.ravel(), lin.z])

    x = np.concatenate([xi.ravel(), pts.ravel()])
    lin = vba.residuals_and_jacobian(xi, pts, obs, ci, pi, poses0, K)
    J = np.zeros((3 * M, 6 * C + 3 * N))
    for k in range(M):
        J[2 * k:2 * k + 2, 6 * ci[k]:6 * ci[k] + 6] = lin.jr_pose[k]
        J[2 * k:2 * k + 2, 6 * C + 3 * pi[k]:6 * C + 3 * pi[k] + 3] = lin.jr_point[k]
        J[2 * M + k, 6 * ci[k]:6 * ci[k] + 6] = lin.jz_pose[k]
        J[2 * M + k, 6 * C + 3 * pi[k]:6 * C + 3 * pi[k] + 3] = lin.jz_point[k]
    J_fd = approx_derivative(fun, x, method="3-point")
    np.testing.assert_allclose(J, J_fd, rtol=1e-6, atol=1e-6 * np.abs(J_fd).max())


def test_split_launch_equals_one_thread(monkeypatch):
    inputs, ci, pi, poses0, K = _problem(3, n_cams=4, n_points=300)
    out = {}
    for threads in ("1", "3"):
        monkeypatch.setenv("DRLAB_THREADS", threads)
        r = kba.reproject(poses0, inputs["points"], inputs["observations"], ci, pi, K)
        out[threads] = (r.residuals, r.depth, r.jac_pose, r.jac_point, r.jac_depth)
    for a, b in zip(out["1"], out["3"]):
        np.testing.assert_array_equal(a, b)
    b = kba.reproject(poses0, inputs["points"], inputs["observations"], ci, pi, K, jacobians=False)
    assert b.jac_pose is None and np.array_equal(out["3"][0], b.residuals)


def test_bundle_adjust_sparse_jacobian_matches_scipy_finite_differences(monkeypatch):
    """The scipy.sparse Jacobian bundle_adjust hands least_squares (pixel and depth rows, fixed and free
    cameras) equals scipy's finite-difference Jacobian of the same residual function."""
    from research.vo import ba as vba

    inputs, ci, pi, poses0, K = _problem(4, n_cams=3, n_points=5)
    obs = inputs["observations"]
    depths = np.where(np.arange(len(obs)) % 3 == 0, 0.0, np.random.default_rng(0).uniform(2.0, 5.0, len(obs)))
    seen = {}

    def capture(fun, x0, jac, **kwargs):
        seen.update(fun=fun, jac=jac, x0=x0)
        raise StopIteration

    monkeypatch.setattr(vba, "least_squares", capture)
    with pytest.raises(StopIteration):
        vba.bundle_adjust(poses0, inputs["points"], obs, ci, pi, K, depths=depths, fixed=(1,))
    x = seen["x0"] + np.random.default_rng(1).normal(0.0, 0.05, seen["x0"].shape)
    J = seen["jac"](x)
    assert J.shape == (2 * len(obs) + int((depths > 0).sum()), 6 * 2 + 3 * 5)
    J_fd = approx_derivative(seen["fun"], x, method="3-point")
    np.testing.assert_allclose(J.toarray(), J_fd, rtol=1e-6, atol=1e-6 * np.abs(J_fd).max())
