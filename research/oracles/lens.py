"""Dr.Jit oracle for the splat projection through a lens model (kernels/splat/lens_projection.py,
kernels/lens.py), written from those docstrings' equations, never calling drlab.

Per splat, with q = (w, x, y, z) / |q|, Sigma = R(q) S S^T R(q)^T, S = diag(exp l), the camera
[W | t] (with the camera gradients: moved by the left perturbation exp(xi^) to first order, as in
research/oracles/splat.py) and intrinsics fx, fy, cx, cy:

    p = W mu + t = (x, y, z),   Sigma_c = W Sigma W^T
    central models: w = (a, b) = (x / z, y / z), s = a^2 + b^2, m = D(w), J_m = J_D(w) J_w with
        J_w = [[1/z, 0, -a/z], [0, 1/z, -b/z]]
        opencv   D(w) = (a R + 2 p1 a b + p2 (s + 2 a^2), b R + p1 (s + 2 b^2) + 2 p2 a b),
                 R = 1 + k1 s + k2 s^2 + k3 s^3, J_D written out with R' = dR/ds
        fisheye  D(w) = G w, G = theta_d / r, theta = atan r, theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8),
                 J_D = G I + 2 G' w w^T, G' = dG/ds = (theta_d'(theta) / (1 + s) / r - theta_d / s) / (2 r)
    orthographic: m = (x, y), J_m = [[1, 0, 0], [0, 1, 0]]
    mean2d = (fx m_x + cx, fy m_y + cy),  J = diag(fx, fy) J_m,  Sigma2d = J Sigma_c J^T + 0.3 I
    conic = (c, -b, a) / det,  depth = z,  colour = max(0, sum_k f_k Y_k(d) + 1/2),  opacity = sigmoid(a)

Dr.Jit's AD differentiates the whole chain, J_m included: the second derivatives of the lens that
kernels.lens.lens_project_vjp writes by hand come from the AD here. The fisheye's G is its closed
form (the kernels switch to a series below s = 1e-4; the cases keep every splat off the axis).
Every splat is kept (the cases draw splats that drlab's projection does not cull).
"""

from __future__ import annotations

import numpy as np

from research.oracles import check_array
from research.oracles.splat import DILATION, SPLAT_INPUTS, _camera, _camera_gaussians, _sh_colors, _splat_leaves


def _lens_point(dr, p, model: str, coeffs):
    """(m_x, m_y, J_m as 2 rows of 3) of the camera-frame point p (module docstring)."""
    x, y, z = p
    if model == "orthographic":
        return x, y, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    a, b = x / z, y / z
    s = a * a + b * b
    if model == "opencv":
        k1, k2, p1, p2, k3 = coeffs
        R = 1.0 + k1 * s + k2 * s * s + k3 * s * s * s
        R1 = k1 + 2.0 * k2 * s + 3.0 * k3 * s * s
        mx = a * R + 2.0 * p1 * a * b + p2 * (s + 2.0 * a * a)
        my = b * R + p1 * (s + 2.0 * b * b) + 2.0 * p2 * a * b
        off = 2.0 * a * b * R1 + 2.0 * p1 * a + 2.0 * p2 * b
        JD = [[R + 2.0 * a * a * R1 + 2.0 * p1 * b + 6.0 * p2 * a, off],
              [off, R + 2.0 * b * b * R1 + 6.0 * p1 * b + 2.0 * p2 * a]]
    elif model == "fisheye":
        k1, k2, k3, k4 = coeffs
        r = dr.sqrt(s)
        th = dr.atan(r)
        t2 = th * th
        td = th * (1.0 + k1 * t2 + k2 * t2 * t2 + k3 * t2 * t2 * t2 + k4 * t2 * t2 * t2 * t2)
        td1 = 1.0 + 3.0 * k1 * t2 + 5.0 * k2 * t2 * t2 + 7.0 * k3 * t2 * t2 * t2 + 9.0 * k4 * t2 * t2 * t2 * t2
        G = td / r
        G1 = (td1 / (1.0 + s) / r - td / s) / (2.0 * r)
        mx, my = G * a, G * b
        JD = [[G + 2.0 * G1 * a * a, 2.0 * G1 * a * b], [2.0 * G1 * a * b, G + 2.0 * G1 * b * b]]
    else:
        raise ValueError(f"model: expected 'opencv', 'fisheye' or 'orthographic', got {model!r}")
    Jw = [[1.0 / z, 0.0, -a / z], [0.0, 1.0 / z, -b / z]]
    Jm = [[JD[i][0] * Jw[0][j] + JD[i][1] * Jw[1][j] for j in range(3)] for i in range(2)]
    return mx, my, Jm


def lens_project_oracle(means, log_scales, quats, opacity_logits, sh, viewmat, K, model: str, coeffs,
                        cotangents: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """({"means2d" (N, 2), "conics" (N, 3), "depths" (N,), "colors" (N, 3), "opacities" (N,)}, VJPs
    {"means", "log_scales", "quats", "opacity_logits", "sh", "pose" (6,), "intrinsics" (4,)}) for the
    cotangents of those five outputs (module docstring; `coeffs` as kernels.lens.Lens holds them)."""
    check_array("means", means, (None, 3))
    n = means.shape[0]
    for name, x, shape in (("log_scales", log_scales, (n, 3)), ("quats", quats, (n, 4)),
                           ("opacity_logits", opacity_logits, (n,)), ("sh", sh, (n, None, 3))):
        check_array(name, x, shape)
    shapes = {"means2d": (n, 2), "conics": (n, 3), "depths": (n,), "colors": (n, 3), "opacities": (n,)}
    for name, shape in shapes.items():
        check_array(f"cotangents[{name!r}]", cotangents[name], shape)
    be, leaves = _splat_leaves(means, log_scales, quats, opacity_logits, sh)
    dr = be.dr
    n_coeffs = sh.shape[1]
    Kn = np.asarray(K, np.float64)
    camera = {"pose": be.leaf(np.zeros(6)), "intrinsics": be.leaf([Kn[0, 0], Kn[1, 1], Kn[0, 2], Kn[1, 2]])}
    Wr, tv, (fx, fy, cx, cy) = _camera(be, viewmat, K, camera)

    mu, p, Sc = _camera_gaussians(be, leaves, n, Wr, tv)

    m_x, m_y, Jm = _lens_point(dr, p, model, coeffs)
    J = [[fx * Jm[0][j] for j in range(3)], [fy * Jm[1][j] for j in range(3)]]
    JS = [[sum(J[i][k] * Sc[k][j] for k in range(3)) for j in range(3)] for i in range(2)]
    cov = [[sum(JS[i][k] * J[j][k] for k in range(3)) for j in range(2)] for i in range(2)]
    a, b, c = cov[0][0] + DILATION, cov[0][1], cov[1][1] + DILATION
    det = a * c - b * b
    u, v = fx * m_x + cx, fy * m_y + cy

    colors = _sh_colors(be, leaves, n, n_coeffs, mu, Wr, tv)
    opac = 1.0 / (1.0 + dr.exp(-leaves["opacity_logits"]))
    outs = {"means2d": [u, v], "conics": [c / det, -b / det, a / det], "depths": [p[2]], "colors": colors,
            "opacities": [opac]}
    flat, cots = [], []
    for name, cols in outs.items():
        cot = np.asarray(cotangents[name], np.float64).reshape(n, -1)
        for j, col in enumerate(cols):
            flat.append(col)
            cots.append(cot[:, j])
    dr.eval(*flat)
    values = {name: np.stack([be.numpy(col, (n,)) for col in cols], axis=1).reshape(shapes[name])
              for name, cols in outs.items()}
    dr.backward(be.dot(flat, cots))
    grads = {k: be.grad(leaves[k], np.shape(x)) for k, x in zip(SPLAT_INPUTS, (means, log_scales, quats,
                                                                              opacity_logits, sh))}
    grads["pose"] = be.grad(camera["pose"], (6,))
    grads["intrinsics"] = be.grad(camera["intrinsics"], (4,))
    return values, grads
