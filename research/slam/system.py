"""The SLAM loop over an RGB-D sequence (SplaTAM-style), and its input checks.

Frame 0 fixes the world frame: its pose is given (`first_c2w`), and the map starts from its pixels
(research/slam/mapping.py: init_map), then is optimised on it alone. For every later frame k:

1. guess: constant velocity in world-to-camera, T_k = T_{k-1} T_{k-2}^-1 T_{k-1} (T_0 for k = 1);
2. track: research/slam/tracking.py from the guess, a fixed iteration budget (three times it for
   frame 1, which has no velocity to predict from);
3. check: the frame is a tracking failure when its best loss exceeds `fail_loss_ratio` x the median
   best loss of the frames tracked so far, when the optimisation diverged (its last iterate's loss above
   `fail_loss_ratio` x the loss at the guess), when the map covers no pixel of it, or when the tracked pose
   leaves the guess by more than `max_jump_trans` (scene units) or `max_jump_deg`; a failed frame keeps
   the constant-velocity guess, is recorded (frame, reason, numbers) and is neither mapped nor used as a
   keyframe; `max_failures` failures in a row raise TrackingLost instead of returning a trajectory
   of guesses;
4. map, on keyframes (every `keyframe_every`-th frame): densify where the map's render at the tracked
   pose has a thin silhouette or a surface behind the measured one, then optimise the splats over the
   window of the last `window` keyframes.

Every frame is checked before any work (`check_sequence`): colour (N, H, W, 3), depth (N, H, W) with
some pixel > 0 in every frame (RGB-D mode), N >= the keyframe window, `first_c2w` a rigid transform.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from research.cameras import check_pose
from research.poses.se3 import rotation_angle_deg
from research.slam.mapping import (Keyframe, MapConfig, add_splats, densify_mask, init_map, make_map_adam,
                                   map_window, new_splats)
from research.slam.tracking import TrackConfig, track_frame
from research.splats.model import GaussianModel


class TrackingLost(RuntimeError):
    """Too many consecutive tracking failures: the trajectory from here on would be guesses."""


@dataclass(frozen=True)
class SlamConfig:
    """Keyframe spacing and window as SplaTAM's order of magnitude, failure bounds set once (the seed-0
    loop's steps are 0.4 units and 6 degrees); none tuned on the reported runs."""

    track: TrackConfig = field(default_factory=TrackConfig)
    map: MapConfig = field(default_factory=MapConfig)
    keyframe_every: int = 2
    window: int = 5
    init_iters: int = 60  # mapping steps on frame 0 alone
    fail_loss_ratio: float = 4.0
    max_jump_trans: float = 1.0
    max_jump_deg: float = 10.0
    max_failures: int = 3
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("keyframe_every", "window", "max_failures"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name}: expected an integer >= 1, got {v!r}")
        if int(self.init_iters) != self.init_iters or self.init_iters < 0:
            raise ValueError(f"init_iters: expected an integer >= 0, got {self.init_iters!r}")
        for name in ("fail_loss_ratio", "max_jump_trans", "max_jump_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a positive value, got {v!r}")


@dataclass
class SlamResult:
    c2w: np.ndarray  # (N, 4, 4) estimated camera-to-world
    model: GaussianModel
    failures: list[dict]
    frames: list[dict]  # per frame: loss, iterations, pixels, splats, keyframe, seconds
    seconds: float  # wall time of the loop (tracking + mapping), excluding input checks
    keyframes: list[int]


def check_sequence(rgba: Any, depth: Any, K: Any, first_c2w: Any, window: int) -> tuple[np.ndarray, np.ndarray,
                                                                                       np.ndarray, np.ndarray]:
    """The checked inputs (colour float32 (N, H, W, 4 or 3), depth float32, K, first_c2w); ValueError naming
    the argument otherwise (module docstring)."""
    rgba = np.asarray(rgba)
    if rgba.ndim != 4 or rgba.shape[-1] not in (3, 4) or not np.issubdtype(rgba.dtype, np.floating):
        raise ValueError(f"rgba: expected float frames (N, H, W, 3 or 4), got {rgba.dtype} {rgba.shape}")
    n, h, w = rgba.shape[:3]
    if depth is None:
        raise ValueError("depth: RGB-D mode needs a depth map for every frame, got None")
    if isinstance(depth, (list, tuple)):
        for k, d in enumerate(depth):
            if d is None:
                raise ValueError(f"depth: frame {k} has no depth map (RGB-D mode needs one per frame)")
        depth = np.stack([np.asarray(d) for d in depth]) if len(depth) else np.zeros((0, h, w))
    depth = np.asarray(depth)
    if depth.shape != (n, h, w):
        raise ValueError(f"depth: expected one (H, W) = ({h}, {w}) map per frame, shape ({n}, {h}, {w}), "
                         f"got {depth.shape}")
    if not np.all(np.isfinite(rgba)) or not np.all(np.isfinite(depth)):
        raise ValueError("rgba, depth: expected finite values")
    for k in range(n):
        if not (depth[k] > 0).any():
            raise ValueError(f"depth: frame {k} has no pixel with depth > 0 (RGB-D mode needs depth in every frame)")
    if int(window) != window or window < 1:
        raise ValueError(f"window: expected an integer >= 1, got {window!r}")
    if n < window:
        raise ValueError(f"rgba: the sequence has {n} frames, fewer than the keyframe window ({window})")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K: expected a finite 3x3 intrinsics matrix with fx, fy > 0, got shape {K.shape}")
    first = check_pose("first_c2w", first_c2w)
    return rgba.astype(np.float32), depth.astype(np.float32), K, first


def _rot_deg(a: np.ndarray, b: np.ndarray) -> float:
    return rotation_angle_deg(a[:3, :3] @ b[:3, :3].T)


def run_slam(rgba: Any, depth: Any, K: Any, first_c2w: Any, cfg: SlamConfig, *, device: Any = None,
             progress: Callable[[int, dict], None] | None = None) -> SlamResult:
    """Track and map the whole sequence (module docstring). `rgba` premultiplied linear (N, H, W, 4)
    (or 3 channels: alpha taken as 1); `depth` z-depth (N, H, W), 0 where there is none."""
    rgba, depth, K, first = check_sequence(rgba, depth, K, first_c2w, cfg.window)
    n, h, w = depth.shape
    rgb = np.ascontiguousarray(rgba[..., :3])
    alpha = rgba[..., 3] if rgba.shape[-1] == 4 else np.ones((n, h, w), dtype=np.float32)
    rng = np.random.default_rng(cfg.seed)
    t0 = time.perf_counter()
    w2c = [np.linalg.inv(first)]
    model = init_map(rgb[0], alpha[0], depth[0], K, w2c[0], cfg.map.stride, cfg.map.init_opacity)
    adam = make_map_adam(model, cfg.map)
    keyframes = [Keyframe(0, w2c[0], rgb[0], depth[0])]
    model, adam, _ = map_window(model, adam, keyframes, K, w, h, _iters(cfg.map, cfg.init_iters), rng, device)
    frames = [{"frame": 0, "loss": 0.0, "keyframe": True, "splats": model.n, "seconds": time.perf_counter() - t0}]
    failures: list[dict] = []
    good_losses: list[float] = []
    in_a_row = 0
    for k in range(1, n):
        tk = time.perf_counter()
        guess = w2c[-1] if k == 1 else w2c[-1] @ np.linalg.inv(w2c[-2]) @ w2c[-1]
        track = cfg.track if k > 1 else replace(cfg.track, iters=3 * cfg.track.iters)  # no velocity yet
        tr = track_frame(model, guess, K, w, h, rgb[k], depth[k], track, device)
        jump_t = float(np.linalg.norm(np.linalg.inv(tr.w2c)[:3, 3] - np.linalg.inv(guess)[:3, 3]))
        jump_r = _rot_deg(tr.w2c, guess)
        reason = None
        if tr.pixels == 0:
            reason = "the map covers no pixel of the frame"
        elif jump_t > cfg.max_jump_trans or jump_r > cfg.max_jump_deg:
            reason = f"pose jump {jump_t:.3g} / {jump_r:.3g} deg from the guess beyond the bound"
        elif tr.losses[-1] > cfg.fail_loss_ratio * tr.losses[0]:
            reason = f"loss rising: {tr.losses[0]:.4g} at the guess, {tr.losses[-1]:.4g} at the last iteration"
        elif good_losses and tr.loss > cfg.fail_loss_ratio * float(np.median(good_losses)):
            reason = f"loss {tr.loss:.4g} above {cfg.fail_loss_ratio:g} x the median {np.median(good_losses):.4g}"
        record = {"frame": k, "loss": tr.loss, "initial_loss": tr.losses[0] if tr.losses else float("nan"),
                  "pixels": tr.pixels, "jump_trans": jump_t, "jump_deg": jump_r, "keyframe": False}
        if reason is not None:
            failures.append({"frame": k, "reason": reason, "loss": tr.loss, "jump_trans": jump_t, "jump_deg": jump_r})
            in_a_row += 1
            if in_a_row >= cfg.max_failures:
                raise TrackingLost(f"tracking lost at frame {k}: {in_a_row} failures in a row (last: {reason})")
            w2c.append(guess)
        else:
            in_a_row = 0
            good_losses.append(tr.loss)
            w2c.append(tr.w2c)
            if k % cfg.keyframe_every == 0 or k == n - 1:
                model, adam = _densify(model, adam, rgb[k], alpha[k], depth[k], K, tr.w2c, cfg.map, w, h, device)
                keyframes.append(Keyframe(k, tr.w2c, rgb[k], depth[k]))
                model, adam, _ = map_window(model, adam, keyframes[-cfg.window:], K, w, h, cfg.map, rng, device)
                record["keyframe"] = True
        record["splats"] = model.n
        record["seconds"] = time.perf_counter() - tk
        frames.append(record)
        if progress is not None:
            progress(k, record)
    c2w = np.array([np.linalg.inv(T) for T in w2c])
    return SlamResult(c2w, model, failures, frames, time.perf_counter() - t0, [kf.index for kf in keyframes])


def _iters(cfg: MapConfig, iters: int) -> MapConfig:
    return replace(cfg, iters=iters)


def _densify(model, adam, rgb, alpha, depth, K, w2c, cfg: MapConfig, w: int, h: int, device):
    from kernels import splat as ks

    res = ks.render(model.inputs(device), ks.SplatCamera(w2c, K, w, h), np.zeros(3, dtype=np.float32), sh_degree=0)
    mask = densify_mask(res.alpha.numpy(), res.depth.numpy(), depth, cfg)
    return add_splats(model, adam, new_splats(rgb, alpha, depth, K, w2c, mask, cfg.stride, cfg.init_opacity)), adam
