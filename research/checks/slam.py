"""Float64 finite-difference checks of the SLAM losses' gradients (research/slam), `drlab gradcheck slam`.

The tracking loss (research/slam/tracking.py: depth L1 on the expected depth plus colour L1 over the
rendered silhouette) and the mapping loss (research/slam/mapping.py: colour L1 over every pixel plus
depth L1 over measured pixels) hand their image cotangents to the splat renderer's backward; these
checks differentiate each whole loss, as a function of the splats, the pose twist xi (left
perturbation of world-to-camera, at xi = 0) and the intrinsics, against central differences. The
scenes are research/checks/splat.py's smooth scenes (every pixel clear of the renderer's
discontinuities); the targets are the scene's own render plus noise, with every colour and depth
residual at least 1e-4 from the L1 kinks and the silhouette threshold clear of every alpha.
"""

from __future__ import annotations

import numpy as np

from kernels import splat as ks
from research.checks.splat import PARAMS, _camera_inputs, camera_loss_fn, depth_target, smooth_scene
from research.gradcheck import GradcheckResult, check_vjp, register_check

MODE = "3dgs"


def _noisy(x: np.ndarray, rng: np.random.Generator, sd: float) -> np.ndarray:
    """x plus normal noise, redrawn until every residual is at least 1e-4 from zero (the L1 kink)."""
    while True:
        y = x + rng.normal(0.0, sd, x.shape)
        if np.min(np.abs(y - x)) >= 1e-4:
            return y


# Loss-of-a-mean checks: one scalar whose splat gradients are as small as 1e-7, so the splats take
# the step 1e-5 as research/checks/splat.py's depth-loss check does (same reason, written there);
# the pose and intrinsics keep the default step.
EPS = {k: 1e-5 for k in PARAMS}


def check_tracking_loss(seed: int) -> list[GradcheckResult]:
    from research.slam.tracking import TrackConfig, tracking_loss

    scene = smooth_scene(seed, mode=MODE, near_clamp=MODE)
    measured, _, min_alpha = depth_target(scene, MODE, seed)  # min_alpha: clear of every alpha by >= 1e-4
    r = ks.render(ks.gaussian_inputs(*(scene.params[k] for k in PARAMS)), scene.camera, scene.background, mode=MODE)
    target = _noisy(r.rgb, np.random.default_rng([seed, 7]), 0.05)
    cfg = TrackConfig(min_silhouette=min_alpha, depth_weight=1.0, color_weight=0.5)

    def loss(res):
        value, g_rgb, g_alpha, g_depth, _ = tracking_loss(res, target, measured, cfg)
        return value, g_rgb, g_alpha, g_depth

    f, vjp = camera_loss_fn(scene, MODE, loss)
    return check_vjp(f, vjp, _camera_inputs(scene), seed=seed, eps=EPS, name=f"slam.tracking_loss[seed={seed}]")


def check_mapping_loss(seed: int) -> list[GradcheckResult]:
    from research.slam.mapping import Keyframe, MapConfig, mapping_loss

    scene = smooth_scene(seed, mode=MODE, near_clamp=MODE)
    # The smooth scene's alphas cross the default depth threshold 0.01, so the check moves it to the
    # value depth_target found clear of every alpha (the loss is the same function of it).
    measured, _, min_alpha = depth_target(scene, MODE, seed)
    r = ks.render(ks.gaussian_inputs(*(scene.params[k] for k in PARAMS)), scene.camera, scene.background, mode=MODE)
    target = _noisy(r.rgb, np.random.default_rng([seed, 8]), 0.05)
    kf = Keyframe(0, scene.camera.viewmat, target, measured)
    cfg = MapConfig(depth_min_alpha=min_alpha)
    f, vjp = camera_loss_fn(scene, MODE, lambda res: mapping_loss(res, kf, cfg))
    return check_vjp(f, vjp, _camera_inputs(scene), seed=seed, eps=EPS, name=f"slam.mapping_loss[seed={seed}]")


@register_check("slam.tracking_loss")
def tracking_loss_checks() -> list[GradcheckResult]:
    return check_tracking_loss(0) + check_tracking_loss(1)


@register_check("slam.mapping_loss")
def mapping_loss_checks() -> list[GradcheckResult]:
    return check_mapping_loss(0) + check_mapping_loss(1)
