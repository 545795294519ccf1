"""Dr.Jit oracle for ICP (kernels/icp.py): residual rows, pose Jacobians, robust weights, normal equations.

Written from kernels/icp.py's docstring, but with every derivative taken by Dr.Jit's AD where drlab
writes a closed form:

* The moved source. Correspondence i has its own twist xi_i = (rho, phi) (translation first), a
  differentiable variable of value 0, and p_i(xi) = exp(xi^) p_i is formed by exp's power series
  applied to the point, p + sum_{k=1..8} t_k with t_1 = rho + phi x p and t_k = phi x t_{k-1} / k
  (the series of [[phi^, rho], [0, 0]] on (p, 1)); at xi = 0 it is exact, and so is its derivative.
* Residual rows: point-to-point r = p(xi) - q (three rows), point-to-plane r = n . (p(xi) - q) (one).
  One reverse pass per row gives that row's Jacobian d r / d xi_i for every correspondence at once
  (drlab: J = [d^T, (p x d)^T]).
* Robust weights: rho written as a function of t = e^2 (none t / 2; Huber t / 2 for e <= c, else
  c e - c^2 / 2; Geman-McClure s t / (2 (s + t))), and w = rho'(e) / e = 2 d rho / d t by reverse mode
  (drlab writes w out by hand).
* Normal equations as explicit sums over correspondences of the AD rows and weights:
  H_jk = sum_i w_i sum_rows J_j J_k, g_j = sum_i w_i sum_rows J_j r, cost = sum_i rho_i. Beside them,
  grad_cost = d/dxi sum_i rho(e_i(xi)) by reverse mode along ONE twist shared by every source point:
  the docstring's claim that the weights make this gradient equal g.
"""

from __future__ import annotations

import numpy as np

from research.oracles import Backend, backend, check_array

ROBUST = ("none", "huber", "gm")
SERIES_ORDER = 8


def _cross(a: list, b: list) -> list:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _moved(p: list, rho: list, phi: list) -> list:
    """exp(xi^) p by its power series (module docstring), component-wise Dr.Jit arrays."""
    term = [rho[j] + c for j, c in enumerate(_cross(phi, p))]
    out = [p[j] + term[j] for j in range(3)]
    for k in range(2, SERIES_ORDER + 1):
        term = [c / float(k) for c in _cross(phi, term)]
        out = [out[j] + term[j] for j in range(3)]
    return out


def _rows(moved: list, q: list, nrm: list | None) -> list:
    """The residual rows of the moved source against (q, n)."""
    u = [moved[j] - q[j] for j in range(3)]
    if nrm is None:
        return u
    return [nrm[0] * u[0] + nrm[1] * u[1] + nrm[2] * u[2]]


def _rho(be: Backend, t, robust: str, s: float):
    """rho(e) of the module docstring as a function of t = e^2 (a Dr.Jit array)."""
    dr = be.dr
    if robust == "none":
        return 0.5 * t
    if robust == "huber":
        far = dr.sqrt(dr.detach(t)) > s
        # the linear branch reads sqrt(max(t, c^2)): where it is not selected its adjoint is not NaN at t = 0
        return dr.select(far, s * dr.sqrt(dr.maximum(t, s * s)) - 0.5 * s * s, 0.5 * t)
    return 0.5 * s * t / (s + t)


def icp_oracle(source: np.ndarray, target: np.ndarray, normals: np.ndarray | None = None, robust: str = "none",
               scale: float = 1.0) -> dict[str, np.ndarray]:
    """{"residuals" (N, R), "jacobians" (N, R, 6), "weights" (N,), "rho" (N,) (kernels.icp.Residuals'
    fields), "H" (6, 6), "g" (6,), "cost" (), "grad_cost" (6,)} in source's dtype; point-to-point when
    normals is None (R = 3), else point-to-plane (R = 1)."""
    check_array("source", source, (None, 3))
    n = source.shape[0]
    if n == 0:
        raise ValueError("source: expected at least one correspondence, got shape (0, 3)")
    check_array("target", target, (n, 3))
    if normals is not None:
        check_array("normals", normals, (n, 3))
        if np.max(np.abs(np.linalg.norm(normals.astype(np.float64), axis=1) - 1.0)) > 1e-3:
            raise ValueError("normals: expected unit vectors (| |n| - 1 | <= 1e-3)")
    if robust not in ROBUST:
        raise ValueError(f"robust: expected one of {', '.join(ROBUST)}, got {robust!r}")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale: expected a finite value > 0, got {scale}")
    s = float(scale)
    be = backend(source.dtype)
    dr = be.dr
    cols = lambda a: [be.const(np.ascontiguousarray(a[:, j])) for j in range(3)]  # noqa: E731
    p, q = cols(source), cols(target)
    nrm = None if normals is None else cols(normals)
    n_rows = 3 if normals is None else 1

    def twist(xi, per_point: bool) -> tuple[list, list]:
        """(rho, phi) read from xi: one twist per correspondence (per_point), else one shared by all."""
        idx = (lambda j: be.arange(n) * 6 + j) if per_point else (lambda j: be.UInt(j))  # noqa: E731
        x = [dr.gather(be.Float, xi, idx(j)) for j in range(6)]
        return x[:3], x[3:]

    # Residual rows and their Jacobians: one reverse pass per row, a twist per correspondence.
    values, jac = [], []
    for a in range(n_rows):
        xi = be.leaf(np.zeros((n, 6)))
        r = _rows(_moved(p, *twist(xi, True)), q, nrm)[a]
        dr.eval(r)
        dr.backward(dr.sum(r))
        values.append(be.numpy(r, (n,)))
        jac.append(be.grad(xi, (n, 6)))
    res, J = np.stack(values, axis=1), np.stack(jac, axis=1)

    # Weights w = 2 d rho / d t and rho, at t = e^2 of the unmoved source.
    t = sum(c * c for c in _rows(p, q, nrm))
    dr.enable_grad(t)
    rho = _rho(be, t, robust, s)
    dr.eval(rho)
    dr.backward(dr.sum(rho))
    w = 2.0 * dr.grad(t)
    weights, rho_np = be.numpy(w, (n,)), be.numpy(rho, (n,))

    # Normal equations as explicit sums over the correspondences.
    Jc = [[be.const(np.ascontiguousarray(J[:, a, j])) for j in range(6)] for a in range(n_rows)]
    rc = [be.const(np.ascontiguousarray(res[:, a])) for a in range(n_rows)]
    H = np.zeros((6, 6), be.np_dtype)
    g = np.zeros(6, be.np_dtype)
    for j in range(6):
        g[j] = be.numpy(dr.sum(w * sum(Jc[a][j] * rc[a] for a in range(n_rows))), (1,))[0]
        for k in range(6):
            H[j, k] = be.numpy(dr.sum(w * sum(Jc[a][j] * Jc[a][k] for a in range(n_rows))), (1,))[0]
    cost = be.numpy(dr.sum(dr.detach(rho)), (1,))[0]

    # d cost / d xi along one twist shared by every point.
    xi = be.leaf(np.zeros(6))
    u = _rows(_moved(p, *twist(xi, False)), q, nrm)
    e2 = sum(c * c for c in u)
    total = dr.sum(_rho(be, e2, robust, s))
    dr.backward(total)
    return {"residuals": res, "jacobians": J, "weights": weights, "rho": rho_np, "H": H, "g": g,
            "cost": np.asarray(cost), "grad_cost": be.grad(xi, (6,))}
