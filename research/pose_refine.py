"""Joint refinement of camera poses and a radiance field from posed images (BARF-style, volume renderer).

BARF (Lin et al. 2021, "BARF: Bundle-Adjusting Neural Radiance Fields") optimises a NeRF and the
training cameras' poses together from poses that start a few degrees off. Here the field is a dense
voxel grid fitted coarse to fine (research.nerf.train.upsample_grid), which smooths the photometric
loss early on as BARF's coarse-to-fine positional encoding does.

Poses (research/poses.py convention): view v keeps its starting world-to-camera matrix B_v and a
6-vector xi_v; its current pose is exp(xi_v^) B_v. Per iteration, with a ray batch drawn from
`views_per_batch` random training views:

    L = mean_rays |C - target|^2 + depth_weight * mean_{rays with a surface} (D - D_measured)^2

where D is the rendered expected z-depth (the depth loss path; off by default, as BARF is RGB only).
The field's gradient comes from kernels.volume.render_backward; the poses' gradient from
kernels.volume.rays (render_backward_rays, then camera_rays_backward per view), which is the
derivative with respect to a left perturbation delta of the CURRENT pose, exp(delta^) exp(xi^) B.
It is used as the gradient of xi: the two differ by the SE(3) left Jacobian J(xi) = I + O(|xi|)
(a few percent at 5 degrees), which changes the path of the optimiser but not its fixed points
(J is invertible, so both gradients vanish together). Adam (kernels.optim.Adam) updates the field and,
with its own rates for rho and phi, the poses; views outside the batch get a zero gradient.
Intrinsics are held at their known values. Sample distances are held fixed in the pose gradient
(kernels/volume/rays.py); the occupancy grid is updated from the field as in research.nerf.train.

Gauge: jointly refined poses and field are defined up to one rigid motion of the whole scene (and
the grid's box does not pin it exactly). `align_to_reference` finds it (Umeyama over the camera
centres, research.poses) for evaluation, as BARF does with Procrustes.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field as dc_field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from kernels import _arrays as A
from kernels.optim import Adam
from kernels.volume import GridField, OccupancyGrid, Workspace, render_backward, render_rays
from kernels.volume.grid import add_tv_grad
from kernels.volume.rays import camera_rays, camera_rays_backward, render_backward_rays
from research import poses as P
from research.cameras import Camera


@dataclass
class JointConfig:
    iters: int = 600
    batch_rays: int = 2048
    views_per_batch: int = 8
    lr: dict[str, float] = dc_field(default_factory=lambda: {"density": 0.1, "color": 0.1})
    lr_rot: float = 2e-3  # Adam rate of phi (radians per step)
    lr_trans: float = 4e-3  # Adam rate of rho (scene units per step)
    refine_poses: bool = True
    pose_start: int = 0  # first iteration that updates the poses
    step: float = 0.04  # ray-marching stratum length
    t_threshold: float = 1e-4
    occupancy_res: tuple[int, int, int] = (32, 32, 8)
    occupancy_every: int = 16
    occupancy_start: int = 64
    occupancy_threshold: float = 1.0
    tv_weight: dict[str, float] = dc_field(default_factory=lambda: {"density": 0.01, "color": 0.001})
    depth_weight: float = 0.0
    lr_decay_from: float = 0.5
    lr_decay_to: float = 0.1
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class TrainingViews:
    """Training images with their (possibly wrong) starting poses."""

    intrinsics: np.ndarray  # (4,) fx, fy, cx, cy shared by every view
    width: int
    height: int
    w2c: np.ndarray  # (N, 4, 4) starting world-to-camera matrices B_v
    srgb: np.ndarray  # (N, H, W, 3) targets in [0, 1]
    depth: np.ndarray | None = None  # (N, H, W) measured z-depth, 0 = no surface

    @classmethod
    def from_cameras(cls, cameras: list[Camera], c2w: np.ndarray, srgb: np.ndarray,
                     depth: np.ndarray | None = None) -> "TrainingViews":
        c0 = cameras[0]
        K = np.array([c0.fx, c0.fy, c0.cx, c0.cy])
        for i, c in enumerate(cameras):
            if (c.width, c.height) != (c0.width, c0.height) or not np.allclose([c.fx, c.fy, c.cx, c.cy], K):
                raise ValueError(f"cameras[{i}]: expected the intrinsics and size of cameras[0] (one camera)")
        w2c = np.array([np.linalg.inv(P.check_trajectory("c2w", c2w)[i]) for i in range(len(c2w))])
        if srgb.shape[:3] != (len(cameras), c0.height, c0.width):
            raise ValueError(f"srgb: expected shape ({len(cameras)}, {c0.height}, {c0.width}, 3), got {srgb.shape}")
        return cls(K, c0.width, c0.height, w2c, srgb[..., :3].astype(np.float64), depth)


def depth_loss(depth: np.ndarray, measured: np.ndarray, weight: float) -> tuple[float, np.ndarray]:
    """(weight * mean over rays with measured > 0 of (depth - measured)^2, its gradient wrt depth)."""
    valid = measured > 0
    n = max(int(valid.sum()), 1)
    diff = np.where(valid, depth - measured, 0.0)
    return float(weight * (diff ** 2).sum() / n), 2.0 * weight * diff / n


def _lr_factor(cfg: JointConfig, it: int) -> float:
    start = int(cfg.lr_decay_from * cfg.iters)
    if it < start or cfg.iters <= start:
        return 1.0
    return float(cfg.lr_decay_to ** ((it - start) / (cfg.iters - start)))


@dataclass
class JointLog:
    losses: list[float]
    rot_step_deg: list[float]  # mean |delta phi| per pose-update iteration, degrees
    seconds: float


def train_joint(field: GridField, views: TrainingViews, xi: np.ndarray, bbox: np.ndarray, cfg: JointConfig,
                occupancy: OccupancyGrid, progress: bool = True, desc: str = "joint") -> JointLog:
    """Fit `field` in place and refine the pose offsets `xi` (N, 6) in place (module docstring)."""
    if not isinstance(field, GridField):
        raise ValueError(f"field: expected a kernels.volume.GridField, got {type(field).__name__}")
    n_views = views.w2c.shape[0]
    A.check_shape("xi", xi, (n_views, 6))
    if cfg.depth_weight and views.depth is None:
        raise ValueError("depth_weight: the views have no measured depth (RGB-D needs a depth image per frame)")
    with threadpool_limits(limits=1, user_api="blas"):
        return _train(field, views, xi, bbox, cfg, occupancy, progress, desc)


def current_w2c(views: TrainingViews, xi: np.ndarray) -> np.ndarray:
    """exp(xi_v^) B_v for every view."""
    return np.array([P.se3_exp(x) @ B for x, B in zip(xi, views.w2c)])


def _train(field: GridField, views: TrainingViews, xi: np.ndarray, bbox: np.ndarray, cfg: JointConfig,
           occupancy: OccupancyGrid, progress: bool, desc: str) -> JointLog:
    rng = np.random.default_rng(cfg.seed)
    np_t = A.NP_OF_WP[field.dtype]
    opt = Adam(field.params, cfg.lr)
    base_lr = dict(opt.lr)
    pose = {"rho": xi[:, :3].copy(), "phi": xi[:, 3:].copy()}
    pose_opt = Adam(pose, {"rho": cfg.lr_trans, "phi": cfg.lr_rot})
    n_views, h, w = views.srgb.shape[:3]
    per_view = max(1, cfg.batch_rays // min(cfg.views_per_batch, n_views))
    losses, rot_steps = [], []
    workspace = Workspace(field.device)
    t0 = time.perf_counter()
    for it in tqdm(range(cfg.iters), desc=desc, disable=not progress, mininterval=2.0):
        with A.value_checks(it == 0):
            warm = it < cfg.occupancy_start
            if not warm and (it - cfg.occupancy_start) % cfg.occupancy_every == 0:
                occupancy.update_from(field.density, seed=cfg.seed * 1_000_003 + it, dtype=field.dtype)
            vids = rng.choice(n_views, size=min(cfg.views_per_batch, n_views), replace=False)
            w2c = [P.se3_exp(np.concatenate([pose["rho"][v], pose["phi"][v]])) @ views.w2c[v] for v in vids]
            pix, rays, targets, depths = [], [], [], []
            for v, W in zip(vids, w2c):
                flat = rng.integers(0, h * w, per_view)
                px = np.stack([flat % w + 0.5, flat // w + 0.5], axis=1).astype(np_t)
                pix.append(px)
                rays.append(camera_rays(W, views.intrinsics, px))
                targets.append(views.srgb[v].reshape(-1, 3)[flat])
                if views.depth is not None:
                    depths.append(views.depth[v].reshape(-1)[flat])
            o, d, zs = (np.concatenate([r[k] for r in rays]) for k in range(3))
            target = np.concatenate(targets)
            res = render_rays(field, o, d, bbox, step=cfg.step * (2.0 if warm else 1.0), z_scale=zs,
                              occupancy=None if warm else occupancy, jitter=True, seed=cfg.seed * 1_000_003 + it,
                              t_threshold=cfg.t_threshold, workspace=workspace)
            diff = res.rgb.numpy().astype(np.float64) - target
            loss = float(np.mean(diff ** 2))
            grad_rgb = (2.0 * diff / diff.size).astype(np_t)
            grad_depth = None
            if cfg.depth_weight:
                dl, gd = depth_loss(res.depth.numpy().astype(np.float64), np.concatenate(depths), cfg.depth_weight)
                loss += dl
                grad_depth = gd.astype(np_t)
            update_poses = cfg.refine_poses and it >= cfg.pose_start
            if update_poses:  # before render_backward, which reuses the workspace's buffers
                g_o, g_d, g_z = (x.numpy() for x in render_backward_rays(field, res, grad_rgb, grad_depth))
            grads = render_backward(field, res, grad_rgb, grad_depth, workspace=workspace)
            nv = field.params["density"].shape[0]
            for name, tw in cfg.tv_weight.items():
                add_tv_grad(field.params[name], field.resolution, tw / nv, grads[name])
            f = _lr_factor(cfg, it)
            opt.lr = {k: v * f for k, v in base_lr.items()}
            opt.step(grads)
            if update_poses:
                g_pose = {"rho": np.zeros((n_views, 3)), "phi": np.zeros((n_views, 3))}
                for j, (v, W) in enumerate(zip(vids, w2c)):
                    s = slice(j * per_view, (j + 1) * per_view)
                    g = camera_rays_backward(W, views.intrinsics, pix[j], g_o[s], g_d[s], g_z[s])
                    g_pose["rho"][v] = g.xi[:3]
                    g_pose["phi"][v] = g.xi[3:]
                before = pose["phi"].copy()
                pose_opt.lr = {"rho": cfg.lr_trans * f, "phi": cfg.lr_rot * f}
                pose_opt.step(g_pose)
                rot_steps.append(float(np.degrees(np.linalg.norm(pose["phi"] - before, axis=1).mean())))
            losses.append(loss)
    occupancy.update_from(field.density, seed=cfg.seed * 1_000_003 + cfg.iters, dtype=field.dtype)
    xi[:, :3], xi[:, 3:] = pose["rho"], pose["phi"]
    return JointLog(losses, rot_steps, time.perf_counter() - t0)


def align_to_reference(c2w: np.ndarray, c2w_ref: np.ndarray) -> np.ndarray:
    """G (4x4, rigid) with G c2w_v ~ c2w_ref_v: Umeyama over the camera centres (research.poses.umeyama)."""
    R, t, _ = P.umeyama(np.asarray(c2w)[:, :3, 3], np.asarray(c2w_ref)[:, :3, 3])
    G = np.eye(4)
    G[:3, :3], G[:3, 3] = R, t
    return G


def pose_error_summary(c2w: np.ndarray, c2w_ref: np.ndarray, align: bool = True) -> dict[str, Any]:
    """Rotation (degrees) and camera-centre errors, after the rigid alignment of `align_to_reference`."""
    G = align_to_reference(c2w, c2w_ref) if align else np.eye(4)
    rot, trans = P.pose_errors(np.array([G @ T for T in c2w]), c2w_ref)
    return {"rot_mean_deg": float(rot.mean()), "rot_median_deg": float(np.median(rot)), "rot_max_deg": float(rot.max()),
            "trans_mean": float(trans.mean()), "trans_max": float(trans.max()), "rot_deg": rot.tolist(),
            "trans": trans.tolist(), "alignment": G.tolist()}
