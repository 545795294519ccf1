"""Per-image appearance in splat training: an affine colour transform or a bilateral grid per image.

Each training image v gets its own colour model, applied to the rendered image before the loss
(kernels/appearance.py: the slice, its adjoint):

  "affine"     a 3x4 affine transform of the linear render (a 1 x 1 x 1 grid): one gain matrix and
               offset per image, the simpler baseline;
  "bilateral"  a bilateral grid (Wang et al., SIGGRAPH 2024, as gsplat's example trainer): a
               (L, GH, GW) = (8, 16, 16) grid of such transforms, indexed by the pixel's position and
               its rendered luminance, so it can also model vignetting and tone curves.

Both start at the identity. The loss of an iteration is the 3DGS loss of the transformed render
plus, for the grid, gsplat's total-variation loss on ALL the grids (N, L, GH, GW, 12):

    TV = (1/N) sum over the axes a in (L, GH, GW) of  sum (G[.., t+1, ..] - G[.., t, ..])^2 / C_a,

C_a the number of entries of one grid's differences along a (12 x the sizes with a shortened by
one), times `tv_weight` = 10 (gsplat's default). Adam (kernels.optim.Adam, eps 1e-15) steps every
grid each iteration at gsplat's rate: 2e-3 times a linear warm-up from 0.01 to 1 over the first
1/30 of the iterations (gsplat: 1000 of 30000) and times 0.01^(t / iterations) (its exponential
decay to 1 % at the end). The grid size, TV weight and rates are gsplat's published defaults, used as
they are for both models; nothing here was tuned on drlab's data.

Held-out views have no appearance of their own: they are rendered with the identity (as gsplat
evaluates), and `corrected_psnr` reports beside it the PSNR after the per-image affine transform
that best fits the render to the target (least squares in linear RGB, then clipped and sRGB-encoded
as research.metrics' protocol), the "colour-corrected" score of the bilateral-grid evaluation that
separates geometry from a global colour offset the held-out view cannot know.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from kernels.appearance import ENTRIES, bilateral_slice, bilateral_slice_backward, identity_grid
from kernels.optim import Adam

KINDS = ("none", "affine", "bilateral")
GRID_SHAPE = (8, 16, 16)  # (L, GH, GW): gsplat's grid_W (guidance) = 8, grid_Y = grid_X = 16
TV_WEIGHT = 10.0  # gsplat's example trainer
LR = 2e-3
EPS = 1e-15
WARMUP_FRACTION = 1000 / 30000  # gsplat: 1000 warm-up steps of its 30000
FINAL_FACTOR = 0.01  # the exponential decay's factor at the last iteration


@dataclass(frozen=True)
class AppearanceConfig:
    kind: str = "none"  # "none", "affine" (one 3x4 transform per image) or "bilateral" (a grid of them)
    grid: tuple[int, int, int] = GRID_SHAPE
    tv_weight: float = TV_WEIGHT
    lr: float = LR

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"appearance.kind: expected one of {', '.join(KINDS)}, got {self.kind!r}")
        if len(self.grid) != 3 or any(isinstance(s, bool) or not isinstance(s, int) or s < 1 for s in self.grid):
            raise ValueError(f"appearance.grid: expected three sizes (L, GH, GW) >= 1, got {self.grid!r}")
        if not (math.isfinite(self.tv_weight) and self.tv_weight >= 0):
            raise ValueError(f"appearance.tv_weight: expected a finite weight >= 0, got {self.tv_weight!r}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"appearance.lr: expected a positive learning rate, got {self.lr!r}")

    @property
    def shape(self) -> tuple[int, int, int]:
        return (1, 1, 1) if self.kind == "affine" else tuple(self.grid)


def total_variation(grids: np.ndarray) -> tuple[float, np.ndarray]:
    """(TV, dTV/dgrids) of gsplat's total-variation loss (module docstring) for grids (N, L, GH, GW, 12)."""
    grids = np.asarray(grids)
    if grids.ndim != 5 or grids.shape[-1] != ENTRIES or grids.shape[0] < 1:
        raise ValueError(f"grids: expected (N, L, GH, GW, {ENTRIES}) with N >= 1, got shape {grids.shape}")
    n = grids.shape[0]
    g = grids.astype(np.float64)
    value, grad = 0.0, np.zeros_like(g)
    for axis in (1, 2, 3):
        if g.shape[axis] < 2:
            continue
        d = np.diff(g, axis=axis)
        count = d[0].size
        value += float((d * d).sum()) / count
        dd = 2.0 * d / (count * n)
        lo = [slice(None)] * 5
        hi = [slice(None)] * 5
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        grad[tuple(hi)] += dd
        grad[tuple(lo)] -= dd
    return value / n, grad.astype(grids.dtype)


def lr_at(step: int, iterations: int, lr: float = LR) -> float:
    """gsplat's bilateral-grid rate at 0-based step `step` of `iterations` (module docstring)."""
    warmup = max(1, round(WARMUP_FRACTION * iterations))
    linear = 0.01 + 0.99 * min(step / warmup, 1.0)
    return lr * linear * FINAL_FACTOR ** (step / max(iterations, 1))


class Appearance:
    """The per-image colour models of one training run: `apply` a view's to its render, then `step`."""

    def __init__(self, cfg: AppearanceConfig, n_images: int, iterations: int, device: Any = None) -> None:
        if cfg.kind == "none":
            raise ValueError("cfg: kind 'none' has no parameters (train without an Appearance)")
        self.cfg, self.iterations, self.device = cfg, int(iterations), device
        self.grids = np.ascontiguousarray(np.broadcast_to(identity_grid(cfg.shape), (n_images, *cfg.shape, ENTRIES)))
        self.adam = Adam({"grids": self.grids}, lr=cfg.lr, betas=(0.9, 0.999), eps=EPS)
        self._last: tuple[int, np.ndarray] | None = None
        self.tv = 0.0

    def apply(self, view: int, rgb: np.ndarray) -> np.ndarray:
        """View `view`'s transform applied to its render `rgb` (H, W, 3) float32."""
        self._last = (view, rgb)
        return bilateral_slice(self.grids[view], rgb, device=self.device)

    def step(self, grad_out: np.ndarray, iteration: int) -> np.ndarray:
        """One Adam step of every grid from dL/d(the last `apply`'s output) and the TV loss; returns dL/drender."""
        if self._last is None:
            raise RuntimeError("Appearance.step: call apply first")
        view, rgb = self._last
        d = bilateral_slice_backward(self.grids[view], rgb, grad_out, device=self.device)
        grad = np.zeros_like(self.grids)
        grad[view] = d["grid"]
        if self.cfg.kind == "bilateral" and self.cfg.tv_weight > 0:
            tv, d_tv = total_variation(self.grids)
            self.tv = self.cfg.tv_weight * tv
            grad += np.float32(self.cfg.tv_weight) * d_tv
        self.adam.lr["grids"] = lr_at(iteration - 1, self.iterations, self.cfg.lr)
        self.adam.step({"grids": grad})
        self._last = None
        return d["rgb"]


def make(cfg: AppearanceConfig, n_images: int, iterations: int, device: Any = None) -> Appearance | None:
    """The run's Appearance, or None for kind "none"."""
    return None if cfg.kind == "none" else Appearance(cfg, n_images, iterations, device)


def affine_fit(render: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The 3x4 affine M minimising sum_p |M [render_p; 1] - target_p|^2 (linear least squares, float64)."""
    x = np.asarray(render, np.float64).reshape(-1, 3)
    y = np.asarray(target, np.float64).reshape(-1, 3)
    if x.shape != y.shape or not len(x):
        raise ValueError(f"render, target: expected two non-empty (H, W, 3) images of one shape, got "
                         f"{np.shape(render)} and {np.shape(target)}")
    design = np.concatenate([x, np.ones((len(x), 1))], axis=1)
    sol, *_ = np.linalg.lstsq(design, y, rcond=None)
    return sol.T


def corrected_psnr(render: np.ndarray, target: np.ndarray) -> float:
    """PSNR (research.metrics protocol: clipped, sRGB) of `render` after the best affine fit to `target`."""
    from research import metrics

    m = affine_fit(render, target)
    fitted = np.asarray(render, np.float64) @ m[:, :3].T + m[:, 3]
    return metrics.psnr(metrics.srgb_on_black(fitted.astype(np.float32)),
                        metrics.srgb_on_black(np.asarray(target, np.float32)))
