"""research/vo: the SE(3) left Jacobian, bundle adjustment, pose-graph optimisation and the feature helpers."""

from __future__ import annotations

import numpy as np
import pytest

from research.checks import ba as cba
from research.poses.se3 import se3_exp, se3_log
from research.vo import ba as vba
from research.vo import features as F
from research.vo.loop import Loop, optimise_pose_graph


@pytest.mark.parametrize("angle", [1.5, 0.3, 0.1005, 0.0995, 0.02, 1e-7])
def test_left_jacobian_matches_finite_differences_of_log(angle):
    rng = np.random.default_rng(int(angle * 1e4) % 1000)
    axis = rng.normal(size=3)
    xi = np.concatenate([rng.normal(size=3), angle * axis / np.linalg.norm(axis)])
    J = vba.se3_left_jacobian(xi)
    base_inv = np.linalg.inv(se3_exp(xi))
    num = np.zeros((6, 6))
    eps = 1e-6
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        num[:, i] = (se3_log(se3_exp(xi + d) @ base_inv) - se3_log(se3_exp(xi - d) @ base_inv)) / (2 * eps)
    np.testing.assert_allclose(J, num, atol=2e-8)


def _ba_scene(seed, n_points=40, noise_px=0.0):
    inputs, (_, _, poses0, K) = cba.ba_problem(seed, n_cams=4, n_points=n_points)
    pts = inputs["points"]
    C = len(poses0)
    ci, pi = np.meshgrid(np.arange(C), np.arange(n_points), indexing="ij")
    ci, pi = ci.ravel().astype(np.int32), pi.ravel().astype(np.int32)
    obs = np.stack([(K[0] * X[0] / X[2] + K[2], K[1] * X[1] / X[2] + K[3]) for X in
                    (poses0[c, :3, :3] @ pts[j] + poses0[c, :3, 3] for c, j in zip(ci, pi))])
    obs = obs + np.random.default_rng(seed).normal(0.0, noise_px, obs.shape) if noise_px else obs
    return poses0, pts, obs, ci, pi, K


def test_bundle_adjust_recovers_perturbed_poses_and_points():
    poses, pts, obs, ci, pi, K = _ba_scene(0)
    rng = np.random.default_rng(1)
    start = poses.copy()
    for c in (2, 3):  # cameras 0 and 1 fix the gauge (and the scale)
        start[c] = se3_exp(np.concatenate([rng.normal(0, 0.05, 3), rng.normal(0, 0.02, 3)])) @ poses[c]
    res = vba.bundle_adjust(start, pts + rng.normal(0, 0.02, pts.shape), obs, ci, pi, K, fixed=(0, 1),
                            loss="linear", max_nfev=50)
    assert res.rms_before > 1.0 and res.rms_after < 1e-6
    np.testing.assert_allclose(res.poses, poses, atol=1e-7)
    np.testing.assert_allclose(res.points, pts, atol=1e-7)


def test_robust_loss_resists_outliers():
    poses, pts, obs, ci, pi, K = _ba_scene(2, noise_px=0.3)
    bad = obs.copy()
    bad[::9] += 25.0  # gross outliers (wrong matches)
    rng = np.random.default_rng(3)
    start = poses.copy()
    start[3] = se3_exp(np.concatenate([rng.normal(0, 0.05, 3), rng.normal(0, 0.02, 3)])) @ poses[3]
    err = {}
    for loss in ("linear", "huber"):
        r = vba.bundle_adjust(start, pts, bad, ci, pi, K, fixed=(0, 1), loss=loss, f_scale=1.0, max_nfev=50)
        err[loss] = np.abs(r.poses[2:] - poses[2:]).max()
    assert err["huber"] < 0.5 * err["linear"]


def _circle(n=16, radius=3.0):
    from research.poses.se3 import loop_path

    return np.stack([np.linalg.inv(T) for T in loop_path(n, radius)])  # world-to-camera


def test_pose_graph_closes_a_drifted_loop():
    gt = _circle()
    n = len(gt)
    rng = np.random.default_rng(0)
    est = [gt[0]]
    for k in range(1, n):  # odometry with a bias: the relative motions are off by a small constant twist
        step = gt[k] @ np.linalg.inv(gt[k - 1])
        est.append(se3_exp(np.r_[0.01, -0.02, 0.015, 0.004, -0.003, 0.005] + rng.normal(0, 1e-4, 6)) @ step @ est[-1])
    est = np.stack(est)
    loop = Loop(0, n - 1, gt[n - 1] @ np.linalg.inv(gt[0]), matches=100, inliers=100)
    out, info = optimise_pose_graph(est, [loop])
    err_before = np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1).max()
    err_after = np.linalg.norm(out[:, :3, 3] - gt[:, :3, 3], axis=1).max()
    assert info["cost_after"] < 1e-2 * info["cost_before"]
    assert err_after < 0.5 * err_before
    np.testing.assert_allclose(out[0], est[0], atol=1e-12)  # keyframe 0 is fixed
    same, _ = optimise_pose_graph(est, [])  # without a loop the odometry edges are already satisfied
    np.testing.assert_allclose(same, est, atol=1e-9)


def test_depth_at_rejects_depth_edges_and_background():
    depth = np.full((10, 10), 2.0)
    depth[:, 6:] = 5.0  # a depth edge between columns 5 and 6
    depth[:3, :3] = 0.0  # no surface
    uv = np.array([[3.5, 6.5], [5.5, 5.5], [1.5, 1.5], [7.9, 7.2]])
    np.testing.assert_allclose(F.depth_at(depth, uv), [2.0, 0.0, 0.0, 5.0])


def test_match_is_mutual_and_guided():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (20, 32), dtype=np.uint8)
    perm = rng.permutation(20)
    b = a[perm].copy()
    m = F.match(a, b)
    assert len(m) == 20 and np.array_equal(perm[m[:, 1]], m[:, 0])
    allowed = np.zeros((20, 20), dtype=bool)
    allowed[perm[:5], np.arange(5)] = True
    m = F.match(a, b, allowed=allowed)
    assert sorted(m[:, 1].tolist()) == [0, 1, 2, 3, 4]


@pytest.fixture(scope="module")
def loop_sequence(tmp_path_factory):
    """The first 10 frames of feature_vo's smoke sequence (objects loop, 60 frames, 128 px, 4 spp)."""
    from research import datasets

    cfg = datasets.DatasetConfig("objects", views=6, res=128, spp=4, seed=0, flow=True, flow_frames=60,
                                 flow_path="loop")
    root = tmp_path_factory.mktemp("vo_data")
    seq = datasets.load_flow(datasets.ensure(cfg, datasets.cache_dir(cfg, root), show_progress=False))
    return seq.frames[:10], seq.depth[:10], seq.cameras[0].K, np.array([c.c2w for c in seq.cameras[:10]])


@pytest.mark.timeout(240)
def test_run_vo_tracks_and_records_failures(loop_sequence):
    from research.poses import se3 as P
    from research.vo.odometry import TrackingError, VOConfig, run_vo

    rgba, depth, K, gt = loop_sequence
    res = run_vo(rgba, depth, K, gt[0], VOConfig())
    assert not res.failures and len(res.keyframes) >= 4
    # measured 0.238 on a path of 3.59 (6.6%; per-frame jitter at 128 px and 4 spp, not drift): a lost
    # or wrongly scaled track is off by far more
    assert P.ate(res.c2w, gt).rmse < 0.1 * P.path_length(gt)
    np.testing.assert_allclose(res.c2w[0], gt[0], atol=1e-12)  # frame 0 fixes the world frame
    blank = rgba.copy()
    blank[5] = 0.0  # a featureless frame: a recorded failure, then tracking resumes at frame 6
    res = run_vo(blank, depth, K, gt[0], VOConfig(max_failures=3))
    assert [f["frame"] for f in res.failures] == [5]
    assert [r["frame"] for r in res.frames if r.get("failure")] == [5]
    blank[5:] = 0.0
    with pytest.raises(TrackingError, match=r"tracking lost for 3 frames in a row, frames 5\.\.7"):
        run_vo(blank, depth, K, gt[0], VOConfig(max_failures=3))


def test_depth_residuals_fix_the_scale():
    """With one fixed camera the pixel residuals leave the scale free; measured depths pin it."""
    poses, pts, obs, ci, pi, K = _ba_scene(5)
    z = np.einsum("kab,kb->ka", poses[ci, :3, :3], pts[pi])[:, 2] + poses[ci, 2, 3]
    rng = np.random.default_rng(6)
    start = poses.copy()
    for c in (1, 2, 3):
        start[c] = se3_exp(np.concatenate([rng.normal(0, 0.05, 3), rng.normal(0, 0.02, 3)])) @ poses[c]
    c0 = -poses[0, :3, :3].T @ poses[0, :3, 3]
    scaled = c0 + 1.1 * (pts - c0)  # the map 10% too large about camera 0
    res = vba.bundle_adjust(start, scaled, obs, ci, pi, K, depths=z, fixed=(0,), loss="linear", max_nfev=100)
    assert res.rms_after < 1e-6
    np.testing.assert_allclose(res.points, pts, atol=1e-6)
    np.testing.assert_allclose(res.poses, poses, atol=1e-6)
