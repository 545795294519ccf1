"""Tracking: one frame's camera pose optimised against a fixed splat map (SplaTAM's tracking step).

The pose is the world-to-camera matrix T (OpenCV axes). Each iteration renders the map at T
(kernels.splat, SH degree 0), and over the silhouette S = {pixels with rendered alpha A > s_min
(0.9; SplaTAM uses 0.99 on maps optimised for longer) and measured depth > 0} takes

    L = w_d (1/|S|) sum_S |D/A - z|  +  w_c (1/(3|S|)) sum_S sum_c |C_c - I_c|,

with D the rendered depth output (D/A the expected z-depth, research.splats.loss.depth_loss), z the
measured depth, C the rendered colour (premultiplied on black) and I the frame's premultiplied
linear colour. Only well-reconstructed pixels are compared, so the unmapped part of a new frame
does not pull the pose. The gradient dL/dxi of the left perturbation T <- exp(xi^) T at xi = 0 is
the renderer's camera gradient (kernels/splat/__init__.py, render_backward(want_camera=True)).

Update: Adam (Kingma & Ba 2015, the PyTorch form with bias correction) on the 6-vector in the tangent
space at the current pose, one learning rate for the translation rho and one for the rotation phi:

    m <- b1 m + (1 - b1) g,  v <- b2 v + (1 - b2) g^2,  step = lr m_hat / (sqrt(v_hat) + eps),
    T <- exp(-step^) T.

A fixed budget of `iters` iterations; the pose returned is the iterate with the lowest loss (as
SplaTAM keeps the best candidate), together with the loss history so the caller can detect a
diverging track (research/slam/system.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from kernels import splat as ks
from kernels.rotation import checked_rigid
from research.splats.loss import depth_loss
from research.splats.model import GaussianModel


@dataclass(frozen=True)
class TrackConfig:
    """Tracking settings. The learning rates were picked from two pairs (0.02 / 0.005 and 0.03 / 0.01) on
    the first 10 frames of experiments/splat_slam.py's seed-0 sequence, and min_silhouette (0.9 against
    SplaTAM's 0.99) from the silhouette of that sequence's frame-0 map; the rest was set once, untuned."""

    iters: int = 40
    lr_trans: float = 0.03  # Adam step size of rho (scene units)
    lr_rot: float = 0.01  # Adam step size of phi (radians)
    depth_weight: float = 1.0
    color_weight: float = 0.5
    min_silhouette: float = 0.9
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-8

    def __post_init__(self) -> None:
        if int(self.iters) != self.iters or self.iters < 1:
            raise ValueError(f"iters: expected an integer >= 1, got {self.iters!r}")
        for name in ("lr_trans", "lr_rot"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a positive learning rate, got {v!r}")
        for name in ("depth_weight", "color_weight"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: expected a finite weight >= 0, got {v!r}")
        if self.depth_weight == 0 and self.color_weight == 0:
            raise ValueError("depth_weight, color_weight: expected at least one positive weight")
        if not 0.0 <= self.min_silhouette < 1.0:
            raise ValueError(f"min_silhouette: expected a value in [0, 1), got {self.min_silhouette!r}")


@dataclass
class TrackResult:
    w2c: np.ndarray  # (4, 4) the best iterate
    loss: float  # its loss
    losses: list[float] = field(default_factory=list)  # every iteration's loss, first = at the initial guess
    pixels: int = 0  # silhouette pixels at the best iterate


def host(x: Any) -> np.ndarray:
    """A render output as a NumPy array (renders of NumPy inputs already are; wp.arrays are copied)."""
    return x if isinstance(x, np.ndarray) else x.numpy()


def tracking_loss(result: ks.Render, rgb: np.ndarray, depth: np.ndarray, cfg: TrackConfig
                  ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, int]:
    """(L, dL/dC, dL/dA, dL/dD, |S|) of the module docstring's loss for a render of the map."""
    alpha, dep, col = host(result.alpha), host(result.depth), host(result.rgb)
    sil = (alpha > cfg.min_silhouette) & (depth > 0)
    m = int(sil.sum())
    g_rgb = np.zeros_like(col)
    if m == 0:
        return float("inf"), g_rgb, np.zeros_like(alpha), np.zeros_like(dep), 0
    ld, g_depth, g_alpha = depth_loss(dep, alpha, depth, sil, min_alpha=cfg.min_silhouette, kind="l1")
    diff = col[sil] - rgb[sil]
    lc = float(np.abs(diff).sum(dtype=np.float64) / (3 * m))
    g_rgb[sil] = (cfg.color_weight * np.sign(diff) / (3 * m)).astype(col.dtype)
    loss = cfg.depth_weight * ld + cfg.color_weight * lc
    return loss, g_rgb, cfg.depth_weight * g_alpha, cfg.depth_weight * g_depth, m


def track_frame(model: GaussianModel, w2c_init: np.ndarray, K: np.ndarray, width: int, height: int,
                rgb: np.ndarray, depth: np.ndarray, cfg: TrackConfig, device: Any = None) -> TrackResult:
    """Optimise the pose of one RGB-D frame (rgb (H, W, 3) premultiplied linear, depth (H, W), 0 = none)
    against the fixed map, from `w2c_init` (module docstring). float32 renders on `device`."""
    inputs = model.inputs(device)
    bg = np.zeros(3, dtype=np.float32)
    w2c = np.array(w2c_init, dtype=np.float64)
    m = np.zeros(6)
    v = np.zeros(6)
    lr = np.array([cfg.lr_trans] * 3 + [cfg.lr_rot] * 3)
    b1, b2 = cfg.betas
    best = TrackResult(w2c.copy(), float("inf"))
    for it in range(1, cfg.iters + 1):
        cam = ks.SplatCamera(w2c, K, width, height)
        res = ks.render(inputs, cam, bg, sh_degree=0)
        loss, g_rgb, g_alpha, g_depth, npix = tracking_loss(res, rgb, depth, cfg)
        if not np.isfinite(loss):
            if npix == 0:  # the map is not in view at all: nothing to track against
                best.losses.append(loss)
                break
            raise RuntimeError(f"tracking: the loss is {loss} at iteration {it}")
        best.losses.append(loss)
        if loss < best.loss:
            best.w2c, best.loss, best.pixels = w2c.copy(), loss, npix
        if it == cfg.iters:
            break
        g = np.asarray(ks.render_backward(inputs, res, g_rgb, g_alpha, g_depth, want_camera=True)["pose"],
                       dtype=np.float64)
        m = b1 * m + (1 - b1) * g
        v = b2 * v + (1 - b2) * g * g
        step = lr * (m / (1 - b1 ** it)) / (np.sqrt(v / (1 - b2 ** it)) + cfg.eps)
        w2c = ks.se3_exp(-step) @ w2c
        w2c = checked_rigid("w2c", w2c)  # the rotation nearest: removes the rounding repeated products accumulate
    return best
