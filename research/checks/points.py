"""Gradient checks of the chamfer distance (kernels/points/chamfer.py), float64, both clouds.

CD(X, Y) is smooth away from ties of a nearest neighbour; at a tie it has a kink (the gradient is one-
sided there). The clouds are screened so that the finite-difference steps (eps = 1e-6) never change a
nearest neighbour: for every point the second-nearest squared distance exceeds the nearest by at
least GAP, far more than a step can move either (|d d2| <= 2 |x - y| eps + eps^2, about 1e-5 here).
Three seeds: overlapping clouds of unequal sizes, clouds offset from each other, and clouds of very
different sizes (one point of Y the nearest of many x).
"""

from __future__ import annotations

import numpy as np

from kernels import points as kp
from kernels.reference.points import sq_dists
from research.gradcheck import GradcheckResult, check_vjp, register_check

GAP = 1e-3


def _well_separated(x: np.ndarray, y: np.ndarray) -> bool:
    d2 = sq_dists(x, y)
    for d in (d2, d2.T):
        two = np.sort(d, axis=1)[:, :2]
        if np.min(two[:, 1] - two[:, 0]) < GAP:
            return False
    return True


def screened_clouds(seed: int, n: int, m: int, shift: float) -> tuple[np.ndarray, np.ndarray]:
    """Random normal clouds X (n, 3), Y (m, 3) + shift whose nearest neighbours have a margin GAP."""
    rng = np.random.default_rng(seed)
    while True:
        x = rng.normal(size=(n, 3))
        y = rng.normal(size=(m, 3)) * 0.8 + shift
        if _well_separated(x, y):
            return x, y


def chamfer_fn():
    def f(x, y):
        return np.array([kp.chamfer_distance(x, y).value])

    def vjp(inputs, cot):
        res = kp.chamfer_distance(inputs["x"], inputs["y"])
        return kp.chamfer_backward(inputs["x"], inputs["y"], res, float(cot[0]))

    return f, vjp


def check_chamfer(seed: int, n: int, m: int, shift: float) -> list[GradcheckResult]:
    x, y = screened_clouds(seed, n, m, shift)
    f, vjp = chamfer_fn()
    return check_vjp(f, vjp, {"x": x, "y": y}, seed=seed, name=f"points.chamfer[seed={seed},{n}x{m},shift={shift}]")


@register_check("points.chamfer")
def chamfer_checks() -> list[GradcheckResult]:
    return check_chamfer(0, 24, 17, 0.0) + check_chamfer(1, 20, 20, 1.5) + check_chamfer(2, 30, 4, 0.2)
