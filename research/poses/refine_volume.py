"""Joint refinement of camera poses and a radiance field from posed images (BARF-style, volume renderer).

BARF (Lin et al. 2021, "BARF: Bundle-Adjusting Neural Radiance Fields") optimises a NeRF and the
training cameras' poses together from poses that start a few degrees off. Here the field is a dense
voxel grid fitted coarse to fine (research.nerf.train.upsample_grid), which smooths the photometric
loss early on as BARF's coarse-to-fine positional encoding does.

Poses (research/poses/se3.py convention): view v keeps its starting world-to-camera matrix B_v and a
6-vector xi_v; its current pose is exp(xi_v^) B_v. Per iteration, with a ray batch drawn from
`views_per_batch` random training views:

    L = mean_rays |C - target|^2 + depth_weight * mean_{rays with a surface} (D - D_measured)^2

where D is the rendered expected z-depth (the depth loss path; off by default, as BARF is RGB only).
The field's gradient comes from kernels.volume.render_backward and Adam (kernels.optim.Adam) updates
it. The poses take one damped Gauss-Newton (Levenberg-Marquardt) step per iteration and view in the
batch, in the left perturbation delta of the CURRENT pose (exp(delta^) T_cw, exactly the convention of
the camera gradients, so no SE(3) Jacobian is approximated):

    J_v = d residuals / d delta   (kernels.volume.rays: render_backward_rays with a one-hot cotangent
                                   per residual kind -- R, G, B, depth -- then camera_rays_backward
                                   with per_pixel rows, since each ray depends on its own pose only)
    delta_v = -pose_step (J^T J + damping diag(J^T J))^-1 J^T r,  clipped to a trust region,

with the residuals weighted as in the loss. Adam on the poses was tried first: it normalises every
coordinate's step, so the directions the images barely see (a rotation traded against a
translation that keeps the object in place) random-walked at full rate and some views diverged
(beyond 20 degrees with a ground-truth field held fixed); the Gauss-Newton step is scaled by the
curvature instead.
Intrinsics are held at their known values. Sample distances are held fixed in the pose gradient
(kernels/volume/rays.py); the occupancy grid is updated from the field as in research.nerf.train.

Gauge: jointly refined poses and field are defined up to one rigid motion of the whole scene (and
the grid's box does not pin it exactly). `align_to_reference` finds it (Umeyama over the camera
centres, research.poses.se3) for evaluation, as BARF does with Procrustes.
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
from kernels.rotation import checked_rigid
from kernels.volume import GridField, OccupancyGrid, Workspace, render_backward, render_rays
from kernels.volume.rays import camera_rays, camera_rays_backward, render_backward_rays
from research.poses import se3 as P
from research.cameras import Camera
from research.nerf.train import optimiser_step


@dataclass
class JointConfig:
    iters: int = 600
    batch_rays: int = 2048
    views_per_batch: int = 8
    lr: dict[str, float] = dc_field(default_factory=lambda: {"density": 0.1, "color": 0.1})
    refine_poses: bool = True
    pose_step: float = 0.5  # fraction of the Gauss-Newton step taken per iteration
    pose_damping: float = 1.0  # Levenberg-Marquardt damping, relative to diag(J^T J)
    max_rot_step_deg: float = 0.1  # trust region of one pose update (0.5 and 0.05 tried: see pose_refinement)
    max_trans_step: float = 0.02  # scene units
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


def _pose_rows(field: GridField, res: Any, vids: np.ndarray, w2c: list, views: TrainingViews, pix: list,
               per_view: int, np_t: Any, cotangents: list[tuple[Any, Any]]) -> list[list[np.ndarray]]:
    """Per view, the Jacobian rows d residual / d xi (per_view, 6) of each residual kind: one reverse pass
    per kind (a one-hot cotangent on every ray: each ray's output depends on its own pose only)."""
    out: list[list[np.ndarray]] = [[] for _ in vids]
    for grad_rgb, grad_depth in cotangents:
        g_o, g_d, g_z = (x.numpy() for x in render_backward_rays(field, res, grad_rgb, grad_depth))
        for j, W in enumerate(w2c):
            s = slice(j * per_view, (j + 1) * per_view)
            out[j].append(camera_rays_backward(W, views.intrinsics, pix[j], g_o[s], g_d[s], g_z[s],
                                               per_pixel=True).xi)
    return out


def gauss_newton_step(J: np.ndarray, r: np.ndarray, damping: float) -> np.ndarray:
    """delta minimising |r + J delta|^2 + damping * delta^T diag(J^T J) delta (Levenberg-Marquardt)."""
    H = J.T @ J
    H = H + damping * np.diag(np.diag(H)) + 1e-12 * np.trace(H) * np.eye(H.shape[0]) + 1e-300 * np.eye(H.shape[0])
    return -np.linalg.solve(H, J.T @ r)


def _train(field: GridField, views: TrainingViews, xi: np.ndarray, bbox: np.ndarray, cfg: JointConfig,
           occupancy: OccupancyGrid, progress: bool, desc: str) -> JointLog:
    rng = np.random.default_rng(cfg.seed)
    np_t = A.NP_OF_WP[field.dtype]
    opt = Adam(field.params, cfg.lr)
    base_lr = dict(opt.lr)
    current = current_w2c(views, xi)
    n_views, h, w = views.srgb.shape[:3]
    per_view = max(1, cfg.batch_rays // min(cfg.views_per_batch, n_views))
    losses, rot_steps = [], []
    workspace = Workspace(field.device)
    max_rot = np.radians(cfg.max_rot_step_deg)
    t0 = time.perf_counter()
    for it in tqdm(range(cfg.iters), desc=desc, disable=not progress, mininterval=2.0):
        with A.value_checks(it == 0):
            warm = it < cfg.occupancy_start
            if not warm and (it - cfg.occupancy_start) % cfg.occupancy_every == 0:
                occupancy.update_from(field.density, seed=cfg.seed * 1_000_003 + it, dtype=field.dtype)
            vids = rng.choice(n_views, size=min(cfg.views_per_batch, n_views), replace=False)
            w2c = [current[v] for v in vids]
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
            grad_depth = depth_diff = None
            if cfg.depth_weight:
                measured = np.concatenate(depths)
                rendered = res.depth.numpy().astype(np.float64)
                dl, gd = depth_loss(rendered, measured, cfg.depth_weight)
                loss += dl
                grad_depth = gd.astype(np_t)
                depth_diff = np.where(measured > 0, rendered - measured, 0.0)
            update_poses = cfg.refine_poses and it >= cfg.pose_start
            if update_poses:  # before render_backward, which reuses the workspace's buffers
                B = len(target)
                cots = []
                for c in range(3):
                    onehot = np.zeros((B, 3), np_t)
                    onehot[:, c] = 1.0
                    cots.append((onehot, None))
                if depth_diff is not None:
                    cots.append((None, (depth_diff != 0).astype(np_t)))
                rows = _pose_rows(field, res, vids, w2c, views, pix, per_view, np_t, cots)
            grads = render_backward(field, res, grad_rgb, grad_depth, workspace=workspace)
            optimiser_step(opt, field, grads, cfg, it, base_lr)
            if update_poses:
                steps = []
                n_valid = max(1, int(np.count_nonzero(depth_diff))) if depth_diff is not None else 1
                for j, v in enumerate(vids):
                    s = slice(j * per_view, (j + 1) * per_view)
                    # Residuals weighted as in the loss: colour / sqrt(3B), depth sqrt(weight / n_valid).
                    Js = [rows[j][c] / np.sqrt(diff.size) for c in range(3)]
                    rs = [diff[s, c] / np.sqrt(diff.size) for c in range(3)]
                    if depth_diff is not None:
                        wd = np.sqrt(cfg.depth_weight / n_valid)
                        Js.append(rows[j][3] * wd)
                        rs.append(depth_diff[s] * wd)
                    delta = cfg.pose_step * gauss_newton_step(np.concatenate(Js), np.concatenate(rs), cfg.pose_damping)
                    rot = np.linalg.norm(delta[3:])
                    if rot > max_rot:  # a trust region: the field moves under the poses
                        delta *= max_rot / rot
                    if np.linalg.norm(delta[:3]) > cfg.max_trans_step:
                        delta *= cfg.max_trans_step / np.linalg.norm(delta[:3])
                    current[v] = P.se3_exp(delta) @ current[v]
                    current[v] = checked_rigid(f"w2c[{v}]", current[v])  # removes the products' rounding
                    steps.append(np.degrees(np.linalg.norm(delta[3:])))
                rot_steps.append(float(np.mean(steps)))
            losses.append(loss)
    occupancy.update_from(field.density, seed=cfg.seed * 1_000_003 + cfg.iters, dtype=field.dtype)
    xi[:] = np.array([P.se3_log(checked_rigid(f"w2c[{v}] w2c_init[{v}]^-1", C @ np.linalg.inv(B)))
                      for v, (C, B) in enumerate(zip(current, views.w2c))])
    return JointLog(losses, rot_steps, time.perf_counter() - t0)


def align_to_reference(c2w: np.ndarray, c2w_ref: np.ndarray, with_scale: bool = False) -> np.ndarray:
    """G (4x4, [[s R, t], [0, 1]]; s = 1 unless `with_scale`, Sim(3)) with G c2w_v ~ c2w_ref_v: Umeyama over the
    camera centres (research.poses.se3.umeyama)."""
    R, t, s = P.umeyama(np.asarray(c2w)[:, :3, 3], np.asarray(c2w_ref)[:, :3, 3], with_scale=with_scale)
    G = np.eye(4)
    G[:3, :3], G[:3, 3] = (s if with_scale else 1.0) * R, t
    return G


def apply_alignment(G: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """G c2w_v with the rotation block divided by G's scale s = det(G_3x3)^(1/3) (1 for a rigid G): the camera
    centres move by the similarity, the orientations by its rotation."""
    G = np.asarray(G, dtype=np.float64)
    scale = float(np.cbrt(np.linalg.det(G[:3, :3])))
    out = np.array([G @ T for T in np.asarray(c2w)])
    if scale != 1.0:
        out[:, :3, :3] /= scale
    return out


def pose_error_summary(c2w: np.ndarray, c2w_ref: np.ndarray, align: bool = True,
                       with_scale: bool = False) -> dict[str, Any]:
    """Rotation (degrees) and camera-centre errors, after the alignment of `align_to_reference`."""
    G = align_to_reference(c2w, c2w_ref, with_scale) if align else np.eye(4)
    rot, trans = P.pose_errors(apply_alignment(G, c2w), c2w_ref)
    return {"rot_mean_deg": float(rot.mean()), "rot_median_deg": float(np.median(rot)), "rot_max_deg": float(rot.max()),
            "trans_mean": float(trans.mean()), "trans_max": float(trans.max()), "rot_deg": rot.tolist(),
            "trans": trans.tolist(), "alignment": G.tolist()}
