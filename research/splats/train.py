"""Fitting splats to posed images, and evaluating them (3DGS's train.py, on the Warp kernels).

Each iteration renders one training view (a fresh random permutation of the views
per epoch, as 3DGS), takes the L1 + D-SSIM loss against the ground truth, runs
the hand-written backward, steps Adam (per-parameter learning rates, position
rate decaying log-linearly), then gathers densification statistics and densifies,
prunes and resets opacities on the scaled 3DGS schedule (research.splats.densify); with
DensifyConfig(absgrad=True) (`DensifyConfig.absgs()`) the backward also returns AbsGS's absolute
mean2d gradient, and the statistics are gathered from it instead.
The active SH degree grows by one every `sh_interval` iterations up to 3.
The only ordering difference from 3DGS: the Adam step comes before (not after)
densification in an iteration, so new splats get their first step one iteration later.
With `strategy="mcmc"` the density control is instead 3DGS-MCMC's (research/splats/mcmc.py, in
gsplat's order): the opacity and scale regularisers' gradients join the rendered loss's before the
Adam step; after it, every refinement interval the dead splats are relocated and new ones added up
to `mcmc.cap_max`, and then every iteration the means get the opacity-gated noise (at the position
learning rate of the next step, as gsplat's scheduler hands it); no opacity reset, no pruning.
With `normal_weight` = lambda > 0 the loss gains lambda L_n, 2DGS's depth-normal consistency loss
(research/splats/geometry.py: the blended shortest-axis splat normals against the normals of the
rendered `normal_depth` map, "expected" or "median"), from iteration round(NORMAL_FROM * iterations)
on: 2DGS's lambda_n = 0.05 from iteration 7000 of 30000 (NORMAL_WEIGHT_2DGS, NORMAL_FROM); its
gradient joins the image's before the projection backward, and so the densification statistics.
With `filter_3d` = s > 0 the splats are rendered through Mip-Splatting's 3D smoothing filter
(research/splats/mip.py: its size from the training cameras, recomputed at the start, after every
densification and every densification interval; the gradients taken back through it), and the
returned model has the last filter baked into its scales and opacities.
With `appearance` of kind "affine" or "bilateral", each view's render passes through its own colour
model before the loss (research/splats/appearance.py: gsplat's bilateral grid, or one 3x4 affine per
image), whose Adam step runs before the splats' backward; TrainResult.appearance holds the models.

Every stage runs on one device: `train`, `evaluate`, `render_fps` and `ply_round_trip_identical`
take the Warp device (TrainResult.device is the one training used). The initial model is checked
once; the loop feeds the kernels its own outputs and runs with value checks off
(kernels._arrays.value_checks), the loss still checked finite every iteration.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from pathlib import Path
from typing import Any

import numpy as np
import warp as wp
from tqdm import tqdm

from kernels import _arrays as A
from kernels import splat as ks
from kernels.splat.modes import mode_id
from research import metrics
from research.cameras import Camera
from research.splats import ply
from research.splats.densify import DensifyConfig, DensifyStats, Schedule, densify_and_prune, reset_opacity
from research.splats import appearance, geometry, mcmc, mip
from research.splats.loss import LAMBDA_DSSIM, l1_dssim
from research.splats.model import GaussianModel, render, splat_camera
from research.splats.mcmc import MCMCConfig, MCMCSchedule
from research.splats.optim import LearningRates, expon_lr, make_adam

STRATEGIES = ("3dgs", "mcmc")
# 2DGS's depth-normal consistency weight and start (lambda_normal = 0.05 after 7000 of 30000 iterations).
NORMAL_WEIGHT_2DGS = 0.05
NORMAL_FROM = 7000 / 30000


@dataclass(frozen=True)
class TrainConfig:
    iterations: int = 3000
    max_sh_degree: int = 3
    lambda_dssim: float = LAMBDA_DSSIM
    lrs: LearningRates = field(default_factory=LearningRates)
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    antialiased: bool = False
    mode: str = ks.DEFAULT_MODE  # "3dgs" (the original code's conventions) or "gsplat" (kernels/splat/modes.py)
    dilation: float | None = None  # the projection's 2D low-pass variance (None: the mode's, 0.3)
    filter_3d: float = 0.0  # Mip-Splatting's 3D filter variance s (0: off; mip.PAPER_S = 0.2 is the paper's)
    seed: int = 0
    log_every: int = 50
    strategy: str = "3dgs"  # density control: "3dgs" (research.splats.densify, with `densify`) or "mcmc" (`mcmc`)
    mcmc: MCMCConfig = field(default_factory=MCMCConfig)
    # per-image colour model before the loss: none / affine / bilateral grid (research/splats/appearance.py)
    appearance: appearance.AppearanceConfig = field(default_factory=appearance.AppearanceConfig)
    normal_weight: float = 0.0  # lambda of 2DGS's depth-normal consistency loss (0: off; NORMAL_WEIGHT_2DGS)
    normal_depth: str = "expected"  # the depth map its normals come from: "expected" or "median"

    def __post_init__(self) -> None:
        mode_id(self.mode)  # ValueError naming `mode` before any work
        if self.strategy not in STRATEGIES:
            raise ValueError(f"strategy: expected one of {', '.join(STRATEGIES)}, got {self.strategy!r}")
        if not self.filter_3d >= 0:
            raise ValueError(f"filter_3d: expected a filter variance >= 0 (0: off), got {self.filter_3d}")
        if self.dilation is not None and not self.dilation >= 0:
            raise ValueError(f"dilation: expected a variance >= 0 or None, got {self.dilation}")
        if not self.normal_weight >= 0:
            raise ValueError(f"normal_weight: expected a weight >= 0 (0: off), got {self.normal_weight}")
        if self.normal_depth not in geometry.DEPTHS:
            raise ValueError(f"normal_depth: expected one of {', '.join(geometry.DEPTHS)}, got {self.normal_depth!r}")
        if self.densify.absgrad and self.strategy != "3dgs":
            raise ValueError(f"densify: absgrad=True is 3DGS density control's statistic, expected "
                             f"strategy='3dgs', got {self.strategy!r}")


@dataclass
class TrainResult:
    model: GaussianModel
    seconds: float
    history: list[dict]
    events: list[dict]
    sh_degree: int
    device: wp.Device  # the device training ran on: pass it to evaluate, render_fps, ...
    appearance: appearance.Appearance | None = None  # the trained per-image colour models (None: none)


def _check_views(cameras: list[Camera], images: np.ndarray) -> None:
    if len(cameras) == 0 or images.ndim != 4 or images.shape[0] != len(cameras) or images.shape[3] != 3:
        raise ValueError(f"images: expected (N={len(cameras)}, H, W, 3), got {images.shape}")
    for cam in cameras:
        if (cam.height, cam.width) != images.shape[1:3]:
            raise ValueError(f"cameras: a camera is {cam.width}x{cam.height}, images are "
                             f"{images.shape[2]}x{images.shape[1]}")


def train(model: GaussianModel, cameras: list[Camera], images: np.ndarray, extent: float, cfg: TrainConfig,
          *, progress: bool = True, device: Any = None) -> TrainResult:
    """Fit a copy of `model` to `images` (N, H, W, 3) linear RGB seen by `cameras` (module docstring),
    rendering on the Warp `device` (None: the CPU)."""
    _check_views(cameras, images)
    if not extent > 0:
        raise ValueError(f"extent: expected a positive scene scale, got {extent}")
    device = A.get_device(device)
    images = np.ascontiguousarray(images, dtype=np.float32)
    model = model.copy()  # Adam updates in place; the caller's model stays as it was
    model.inputs(device)  # checks the initial model once (values included) before the unchecked loop
    rng = np.random.default_rng(cfg.seed)
    sched = Schedule.scaled(cfg.iterations)
    use_mcmc = cfg.strategy == "mcmc"
    absgrad = cfg.densify.absgrad  # 3DGS strategy only (TrainConfig checks)
    msched = MCMCSchedule.scaled(cfg.iterations, cfg.mcmc)
    lr = cfg.lrs
    adam = make_adam(model, {"means": lr.means_init * extent, "log_scales": lr.log_scales, "quats": lr.quats,
                             "opacity_logits": lr.opacity_logits, "sh_dc": lr.sh_dc, "sh_rest": lr.sh_rest})
    stats = DensifyStats(model.n)
    background = np.asarray(cfg.background, dtype=np.float32)
    splat_cams = [splat_camera(c) for c in cameras]
    history, events, order = [], [], []
    use_normals = cfg.normal_weight > 0
    normal_from = round(NORMAL_FROM * cfg.iterations)
    zero = {"loss": 0.0, "l1": 0.0, "ssim": 0.0, **({"reg": 0.0} if use_mcmc else {}),
            **({"normal": 0.0} if use_normals else {}), "k": 0}
    running = dict(zero)
    t0 = time.perf_counter()
    bar = tqdm(range(1, cfg.iterations + 1), desc="fit splats", disable=not progress, mininterval=2.0)
    degree = 0
    sigma = mip.filter_sigma(model.means, cameras, cfg.filter_3d) if cfg.filter_3d > 0 else None
    app = appearance.make(cfg.appearance, len(cameras), cfg.iterations, device)
    with A.value_checks(False):
        for it in bar:
            adam.lr["means"] = expon_lr(it - 1, lr.means_init * extent, lr.means_final * extent, cfg.iterations)
            degree = sched.sh_degree(it, cfg.max_sh_degree)
            if not order:
                order = list(rng.permutation(len(cameras)))
            v = order.pop()
            inputs = _filtered(model, sigma).inputs(device) if sigma is not None else model.inputs(device)
            result = ks.render(inputs, splat_cams[v], background, sh_degree=degree, antialiased=cfg.antialiased,
                               mode=cfg.mode, dilation=cfg.dilation)
            rgb = result.rgb.numpy() if app is None else app.apply(v, result.rgb.numpy())
            loss, grad_img, parts = l1_dssim(rgb, images[v], cfg.lambda_dssim, device=device)
            if app is not None:  # the view's colour model and the grids' TV loss: Adam step, dL/drender back
                grad_img = app.step(grad_img, it)
            if not np.isfinite(loss):
                raise RuntimeError(f"iteration {it}: the loss is {loss}")
            if use_normals and it > normal_from:
                geo = geometry.render_geometry(inputs, splat_cams[v], background, depth=cfg.normal_depth,
                                               render=result)
                l_n = geometry.consistency_loss(geo)
                extra = geometry.consistency_backward(inputs, geo, cfg.normal_weight)
                g = geometry.render_backward_with(inputs, result, grad_img, extra, absgrad=absgrad)
                running["normal"] += l_n
                loss += cfg.normal_weight * l_n
            else:
                g = {k: x.numpy() for k, x in ks.render_backward(inputs, result, grad_img, absgrad=absgrad).items()}
            if sigma is not None:
                g["log_scales"], g["opacity_logits"] = mip.unfiltered_grads(
                    model.log_scales, model.opacity_logits, sigma, g["log_scales"], g["opacity_logits"])
            if use_mcmc:
                reg, d_logits, d_log_scales = mcmc.regularizer(model.opacity_logits, model.log_scales,
                                                               cfg.mcmc.opacity_reg, cfg.mcmc.scale_reg)
                g["opacity_logits"] = g["opacity_logits"] + d_logits.astype(np.float32)
                g["log_scales"] = g["log_scales"] + d_log_scales.astype(np.float32)
                running["reg"] += reg
            adam.step({"means": g["means"], "log_scales": g["log_scales"], "quats": g["quats"],
                       "opacity_logits": g["opacity_logits"], "sh_dc": np.ascontiguousarray(g["sh"][:, :1]),
                       "sh_rest": np.ascontiguousarray(g["sh"][:, 1:])}, params=model.arrays())
            refined = False
            if use_mcmc:
                if msched.refine_now(it):
                    n_before = model.n
                    model, counts = mcmc.refine(model, adam, cfg.mcmc, rng)
                    refined = True
                    events.append({"iteration": it, "before": n_before, "after": model.n, **counts})
                next_lr = expon_lr(it, lr.means_init * extent, lr.means_final * extent, cfg.iterations)
                mcmc.inject_noise(model, next_lr, cfg.mcmc.noise_lr, rng)
            elif it < sched.densify_until:
                cam = splat_cams[v]
                stats.add(g["means2d_abs" if absgrad else "means2d"], result.projection.radii.numpy(), cam.width,
                          cam.height)
                if sched.densify_now(it):
                    n_before = model.n
                    model, counts = densify_and_prune(model, adam, stats, extent, cfg.densify, rng,
                                                      prune_screen=it > sched.reset_interval)
                    stats = DensifyStats(model.n)
                    events.append({"iteration": it, "before": n_before, "after": model.n, **counts})
                if sched.reset_now(it):
                    reset_opacity(model, adam)
                    events.append({"iteration": it, "opacity_reset": True})
            if sigma is not None and (refined or len(sigma) != model.n or it % sched.densify_interval == 0):
                sigma = mip.filter_sigma(model.means, cameras, cfg.filter_3d)
            running["loss"] += loss
            running["l1"] += parts["l1"]
            running["ssim"] += parts["ssim"]
            running["k"] += 1
            if it % cfg.log_every == 0 or it == cfg.iterations:
                k = running.pop("k")
                history.append({"iteration": it, "gaussians": model.n, "sh_degree": degree,
                                **{key: val / k for key, val in running.items()}})
                running = dict(zero)
                bar.set_postfix(loss=f"{history[-1]['loss']:.4f}", n=model.n)
    if sigma is not None:
        model = _filtered(model, sigma)  # what the last iterations rendered, baked in
    return TrainResult(model, time.perf_counter() - t0, history, events, degree, device, app)


def _filtered(model: GaussianModel, sigma: np.ndarray) -> GaussianModel:
    """`model` with Mip-Splatting's 3D filter of size `sigma` (N,) in its scales and opacities."""
    log_scales, logits = mip.filtered(model.log_scales, model.opacity_logits, sigma)
    return GaussianModel(model.means, log_scales, model.quats, logits, model.sh_dc, model.sh_rest)


@dataclass
class Evaluation:
    psnr: float  # mean over views, sRGB-encoded, clipped to [0, 1]
    ssim: float
    psnr_linear: float  # mean over views, linear RGB clipped to [0, 1]
    per_view: list[dict]
    renders: np.ndarray  # (N, H, W, 3) linear


def evaluate(model: GaussianModel, cameras: list[Camera], images: np.ndarray, sh_degree: int,
             background=(0.0, 0.0, 0.0), antialiased: bool = False, device: Any = None,
             mode: str = ks.DEFAULT_MODE, dilation: float | None = None) -> Evaluation:
    """PSNR and SSIM (research.metrics) of renders against `images` (linear RGB, premultiplied on black).

    Both images are compared as research.metrics.EVAL_PROTOCOL says (clipped to [0, 1], then
    sRGB-encoded); the linear-space PSNR is reported beside it. Renders run on `device`, with the low-pass
    `dilation` of kernels.splat.render (None: the mode's).
    """
    _check_views(cameras, images)
    renders, per_view = [], []
    for cam, gt in zip(cameras, images):
        img = render(model, cam, sh_degree=sh_degree, background=background, antialiased=antialiased,
                     mode=mode, device=device, dilation=dilation).rgb.numpy()
        a, b = metrics.srgb_on_black(img), metrics.srgb_on_black(gt)
        per_view.append({"psnr": metrics.psnr(a, b), "ssim": metrics.ssim(a, b),
                         "psnr_linear": metrics.psnr(np.clip(img, 0, 1), np.clip(gt, 0, 1))})
        renders.append(img)
    mean = {k: float(np.mean([p[k] for p in per_view])) for k in per_view[0]}
    return Evaluation(mean["psnr"], mean["ssim"], mean["psnr_linear"], per_view, np.stack(renders))


def render_fps(model: GaussianModel, cameras: list[Camera], sh_degree: int, repeats: int = 3,
               antialiased: bool = False, device: Any = None, mode: str = ks.DEFAULT_MODE) -> float:
    """Frames per second of the forward render (projection, binning, sorting, rasterisation) on
    `device`, from the median time per view over `repeats` passes after a warm-up pass."""
    from research.bench import time_median

    device = A.get_device(device)
    inputs = model.inputs(device)
    cams = [splat_camera(c) for c in cameras]

    def one_pass() -> None:
        for cam in cams:
            ks.render(inputs, cam, sh_degree=sh_degree, antialiased=antialiased, mode=mode)

    return len(cams) / time_median(one_pass, repeats=repeats, sync=lambda: wp.synchronize_device(device))


def ply_round_trip_identical(path: Path, model: GaussianModel, camera: Camera, sh_degree: int,
                             device: Any = None) -> bool:
    """Save `model` as a PLY at `path`, load it back, and whether the reloaded model renders `camera`
    bit-identically to `model`, both on `device`."""
    ply.save_ply(path, model)
    reloaded = ply.load_ply(path)
    before = render(model, camera, sh_degree=sh_degree, device=device).rgb.numpy()
    return bool(np.array_equal(render(reloaded, camera, sh_degree=sh_degree, device=device).rgb.numpy(), before))
