"""Adaptive density control of 3DGS (Kerbl et al. 2023, Sec. 5), on a schedule scaled to the run.

Statistics, per splat, over the views in which it is visible (radius > 0): the norm
of the view-space gradient of its 2D mean in normalised device coordinates
(pixel gradient times (W/2, H/2), as the 3DGS rasteriser reports it), summed and
counted, and the largest screen radius.

Every `interval` iterations in [from_iter, until_iter):
  * splats whose mean gradient is >= grad_threshold are densified: those with
    max scale <= percent_dense * extent are CLONED (an identical copy), larger
    ones are SPLIT into 2 splats sampled from N(mean, Sigma) with scales / 1.6,
    replacing the original;
  * splats with opacity < min_opacity are pruned, and, after the first opacity
    reset, those with a screen radius > max_screen_size px or a world scale
    > 0.1 * extent;
  * every `reset_interval` iterations opacities are clamped to <= 0.01 (and
    their Adam moments zeroed).
`max_gaussians` caps the count for CPU budgets: when densification would exceed
it, only the candidates with the largest gradients are densified.

With `absgrad=True` (AbsGS: Ye et al., "AbsGS: Recovering Fine Details for 3D Gaussian
Splatting", 2024, as gsplat's DefaultStrategy(absgrad=True) has it) the statistic summed per view is
instead the norm of the per-component sums over pixels of |each pixel's term of dL/dmean2d|
(the rasteriser backward's "means2d_abs", kernels/splat/raster.py), in the same NDC scaling: terms of
opposite sign no longer cancel, so splats over fine detail whose pixels pull them both ways are
densified too. The statistic is larger than the plain one, so it has its own threshold:
ABSGRAD_GRAD_THRESHOLD = 0.0008, the value gsplat's DefaultStrategy documentation gives for absgrad
(against 0.0002); `DensifyConfig.absgs()` sets both.

The 3DGS schedule (30k iterations: densify from 500 to 15000 every 100, reset
every 3000, SH degree + 1 every 1000) is scaled by iterations / 30000, except
that densification runs at most every MIN_DENSIFY_INTERVAL iterations and
opacity resets at most every RESET_EVERY_DENSIFY densification intervals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kernels.optim import Adam
from research.splats.model import GaussianModel, logit

REFERENCE_ITERATIONS = 30_000
# Floors for short runs: statistics over at least this many views, and time for new
# splats to move apart before the next decision (at interval 2, clones of clones pile up).
MIN_DENSIFY_INTERVAL = 50
# 3DGS resets opacities every 30 densification steps; at least every 10 here (recovering
# from a reset takes ~100 Adam steps at the opacity learning rate).
RESET_EVERY_DENSIFY = 10


@dataclass(frozen=True)
class Schedule:
    iterations: int
    densify_from: int
    densify_until: int
    densify_interval: int
    reset_interval: int
    sh_interval: int

    @classmethod
    def scaled(cls, iterations: int) -> "Schedule":
        if iterations < 1:
            raise ValueError(f"iterations: expected a positive integer, got {iterations}")
        s = iterations / REFERENCE_ITERATIONS

        def at(x: float) -> int:
            return max(1, round(x * s))

        interval = max(at(100), MIN_DENSIFY_INTERVAL)
        return cls(iterations, at(500), at(15_000), interval, max(at(3_000), RESET_EVERY_DENSIFY * interval),
                   at(1_000))

    def sh_degree(self, iteration: int, max_degree: int = 3) -> int:
        return min(max_degree, iteration // self.sh_interval)

    def densify_now(self, iteration: int) -> bool:
        """After `iteration` iterations (1-based, as 3DGS counts)."""
        return self.densify_from < iteration < self.densify_until and iteration % self.densify_interval == 0

    def reset_now(self, iteration: int) -> bool:
        return iteration < self.densify_until and iteration % self.reset_interval == 0


# gsplat's grow_grad2d for absgrad (its DefaultStrategy docstring: "e.g., 0.0008"), not tuned here.
ABSGRAD_GRAD_THRESHOLD = 0.0008


@dataclass(frozen=True)
class DensifyConfig:
    grad_threshold: float = 0.0002
    percent_dense: float = 0.01
    min_opacity: float = 0.005
    max_screen_size: float = 20.0
    max_gaussians: int = 1_000_000
    absgrad: bool = False  # densify on AbsGS's absolute mean2d gradient (module docstring)

    def __post_init__(self) -> None:
        if not isinstance(self.absgrad, bool):
            raise ValueError(f"absgrad: expected True or False, got {self.absgrad!r}")
        if not self.grad_threshold > 0:
            raise ValueError(f"grad_threshold: expected a positive threshold, got {self.grad_threshold}")

    @classmethod
    def absgs(cls, **kwargs) -> "DensifyConfig":
        """AbsGS's density control: absgrad=True with gsplat's threshold for it, ABSGRAD_GRAD_THRESHOLD
        (other fields as given)."""
        return cls(**{"grad_threshold": ABSGRAD_GRAD_THRESHOLD, **kwargs, "absgrad": True})


class DensifyStats:
    def __init__(self, n: int) -> None:
        self.grad_sum = np.zeros(n)
        self.count = np.zeros(n)
        self.max_radii = np.zeros(n)

    def add(self, means2d_grad: np.ndarray, radii: np.ndarray, width: int, height: int) -> None:
        """One view's statistic: `means2d_grad` (N, 2) the pixel gradient of the 2D means (with absgrad
        the backward's "means2d_abs" in its place), `radii` the projection's."""
        visible = radii > 0
        ndc = means2d_grad * np.array([0.5 * width, 0.5 * height])
        self.grad_sum[visible] += np.linalg.norm(ndc[visible], axis=1)
        self.count[visible] += 1
        self.max_radii[visible] = np.maximum(self.max_radii[visible], radii[visible])

    def mean_grad(self) -> np.ndarray:
        return np.where(self.count > 0, self.grad_sum / np.maximum(self.count, 1), 0.0)


def _quat_to_rotmats(q: np.ndarray) -> np.ndarray:
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def densify_and_prune(model: GaussianModel, adam: Adam, stats: DensifyStats, extent: float, cfg: DensifyConfig,
                      rng: np.random.Generator, prune_screen: bool) -> tuple[GaussianModel, dict[str, int]]:
    """One densification step (module docstring); returns the new model and the counts of each edit.

    `adam` is edited to match the new rows; `stats` must be reset by the caller.
    """
    grads = stats.mean_grad()
    max_scale = np.exp(model.log_scales).max(axis=1)
    candidates = np.flatnonzero(grads >= cfg.grad_threshold)
    room = max(0, cfg.max_gaussians - model.n)
    small = max_scale[candidates] <= cfg.percent_dense * extent
    # A clone adds one splat, a split adds one net (two replace one).
    if len(candidates) > room:
        candidates = candidates[np.argsort(-grads[candidates], kind="stable")[:room]]
        small = max_scale[candidates] <= cfg.percent_dense * extent
    clone_idx, split_idx = candidates[small], candidates[~small]

    clones = model.select(clone_idx)
    split_src = model.select(np.repeat(split_idx, 2))
    if len(split_idx):
        stds = np.exp(split_src.log_scales.astype(np.float64))
        samples = rng.normal(0.0, 1.0, stds.shape) * stds
        R = _quat_to_rotmats(split_src.quats.astype(np.float64))
        split_src.means = (np.einsum("nij,nj->ni", R, samples) + split_src.means).astype(np.float32)
        split_src.log_scales = (split_src.log_scales - np.log(1.6)).astype(np.float32)
    n0 = model.n
    model = model.append(clones).append(split_src)
    adam.append(len(clone_idx) + 2 * len(split_idx))

    replaced = np.zeros(model.n, dtype=bool)
    replaced[split_idx] = True
    opac = model.opacities
    prune = opac < cfg.min_opacity
    if prune_screen:
        radii = np.concatenate([stats.max_radii, np.zeros(model.n - n0)])
        prune |= radii > cfg.max_screen_size
        prune |= np.exp(model.log_scales).max(axis=1) > 0.1 * extent
    keep = ~replaced & ~prune
    model = model.select(keep)
    adam.select(keep)
    return model, {"cloned": len(clone_idx), "split": len(split_idx), "pruned": int((prune & ~replaced).sum())}


def reset_opacity(model: GaussianModel, adam: Adam, value: float = 0.01) -> None:
    model.opacity_logits = np.minimum(model.opacity_logits, np.float32(logit(value)))
    adam.reset("opacity_logits")
