"""Camera gradients of the splat renderer (render_backward(want_camera=True)): float64 finite
differences (research/checks/splat.py), the se(3) convention, float32 against float64, the array
kinds, independence of the thread count, and the depth loss path."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from scipy.spatial.transform import Rotation

from kernels import splat as ks
from research.checks import splat as cs
from research.gradcheck import assert_gradcheck
from research.splats.loss import depth_loss

PARAMS = cs.PARAMS


@pytest.mark.usefixtures("warp_device")
def test_camera_gradients():
    assert_gradcheck(cs.camera_checks())


@pytest.mark.usefixtures("warp_device")
def test_depth_loss_gradients():
    assert_gradcheck(cs.depth_loss_checks())


@pytest.mark.parametrize("xi", [np.array([0.3, -0.2, 0.1, 0.4, -0.7, 0.2]), np.array([1.0, 2.0, 3.0, 0, 0, 1e-9]),
                                np.zeros(6)], ids=["generic", "tiny_rotation", "zero"])
def test_se3_exp_is_the_rigid_exponential(xi):
    """se3_exp against scipy's rotation vector and the closed form of the translation, V rho."""
    T = ks.se3_exp(xi)
    R = Rotation.from_rotvec(xi[3:]).as_matrix()
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-15)
    # V = integral_0^1 exp(s [phi]x) ds, by a fine midpoint rule.
    s = (np.arange(2000) + 0.5) / 2000
    V = np.mean([Rotation.from_rotvec(si * xi[3:]).as_matrix() for si in s], axis=0)
    np.testing.assert_allclose(T[:3, 3], V @ xi[:3], atol=1e-7)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


def test_pose_gradient_is_a_left_perturbation_of_world_to_camera():
    """dL/drho equals W sum_i dL/dmu_i (moving the camera by rho in its frame is moving every mean,
    and the view directions, by W^T rho), which ties the convention to the splats' gradients."""
    scene = cs.smooth_scene(0)
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    r = ks.render(g, scene.camera, scene.background)
    rng = np.random.default_rng(0)
    grads = ks.render_backward(g, r, rng.normal(size=r.rgb.shape), rng.normal(size=r.alpha.shape),
                               rng.normal(size=r.depth.shape), want_camera=True)
    W = scene.camera.viewmat[:3, :3]
    np.testing.assert_allclose(grads["pose"][:3], W @ grads["means"].sum(axis=0), rtol=1e-12, atol=1e-12)
    assert "pose" not in ks.render_backward(g, r, np.ones(r.rgb.shape))


def test_float32_camera_gradients_follow_float64():
    scene = cs.smooth_scene(2, near_clamp="3dgs")
    rng = np.random.default_rng(1)
    H, W = scene.camera.height, scene.camera.width
    cot = [rng.normal(size=(H, W, 3)), rng.normal(size=(H, W)), rng.normal(size=(H, W))]
    out = {}
    for dtype in (np.float32, np.float64):
        g = ks.gaussian_inputs(*(scene.params[k].astype(dtype) for k in PARAMS))
        r = ks.render(g, scene.camera, scene.background.astype(dtype))
        grads = ks.render_backward(g, r, *(c.astype(dtype) for c in cot), want_camera=True)
        assert grads["pose"].dtype == dtype and grads["intrinsics"].dtype == dtype
        out[dtype] = grads
    for key in ("pose", "intrinsics"):
        ref = out[np.float64][key]
        # float32 against float64, not a formula check (the float64 FD checks are): the pose and intrinsics
        # gradients sum thousands of float32 per-pixel terms, so agreement is to ~1e-3 relative, not 1e-6
        np.testing.assert_allclose(out[np.float32][key], ref, rtol=2e-3, atol=2e-4 * np.abs(ref).max(), err_msg=key)


def test_camera_gradients_follow_the_input_kind_and_not_the_thread_count(monkeypatch):
    rng = np.random.default_rng(11)
    scene = cs.random_scene(rng, n=60, width=96, height=80)
    cot = rng.normal(size=(80, 96, 3))
    runs = []
    for threads in ("1", "2", "3"):
        monkeypatch.setenv("DRLAB_THREADS", threads)
        g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
        runs.append(ks.render_backward(g, ks.render(g, scene.camera, scene.background), cot, want_camera=True))
    for other in runs[1:]:
        for key in ("pose", "intrinsics"):
            np.testing.assert_array_equal(other[key], runs[0][key], err_msg=key)
    g_wp = ks.gaussian_inputs(*(wp.array(scene.params[k]) for k in PARAMS))
    grads = ks.render_backward(g_wp, ks.render(g_wp, scene.camera, scene.background), cot, want_camera=True)
    assert isinstance(grads["pose"], wp.array) and grads["pose"].shape == (6,)
    np.testing.assert_array_equal(grads["pose"].numpy(), runs[0]["pose"])
    np.testing.assert_array_equal(grads["intrinsics"].numpy(), runs[0]["intrinsics"])


def test_depth_loss_values():
    depth = np.array([[2.0, 1.0], [0.0, 3.0]])
    alpha = np.array([[0.8, 0.4], [0.9, 0.6]])
    measured = np.array([[2.0, 1.0], [2.0, 0.0]])  # (1, 1) has no measurement
    mask = np.array([[True, True], [True, True]])
    # Valid: (0, 0) z_hat 2.5 (r 0.5); (1, 0) z_hat 0 (r -2); (0, 1) has alpha 0.4 <= 0.5.
    loss, g_d, g_a = depth_loss(depth, alpha, measured, mask, min_alpha=0.5, kind="l1")
    assert loss == pytest.approx((0.5 + 2.0) / 2)
    np.testing.assert_allclose(g_d, [[0.5 / 0.8, 0.0], [-0.5 / 0.9, 0.0]])
    np.testing.assert_allclose(g_a, [[-0.5 * 2.0 / 0.64, 0.0], [0.0, 0.0]])
    loss2, _, _ = depth_loss(depth, alpha, measured, mask, min_alpha=0.5, kind="l2")
    assert loss2 == pytest.approx((0.25 + 4.0) / 2)
    none, g0, _ = depth_loss(depth, alpha, measured, np.zeros((2, 2), bool))
    assert none == 0.0 and not g0.any()
