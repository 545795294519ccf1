"""Adam with one learning rate per parameter group, resizable as splats are added and removed.

The update is PyTorch's Adam (which 3DGS uses), elementwise per group p with gradient g:
    m <- b1 m + (1 - b1) g,   v <- b2 v + (1 - b2) g^2,   t <- t + 1,
    p <- p - lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps),
with 3DGS's betas (0.9, 0.999) and eps 1e-15. Densification appends rows with zero
moments and removes rows with their moments; the step count t is per group, as in
3DGS (whose optimiser keeps its state across these edits). The position learning
rate decays log-linearly from `lr_init` to `lr_final` (3DGS's get_expon_lr_func).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from research.splats.model import GaussianModel


@dataclass(frozen=True)
class LearningRates:
    """3DGS defaults (arguments/__init__.py); position rates are multiplied by the scene extent."""

    means_init: float = 0.00016
    means_final: float = 0.0000016
    sh_dc: float = 0.0025
    sh_rest: float = 0.0025 / 20.0
    opacity_logits: float = 0.05
    log_scales: float = 0.005
    quats: float = 0.001


def expon_lr(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """Log-linear interpolation from lr_init (step 0) to lr_final (step max_steps and after)."""
    t = min(max(step / max(max_steps, 1), 0.0), 1.0)
    return math.exp(math.log(lr_init) * (1.0 - t) + math.log(lr_final) * t)


class Adam:
    def __init__(self, model: GaussianModel, lrs: dict[str, float], betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-15) -> None:
        unknown = set(lrs) ^ set(model.names())
        if unknown:
            raise ValueError(f"lrs: expected one rate per parameter {model.names()}, mismatch {sorted(unknown)}")
        self.lrs = dict(lrs)
        self.b1, self.b2 = betas
        self.eps = eps
        self.m = {k: np.zeros_like(v) for k, v in model.arrays().items()}
        self.v = {k: np.zeros_like(v) for k, v in model.arrays().items()}
        self.t = {k: 0 for k in model.names()}

    def step(self, model: GaussianModel, grads: dict[str, np.ndarray]) -> None:
        """Update `model` in place from `grads` (one array per parameter, like the model's)."""
        for name in model.names():
            p, g = getattr(model, name), grads[name]
            if g.shape != p.shape:
                raise ValueError(f"grads[{name!r}]: expected shape {p.shape}, got {g.shape}")
            m, v = self.m[name], self.v[name]
            m *= self.b1
            m += (1.0 - self.b1) * g
            v *= self.b2
            v += (1.0 - self.b2) * g * g
            self.t[name] += 1
            t = self.t[name]
            denom = np.sqrt(v) / math.sqrt(1.0 - self.b2**t) + self.eps
            p -= (self.lrs[name] / (1.0 - self.b1**t)) * m / denom

    def select(self, index: np.ndarray) -> None:
        """Keep the moments of rows `index` (a boolean mask or indices), as the model does."""
        for name in self.m:
            self.m[name] = self.m[name][index]
            self.v[name] = self.v[name][index]

    def append(self, n: int) -> None:
        """Zero moments for `n` new rows at the end."""
        for name in self.m:
            z = np.zeros((n,) + self.m[name].shape[1:], dtype=self.m[name].dtype)
            self.m[name] = np.concatenate([self.m[name], z])
            self.v[name] = np.concatenate([self.v[name], z])

    def reset(self, name: str) -> None:
        self.m[name][:] = 0.0
        self.v[name][:] = 0.0
