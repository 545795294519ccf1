"""Self-test of the gradient checker on an analytic function with a known gradient.

    f(x, y) = ( sin(x) * y**2,            shape (n,)   elementwise
                exp(x).sum() * y,         shape (n,)
                sum(x * y) )              shape ()

For cotangents (a, b, c) the VJP of <(a, b, c), f> is

    dx = a * cos(x) * y**2 + exp(x) * sum(b * y) + c * y
    dy = 2 * a * sin(x) * y + b * exp(x).sum() + c * x
"""

from __future__ import annotations

import numpy as np

from research.gradcheck import GradcheckResult, check_vjp, register_check


def f(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.sin(x) * y**2, np.exp(x).sum() * y, np.sum(x * y)


def vjp(inputs: dict[str, np.ndarray], cot: tuple[np.ndarray, ...]) -> dict[str, np.ndarray]:
    x, y = inputs["x"], inputs["y"]
    a, b, c = cot
    dx = a * np.cos(x) * y**2 + np.exp(x) * np.sum(b * y) + c * y
    dy = 2.0 * a * np.sin(x) * y + b * np.exp(x).sum() + c * x
    return {"x": dx, "y": dy}


@register_check("selftest.known_gradient")
def known_gradient() -> list[GradcheckResult]:
    results = []
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        inputs = {"x": rng.uniform(-1.0, 1.0, 12), "y": rng.uniform(0.5, 1.5, 12)}
        results += check_vjp(f, vjp, inputs, seed=seed, name="selftest.known_gradient")
    return results
