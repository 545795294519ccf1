"""Dr.Jit oracle for the volume renderer's camera gradients (kernels/volume/rays.py).

Written from the docstrings of kernels/volume/rays.py, spheres.py, grid.py and composite.py.

Camera: world-to-camera T_cw = [[R, t], [0, 1]] perturbed on the LEFT, T_cw(xi) = exp(xi^) T_cw with
xi = (rho, phi) translation first and xi^ = [[phi^, rho], [0, 0]]. The oracle forms exp(xi^) as
its power series sum_{k <= 8} (xi^)^k / k! of Dr.Jit values, differentiated at xi = 0 (a
differentiable variable of value 0), where the series is exact; R(xi), t(xi) are read off the
product. Intrinsics (fx, fy, cx, cy) are differentiable too. Per pixel (u, v):

    c = ((u - cx)/fx, (v - cy)/fy, 1),  n = |c|,  e = c / n,
    o = -R(xi)^T t(xi),  d = R(xi)^T e,  z_scale = 1 / n.

Render through the rays with the sample distances s_k and intervals delta_k of each ray given and
held fixed (rays.py's convention): x_k = o + s_k d, z_k = s_k z_scale, the field's (sigma_k, c_k) at
(x_k, d), and NeRF compositing

    alpha_k = 1 - exp(-sigma_k delta_k),  T_k = prod_{j<k} (1 - alpha_j),  w_k = T_k alpha_k,
    C = sum_k w_k c_k + T_N b,  D = sum_k w_k z_k,  A = 1 - T_N,

stopping before sample k once T_k < t_threshold (a detached mask; the samples after the stop do
not contribute). Fields (a plain dict, never a drlab object): "spheres", the soft spheres
sigma = sum_k s_k exp(-s_k max(0, |x - c_k| - r_k)), rgb = sum_k d_k col_k / sigma (sigma > 1e-6,
else the plain sum); "grid", the dense grid of research/oracles/volume.py (RGB or SH colour of the
view direction d).

VJPs by `drjit.backward` of <g_C, C> + <g_D, D> + <g_A, A>: with respect to (xi, fx, fy, cx, cy)
through the whole chain (`render_camera_oracle`), with respect to the rays (o, d, z_scale) alone
(`render_rays_oracle`), and of the ray generation alone (`camera_rays_oracle`). The sample loop is
a Python loop (unrolled, research/oracles/__init__.py); the render's reverse pass is staged at the
per-sample field outputs and at the rays (`_render_vjp`: the chain rule between stages, Dr.Jit's
AD within each), because one backward over every sample's field compiles for hours.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from research.oracles import Backend, backend, check_array
from research.oracles.volume import grid_eval

SERIES_ORDER = 8
SPHERE_EPS = 1e-6


# --------------------------------------------------------------------------- checks


def _check_camera(w2c: Any, intrinsics: Any, pixels: Any) -> tuple[np.ndarray, np.ndarray]:
    M = check_array("w2c", np.asarray(w2c, np.float64), (4, 4))
    K = check_array("intrinsics", np.asarray(intrinsics, np.float64), (4,))
    if K[0] <= 0 or K[1] <= 0:
        raise ValueError(f"intrinsics: expected fx, fy > 0, got {K.tolist()}")
    check_array("pixels", pixels, (None, 2))
    return M, K


def _check_field(field: Any) -> dict:
    if not isinstance(field, dict) or field.get("kind") not in ("spheres", "grid"):
        raise ValueError("field: expected a dict with kind 'spheres' or 'grid'")
    if field["kind"] == "spheres":
        c = check_array("field centers", np.asarray(field.get("centers", np.zeros((0, 0))), np.float64), (None, 3))
        for name, shape in (("radii", (c.shape[0],)), ("colors", (c.shape[0], 3)), ("sharpness", (c.shape[0],))):
            check_array(f"field {name}", np.asarray(field.get(name, np.zeros(0)), np.float64), shape)
    else:
        res = tuple(int(r) for r in field.get("resolution", ()))
        if len(res) != 3 or min(res) < 2:
            raise ValueError(f"field resolution: expected three sizes >= 2, got {field.get('resolution')}")
        sh = field.get("sh_degree")
        n_coef = 1 if sh is None else (int(sh) + 1) ** 2
        check_array("field bbox", np.asarray(field.get("bbox", np.zeros(0)), np.float64), (2, 3))
        check_array("field density", np.asarray(field.get("density", np.zeros(0)), np.float64), (int(np.prod(res)),))
        check_array("field color", np.asarray(field.get("color", np.zeros(0)), np.float64),
                    (int(np.prod(res)), 3 * n_coef))
    return field


def _check_samples(n_rays: int, t: Any, delta: Any, background: Any, t_threshold: float, cot: tuple) -> None:
    check_array("t", t, (n_rays, None))
    check_array("delta", delta, t.shape)
    if np.any(delta < 0):
        raise ValueError("delta: expected interval lengths >= 0")
    check_array("background", np.asarray(background, np.float64), (3,))
    if not 0.0 <= float(t_threshold) < 1.0:
        raise ValueError(f"t_threshold: expected a value in [0, 1), got {t_threshold}")
    for name, g, shape in zip(("grad_rgb", "grad_depth", "grad_opacity"), cot, ((n_rays, 3), (n_rays,), (n_rays,))):
        check_array(name, g, shape)


# --------------------------------------------------------------------------- camera


def _matmul(A: list, B: list) -> list:
    n, m, p = len(A), len(B), len(B[0])
    return [[sum(A[i][k] * B[k][j] for k in range(m)) for j in range(p)] for i in range(n)]


def _pose(be: Backend, w2c: np.ndarray, xi_leaf) -> tuple[list, list]:
    """(R(xi) 3x3, t(xi) 3) of exp(xi^) T_cw, exp by its power series to SERIES_ORDER (module docstring)."""
    dr = be.dr
    xi = [dr.gather(be.Float, xi_leaf, be.UInt(j)) for j in range(6)]
    (r0, r1, r2), (a, b, c) = xi[:3], xi[3:]
    zero = 0.0 * a
    X = [[zero, -c, b, r0], [c, zero, -a, r1], [-b, a, zero, r2], [zero, zero, zero, zero]]
    E = [[(1.0 if i == j else 0.0) + zero for j in range(4)] for i in range(4)]
    term = [row[:] for row in E]
    for k in range(1, SERIES_ORDER + 1):
        term = [[v / float(k) for v in row] for row in _matmul(term, X)]
        E = [[E[i][j] + term[i][j] for j in range(4)] for i in range(4)]
    T = _matmul(E, [[float(w2c[i, j]) + zero for j in range(4)] for i in range(4)])
    dr.eval(T)
    return [[T[i][j] for j in range(3)] for i in range(3)], [T[i][3] for i in range(3)]


def _rays(be: Backend, w2c: np.ndarray, xi_leaf, intr_leaf, pixels: np.ndarray) -> tuple[list, list, Any]:
    """([o_x, o_y, o_z], [d_x, d_y, d_z], z_scale) per pixel as Dr.Jit arrays (module docstring)."""
    dr = be.dr
    R, t = _pose(be, w2c, xi_leaf)
    fx, fy, cx, cy = (dr.gather(be.Float, intr_leaf, be.UInt(j)) for j in range(4))
    u, v = be.const(pixels[:, 0]), be.const(pixels[:, 1])
    c = [(u - cx) / fx, (v - cy) / fy, 1.0]
    n = dr.sqrt(c[0] * c[0] + c[1] * c[1] + 1.0)
    e = [c[0] / n, c[1] / n, 1.0 / n]
    o = [-(R[0][a] * t[0] + R[1][a] * t[1] + R[2][a] * t[2]) for a in range(3)]
    d = [R[0][a] * e[0] + R[1][a] * e[1] + R[2][a] * e[2] for a in range(3)]
    zs = 1.0 / n
    dr.eval(o, d, zs)
    return o, d, zs


def camera_rays_oracle(w2c: np.ndarray, intrinsics: np.ndarray, pixels: np.ndarray, grad_origins: np.ndarray,
                       grad_dirs: np.ndarray, grad_z_scale: np.ndarray
                       ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], dict[str, np.ndarray]]:
    """((origins (P, 3), dirs (P, 3), z_scale (P,)), {"xi" (6,), "intrinsics" (4,)}) for
    L = <g_o, origins> + <g_d, dirs> + <g_z, z_scale>, in the dtype of `pixels`."""
    M, K = _check_camera(w2c, intrinsics, pixels)
    n = pixels.shape[0]
    check_array("grad_origins", grad_origins, (n, 3))
    check_array("grad_dirs", grad_dirs, (n, 3))
    check_array("grad_z_scale", grad_z_scale, (n,))
    be = backend(pixels.dtype)
    dr = be.dr
    xi, intr = be.leaf(np.zeros(6)), be.leaf(K)
    o, d, zs = _rays(be, M, xi, intr, pixels)
    o, d = [o_ + 0.0 * zs for o_ in o], d  # the origin is one point: broadcast it to every pixel
    dr.eval(*o, *d, zs)
    dr.backward(be.dot([*o, *d, zs], [*(grad_origins[:, a] for a in range(3)), *(grad_dirs[:, a] for a in range(3)),
                                      grad_z_scale]))
    out = (np.stack([be.numpy(x, (n,)) for x in o], 1), np.stack([be.numpy(x, (n,)) for x in d], 1),
           be.numpy(zs, (n,)))
    return out, {"xi": be.grad(xi, (6,)), "intrinsics": be.grad(intr, (4,))}


# --------------------------------------------------------------------------- fields and compositing


def _spheres(be: Backend, field: dict, x: list) -> tuple[Any, list]:
    dr = be.dr
    C, rad = np.asarray(field["centers"], np.float64), np.asarray(field["radii"], np.float64)
    col, sharp = np.asarray(field["colors"], np.float64), np.asarray(field["sharpness"], np.float64)
    sigma = 0.0 * x[0]
    acc = [0.0 * x[0] for _ in range(3)]
    for k in range(C.shape[0]):
        dist = dr.sqrt(sum((x[a] - float(C[k, a])) ** 2 for a in range(3)))
        m = dr.maximum(dist - float(rad[k]), 0.0)
        dk = float(sharp[k]) * dr.exp(-float(sharp[k]) * m)
        sigma = sigma + dk
        acc = [acc[a] + dk * float(col[k, a]) for a in range(3)]
    big = sigma > SPHERE_EPS
    return sigma, [dr.select(big, acc[a] / dr.select(big, sigma, 1.0), acc[a]) for a in range(3)]


def _field(be: Backend, field: dict, x: list, d: list) -> tuple[Any, list]:
    if field["kind"] == "spheres":
        return _spheres(be, field, x)
    sh = field.get("sh_degree")
    return grid_eval(be, x, d, be.const(field["density"]), be.const(field["color"]), np.asarray(field["bbox"]),
                     tuple(int(r) for r in field["resolution"]), None if sh is None else int(sh),
                     float(field.get("density_bias", 0.0)), float(field.get("density_scale", 1.0)),
                     field.get("activation", "softplus"))


def _render_vjp(be: Backend, field: dict, o: list, d: list, zs, t: np.ndarray, delta: np.ndarray, background,
                t_threshold: float, cot: tuple) -> tuple[tuple, tuple]:
    """((rgb, depth, opacity) NumPy, (g_o [3], g_d [3], g_zs) Dr.Jit arrays) of rays o + s d at the fixed
    samples (module docstring), for the output cotangents cot = (g_C, g_D, g_A).

    Dr.Jit's reverse mode traced over all samples at once makes one backward kernel of every
    sample's field (hours to compile for an SH grid), so the chain rule is split at the per-sample
    field outputs (sigma_k, c_k): (1) the field at every sample, detached; (2) the compositing with
    (sigma_k, c_k) and z_scale as leaves, one backward; (3) per sample, the field again from the ray
    leaves (o, d) and a backward of <dL/dsigma_k, sigma_k> + <dL/dc_k, c_k>, whose gradients
    accumulate on those leaves. Every derivative is Dr.Jit's AD; only the composition is staged."""
    dr = be.dr
    n_rays, n_s = t.shape
    o = [be.Float(dr.detach(x)) + dr.zeros(be.Float, n_rays) for x in o]
    d = [be.Float(dr.detach(x)) for x in d]
    zs = be.Float(dr.detach(zs))
    dr.enable_grad(*o, *d, zs)
    S = [be.const(t[:, k]) for k in range(n_s)]

    def field_at(k: int) -> tuple[Any, list]:
        return _field(be, field, [o[a] + S[k] * d[a] for a in range(3)], d)

    sig, col = [], []
    for k in range(n_s):  # (1)
        with dr.suspend_grad():
            sk, ck = field_at(k)
        sk, ck = be.Float(dr.detach(sk)), [be.Float(dr.detach(c)) for c in ck]
        dr.enable_grad(sk, *ck)
        dr.eval(sk, *ck)
        sig.append(sk)
        col.append(ck)
    T = dr.full(be.Float, 1.0, n_rays)  # (2)
    active = dr.full(be.Bool, True, n_rays)
    C = [dr.zeros(be.Float, n_rays) for _ in range(3)]
    D = dr.zeros(be.Float, n_rays)
    for k in range(n_s):
        active = active & (dr.detach(T) >= t_threshold)  # stop before sample k once T_k < t_threshold
        alpha = dr.select(active, 1.0 - dr.exp(-sig[k] * be.const(delta[:, k])), 0.0)
        w = T * alpha
        C = [C[a] + w * col[k][a] for a in range(3)]
        D = D + w * (S[k] * zs)
        T = T * (1.0 - alpha)
        dr.eval(T, active, D, *C)  # one small kernel per sample (compiled once)
    C = [C[a] + T * float(background[a]) for a in range(3)]
    A = 1.0 - T
    g_rgb, g_depth, g_opacity = cot
    dr.backward(be.dot([*C, D, A], [*(g_rgb[:, a] for a in range(3)), g_depth, g_opacity]))
    for k in range(n_s):  # (3)
        g_s, g_c = dr.grad(sig[k]), [dr.grad(c) for c in col[k]]
        dr.eval(g_s, *g_c)
        sk, ck = field_at(k)
        loss = dr.sum(sk * be.Float(g_s))
        for a in range(3):
            loss = loss + dr.sum(ck[a] * be.Float(g_c[a]))
        dr.backward(loss)
        dr.eval(*(dr.grad(x) for x in (*o, *d)))
    out = (np.stack([be.numpy(c, (n_rays,)) for c in C], 1), be.numpy(D, (n_rays,)), be.numpy(A, (n_rays,)))
    return out, ([dr.grad(x) for x in o], [dr.grad(x) for x in d], dr.grad(zs))


def render_camera_oracle(field: dict, w2c: np.ndarray, intrinsics: np.ndarray, pixels: np.ndarray, t: np.ndarray,
                         delta: np.ndarray, background: Any, t_threshold: float, grad_rgb: np.ndarray,
                         grad_depth: np.ndarray, grad_opacity: np.ndarray
                         ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], dict[str, np.ndarray]]:
    """((rgb (P, 3), depth (P,), opacity (P,)), {"xi" (6,), "intrinsics" (4,)}) of the pixels' rays
    rendered at the fixed samples t, delta (P, S), in the dtype of `pixels`."""
    M, K = _check_camera(w2c, intrinsics, pixels)
    field = _check_field(field)
    n = pixels.shape[0]
    _check_samples(n, t, delta, background, t_threshold, (grad_rgb, grad_depth, grad_opacity))
    be = backend(pixels.dtype)
    dr = be.dr
    xi, intr = be.leaf(np.zeros(6)), be.leaf(K)
    o, d, zs = _rays(be, M, xi, intr, pixels)
    out, (g_o, g_d, g_z) = _render_vjp(be, field, o, d, zs, t, delta, np.asarray(background, np.float64),
                                       t_threshold, (grad_rgb, grad_depth, grad_opacity))
    loss = dr.sum(zs * be.Float(dr.detach(g_z)))  # (4) the rays' cotangents back to the camera
    for a in range(3):
        loss = loss + dr.sum(o[a] * be.Float(dr.detach(g_o[a]))) + dr.sum(d[a] * be.Float(dr.detach(g_d[a])))
    dr.backward(loss)
    return out, {"xi": be.grad(xi, (6,)), "intrinsics": be.grad(intr, (4,))}


def render_rays_oracle(field: dict, origins: np.ndarray, dirs: np.ndarray, z_scale: np.ndarray, t: np.ndarray,
                       delta: np.ndarray, background: Any, t_threshold: float, grad_rgb: np.ndarray,
                       grad_depth: np.ndarray, grad_opacity: np.ndarray
                       ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], dict[str, np.ndarray]]:
    """((rgb, depth, opacity), {"origins" (R, 3), "dirs" (R, 3), "z_scale" (R,)}) of rays o + s d
    rendered at the fixed samples t, delta (R, S), in the dtype of `origins`."""
    check_array("origins", origins, (None, 3))
    n = origins.shape[0]
    check_array("dirs", dirs, (n, 3))
    check_array("z_scale", z_scale, (n,))
    field = _check_field(field)
    _check_samples(n, t, delta, background, t_threshold, (grad_rgb, grad_depth, grad_opacity))
    be = backend(origins.dtype)
    o, d, zs = [be.const(origins[:, a]) for a in range(3)], [be.const(dirs[:, a]) for a in range(3)], be.const(z_scale)
    out, (g_o, g_d, g_z) = _render_vjp(be, field, o, d, zs, t, delta, np.asarray(background, np.float64),
                                       t_threshold, (grad_rgb, grad_depth, grad_opacity))
    grads = {"origins": np.stack([be.numpy(x, (n,)) for x in g_o], 1),
             "dirs": np.stack([be.numpy(x, (n,)) for x in g_d], 1), "z_scale": be.numpy(g_z, (n,))}
    return out, grads
