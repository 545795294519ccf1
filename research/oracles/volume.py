"""Dr.Jit oracles for the volume fields of kernels/volume: dense grid, hash encoding, MLP, hash-grid field.

Written from the docstrings of kernels/volume/grid.py, hashgrid.py, mlp.py, neural.py and _act.py.

Dense grid (Plenoxels / DVGO). Vertices v = ix + nx (iy + ny iz) of a grid over [lo, hi]; a point
has u_a = (p_a - lo_a) / (hi_a - lo_a) (n_a - 1), cell i_a = min(floor(u_a), n_a - 2) (and >= 0),
f_a = u_a - i_a, trilinear weights w_b = prod_a (b_a f_a + (1 - b_a)(1 - f_a)), and

    sigma = scale act(sum_b w_b D[i + b] + bias),   rgb_c = sigmoid(sum_j Y_j(d) sum_b w_b K_{c,j}[i + b]),

K laid out (V, 3 n_coef) channel-major (column c n_coef + j), Y the real SH basis of kernels/sh.py
(plain RGB: Y_0 = 1); act = softplus(x) = log(1 + e^x) or exp(min(x, 15)). Points outside the box
(u_a < 0 or u_a > n_a - 1) get sigma = rgb = 0.

Hash encoding (instant-ngp). x = clamp((p - lo) / (hi - lo), 0, 1); level l of resolution N_l:
u = x N_l, i = clamp(floor(u), 0, N_l - 1), f = u - i; enc_l = sum_b w_b table[l T + h_l(i + b)],
h_l(v) = v_x + (N_l + 1)(v_y + (N_l + 1) v_z) on dense levels ((N_l + 1)^3 <= T), else
(v_x XOR v_y 2654435761 XOR v_z 805459861) mod T in uint32 arithmetic.

MLP: z_l = a_l W_l^T + b_l, a_{l+1} = relu(z_l), output z_{L-1}. Hash-grid field: MLP on the
encoding, then sigma = act(y_0 + bias), rgb = sigmoid(y_1..3); outside the box all 0.

Gradients of every parameter come from Dr.Jit's AD of sum(g_sigma sigma) + sum(g_rgb rgb) (or
sum(G out)); the gathers' adjoints are Dr.Jit's scatter-adds.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from research.oracles import Backend, backend, check_array

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)
PRIME_Y = 2654435761
PRIME_Z = 805459861
EXP_CLAMP = 15.0


def sh_basis(x, y, z, n: int) -> list:
    """The first n real SH functions (kernels/sh.py's table, Plenoxels/3DGS signs) of (x, y, z)."""
    xx, yy, zz = x * x, y * y, z * z
    Y = [SH_C0 + 0.0 * x, -SH_C1 * y, SH_C1 * z, -SH_C1 * x,
         SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2.0 * zz - xx - yy), SH_C2[3] * x * z, SH_C2[4] * (xx - yy),
         SH_C3[0] * y * (3.0 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4.0 * zz - xx - yy),
         SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), SH_C3[4] * x * (4.0 * zz - xx - yy),
         SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3.0 * yy)]
    return Y[:n]


def _act(be: Backend, x, kind: str):
    dr = be.dr
    if kind == "exp":
        return dr.exp(dr.minimum(x, EXP_CLAMP))
    return dr.maximum(x, 0.0) + dr.log(1.0 + dr.exp(-dr.abs(x)))


def _sigmoid(be: Backend, x):
    return 1.0 / (1.0 + be.dr.exp(-x))


def _corners():
    return [(c & 1, (c >> 1) & 1, (c >> 2) & 1) for c in range(8)]


def grid_eval(be: Backend, pts: list, dirs: list | None, Dn, K, bbox: np.ndarray, resolution: Sequence[int],
              sh_degree: int | None, density_bias: float, density_scale: float, activation: str) -> tuple:
    """(sigma, [r, g, b]) of the dense grid field (module docstring) at points pts = [x, y, z] and view
    directions dirs (Dr.Jit arrays, differentiable or not), for the flat vertex arrays Dn (V,) and K
    (V, 3 n_coef). The cell index floor(u) is piecewise constant; the weights carry the points' gradient."""
    dr = be.dr
    n = dr.width(pts[0])
    nx, ny, nz = resolution
    n_coef = 1 if sh_degree is None else (sh_degree + 1) ** 2
    cells, fracs, inside = [], [], be.Bool(True)
    for a, na in enumerate(resolution):
        lo, hi = float(bbox[0][a]), float(bbox[1][a])
        u = (pts[a] - lo) / (hi - lo) * float(na - 1)
        inside = inside & (u >= 0.0) & (u <= float(na - 1))
        i = dr.clip(be.Int(dr.floor(dr.detach(u))), 0, na - 2)
        cells.append(i)
        fracs.append(u - be.Float(i))
    raw_d = dr.zeros(be.Float, n)
    coef = [[dr.zeros(be.Float, n) for _ in range(n_coef)] for _ in range(3)]
    for bx, by, bz in _corners():
        w = ((fracs[0] if bx else 1.0 - fracs[0]) * (fracs[1] if by else 1.0 - fracs[1])
             * (fracs[2] if bz else 1.0 - fracs[2]))
        v = be.UInt((cells[0] + bx) + nx * ((cells[1] + by) + ny * (cells[2] + bz)))
        raw_d = raw_d + w * dr.gather(be.Float, Dn, v, inside)
        for c in range(3):
            for j in range(n_coef):
                coef[c][j] = coef[c][j] + w * dr.gather(be.Float, K, v * (3 * n_coef) + c * n_coef + j, inside)
    sigma = dr.select(inside, density_scale * _act(be, raw_d + density_bias, activation), 0.0)
    Y = [be.Float(1.0)] if sh_degree is None else sh_basis(dirs[0], dirs[1], dirs[2], n_coef)
    rgb = []
    for c in range(3):
        s = dr.zeros(be.Float, n)
        for j in range(n_coef):
            s = s + Y[j] * coef[c][j]
        rgb.append(dr.select(inside, _sigmoid(be, s), 0.0))
    return sigma, rgb


def grid_field_oracle(points: np.ndarray, dirs: np.ndarray | None, density: np.ndarray, color: np.ndarray,
                      bbox: np.ndarray, resolution: Sequence[int], sh_degree: int | None, density_bias: float,
                      density_scale: float, activation: str, grad_sigma: np.ndarray, grad_rgb: np.ndarray
                      ) -> tuple[tuple[np.ndarray, np.ndarray], dict[str, np.ndarray]]:
    """((sigma (N,), rgb (N, 3)), {"density", "color": VJPs}) of the dense grid field."""
    check_array("points", points, (None, 3))
    n_coef = 1 if sh_degree is None else (sh_degree + 1) ** 2
    if sh_degree is not None:
        check_array("dirs", dirs, points.shape)
    check_array("density", density, (int(np.prod(resolution)),))
    check_array("color", color, (int(np.prod(resolution)), 3 * n_coef))
    check_array("grad_sigma", grad_sigma, (points.shape[0],))
    check_array("grad_rgb", grad_rgb, (points.shape[0], 3))
    be = backend(points.dtype)
    dr = be.dr
    n = points.shape[0]
    Dn, K = be.leaf(density), be.leaf(color)
    pts = [be.const(points[:, a]) for a in range(3)]
    dvs = None if sh_degree is None else [be.const(dirs[:, a]) for a in range(3)]
    sigma, rgb = grid_eval(be, pts, dvs, Dn, K, bbox, resolution, sh_degree, density_bias, density_scale, activation)
    dr.eval(sigma, *rgb)
    dr.backward(be.dot([sigma, *rgb], [grad_sigma, *(grad_rgb[:, c] for c in range(3))]))
    out = (be.numpy(sigma, (n,)), np.stack([be.numpy(r, (n,)) for r in rgb], axis=1))
    return out, {"density": be.grad(Dn, density.shape), "color": be.grad(K, color.shape)}


def _hash_encode(be: Backend, pts: list, table, bbox, resolutions, table_size: int, n_features: int) -> list:
    """[enc_l,f] as flat arrays (one per level and feature), from a differentiable flat table."""
    dr = be.dr
    xs = []
    for a in range(3):
        lo, hi = float(bbox[0][a]), float(bbox[1][a])
        xs.append(dr.clip((pts[a] - lo) / (hi - lo), 0.0, 1.0))
    feats = []
    for l, res in enumerate(int(r) for r in resolutions):
        dense = (res + 1) ** 3 <= table_size
        cells, fracs = [], []
        for a in range(3):
            u = xs[a] * float(res)
            i = dr.clip(be.Int(dr.floor(u)), 0, res - 1)
            cells.append(i)
            fracs.append(u - be.Float(i))
        acc = [dr.zeros(be.Float, dr.width(pts[0])) for _ in range(n_features)]
        for bx, by, bz in _corners():
            w = ((fracs[0] if bx else 1.0 - fracs[0]) * (fracs[1] if by else 1.0 - fracs[1])
                 * (fracs[2] if bz else 1.0 - fracs[2]))
            vx, vy, vz = (be.UInt(cells[0] + bx), be.UInt(cells[1] + by), be.UInt(cells[2] + bz))
            if dense:
                h = vx + (res + 1) * (vy + (res + 1) * vz)
            else:
                h = (vx ^ (vy * be.UInt(PRIME_Y)) ^ (vz * be.UInt(PRIME_Z))) & be.UInt(table_size - 1)
            row = h + l * table_size
            for f in range(n_features):
                acc[f] = acc[f] + w * dr.gather(be.Float, table, row * n_features + f)
        dr.eval(*acc)
        feats.extend(acc)
    return feats


def hash_encoding_oracle(points: np.ndarray, table: np.ndarray, bbox: np.ndarray, resolutions: Sequence[int],
                         table_size: int, grad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(enc (N, L F), dL/dtable (L T, F)) for L = sum(grad * enc)."""
    check_array("points", points, (None, 3))
    check_array("table", table, (len(resolutions) * table_size, None))
    check_array("grad", grad, (points.shape[0], len(resolutions) * table.shape[1]))
    be = backend(points.dtype)
    dr = be.dr
    n, F = points.shape[0], table.shape[1]
    T = be.leaf(table)
    feats = _hash_encode(be, [be.const(points[:, a]) for a in range(3)], T, bbox, resolutions, table_size, F)
    dr.backward(be.dot(feats, [grad[:, k] for k in range(grad.shape[1])]))
    return np.stack([be.numpy(f, (n,)) for f in feats], axis=1), be.grad(T, table.shape)


def _mlp(be: Backend, a, n: int, leaves: dict, sizes: Sequence[int]):
    """The MLP on inputs a, flat (N, n_0) row-major or a list of n_0 columns; leaves W_l (flat (n_out, n_in)) and b_l.

    Each layer is vectorised over its N n_out outputs (n, j) with a Python loop over the inputs k:
    z[n, j] = b[j] + sum_k a[n, k] W[j, k], gathers whose adjoints scatter-add into a, W and b.
    """
    dr = be.dr
    n_layers = len(sizes) - 1
    for l in range(n_layers):
        n_in, n_out = sizes[l], sizes[l + 1]
        W, b = leaves[f"W{l}"], leaves[f"b{l}"]
        i = be.arange(n * n_out)
        row, j = i // n_out, i % n_out
        z = dr.gather(be.Float, b, j)
        for k in range(n_in):
            a_k = dr.gather(be.Float, a[k], row) if isinstance(a, list) else dr.gather(be.Float, a, row * n_in + k)
            z = dr.fma(a_k, dr.gather(be.Float, W, j * n_in + k), z)
            if k % 16 == 15:
                dr.eval(z)
        a = dr.maximum(z, 0.0) if l < n_layers - 1 else z
        dr.eval(a)
    return a


def mlp_oracle(x: np.ndarray, params: dict[str, np.ndarray], sizes: Sequence[int], grad: np.ndarray
               ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(y (N, n_out), {"x", "W0", "b0", ...: VJPs}) of the ReLU MLP for L = sum(grad * y)."""
    check_array("x", x, (None, sizes[0]))
    for l in range(len(sizes) - 1):
        check_array(f"W{l}", params.get(f"W{l}"), (sizes[l + 1], sizes[l]))
        check_array(f"b{l}", params.get(f"b{l}"), (sizes[l + 1],))
    check_array("grad", grad, (x.shape[0], sizes[-1]))
    be = backend(x.dtype)
    dr = be.dr
    n = x.shape[0]
    leaves = {k: be.leaf(v) for k, v in params.items()}
    xl = be.leaf(x)
    y = _mlp(be, xl, n, leaves, sizes)
    dr.backward(be.dot([y], [grad]))
    grads = {k: be.grad(v, params[k].shape) for k, v in leaves.items()}
    grads["x"] = be.grad(xl, x.shape)
    return be.numpy(y, (n, sizes[-1])), grads


def hashgrid_field_oracle(points: np.ndarray, params: dict[str, np.ndarray], bbox: np.ndarray,
                          resolutions: Sequence[int], table_size: int, sizes: Sequence[int], density_bias: float,
                          activation: str, grad_sigma: np.ndarray, grad_rgb: np.ndarray
                          ) -> tuple[tuple[np.ndarray, np.ndarray], dict[str, np.ndarray]]:
    """((sigma, rgb), {parameter: VJP}) of the hash-grid field: encoding, MLP, head."""
    be = backend(points.dtype)
    dr = be.dr
    n = points.shape[0]
    leaves = {k: be.leaf(v) for k, v in params.items()}
    pts = [be.const(points[:, a]) for a in range(3)]
    feats = _hash_encode(be, pts, leaves["table"], bbox, resolutions, table_size, params["table"].shape[1])
    y = _mlp(be, feats, n, leaves, sizes)
    out4 = [dr.gather(be.Float, y, be.arange(n) * 4 + c) for c in range(4)]
    inside = be.Bool(True)
    for a in range(3):
        inside = inside & (pts[a] >= float(bbox[0][a])) & (pts[a] <= float(bbox[1][a]))
    sigma = dr.select(inside, _act(be, out4[0] + density_bias, activation), 0.0)
    rgb = [dr.select(inside, _sigmoid(be, out4[1 + c]), 0.0) for c in range(3)]
    dr.eval(sigma, *rgb)
    dr.backward(be.dot([sigma, *rgb], [grad_sigma, *(grad_rgb[:, c] for c in range(3))]))
    out = (be.numpy(sigma, (n,)), np.stack([be.numpy(r, (n,)) for r in rgb], axis=1))
    return out, {k: be.grad(v, params[k].shape) for k, v in leaves.items()}
