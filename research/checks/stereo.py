"""Gradient checks of kernels.stereo: the feature correlation (both feature maps) and the soft-argmin.

Inputs are random and non-degenerate: standard-normal features over a
disparity range that runs past both image borders (so out-of-range cells are
exercised), and costs spread over a few temperatures so that the softmax is
neither flat nor saturated.
"""

from __future__ import annotations

import numpy as np

from kernels import stereo
from research.gradcheck import GradcheckResult, check_vjp, register_check

SEEDS = (0, 1, 2)


def check_feature_correlation(seed: int, shape: tuple[int, int, int] = (4, 3, 7),
                              drange: tuple[int, int] = (-2, 4)) -> list[GradcheckResult]:
    """corr = <F_L(x), F_R(x - d)> / sqrt(C) for features (C, H, W), against both F_L and F_R."""
    rng = np.random.default_rng(seed)
    dmin, dmax = drange
    inputs = {"feat_left": rng.standard_normal(shape), "feat_right": rng.standard_normal(shape)}

    def f(feat_left: np.ndarray, feat_right: np.ndarray) -> np.ndarray:
        return stereo.feature_correlation(feat_left, feat_right, dmin, dmax)

    def vjp(x: dict[str, np.ndarray], cot: np.ndarray) -> dict[str, np.ndarray]:
        return stereo.feature_correlation_backward(x["feat_left"], x["feat_right"], cot, dmin)

    return check_vjp(f, vjp, inputs, seed=seed, name="stereo.feature_correlation")


def check_soft_argmin(seed: int, shape: tuple[int, int, int] = (3, 6, 5), dmin: int = -1,
                      temperature: float = 0.7) -> list[GradcheckResult]:
    """d = sum_k d_k softmax(-C / T)_k, against the cost volume C."""
    rng = np.random.default_rng(seed)
    inputs = {"cost": rng.uniform(0.0, 2.0, shape)}

    def f(cost: np.ndarray) -> np.ndarray:
        return stereo.soft_argmin(cost, dmin, temperature)

    def vjp(x: dict[str, np.ndarray], cot: np.ndarray) -> dict[str, np.ndarray]:
        return stereo.soft_argmin_backward(x["cost"], dmin, cot, temperature)

    return check_vjp(f, vjp, inputs, seed=seed, name="stereo.soft_argmin")


@register_check("stereo.feature_correlation")
def feature_correlation() -> list[GradcheckResult]:
    return [r for seed in SEEDS for r in check_feature_correlation(seed)]


@register_check("stereo.soft_argmin")
def soft_argmin() -> list[GradcheckResult]:
    return [r for seed in SEEDS for r in check_soft_argmin(seed, temperature=(0.3, 0.7, 2.0)[seed % 3])]
