"""Fitting an unbounded radiance field: mip-NeRF 360's contraction with a proposal sampler.

The main field and a small proposal field are both ContractedFields (kernels.volume.contract:
contract((x - centre) / radius), L2 norm, on [-2, 2]^3), so they cover all of space. Per iteration
(mip-NeRF 360, Barron et al. 2022; nerfacc's PropNetEstimator, Li et al. 2023):
  1. draw `batch_rays` pixels from all training views (seeded); targets are the sRGB pixels
     (opaque photographs and renders; over black where alpha < 1);
  2. proposal intervals: K + 1 edges uniform in s in [0, 1] (the interior ones shifted by one
     jitter per ray), mapped to distances by the s-space spacing (kernels.volume.contract.s_to_t:
     linear up to `tau`, disparity beyond, out to `far`); the proposal density at the interval
     midpoints gives weights q (kernels.volume.proposal.interval_weights);
  3. main intervals: M + 1 edges resampled from (s, q) by inverse-CDF (kernels.volume.proposal.
     resample; no gradient, as in nerfacc), the main field rendered at their t-midpoints
     (kernels.volume.render_samples over a black background) and its MSE backpropagated into it;
  4. the proposal's loss `interlevel_weight` * mean_r interlevel(s', w, s, q), with the main weights
     w held constant (mip-NeRF 360's stop-gradient), backpropagated through the weights to the
     proposal densities and the proposal field;
  5. one Adam step of each field (kernels.optim.Adam), learning rates decayed as research.nerf.train.
mip-NeRF 360's distortion loss, its second proposal round and nerfacc's proposal annealing are not
used (one proposal round, to keep the CPU cost small).

Rendering a test view runs steps 2-3 without jitter. The depth is the expected z-depth over the main
samples (their t-midpoints times the ray's cosine to the optical axis).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from kernels import _arrays as A
from kernels.optim import Adam
from kernels.volume import Workspace, render_backward, render_samples
from kernels.volume.contract import CONTRACTED_BOX, ContractedField, s_to_t
from kernels.volume.proposal import (DEFAULT_PADDING, interlevel_loss, interlevel_loss_backward, interval_weights,
                                     interval_weights_backward, resample)
from kernels.volume.sampling import dense_samples
from research.cameras import Camera
from research.nerf.render import Image, camera_rays
from research.nerf.train import RayBank, _lr_factor


@dataclass
class UnboundedConfig:
    iters: int = 1000
    batch_rays: int = 2048
    lr: float = 1e-2  # nerfacc's unbounded example, both fields
    lr_proposal: float = 1e-2
    betas: tuple[float, float] = (0.9, 0.99)
    adam_eps: float = 1e-15
    n_proposal: int = 64  # K proposal intervals per ray
    n_main: int = 32  # M main intervals per ray
    near: float = 0.05  # ray distances, world units
    far: float = 1e3
    tau: float = 1.0  # the spacing's linear range (world units)
    padding: float = DEFAULT_PADDING
    interlevel_weight: float = 1.0  # mip-NeRF 360's coefficient
    lr_decay_from: float = 0.5
    lr_decay_to: float = 0.1
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def validate(self) -> None:
        for name in ("iters", "batch_rays", "n_proposal", "n_main"):
            A.check_int(name, getattr(self, name), minimum=1)
        for name in ("lr", "lr_proposal", "tau", "padding", "far"):
            A.check_float(name, getattr(self, name), positive=True)
        if not 0.0 <= self.near < self.far:
            raise ValueError(f"near: expected 0 <= near < far ({self.far}), got {self.near}")
        A.check_float("interlevel_weight", self.interlevel_weight, nonnegative=True)


def contracted_hashgrid(center: Any, radius: float, *, n_levels: int, log2_table_size: int, max_resolution: int,
                        hidden: tuple[int, ...] = (64, 64), base_resolution: int = 16, density_bias: float = -1.0,
                        seed: int = 0) -> ContractedField:
    """A HashGridField on CONTRACTED_BOX behind the contraction of (x - center) / radius."""
    from kernels.volume import HashGridField

    inner = HashGridField(CONTRACTED_BOX, n_levels=n_levels, n_features=2, log2_table_size=log2_table_size,
                          base_resolution=base_resolution, max_resolution=max_resolution, hidden=hidden,
                          density_bias=density_bias, seed=seed)
    return ContractedField(inner, center, radius)


@dataclass
class _Pass:
    """One batch through the proposal and the main field (wp.arrays and NumPy arrays)."""

    s_prop: np.ndarray
    prop_points: np.ndarray
    prop_out: Any
    prop_delta: np.ndarray
    q: np.ndarray
    s_main: np.ndarray
    main_delta: np.ndarray
    result: Any


def _edges_uniform(n_rays: int, k: int, rng: np.random.Generator | None, dtype: Any) -> np.ndarray:
    s = np.broadcast_to(np.linspace(0.0, 1.0, k + 1), (n_rays, k + 1)).copy()
    if rng is not None and k > 1:  # one shift per ray of the interior edges, within half an interval
        s[:, 1:-1] += rng.uniform(-0.5, 0.5, (n_rays, 1)) / k
    return s.astype(dtype)


def _midpoints(o: np.ndarray, d: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mid = 0.5 * (t[:, 1:] + t[:, :-1])
    return mid, np.diff(t, axis=1)


def _forward(main: ContractedField, prop: ContractedField, o: np.ndarray, d: np.ndarray, zs: np.ndarray,
             cfg: UnboundedConfig, rng: np.random.Generator | None, seed: int, workspace: Workspace | None,
             keep_factor: bool) -> _Pass:
    n = o.shape[0]
    np_t = o.dtype
    s_prop = _edges_uniform(n, cfg.n_proposal, rng, np_t)
    t_prop = s_to_t(s_prop, cfg.near, cfg.far, cfg.tau)
    mid, delta = _midpoints(o, d, t_prop)
    points = (o[:, None, :] + mid[..., None] * d[:, None, :]).reshape(-1, 3)
    prop_out = prop.forward(points)
    q = interval_weights(np.asarray(prop_out.sigma).reshape(n, -1), delta)
    s_main = resample(s_prop, q, cfg.n_main, padding=cfg.padding, jitter=rng is not None, seed=seed)
    t_main = s_to_t(s_main, cfg.near, cfg.far, cfg.tau)
    mid_m, delta_m = _midpoints(o, d, t_main)
    samples = dense_samples(o, d, np.ascontiguousarray(mid_m), np.ascontiguousarray(delta_m), zs, device=main.device)
    result = render_samples(main, samples, background=(0.0, 0.0, 0.0), workspace=workspace, keep_factor=keep_factor)
    return _Pass(s_prop, points, prop_out, delta, q, s_main, delta_m, result)


def train_unbounded(main: ContractedField, prop: ContractedField, bank: RayBank, cfg: UnboundedConfig,
                    progress: bool = True, desc: str = "unbounded") -> dict[str, Any]:
    """Fit `main` and `prop` to `bank` in place (module docstring); the loss curves and seconds.

    NumPy's BLAS runs on one thread, as in research.nerf.train.train (its reason)."""
    cfg.validate()
    for name in ("origins", "dirs", "z_scale", "rgba"):
        A.check_finite(f"bank.{name}", getattr(bank, name))
    with threadpool_limits(limits=1, user_api="blas"):
        return _train(main, prop, bank, cfg, progress, desc)


def _train(main: ContractedField, prop: ContractedField, bank: RayBank, cfg: UnboundedConfig, progress: bool,
           desc: str) -> dict[str, Any]:
    rng = np.random.default_rng(cfg.seed)
    opt = Adam(main.params, cfg.lr, cfg.betas, cfg.adam_eps)
    opt_p = Adam(prop.params, cfg.lr_proposal, cfg.betas, cfg.adam_eps)
    base, base_p = dict(opt.lr), dict(opt_p.lr)
    workspace = Workspace(main.device)
    losses, prop_losses = [], []
    t0 = time.perf_counter()
    for it in tqdm(range(cfg.iters), desc=desc, disable=not progress, mininterval=2.0):
        with A.value_checks(it == 0):
            idx = rng.integers(0, len(bank), cfg.batch_rays)
            o, d, zs = bank.origins[idx], bank.dirs[idx], bank.z_scale[idx]
            target = bank.rgba[idx, :3]  # premultiplied sRGB: over black
            p = _forward(main, prop, o, d, zs, cfg, rng, cfg.seed * 1_000_003 + it, workspace, True)
            diff = p.result.rgb.numpy().astype(np.float64) - target
            losses.append(float(np.mean(diff**2)))
            grads = render_backward(main, p.result, (2.0 * diff / diff.size).astype(o.dtype), workspace=workspace)
            f = _lr_factor(cfg, it)
            opt.lr = {k: v * f for k, v in base.items()}
            opt.step(grads)
            # The proposal: interlevel loss against the main weights (constants), back to its densities.
            w = interval_weights(p.result.field_out.sigma.numpy().reshape(cfg.batch_rays, -1), p.main_delta)
            per_ray = interlevel_loss(p.s_main, w, p.s_prop, p.q)
            prop_losses.append(float(per_ray.mean()))
            g_q = interlevel_loss_backward(p.s_main, w, p.s_prop, p.q,
                                           np.full(cfg.batch_rays, cfg.interlevel_weight / cfg.batch_rays, o.dtype))
            sigma_p = np.asarray(p.prop_out.sigma).reshape(cfg.batch_rays, -1)
            g_sigma = interval_weights_backward(sigma_p, p.prop_delta, g_q)
            grads_p = prop.backward(p.prop_points, None, p.prop_out, g_sigma.reshape(-1), None)
            opt_p.lr = {k: v * f for k, v in base_p.items()}
            opt_p.step(grads_p)
    return {"losses": losses, "interlevel": prop_losses, "train_s": time.perf_counter() - t0}


def render_image_unbounded(camera: Camera, main: ContractedField, prop: ContractedField, cfg: UnboundedConfig,
                           chunk: int = 8192) -> Image:
    """The view of `camera` (module docstring: no jitter); depth is the expected z-depth."""
    if not isinstance(camera, Camera):
        raise ValueError(f"camera: expected a research.cameras.Camera, got {type(camera).__name__}")
    o, d, zs = camera_rays(camera, A.NP_OF_WP[main.dtype])
    n = o.shape[0]
    rgb, depth, opacity = np.empty((n, 3)), np.empty(n), np.empty(n)
    workspace = Workspace(main.device)
    for s in range(0, n, chunk):
        e = min(s + chunk, n)
        p = _forward(main, prop, o[s:e], d[s:e], zs[s:e], cfg, None, 0, workspace, False)
        rgb[s:e], depth[s:e], opacity[s:e] = (p.result.rgb.numpy(), p.result.depth.numpy(),
                                              p.result.opacity.numpy())
    h, w = camera.height, camera.width
    return Image(rgb.reshape(h, w, 3), depth.reshape(h, w), opacity.reshape(h, w), n * cfg.n_main)
