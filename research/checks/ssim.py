"""Gradient checks of the SSIM kernel (kernels/ssim.py), float64.

SSIM is smooth wherever its denominators are positive (always, with C1, C2 > 0),
so random images need no screening. The inputs are a random image y and a
perturbed copy x (the regime of a loss near convergence) plus, in the second
seed, two independent images (far from convergence), with 3 channels and a
size that is not a multiple of the window.
"""

from __future__ import annotations

import numpy as np

from kernels import ssim as kssim
from research.gradcheck import GradcheckResult, check_vjp, register_check


def ssim_map_fn(data_range: float = 1.0):
    def f(x, y):
        return kssim.ssim_map(x, y, data_range=data_range).map

    def vjp(inputs, cot):
        state = kssim.ssim_map(inputs["x"], inputs["y"], data_range=data_range)
        dx, dy = kssim.ssim_map_backward(state, cot)
        return {"x": dx, "y": dy}

    return f, vjp


def check_ssim(seed: int, independent: bool, data_range: float = 1.0) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    y = rng.uniform(0.0, data_range, (13, 17, 3))
    x = rng.uniform(0.0, data_range, y.shape) if independent else y + rng.normal(0.0, 0.05 * data_range, y.shape)
    f, vjp = ssim_map_fn(data_range)
    return check_vjp(f, vjp, {"x": x, "y": y}, seed=seed,
                     name=f"ssim.map[seed={seed},{'independent' if independent else 'near'},L={data_range}]")


@register_check("ssim.map")
def ssim_checks() -> list[GradcheckResult]:
    return check_ssim(0, False) + check_ssim(1, True) + check_ssim(2, False, data_range=2.0)
