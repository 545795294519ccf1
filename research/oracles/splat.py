"""Dr.Jit oracle for the splat chain (kernels/splat) following the ORIGINAL 3D Gaussian splatting code.

Kerbl et al., "3D Gaussian Splatting for Real-Time Radiance Field Rendering" (SIGGRAPH 2023), its
CUDA rasteriser's forward equations, in drlab's conventions (world-to-camera [W | t] with OpenCV
axes, intrinsics fx, fy, cx, cy, pixel (i, j) centred at (i + 1/2, j + 1/2); 3DGS centres pixels
at integers, so its screen point is ours minus 1/2). Per splat, with q = (w, x, y, z) / |q|:

    Sigma = R(q) S S^T R(q)^T,  S = diag(exp l);  p = W mu + t = (x, y, z); culled if z < near or z > far
    tan_fx = W_img / (2 fx),  lim_x = 1.3 tan_fx  (likewise y):  x' = z clamp(x / z, -lim_x, lim_x)
    J = [[fx / z, 0, -fx x' / z^2], [0, fy / z, -fy y' / z^2]],  Sigma2d = J W Sigma W^T J^T + 0.3 I
    det = a c - b^2 (culled if <= 0),  conic = (c, -b, a) / det
    mean2d = (fx x / z + cx, fy y / z + cy)
    mid = (a + c) / 2,  lambda = mid + sqrt(max(0.1, mid^2 - det)),  radius = ceil(3 sqrt(lambda))
    tiles (16 px, getRect on the 3DGS screen point m = mean2d - 1/2):
        x range [min(Tx, max(0, int((m_x - r) / 16))), min(Tx, max(0, int((m_x + r + 15) / 16))))
        and likewise y; culled if the rectangle is empty
    colour = max(0, sum_k f_k Y_k(d) + 1/2),  d = (mu - camera centre) / |mu - camera centre|
    opacity = sigmoid(a)

Per pixel, over its tile's splats sorted by depth z, front to back, T = 1:

    power = -1/2 (Q00 dx^2 + Q11 dy^2) - Q01 dx dy,  d = mean2d - pixel centre;  skip if power > 0
    alpha = min(0.99, o exp(power));  skip if alpha < 1/255
    if T (1 - alpha) < 1e-4: stop (this splat is not blended)
    C += c alpha T,  D += z alpha T,  T *= 1 - alpha
    rgb = C + T background,  alpha_out = 1 - T,  depth = D

(depth is drlab's extra output: the alpha-weighted z, background 0). As drlab, the oracle divides by
z exactly where 3DGS's projection matrix divides by w + 1e-7, and culls outside [near, far] where
3DGS hard-codes z <= 0.2 (kernels/splat/modes.py states both). The discrete choices (tile
lists, depth order) are computed from the oracle's own values, detached; every continuous value
stays in Dr.Jit's AD graph. `tile_rule="square"` replaces getRect by the tiles the square
mean2d +- radius meets (gsplat's rule, and drlab's before it followed 3DGS); the two differ where a
splat's square ends inside a tile's first pixel column or row: getRect's int((m + r + 15) / 16)
is ceil(m + r) / 16 rounded down, so it leaves out a tile whose first pixel centre lies within
the radius but beyond floor(m + r), where alpha can still exceed 1/255. The per-pixel loop is unrolled over the slots of the longest tile
list, one small evaluated kernel per slot (the slot index is opaque, so it compiles once); the
skip and stop tests are masks, so the gradient is that of the branch each pixel takes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from research.oracles import Backend, backend, check_array
from research.oracles.volume import sh_basis

TILE = 16
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4
DILATION = 0.3
FRUSTUM = 1.3
EIG_FLOOR = 0.1


def _check_splats(means, log_scales, quats, opacity_logits, sh, viewmat, K, tile_rule: str) -> None:
    """ValueError naming the first bad argument (shapes, finite floats, the camera, the tile rule)."""
    check_array("means", means, (None, 3))
    n = means.shape[0]
    check_array("log_scales", log_scales, (n, 3))
    check_array("quats", quats, (n, 4))
    check_array("opacity_logits", opacity_logits, (n,))
    check_array("sh", sh, (n, None, 3))
    if sh.shape[1] not in (1, 4, 9, 16):
        raise ValueError(f"sh: expected (L+1)^2 <= 16 coefficients per channel, got {sh.shape[1]}")
    check_array("viewmat", np.asarray(viewmat, np.float64), (4, 4))
    check_array("K", np.asarray(K, np.float64), (3, 3))
    if tile_rule not in ("3dgs", "square"):
        raise ValueError(f"tile_rule: expected '3dgs' or 'square', got {tile_rule!r}")


def _rows(be: Backend, leaf, n: int, k: int) -> list:
    return [be.dr.gather(be.Float, leaf, be.arange(n) * k + j) for j in range(k)]


def _camera(be: Backend, viewmat: np.ndarray, K: np.ndarray, camera: dict | None):
    """([W], [t], (fx, fy, cx, cy)) as Python floats, or, with `camera` (the leaves "pose" (6,) and
    "intrinsics" (4,)), as Dr.Jit values: the intrinsics themselves, and [W | t] moved by the left
    perturbation exp(xi^) of xi = (rho, phi) = pose at 0, to first order (I + phi^) [W | t] + [0 | rho],
    whose derivative at xi = 0 is exp's (kernels/splat/camera.py's convention)."""
    view = np.asarray(viewmat, np.float64)
    if camera is None:
        Wr = [[float(view[i, j]) for j in range(3)] for i in range(3)]
        return Wr, [float(view[i, 3]) for i in range(3)], (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]),
                                                            float(K[1, 2]))
    dr = be.dr
    xi = [dr.gather(be.Float, camera["pose"], be.UInt(j)) for j in range(6)]
    rho, (a, b, c) = xi[:3], xi[3:]
    hat = [[0.0, -c, b], [c, 0.0, -a], [-b, a, 0.0]]
    Wr = [[float(view[i, j]) + sum(hat[i][k] * float(view[k, j]) for k in range(3)) for j in range(3)]
          for i in range(3)]
    tv = [float(view[i, 3]) + sum(hat[i][k] * float(view[k, 3]) for k in range(3)) + rho[i] for i in range(3)]
    intr = tuple(dr.gather(be.Float, camera["intrinsics"], be.UInt(j)) for j in range(4))
    return Wr, tv, intr


def _camera_gaussians(be: Backend, leaves: dict, n: int, Wr: list, tv: list) -> tuple[tuple, list, list]:
    """(mu, p = W mu + t, Sigma_c = W R S S^T R^T W^T) of every splat (Dr.Jit rows), with
    R = R(q / |q|) and S = diag(exp l)."""
    dr = be.dr
    mx, my, mz = _rows(be, leaves["means"], n, 3)
    l0, l1, l2 = _rows(be, leaves["log_scales"], n, 3)
    qw, qx, qy, qz = _rows(be, leaves["quats"], n, 4)
    qn = dr.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w, x, y, z = qw / qn, qx / qn, qy / qn, qz / qn
    R = [[1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
         [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
         [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)]]
    s = [dr.exp(l0), dr.exp(l1), dr.exp(l2)]
    M = [[R[i][j] * s[j] for j in range(3)] for i in range(3)]
    Sig = [[sum(M[i][k] * M[j][k] for k in range(3)) for j in range(3)] for i in range(3)]
    mu = (mx, my, mz)
    p = [sum(Wr[i][j] * mu[j] for j in range(3)) + tv[i] for i in range(3)]
    WS = [[sum(Wr[i][k] * Sig[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    return mu, p, [[sum(WS[i][k] * Wr[j][k] for k in range(3)) for j in range(3)] for i in range(3)]


def _sh_colors(be: Backend, leaves: dict, n: int, n_coeffs: int, mu: tuple, Wr: list, tv: list) -> list:
    """max(0, sum_k f_k Y_k(d) + 1/2) per channel, d the unit direction from the camera centre -W^T t."""
    dr = be.dr
    centre = [-sum(Wr[k][i] * tv[k] for k in range(3)) for i in range(3)]
    dv = [mu[i] - centre[i] for i in range(3)]
    dn = dr.sqrt(dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2])
    Y = sh_basis(dv[0] / dn, dv[1] / dn, dv[2] / dn, n_coeffs)
    colors = []
    for ch in range(3):
        acc = dr.zeros(be.Float, n)
        for k in range(n_coeffs):
            acc = acc + Y[k] * dr.gather(be.Float, leaves["sh"], be.arange(n) * (n_coeffs * 3) + k * 3 + ch)
        colors.append(dr.maximum(acc + 0.5, 0.0))
    return colors


def _project(be: Backend, leaves: dict, n: int, n_coeffs: int, viewmat: np.ndarray, K: np.ndarray,
             width: int, height: int, near: float, far: float, camera: dict | None = None) -> dict:
    """Per-splat screen-space values (Dr.Jit arrays) of the module docstring's projection; `camera`:
    the pose and intrinsics leaves (`_camera`) when their gradients are wanted."""
    dr = be.dr
    Wr, tv, (fx, fy, cx, cy) = _camera(be, viewmat, K, camera)
    mu, p, Sc = _camera_gaussians(be, leaves, n, Wr, tv)
    tz = p[2]
    lim_x = FRUSTUM * width / (2.0 * fx)
    lim_y = FRUSTUM * height / (2.0 * fy)
    txc = dr.clip(p[0] / tz, -lim_x, lim_x) * tz
    tyc = dr.clip(p[1] / tz, -lim_y, lim_y) * tz
    J00, J02 = fx / tz, -fx * txc / (tz * tz)
    J11, J12 = fy / tz, -fy * tyc / (tz * tz)
    a = J00 * J00 * Sc[0][0] + 2.0 * J00 * J02 * Sc[0][2] + J02 * J02 * Sc[2][2] + DILATION
    b = J00 * J11 * Sc[0][1] + J00 * J12 * Sc[0][2] + J02 * J11 * Sc[1][2] + J02 * J12 * Sc[2][2]
    c = J11 * J11 * Sc[1][1] + 2.0 * J11 * J12 * Sc[1][2] + J12 * J12 * Sc[2][2] + DILATION
    det = a * c - b * b
    u = fx * p[0] / tz + cx
    v = fy * p[1] / tz + cy
    mid = 0.5 * (a + c)
    lam = mid + dr.sqrt(dr.maximum(EIG_FLOOR, mid * mid - det))
    radius = dr.ceil(3.0 * dr.sqrt(lam))
    colors, opac = _sh_colors(be, leaves, n, n_coeffs, mu, Wr, tv), 1.0 / (1.0 + dr.exp(-leaves["opacity_logits"]))
    out = dict(u=u, v=v, qa=c / det, qb=-b / det, qc=a / det, det=det, z=tz, radius=radius, o=opac,
               c0=colors[0], c1=colors[1], c2=colors[2], in_depth=(tz >= near) & (tz <= far))
    dr.eval(*(x for x in out.values()))
    return out


def _tile_rects(u: np.ndarray, v: np.ndarray, r: np.ndarray, tiles_x: int, tiles_y: int,
                rule: str = "3dgs") -> np.ndarray:
    """Tile rectangles (x0, x1, y0, y1) of the splats: rule "3dgs" is 3DGS's getRect on the screen
    point m = mean2d - 1/2 with C integer truncation; rule "square" lists the tiles that the square
    mean2d +- r meets, [floor((u - r) / 16), ceil((u + r) / 16)) clamped to the image's tiles."""
    if rule == "square":
        with np.errstate(invalid="ignore"):
            x0 = np.clip(np.floor((u - r) / TILE), 0, tiles_x)
            x1 = np.clip(np.ceil((u + r) / TILE), 0, tiles_x)
            y0 = np.clip(np.floor((v - r) / TILE), 0, tiles_y)
            y1 = np.clip(np.ceil((v + r) / TILE), 0, tiles_y)
        return np.stack([x0, x1, y0, y1], axis=1).astype(np.int64)
    if rule != "3dgs":
        raise ValueError(f"tile_rule: expected '3dgs' or 'square', got {rule!r}")
    mx, my = u - 0.5, v - 0.5
    with np.errstate(invalid="ignore"):
        x0 = np.minimum(tiles_x, np.maximum(0, np.trunc((mx - r) / TILE))).astype(np.int64)
        x1 = np.minimum(tiles_x, np.maximum(0, np.trunc((mx + r + TILE - 1) / TILE))).astype(np.int64)
        y0 = np.minimum(tiles_y, np.maximum(0, np.trunc((my - r) / TILE))).astype(np.int64)
        y1 = np.minimum(tiles_y, np.maximum(0, np.trunc((my + r + TILE - 1) / TILE))).astype(np.int64)
    return np.stack([x0, x1, y0, y1], axis=1)


SPLAT_INPUTS = ("means", "log_scales", "quats", "opacity_logits", "sh")


def _splat_leaves(means, log_scales, quats, opacity_logits, sh):
    """The Dr.Jit backend for the inputs' dtype, and one differentiable leaf per splat input (SPLAT_INPUTS)."""
    be = backend(np.asarray(means).dtype)
    return be, {k: be.leaf(x) for k, x in zip(SPLAT_INPUTS, (means, log_scales, quats, opacity_logits, sh))}


def project_oracle(means, log_scales, quats, opacity_logits, sh, viewmat, K, width: int, height: int,
                   near: float, far: float, cotangents: dict[str, np.ndarray] | None = None, tile_rule: str = "3dgs"
                   ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Per-splat projection: ({"means2d", "conics", "depths", "radii", "colors", "opacities"} with
    culled splats' entries 0, as drlab stores them), and the VJPs for cotangents of
    means2d (N, 2), conics (N, 3), depths (N,), colors (N, 3), opacities (N,) (culled splats: none)."""
    _check_splats(means, log_scales, quats, opacity_logits, sh, viewmat, K, tile_rule)
    be, leaves = _splat_leaves(means, log_scales, quats, opacity_logits, sh)
    dr = be.dr
    n = means.shape[0]
    n_coeffs = sh.shape[1]
    P = _project(be, leaves, n, n_coeffs, viewmat, K, width, height, near, far)
    tx, ty = (width + TILE - 1) // TILE, (height + TILE - 1) // TILE
    vis = _visible(be, P, n, tx, ty, tile_rule)
    keep = be.Bool(vis)
    outs = {k: dr.select(keep, P[k], 0.0) for k in ("u", "v", "qa", "qb", "qc", "z", "c0", "c1", "c2", "o")}
    res = {
        "means2d": np.stack([be.numpy(outs["u"], (n,)), be.numpy(outs["v"], (n,))], axis=1),
        "conics": np.stack([be.numpy(outs[k], (n,)) for k in ("qa", "qb", "qc")], axis=1),
        "depths": be.numpy(outs["z"], (n,)),
        "radii": np.where(vis, np.array(P["radius"], np.float64), 0).astype(np.int64),
        "colors": np.stack([be.numpy(outs[k], (n,)) for k in ("c0", "c1", "c2")], axis=1),
        "opacities": be.numpy(outs["o"], (n,)),
    }
    grads: dict[str, np.ndarray] = {}
    if cotangents is not None:
        cot = cotangents
        pairs = [(outs["u"], cot["means2d"][:, 0]), (outs["v"], cot["means2d"][:, 1]),
                 (outs["qa"], cot["conics"][:, 0]), (outs["qb"], cot["conics"][:, 1]),
                 (outs["qc"], cot["conics"][:, 2]), (outs["z"], cot["depths"]),
                 (outs["c0"], cot["colors"][:, 0]), (outs["c1"], cot["colors"][:, 1]),
                 (outs["c2"], cot["colors"][:, 2]), (outs["o"], cot["opacities"])]
        dr.backward(be.dot([p for p, _ in pairs], [c for _, c in pairs]))
        grads = {k: be.grad(leaves[k], np.shape(x)) for k, x in zip(SPLAT_INPUTS, (means, log_scales, quats,
                                                                            opacity_logits, sh))}
    return res, grads


def _visible(be: Backend, P: dict, n: int, tiles_x: int, tiles_y: int, rule: str) -> np.ndarray:
    """Boolean (N,): in the depth range, det > 0 and a non-empty tile rectangle."""
    det = np.array(P["det"], np.float64)
    u, v, r = (np.array(P[k], np.float64) for k in ("u", "v", "radius"))
    rect = _tile_rects(u, v, r, tiles_x, tiles_y, rule)
    area = (rect[:, 1] - rect[:, 0]) * (rect[:, 3] - rect[:, 2])
    return np.array(P["in_depth"], bool) & (det > 0) & np.isfinite(det) & (area > 0)


def render_oracle(means, log_scales, quats, opacity_logits, sh, viewmat, K, width: int, height: int,
                  near: float, far: float, background, grad_rgb, grad_alpha=None, grad_depth=None,
                  tile_rule: str = "3dgs", want_camera: bool = False) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], dict[str, np.ndarray], dict[str, Any]]:
    """((rgb (H, W, 3), alpha (H, W), depth (H, W)), VJPs {"means", "log_scales", "quats",
    "opacity_logits", "sh", "background"} (with `want_camera` also "pose" (6,), d/dxi at xi = 0 of the
    left perturbation exp(xi^) [W | t], xi = (rho, phi), and "intrinsics" (4,), d/d(fx, fy, cx, cy)),
    info {"max_list": longest tile list, "visible": visible splats}) of the whole chain."""
    _check_splats(means, log_scales, quats, opacity_logits, sh, viewmat, K, tile_rule)
    check_array("background", np.asarray(background, dtype=means.dtype), (3,))
    for name, c, shape in (("grad_rgb", grad_rgb, (height, width, 3)), ("grad_alpha", grad_alpha, (height, width)),
                           ("grad_depth", grad_depth, (height, width))):
        if c is not None:
            check_array(name, c, shape)
    be, leaves = _splat_leaves(means, log_scales, quats, opacity_logits, sh)
    dr = be.dr
    n = means.shape[0]
    n_coeffs = sh.shape[1]
    bg = be.leaf(np.asarray(background))
    camera = None
    if want_camera:
        Kn = np.asarray(K, np.float64)
        camera = {"pose": be.leaf(np.zeros(6)), "intrinsics": be.leaf([Kn[0, 0], Kn[1, 1], Kn[0, 2], Kn[1, 2]])}
    P = _project(be, leaves, n, n_coeffs, viewmat, K, width, height, near, far, camera)
    tx, ty = (width + TILE - 1) // TILE, (height + TILE - 1) // TILE
    vis = _visible(be, P, n, tx, ty, tile_rule)
    # Tile lists: every visible splat in every tile of its rectangle, front to back (depth order).
    u, v, r = (np.array(P[k], np.float64) for k in ("u", "v", "radius"))
    rect = _tile_rects(u, v, r, tx, ty, tile_rule)
    order = np.argsort(np.array(P["z"], np.float64), kind="stable")
    lists: list[list[int]] = [[] for _ in range(tx * ty)]
    for i in order:
        if vis[i]:
            x0, x1, y0, y1 = rect[i]
            for tyy in range(y0, y1):
                for txx in range(x0, x1):
                    lists[tyy * tx + txx].append(int(i))
    kmax = max((len(l) for l in lists), default=0)
    table = np.full((tx * ty, max(kmax, 1)), -1, np.int64)
    for t, l in enumerate(lists):
        table[t, :len(l)] = l
    has = table >= 0
    table_idx = be.UInt(np.where(has, table, 0).astype(np.uint32).ravel())
    table_has = be.Bool(has.ravel())
    npx = width * height
    pix = be.arange(npx)
    px, py = pix % width, pix // width
    tile = (py // TILE) * tx + px // TILE
    pxf, pyf = be.Float(px) + 0.5, be.Float(py) + 0.5
    T = dr.full(be.Float, 1.0, npx)
    C = [dr.zeros(be.Float, npx) for _ in range(3)]
    D = dr.zeros(be.Float, npx)
    done = dr.full(be.Bool, False, npx)
    attrs = [P[k] for k in ("u", "v", "qa", "qb", "qc", "o", "c0", "c1", "c2", "z")]
    stride = max(kmax, 1)
    for k in range(kmax):
        slot = tile * stride + dr.opaque(be.UInt, k)
        g = dr.gather(be.UInt, table_idx, slot)
        present = dr.gather(be.Bool, table_has, slot) & ~done
        gu, gv, qa, qb, qc, o, c0, c1, c2, z = (dr.gather(be.Float, a, g, present) for a in attrs)
        dx, dy = gu - pxf, gv - pyf
        power = -0.5 * (qa * dx * dx + qc * dy * dy) - qb * dx * dy
        alpha = dr.minimum(ALPHA_MAX, o * dr.exp(power))
        use = present & (power <= 0.0) & (alpha >= ALPHA_MIN)
        test_t = T * (1.0 - alpha)
        stop = use & (test_t < T_MIN)
        done = done | stop
        use = use & ~stop
        wgt = dr.select(use, alpha * T, 0.0)
        C = [C[0] + wgt * c0, C[1] + wgt * c1, C[2] + wgt * c2]
        D = D + wgt * z
        T = dr.select(use, test_t, T)
        dr.eval(T, done, D, *C)
    rgb = [C[ch] + T * dr.gather(be.Float, bg, be.UInt(ch)) for ch in range(3)]
    alpha_out = 1.0 - T
    dr.eval(alpha_out, *rgb)
    outs = [*rgb, alpha_out, D]
    cots = [grad_rgb[..., 0], grad_rgb[..., 1], grad_rgb[..., 2],
            np.zeros((height, width)) if grad_alpha is None else grad_alpha,
            np.zeros((height, width)) if grad_depth is None else grad_depth]
    dr.backward(be.dot(outs, cots))
    grads = {k: be.grad(leaves[k], np.shape(x))
             for k, x in zip(SPLAT_INPUTS, (means, log_scales, quats, opacity_logits, sh))}
    grads["background"] = be.grad(bg, (3,))
    if camera is not None:
        grads["pose"] = be.grad(camera["pose"], (6,))
        grads["intrinsics"] = be.grad(camera["intrinsics"], (4,))
    image = (np.stack([be.numpy(c, (height, width)) for c in rgb], axis=-1), be.numpy(alpha_out, (height, width)),
             be.numpy(D, (height, width)))
    return image, grads, {"max_list": kmax, "visible": int(vis.sum())}
