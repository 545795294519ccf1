"""The optimiser settings of 3DGS: Adam (kernels.optim.Adam) with one learning rate per group.

The update is PyTorch's Adam (which 3DGS uses) with 3DGS's betas (0.9, 0.999) and eps 1e-15,
one step count per group. Densification appends rows with zero moments and removes rows with
their moments (`Adam.append`, `Adam.select`); the step counts stay, as in 3DGS (whose optimiser
keeps its state across these edits). The position learning rate decays log-linearly from
`lr_init` to `lr_final` (3DGS's get_expon_lr_func).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from kernels.optim import Adam
from research.splats.model import GaussianModel

BETAS = (0.9, 0.999)
EPS = 1e-15


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


def make_adam(model: GaussianModel, lrs: dict[str, float]) -> Adam:
    """Adam over the model's arrays (updated in place), one rate per parameter group."""
    return Adam(model.arrays(), lr=lrs, betas=BETAS, eps=EPS)
