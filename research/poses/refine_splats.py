"""Joint refinement of camera poses and Gaussian splats from posed images (BARF-style, splat renderer).

The splat variant of research/poses/refine_volume.py. Each iteration renders one training view v at its
current world-to-camera pose T_v (a fresh random permutation of the views per epoch, as 3DGS) and
takes the 3DGS loss on images blurred by a Gaussian of width s(it) pixels (coarse to fine):

    L = (1 - lambda) |b_s * I - b_s * I_v|_1 + lambda (1 - SSIM(b_s * I, b_s * I_v)),
    s(it) = blur_start (1 - it / blur_until) for it < blur_until, 0 after,

where b_s is a Gaussian filter with zero padding (so dL/dI = b_s * dL/d(b_s * I): the filter is
self-adjoint) and lambda = 0.2. The blur plays the part of BARF's coarse-to-fine positional encoding:
it widens the basin of the photometric loss in the pose while the splats are still wrong. The
active SH degree also starts at 0 and grows by one every `sh_interval` iterations once the blur is
gone (view-dependent colour could otherwise absorb pose error).

One backward (kernels.splat.render_backward(..., want_camera=True)) gives both the splats' gradients
and the pose gradient g_v = dL/ddelta (6,), delta = (rho, phi) the left perturbation of the CURRENT
pose, T_v <- exp(delta^) T_v (kernels/splat/camera.py). The splats take 3DGS's Adam step
(research.splats.optim, position rate decaying log-linearly); the pose takes a per-view Adam step in
that tangent space,

    m_v <- b1 m_v + (1 - b1) g_v,  u_v <- b2 u_v + (1 - b2) g_v^2,
    delta_v = -lr * m_hat_v / (sqrt(u_hat_v) + eps),   T_v <- exp(delta_v^) T_v,

with lr = (pose_lr_trans * extent (x3), pose_lr_rot (x3)) decaying log-linearly to `pose_lr_final`
times itself, and bias corrections counted per view. Poses move only from `pose_start` on, so the
splats first form from the poses as given. No densification: the splats are initialised from many
back-projected depth pixels (or uniformly in the box) and only move, rescale and recolour.

Gauge: jointly refined poses and splats are defined up to one rigid motion of the whole scene;
research.poses.refine_volume.align_to_reference (Umeyama over the camera centres) removes it for
evaluation, as BARF does with Procrustes.

RGB-D (`depth_weight` > 0): the loss adds depth_weight times research.splats.loss.depth_loss (L1 of
the expected z-depth D/A against the measured depth, over pixels with A > 0.5 and a measurement), its
gradients entering the same backward as grad_depth and grad_alpha. `antialiased` renders with the
Mip-Splatting opacity compensation (kernels.splat.render).

`polish_poses` refines every view's pose alone against a FIXED model by Levenberg-Marquardt on
0.5 |I(T) - image|^2: the gradient g = J^T r is the exact backward (want_camera=True); the curvature
J^T J comes from J, the image's six directional derivatives along the left-perturbation axes by
central differences of the forward render (`pose_jacobian`, step 1e-3; the backward gives only
vector-Jacobian products, and J^T J needs J), so a converged pose is a zero of the exact gradient;
delta = -(J^T J + lambda diag(J^T J))^-1 g, accepted when the cost falls (lambda / 3), else lambda x 4.
The experiment uses it for BARF's test-time pose optimisation of the test views.

Why the joint fit stalls near 0.7 degree (`experiments.pose_refinement`, quick size, --seed 1; the
reported seed 0 was not used for any of this):
  * the residual is not noise: after the Sim(3) alignment it is almost all a camera-frame PITCH
    (rotation about the camera's x axis) of the same sign in every view, growing with the view's
    closeness to the horizon, about 0.93 cos(elevation) degrees (0.9 at 16 degrees of elevation, 0.1
    at 82), with the centre error along the camera's y axis (correlation 0.88);
  * it is a flat direction of the JOINT problem, not a convergence failure: started from the
    ground-truth poses, the same fit drifts to the same pattern (RGB: 0.62 mean / 1.10 max degrees,
    final training loss 0.0328, as low as the fit with the poses held at the ground truth, 0.0335),
    and with the depth loss too (0.48 / 0.82);
  * the pose optimiser is not the limit: the pose-only Levenberg-Marquardt polish of every view
    against the jointly fitted model lowers the cost by 0.3% and leaves the errors as they are
    (0.69 / 1.39 -> 0.67 / 1.48): model and poses agree, the model has absorbed the error. A longer
    and stronger coarse phase (blur 4 px until 75% of the iterations instead of 2 px until 50%) gives
    0.70 / 1.32, and a slower pose-rate decay changed nothing earlier (0.68 / 1.37);
  * what reduces it is the image formation: with the Mip-Splatting opacity compensation
    (`antialiased`) the RGB-D fit goes from 0.61 / 0.92 to 0.42 / 0.70 degrees, the RGB fit from
    0.69 / 1.39 to 0.54 / 1.09. The likely mechanism
    (supported by that one test, not proven): the rasteriser's 0.3 px^2 dilation widens every splat,
    most on the ground seen near the horizon and at its far edge against the black background, which
    the low views' pitch then compensates. Tested with the dilation as a parameter (`dilation`,
    kernels/splat/modes.py), the same RGB fit started from the ground-truth poses with the compensation,
    3000 iterations, seed 1: the pitch mode (least-squares amplitude of the camera-x rotation against
    cos(elevation)) shrinks with the dilation, 0.3 px^2: 0.63 cos(elev) (0.43 mean / 0.82 max deg,
    training loss 0.0343); 0.1: 0.36 (0.28 / 0.55, 0.0303); 0.03: 0.27 (0.23 / 0.48, 0.0286); 0 (where
    the compensation is 1, so effectively without it): 0.29 (0.23 / 0.51, 0.0276). So the dilation
    is the larger part of the drift, not all of it (the residual about the fit, 0.11-0.13 deg rms,
    does not change). Depth
    pins the scale and the centres (0.59% -> 0.24% of the radius) but not the pitch. The 64 x 64
    images were suspected as the other limit (a 1-degree pitch traded against the matching centre shift
    moves the scene's depth extent by about 0.3 px of parallax), but they are not: at 128 x 128 (the
    same 40 cameras as experiments.pose_refinement's full mode, 2-px blur) the mode keeps its size in
    degrees, 0.37 cos(elevation) in the RGB fit from the perturbed poses (0.29 with the depth loss), against
    0.36 at 64 px from the ground-truth poses; the errors fall (0.437 / 0.951 -> 0.295 / 0.801 deg RGB,
    0.347 / 0.598 -> 0.226 / 0.438 RGB-D) because the rest of the residual shrinks (the pitch about
    its cos(elevation) fit 0.15 deg rms RGB, 0.06 RGB-D; yaw and roll under 0.1 rms);
  * is it the gauge that the centre alignment leaves? The pattern is what a camera whose centre stays
    put shows when it turns to look at a scene translated by d: omega_v = f_v x d / r_v (f_v the
    viewing direction, r_v the distance; the turn is |d| cos(elevation) / r about the camera's x axis
    for a vertical d). A least-squares d for the 32 rotation errors (world frame) at 128 px explains
    67% of their sum of squares in the RGB fit and 81% in the RGB-D fit, with d = (0.000, 0.001, 0.027)
    and (0.001, 0.005, 0.021): every camera turned towards a point 2-3 cm ABOVE the true one (0.5-0.6%
    of the radius), the centres hardly moving (their camera-y error is 0.26 (RGB) and 0.04 (RGB-D) of
    r_v times the pitch). Moving the whole model up by d would be such a mode and the alignment over
    the camera centres could not remove it (it is no similarity: the centres stay, the orientations
    turn). Measured against a baseline (128 px, seed 1, 3000 iterations; the opaque splats, opacity > 0.5,
    mapped by the fit's Sim(3) alignment, each against its nearest ground-truth surface point, every
    training depth pixel back-projected at the true poses; median vertical offset per surface, cm):

        fit                              ground  coaster  can lid  ball   loss    opaque  distance
        poses held at the ground truth   -1.56   -1.73    -0.42    -1.60  0.0347  4586    2.1 cm
        refined, one joint fit           -1.76   -3.60    +2.37    -1.32  0.0469  2557    6.1 cm
        refined, second fit (2 passes)   +1.66   +1.41    +1.20    -0.87  0.0394  2635    1.9 cm

    ("distance": median to the nearest surface point; "loss": the last 200 iterations' training loss;
    the splats of the baseline sit 1.5 cm into the ground, a bias of the fit, not of the poses). The
    one-fit refined model (0.270 / 0.640 deg) is not shifted as a whole (ground -0.2 cm against the
    baseline, lid +2.8, coaster -1.9): it is a messier model than the baseline (fewer opaque splats,
    scattered 3 times as far from the surfaces) at a training loss 35% higher, so at 128 px and 3000
    iterations the refined fit has not reached the loss of the fit at the true poses (unlike the 64-px
    fit from the true poses above). That is mostly LENGTH, not the scattered starting cloud: one fit of
    6000 iterations (schedule scaled) reaches the loss of the second fit below (0.0395) with a model as
    scattered (5.6 cm, 3001 opaque splats) and better poses (0.135 / 0.338 deg, pitch 0.18
    cos(elevation)). The second joint fit from a fresh model back-projected at the first fit's poses
    (experiments.pose_refinement's REFINE_PASSES) gives a clean model (1.9 cm) and there the near-gauge
    shows plainly: the model is raised against the baseline by
    3.2 cm on the ground, 3.1 on the coaster, 1.6 on the lid (+0.7 on the ball, whose offsets are
    mostly horizontal), while the cameras are pitched towards it (0.26 cos(elevation) deg, d =
    (-0.002, 0.000, 0.019) explaining 74% of the rotation errors, centre error 0.18% of the radius):
    "model up by 2-3 cm, every camera turned towards it, centres fixed", which the alignment over the
    centres cannot remove. Measured with scratch scripts (fit, then this nearest-point offset), not
    part of the package;
  * nor is it a preference of the image formation alone: a model fitted with the poses held at the
    ground truth (64 px, 3000 iterations, seed 1), every training pose then polished alone against it
    (polish_poses, 10 iterations; cost down 0.6%), moves 0.066 mean / 0.146 max deg, with a pitch of
    0.056 cos(elevation) deg, same sign as the drift but a sixth of it. The mode needs the model and
    the poses to move together: it is a near-flat direction of the joint problem, whose mechanism
    (which deformation of the model pays for the pitched low views) is still open.

`refine_pose` is the tracking half alone: one view's pose against a fixed splat model (plain
photometric L2 loss, no blur), the building block the single-view unit test checks.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter
from tqdm import tqdm

from kernels import _arrays as A
from kernels import splat as ks
from kernels.rotation import checked_rigid
from research.splats.loss import LAMBDA_DSSIM, depth_loss, l1_dssim
from research.splats.model import GaussianModel
from research.splats.optim import BETAS, LearningRates, expon_lr, make_adam


@dataclass(frozen=True)
class SplatJointConfig:
    iterations: int = 2000
    refine_poses: bool = True
    pose_start: int = 100  # first iteration that moves the poses
    pose_lr_rot: float = 3e-2  # radians per Adam step at the start (chosen on pose_refinement --seed 1)
    pose_lr_trans: float = 3e-2  # times the scene extent
    pose_lr_final: float = 0.05  # final pose rate as a fraction of the initial one
    blur_start: float = 2.0  # pixels (Gaussian sigma) at iteration 0
    blur_until: float = 0.5  # fraction of the iterations after which the images are sharp
    sh_interval: int = 200
    max_sh_degree: int = 3
    lambda_dssim: float = LAMBDA_DSSIM
    antialiased: bool = False  # render with the Mip-Splatting opacity compensation (kernels.splat.render)
    dilation: float | None = None  # the renderer's low-pass dilation in px^2 (None: the mode's 0.3)
    depth_weight: float = 0.0  # weight of the expected-depth L1 loss (RGB-D); 0: colour only, as BARF
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    seed: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.iterations, int) and self.iterations >= 1):
            raise ValueError(f"iterations: expected an integer >= 1, got {self.iterations!r}")
        for name in ("pose_lr_rot", "pose_lr_trans", "pose_lr_final", "blur_start", "depth_weight"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: expected a finite value >= 0, got {v}")
        if not 0.0 <= self.blur_until <= 1.0:
            raise ValueError(f"blur_until: expected a fraction in [0, 1], got {self.blur_until}")
        if not 0 <= self.max_sh_degree <= 3:
            raise ValueError(f"max_sh_degree: expected 0..3, got {self.max_sh_degree}")
        ks.dilation_of(ks.DEFAULT_MODE, self.dilation, self.antialiased)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def blur(self, it: int) -> float:
        end = self.blur_until * self.iterations
        return float(self.blur_start * (1.0 - it / end)) if it < end else 0.0

    def sh_degree(self, it: int) -> int:
        sharp = int(self.blur_until * self.iterations)
        return int(min(self.max_sh_degree, max(0, it - sharp) // max(self.sh_interval, 1)))


@dataclass
class SplatJointLog:
    losses: list[float]
    rot_step_deg: list[float]  # |delta phi| of each pose update, degrees
    seconds: float
    sh_degree: int


def _blur(img: np.ndarray, sigma: float) -> np.ndarray:
    if sigma < 0.05:
        return img
    return gaussian_filter(img, sigma=(sigma, sigma, 0.0), mode="constant", truncate=3.0).astype(img.dtype)


class PoseAdam:
    """Per-view Adam in the left tangent space of each current pose (module docstring)."""

    def __init__(self, n_views: int, eps: float = 1e-15):
        self.m = np.zeros((n_views, 6))
        self.u = np.zeros((n_views, 6))
        self.t = np.zeros(n_views, dtype=int)
        self.eps = eps

    def step(self, v: int, grad: np.ndarray, lr: np.ndarray) -> np.ndarray:
        b1, b2 = BETAS
        self.t[v] += 1
        self.m[v] = b1 * self.m[v] + (1 - b1) * grad
        self.u[v] = b2 * self.u[v] + (1 - b2) * grad * grad
        mh = self.m[v] / (1 - b1 ** self.t[v])
        uh = self.u[v] / (1 - b2 ** self.t[v])
        return -lr * mh / (np.sqrt(uh) + self.eps)


def _apply(delta: np.ndarray, w2c: np.ndarray) -> np.ndarray:
    """exp(delta^) w2c, its rotation re-orthonormalised and its last row exact (the products' rounding removed)."""
    return checked_rigid("w2c", ks.se3_exp(delta) @ w2c)


def _check_inputs(model: GaussianModel, w2c: np.ndarray, K: np.ndarray, images: np.ndarray) -> None:
    if not isinstance(model, GaussianModel):
        raise ValueError(f"model: expected a research.splats.model.GaussianModel, got {type(model).__name__}")
    w2c = np.asarray(w2c)
    if w2c.ndim != 3 or w2c.shape[1:] != (4, 4) or len(w2c) == 0:
        raise ValueError(f"w2c: expected shape (N >= 1, 4, 4), got {w2c.shape}")
    if np.asarray(K).shape != (3, 3):
        raise ValueError(f"K: expected a 3x3 intrinsics matrix, got shape {np.asarray(K).shape}")
    if images.ndim != 4 or images.shape[0] != len(w2c) or images.shape[3] != 3:
        raise ValueError(f"images: expected shape ({len(w2c)}, H, W, 3), got {images.shape}")
    if not np.all(np.isfinite(images)):
        raise ValueError("images: contain NaN or infinite values")


def train_joint_splats(model: GaussianModel, w2c: np.ndarray, K: np.ndarray, images: np.ndarray, extent: float,
                       cfg: SplatJointConfig, *, progress: bool = True, device: Any = None,
                       desc: str = "joint splats", depths: np.ndarray | None = None
                       ) -> tuple[GaussianModel, np.ndarray, SplatJointLog]:
    """Fit a copy of `model` to `images` (N, H, W, 3, linear RGB) seen from starting world-to-camera
    poses `w2c` (N, 4, 4) with intrinsics K, refining the poses (module docstring).
    Returns (model, refined w2c (N, 4, 4), log); the inputs are not modified."""
    images = np.ascontiguousarray(images, dtype=np.float32)
    _check_inputs(model, w2c, K, images)
    if not (math.isfinite(extent) and extent > 0):
        raise ValueError(f"extent: expected a positive scene scale, got {extent}")
    if cfg.depth_weight > 0:
        if depths is None or np.shape(depths) != images.shape[:3]:
            raise ValueError(f"depths: expected measured z-depths of shape {images.shape[:3]} with depth_weight > 0, "
                             f"got {None if depths is None else np.shape(depths)}")
        depths = np.asarray(depths, dtype=np.float64)
    cams = [ks.SplatCamera(T, K, images.shape[2], images.shape[1]) for T in np.asarray(w2c, dtype=np.float64)]
    device = A.get_device(device)
    current = np.array([c.viewmat for c in cams])
    model = model.copy()
    model.inputs(device)  # checks the initial model once before the unchecked loop
    rng = np.random.default_rng(cfg.seed)
    lr = LearningRates()
    adam = make_adam(model, {"means": lr.means_init * extent, "log_scales": lr.log_scales, "quats": lr.quats,
                             "opacity_logits": lr.opacity_logits, "sh_dc": lr.sh_dc, "sh_rest": lr.sh_rest})
    pose_adam = PoseAdam(len(cams))
    pose_lr0 = np.array([cfg.pose_lr_trans * extent] * 3 + [cfg.pose_lr_rot] * 3)
    background = np.asarray(cfg.background, dtype=np.float32)
    losses, rot_steps, order = [], [], []
    degree = 0
    t0 = time.perf_counter()
    with A.value_checks(False):
        for it in tqdm(range(cfg.iterations), desc=desc, disable=not progress, mininterval=2.0):
            adam.lr["means"] = expon_lr(it, lr.means_init * extent, lr.means_final * extent, cfg.iterations)
            degree = cfg.sh_degree(it)
            if not order:
                order = list(rng.permutation(len(cams)))
            v = order.pop()
            cam = ks.SplatCamera(current[v], K, cams[v].width, cams[v].height)
            inputs = model.inputs(device)
            update_pose = cfg.refine_poses and it >= cfg.pose_start
            result = ks.render(inputs, cam, background, sh_degree=degree, antialiased=cfg.antialiased,
                               dilation=cfg.dilation)
            sigma = cfg.blur(it)
            pred = result.rgb.numpy()
            loss, grad_b, _ = l1_dssim(_blur(pred, sigma), _blur(images[v], sigma), cfg.lambda_dssim, device=device)
            if not np.isfinite(loss):
                raise RuntimeError(f"iteration {it}: the loss is {loss}")
            grad_img = np.ascontiguousarray(_blur(grad_b, sigma), dtype=np.float32)
            g_alpha = g_depth = None
            if cfg.depth_weight > 0:
                ld, gd, ga = depth_loss(result.depth.numpy(), result.alpha.numpy(), depths[v], kind="l1")
                loss += cfg.depth_weight * ld
                g_depth = np.ascontiguousarray(cfg.depth_weight * gd, dtype=np.float32)
                g_alpha = np.ascontiguousarray(cfg.depth_weight * ga, dtype=np.float32)
            g = ks.render_backward(inputs, result, grad_img, g_alpha, g_depth, want_camera=update_pose)
            g = {k: x.numpy() for k, x in g.items()}
            adam.step({"means": g["means"], "log_scales": g["log_scales"], "quats": g["quats"],
                       "opacity_logits": g["opacity_logits"], "sh_dc": np.ascontiguousarray(g["sh"][:, :1]),
                       "sh_rest": np.ascontiguousarray(g["sh"][:, 1:])}, params=model.arrays())
            if update_pose:
                frac = (it - cfg.pose_start) / max(cfg.iterations - cfg.pose_start, 1)
                lr_pose = pose_lr0 * cfg.pose_lr_final ** frac
                delta = pose_adam.step(v, g["pose"].astype(np.float64), lr_pose)
                current[v] = _apply(delta, current[v])
                rot_steps.append(float(np.degrees(np.linalg.norm(delta[3:]))))
            losses.append(float(loss))
    return model, current, SplatJointLog(losses, rot_steps, time.perf_counter() - t0, degree)


@dataclass
class PolishLog:
    cost_before: np.ndarray  # (N,) 0.5 |r|^2 per view at the starting poses
    cost_after: np.ndarray
    steps: np.ndarray  # (N,) accepted LM steps per view
    seconds: float


def _render_rgb(inputs: Any, T: np.ndarray, K: np.ndarray, W: int, H: int, background: np.ndarray, sh_degree: int,
                antialiased: bool = False, dilation: float | None = None):
    return ks.render(inputs, ks.SplatCamera(T, K, W, H), background, sh_degree=sh_degree, antialiased=antialiased,
                     dilation=dilation)


def pose_jacobian(inputs: Any, T: np.ndarray, K: np.ndarray, W: int, H: int, background: np.ndarray,
                  sh_degree: int, h: float = 1e-3, antialiased: bool = False,
                  dilation: float | None = None) -> np.ndarray:
    """J (H W 3, 6): the rendered image's directional derivatives along the six left-perturbation axes
    (translation first), by central differences of the forward render with step h (radians for the
    rotation, scene units for the translation). Used only for the Gauss-Newton curvature J^T J; the
    gradient J^T r comes from the exact backward."""
    cols = []
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        plus = _render_rgb(inputs, ks.se3_exp(e) @ T, K, W, H, background, sh_degree, antialiased,
                           dilation).rgb.numpy()
        minus = _render_rgb(inputs, ks.se3_exp(-e) @ T, K, W, H, background, sh_degree, antialiased,
                            dilation).rgb.numpy()
        cols.append((plus.astype(np.float64) - minus).ravel() / (2 * h))
    return np.stack(cols, axis=1)


def polish_poses(model: GaussianModel, w2c: np.ndarray, K: np.ndarray, images: np.ndarray, *, sh_degree: int,
                 iterations: int = 10, background: Any = (0.0, 0.0, 0.0), tol_deg: float = 1e-4,
                 antialiased: bool = False, device: Any = None,
                 dilation: float | None = None) -> tuple[np.ndarray, PolishLog]:
    """Every view's world-to-camera pose refined alone against the FIXED splat model by Levenberg-Marquardt
    on the photometric cost 0.5 |I(T) - image|^2 (module docstring). Returns (w2c (N, 4, 4), log)."""
    images = np.ascontiguousarray(images, dtype=np.float32)
    _check_inputs(model, w2c, K, images)
    if not (isinstance(iterations, int) and iterations >= 0):
        raise ValueError(f"iterations: expected an integer >= 0, got {iterations!r}")
    n, H, W = images.shape[:3]
    bg = np.asarray(background, dtype=np.float32)
    inputs = model.inputs(device)
    out = np.array([ks.SplatCamera(T, K, W, H).viewmat for T in np.asarray(w2c, dtype=np.float64)])
    before, after, steps = np.zeros(n), np.zeros(n), np.zeros(n, dtype=int)
    t0 = time.perf_counter()
    with A.value_checks(False):
        for v in range(n):
            T = out[v]
            result = _render_rgb(inputs, T, K, W, H, bg, sh_degree, antialiased, dilation)
            r = result.rgb.numpy().astype(np.float64) - images[v]
            cost = 0.5 * float(np.sum(r * r))
            before[v] = cost
            lam = 1e-3
            for _ in range(iterations):
                g = ks.render_backward(inputs, result, np.ascontiguousarray(r, dtype=np.float32),
                                       want_camera=True)["pose"].numpy().astype(np.float64)
                J = pose_jacobian(inputs, T, K, W, H, bg, sh_degree, antialiased=antialiased, dilation=dilation)
                JtJ = J.T @ J
                accepted = False
                for _try in range(8):
                    delta = -np.linalg.solve(JtJ + lam * np.diag(np.diag(JtJ)) + 1e-12 * np.eye(6), g)
                    T_new = _apply(delta, T)
                    res_new = _render_rgb(inputs, T_new, K, W, H, bg, sh_degree, antialiased, dilation)
                    r_new = res_new.rgb.numpy().astype(np.float64) - images[v]
                    cost_new = 0.5 * float(np.sum(r_new * r_new))
                    if cost_new < cost:
                        T, result, r, cost, accepted = T_new, res_new, r_new, cost_new, True
                        lam = max(lam / 3.0, 1e-6)
                        steps[v] += 1
                        break
                    lam *= 4.0
                if not accepted or np.degrees(np.linalg.norm(delta[3:])) < tol_deg:
                    break
            out[v], after[v] = T, cost
    return out, PolishLog(before, after, steps, time.perf_counter() - t0)


def refine_pose(model: GaussianModel, w2c: np.ndarray, K: np.ndarray, image: np.ndarray, *, iterations: int = 200,
                lr_rot: float = 2e-3, lr_trans: float = 2e-3, lr_final: float = 0.05, sh_degree: int = 0,
                device: Any = None) -> tuple[np.ndarray, list[float]]:
    """One view's world-to-camera pose refined against a FIXED splat model by Adam on the left
    perturbation (module docstring), photometric L2 loss mean |I - image|^2. Returns (w2c, losses)."""
    image = np.ascontiguousarray(image, dtype=np.float32)
    _check_inputs(model, np.asarray(w2c)[None], K, image[None] if image.ndim == 3 else image)
    if not (isinstance(iterations, int) and iterations >= 1):
        raise ValueError(f"iterations: expected an integer >= 1, got {iterations!r}")
    current = ks.SplatCamera(w2c, K, image.shape[1], image.shape[0]).viewmat.copy()
    inputs = model.inputs(device)
    opt = PoseAdam(1)
    lr0 = np.array([lr_trans] * 3 + [lr_rot] * 3)
    losses = []
    with A.value_checks(False):
        for it in range(iterations):
            cam = ks.SplatCamera(current, K, image.shape[1], image.shape[0])
            result = ks.render(inputs, cam, sh_degree=sh_degree)
            diff = result.rgb.numpy().astype(np.float64) - image
            losses.append(float(np.mean(diff ** 2)))
            grad = (2.0 * diff / diff.size).astype(np.float32)
            g = ks.render_backward(inputs, result, grad, want_camera=True)["pose"].numpy().astype(np.float64)
            current = _apply(opt.step(0, g, lr0 * lr_final ** (it / max(iterations - 1, 1))), current)
    return current, losses
