"""research/slam: tracking recovers a known pose offset, mapping densifies where the map is missing or
behind the measured surface, and a tiny sequence runs end to end (SplaTAM-style SLAM on the splat kernels).

The world is a known splat model (a textured back wall and a box in front of it), rendered by the same
kernels: its renders are the RGB-D frames, so the ground-truth poses are exact and each test is fast.
"""

from __future__ import annotations

import numpy as np
import pytest

from kernels import splat as ks
from kernels.sh import SH_C0
from research.poses import se3 as P
from research.slam import MapConfig, SlamConfig, TrackConfig, densify_mask, init_map, new_splats, run_slam, track_frame
from research.slam.system import TrackingLost
from research.splats.model import SH_COEFFS, GaussianModel

W = H = 48
K = np.array([[48.0, 0.0, 24.0], [0.0, 48.0, 24.0], [0.0, 0.0, 1.0]])


def _world() -> GaussianModel:
    """A checker-textured wall at z = 4 and a box face at z = 2.6 (camera 0 at the origin looking down +z)."""
    pts, cols = [], []
    for x in np.linspace(-2.2, 2.2, 34):
        for y in np.linspace(-2.2, 2.2, 34):
            pts.append((x, y, 4.0 + 0.15 * np.sin(2 * x)))
            c = 0.8 if (int(np.floor(x * 1.5)) + int(np.floor(y * 1.5))) % 2 else 0.2
            cols.append((c, 0.5 + 0.3 * np.sin(3 * y), 1.0 - c))
    for x in np.linspace(-0.5, 0.3, 10):
        for y in np.linspace(-0.3, 0.5, 10):
            pts.append((x, y, 2.6))
            cols.append((0.9, 0.3 + 0.5 * (x + 0.5), 0.1))
    pts, cols = np.array(pts), np.array(cols)
    n = len(pts)
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    scale = np.where(pts[:, 2] > 3.0, 0.1, 0.06)
    return GaussianModel(means=pts, log_scales=np.repeat(np.log(scale)[:, None], 3, axis=1), quats=quats,
                         opacity_logits=np.full(n, 4.0), sh_dc=((cols - 0.5) / SH_C0)[:, None, :],
                         sh_rest=np.zeros((n, SH_COEFFS - 1, 3)))


def _frame(world: GaussianModel, w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rgba (H, W, 4) premultiplied, depth (H, W), 0 where the world's silhouette is thin)."""
    r = ks.render(world.inputs(), ks.SplatCamera(w2c, K, W, H), np.zeros(3, np.float32), sh_degree=0)
    alpha, d = r.alpha.numpy(), r.depth.numpy()
    depth = np.where(alpha > 0.5, d / np.maximum(alpha, 1e-6), 0.0).astype(np.float32)
    return np.concatenate([r.rgb.numpy(), alpha[..., None]], axis=-1), depth


@pytest.fixture(scope="module")
def world() -> GaussianModel:
    return _world()


def test_tracking_recovers_a_known_pose_offset(world):
    w2c = np.eye(4)
    rgba, depth = _frame(world, w2c)
    xi = np.array([0.04, -0.03, 0.05, 0.01, -0.015, 0.012])  # 3 cm-ish and ~1.1 degrees
    start = P.perturb_w2c(w2c, xi)
    cfg = TrackConfig(iters=80, lr_trans=0.01, lr_rot=0.003)
    tr = track_frame(world, start, K, W, H, np.ascontiguousarray(rgba[..., :3]), depth, cfg)
    t0, r0 = np.linalg.norm(start[:3, 3]), P.rotation_angle_deg(start[:3, :3])
    t1, r1 = np.linalg.norm(tr.w2c[:3, 3]), P.rotation_angle_deg(tr.w2c[:3, :3])
    assert tr.loss < 0.5 * tr.losses[0]  # the pose errors below are the point; Adam at a fixed rate leaves a residual
    assert t1 < 0.2 * t0 and r1 < 0.2 * r0, (t0, t1, r0, r1)
    assert tr.pixels > 0.5 * W * H


def test_densify_marks_unmapped_and_occluding_pixels(world):
    rgba, depth = _frame(world, np.eye(4))
    rgb, alpha = np.ascontiguousarray(rgba[..., :3]), rgba[..., 3]
    cfg = MapConfig(stride=1)
    left = np.zeros((H, W), bool)
    left[:, : W // 2] = True
    half = new_splats(rgb, alpha, depth, K, np.eye(4), left, 1)  # a map of the left half only
    assert half.n == int((left & (depth > 0)).sum())
    r = ks.render(half.inputs(), ks.SplatCamera(np.eye(4), K, W, H), np.zeros(3, np.float32), sh_degree=0)
    mask = densify_mask(r.alpha.numpy(), r.depth.numpy(), depth, cfg)
    assert mask[:, W // 2 + 3:].mean() > 0.9 and mask[:, : W // 2 - 3].mean() < 0.05
    # A full map, and a frame with a new surface in front of a patch: only that patch is densified.
    full = init_map(rgb, alpha, depth, K, np.eye(4), 1)
    r = ks.render(full.inputs(), ks.SplatCamera(np.eye(4), K, W, H), np.zeros(3, np.float32), sh_degree=0)
    closer = depth.copy()
    closer[36:42, 4:10] = 1.0
    mask = densify_mask(r.alpha.numpy(), r.depth.numpy(), closer, cfg)
    assert mask[36:42, 4:10].all() and mask.sum() < 36 + 0.05 * W * H
    extra = new_splats(rgb, alpha, closer, K, np.eye(4), mask, 1)
    assert extra.n == int(mask.sum()) and np.allclose(extra.means[:, 2].min(), 1.0, atol=1e-5)


def _sequence(world, n: int, step: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    w2c = [P.perturb_w2c(np.eye(4), k * step) for k in range(n)]
    frames = [_frame(world, T) for T in w2c]
    return np.stack([f[0] for f in frames]), np.stack([f[1] for f in frames]), np.array([np.linalg.inv(T) for T in w2c])


STEP = np.array([0.03, 0.0, 0.02, 0.0, 0.0, 0.01])  # 3.6 cm (sideways and forward) and a 0.57-degree roll a frame


def test_tiny_sequence_end_to_end(world):
    rgba, depth, gt = _sequence(world, 6, STEP)
    cfg = SlamConfig(track=TrackConfig(iters=40, lr_trans=0.01, lr_rot=0.003), map=MapConfig(iters=15),
                     window=3, init_iters=60)
    res = run_slam(rgba, depth, K, gt[0], cfg)
    assert res.c2w.shape == (6, 4, 4) and not res.failures
    assert res.keyframes == [0, 2, 4, 5] and len(res.frames) == 6 and res.seconds > 0
    err = np.linalg.norm(res.c2w[:, :3, 3] - gt[:, :3, 3], axis=1)
    assert err.max() < 0.2 * np.linalg.norm(gt[-1, :3, 3] - gt[0, :3, 3]), err
    assert P.ate(res.c2w, gt).rmse < 0.01


def test_a_frame_that_does_not_fit_is_a_recorded_failure_or_an_error(world):
    rgba, depth, gt = _sequence(world, 6, STEP)
    depth[3] *= 3.0  # a depth frame that no pose of the map explains
    cfg = SlamConfig(track=TrackConfig(iters=20, lr_trans=0.01, lr_rot=0.003), map=MapConfig(iters=5),
                     window=3, init_iters=10, fail_loss_ratio=3.0)
    res = run_slam(rgba, depth, K, gt[0], cfg)
    assert [f["frame"] for f in res.failures] == [3]
    w1, w2 = np.linalg.inv(res.c2w[1]), np.linalg.inv(res.c2w[2])
    np.testing.assert_allclose(np.linalg.inv(res.c2w[3]), w2 @ np.linalg.inv(w1) @ w2, atol=1e-9)  # kept the guess
    assert res.frames[3]["keyframe"] is False
    with pytest.raises(TrackingLost, match="tracking lost at frame 3"):
        run_slam(rgba, depth, K, gt[0], SlamConfig(track=cfg.track, map=cfg.map, window=3, init_iters=10,
                                                    fail_loss_ratio=3.0, max_failures=1))


def test_loss_gradients_match_float64_finite_differences():
    """The tracking and mapping losses through the renderer's backward, splats, pose and intrinsics
    (research/checks/slam.py; all seeds run under `drlab gradcheck slam`)."""
    from research.checks.slam import check_mapping_loss, check_tracking_loss
    from research.gradcheck import assert_gradcheck

    assert_gradcheck(check_tracking_loss(0) + check_mapping_loss(1))


def test_diverging_tracking_is_never_a_silent_trajectory(world):
    """Step sizes far too large send the pose away: every frame is a recorded failure (the guess kept),
    and the run stops with TrackingLost after max_failures of them."""
    rgba, depth, gt = _sequence(world, 4, STEP)
    wild = TrackConfig(iters=8, lr_trans=3.0, lr_rot=1.0)
    cfg = SlamConfig(track=wild, map=MapConfig(iters=3), window=2, init_iters=5, max_failures=3)
    lost = r"tracking lost at frame 3: 3 failures in a row \(last: (loss rising|pose jump)"
    with pytest.raises(TrackingLost, match=lost):
        run_slam(rgba, depth, K, gt[0], cfg)
