"""Gradient checks of the ICP kernels (kernels/icp.py), float64: the pose Jacobians J of the residual rows
and the gradient g of the robust cost, each against central differences along the twist xi.

The source moves as p(xi) = exp(xi^) p (research.poses.se3.se3_exp, translation first), so
f(xi) = r(exp(xi^) p, q, n) and E(xi) = sum_i rho(e_i(xi)); the kernels' J and g are d/dxi at xi = 0.
J's check: the VJP of r with a cotangent c is sum_i J_i^T c_i (from icp_residuals); g's check: the VJP of
E with a cotangent c is c g (from normal_equations). Both metrics (point-to-point, point-to-plane) and the
three robust kernels. Huber's weight has a kink at e = c: its clouds are screened so that every e_i is at
least GAP away from c (a step eps = 1e-6 of xi moves e_i by far less here), so the cost is twice
differentiable along every finite-difference stencil. Three seeds each; offsets u_i of a few tenths so
that the Geman-McClure and Huber weights differ from 1.
"""

from __future__ import annotations

import numpy as np

from kernels import icp
from research.gradcheck import GradcheckResult, check_vjp, register_check
from research.poses.se3 import se3_exp

GAP = 1e-3
SCALE = {"none": 1.0, "huber": 0.3, "gm": 0.05}


def _moved(source: np.ndarray, xi: np.ndarray) -> np.ndarray:
    T = se3_exp(xi)
    return source @ T[:3, :3].T + T[:3, 3]


def correspondences(seed: int, n: int, plane: bool, robust: str) -> dict[str, np.ndarray]:
    """Random correspondences (source, target, normals or None) whose e_i avoid Huber's kink by GAP."""
    rng = np.random.default_rng(seed)
    c = SCALE[robust]
    while True:
        p = rng.normal(size=(n, 3)) * 2.0
        q = p + rng.normal(size=(n, 3)) * 0.3
        nrm = rng.normal(size=(n, 3))
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        e = np.abs(np.einsum("nc,nc->n", nrm, p - q)) if plane else np.linalg.norm(p - q, axis=1)
        if robust != "huber" or np.min(np.abs(e - c)) > GAP:
            return {"source": p, "target": q, "normals": nrm if plane else None}


def check_jacobian(seed: int, n: int, plane: bool) -> list[GradcheckResult]:
    data = correspondences(seed, n, plane, "none")

    def f(xi):
        return icp.icp_residuals(_moved(data["source"], xi), data["target"], data["normals"]).residuals

    def vjp(inputs, cot):
        J = icp.icp_residuals(data["source"], data["target"], data["normals"]).jacobians
        return {"xi": np.einsum("nr,nra->a", cot, J)}

    kind = "plane" if plane else "point"
    return check_vjp(f, vjp, {"xi": np.zeros(6)}, seed=seed, name=f"icp.jacobian[{kind},seed={seed},n={n}]")


def check_gradient(seed: int, n: int, plane: bool, robust: str) -> list[GradcheckResult]:
    data = correspondences(seed, n, plane, robust)
    scale = SCALE[robust]

    def f(xi):
        ne = icp.normal_equations(_moved(data["source"], xi), data["target"], data["normals"], robust=robust,
                                  scale=scale)
        return np.array([ne.cost])

    def vjp(inputs, cot):
        ne = icp.normal_equations(data["source"], data["target"], data["normals"], robust=robust, scale=scale)
        return {"xi": float(cot[0]) * ne.g}

    kind = "plane" if plane else "point"
    return check_vjp(f, vjp, {"xi": np.zeros(6)}, seed=seed,
                     name=f"icp.gradient[{kind},{robust},seed={seed},n={n}]")


@register_check("icp.jacobian")
def jacobian_checks() -> list[GradcheckResult]:
    return [r for plane in (False, True) for seed in range(3) for r in check_jacobian(seed, 40 + 7 * seed, plane)]


@register_check("icp.gradient")
def gradient_checks() -> list[GradcheckResult]:
    return [r for plane in (False, True) for robust in icp.ROBUST for seed in range(3)
            for r in check_gradient(seed, 50 + 5 * seed, plane, robust)]
