"""kernels/volume's fields against their Dr.Jit oracles (research/oracles/volume.py): the dense grid
(RGB and SH colour, softplus and exp densities), the hash encoding (dense and hashed levels), the
MLP (both backends) and the whole hash-grid field, forward and VJPs, float64 and float32."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels.volume import GridField, HashGridField
from kernels.volume.hashgrid import HashEncoding
from kernels.volume.mlp import MLP, init_mlp_params
from research.oracles.volume import grid_field_oracle, hash_encoding_oracle, hashgrid_field_oracle, mlp_oracle
from tests.oracles.conftest import U32, close64, within

BBOX = np.array([[-1.0, -0.8, -1.2], [1.0, 1.1, 0.9]])
WP = {np.float32: wp.float32, np.float64: wp.float64}


def _points(rng, n, dtype, margin=0.1):
    lo, hi = BBOX[0] - margin, BBOX[1] + margin  # some points outside the box: zero outputs, no gradient
    pts = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    return pts.astype(dtype), (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(dtype)


def _grid_case(seed, dtype, sh_degree, activation, n=300, res=(7, 6, 5)):
    rng = np.random.default_rng(seed)
    f = GridField(BBOX, res, sh_degree=sh_degree, density_bias=-0.7, density_scale=2.5,
                  density_activation=activation, dtype=WP[dtype])
    nc = 1 if sh_degree is None else (sh_degree + 1) ** 2
    nv = int(np.prod(res))
    density = rng.normal(size=nv).astype(dtype)
    color = rng.normal(size=(nv, 3 * nc)).astype(dtype)
    f.set_params({"density": density, "color": color})
    pts, dirs = _points(rng, n, dtype)
    dirs = dirs if sh_degree is not None else None
    gs, gr = rng.normal(size=n).astype(dtype), rng.normal(size=(n, 3)).astype(dtype)
    out = f.forward(pts, dirs)
    grads = f.backward(pts, dirs, out, gs, gr)
    return f, (pts, dirs, density, color, gs, gr), out, {k: v.numpy() for k, v in grads.items()}


@pytest.mark.parametrize("sh_degree, activation", [(None, "softplus"), (2, "softplus"), (1, "exp")])
def test_grid_float64(sh_degree, activation):
    f, (pts, dirs, density, color, gs, gr), out, grads = _grid_case(0, np.float64, sh_degree, activation)
    (s, c), og = grid_field_oracle(pts, dirs, density, color, BBOX, f.resolution, sh_degree, -0.7, 2.5, activation,
                                   gs, gr)
    close64("sigma", out.sigma, s)
    close64("rgb", out.rgb, c)
    close64("d density", grads["density"], og["density"])
    close64("d color", grads["color"], og["color"])


def _points_per_vertex(pts, res) -> int:
    """The most points that share one grid vertex (they add into its gradient)."""
    u = (pts.astype(np.float64) - BBOX[0]) / (BBOX[1] - BBOX[0]) * (np.array(res) - 1)
    inside = np.all((u >= 0) & (u <= np.array(res) - 1), axis=1)
    cell = np.minimum(np.floor(u[inside]).astype(int), np.array(res) - 2)
    counts = np.zeros(res[::-1])
    for b in range(8):
        off = np.array([b & 1, (b >> 1) & 1, (b >> 2) & 1])
        v = cell + off
        np.add.at(counts, (v[:, 2], v[:, 1], v[:, 0]), 1)
    return int(counts.max())


def test_grid_float32_within_the_rounding_bound():
    """The grid coordinate u = (p - lo) / (hi - lo) (n - 1) has absolute error ~ 3 u n_max, which moves
    the trilinear weights (products of 3 factors, 8 corners): raw = sum_b w_b D has |error| <=
    (8 + 3 (n_max + 3)) u max|D| =: e. sigma = scale softplus(raw + bias), softplus' <= 1 and softplus(x)
    <= |x| + 1: |error| <= scale (e + 4 u (max|D| + |bias| + 1)). rgb = sigmoid(sum_j Y_j sum_b w_b K),
    sigmoid' <= 1/4: |error| <= (e' / 4 + 4 u) with e' = (8 + 3 (n_max + 3) + n_coef) u max sum|Y| max|K|.
    Gradients: each vertex sums the terms of the m points around it, |error| <= (m + 12 + 3 n_max) u
    times the sum of |terms|: for the density the oracle's VJP on |g_sigma| (every factor then >= 0),
    for the colour m max|term|, |term| <= max|g_rgb| / 4 max|Y| <= max|g_rgb| / 4 sum|Y|."""
    res, deg = (7, 6, 5), 2
    f, (pts, dirs, density, color, gs, gr), out, grads = _grid_case(1, np.float32, deg, "softplus", res=res)
    a64 = [None if a is None else a.astype(np.float64) for a in (pts, dirs, density, color, gs, gr)]
    (s, c), og = grid_field_oracle(*a64[:4], BBOX, res, deg, -0.7, 2.5, "softplus", *a64[4:])
    _, mg = grid_field_oracle(*a64[:4], BBOX, res, deg, -0.7, 2.5, "softplus", np.abs(a64[4]), np.abs(a64[5]))
    n_max, n_coef = max(res), (deg + 1) ** 2
    e = (8 + 3 * (n_max + 3)) * U32 * np.abs(density).max()
    within("sigma", out.sigma, s, 2.5 * (e + 4 * U32 * (np.abs(density).max() + 0.7 + 1)))
    # sum_j |Y_j(d)| for degree <= 2 on the unit sphere: C0 + sqrt(3) C1 + 1.0925 (|xy| + |yz| + |zx| <= 1)
    # + 0.3154 |2z^2 - x^2 - y^2| (<= 2) + 0.5463 |x^2 - y^2| (<= 1) = 3.39 at most.
    y_sum = 3.4
    e_rgb = (8 + 3 * (n_max + 3) + n_coef) * U32 * y_sum * np.abs(color).max()
    within("rgb", out.rgb, c, e_rgb / 4 + 4 * U32)
    m = _points_per_vertex(pts, res)
    within("d density", grads["density"], og["density"], (m + 12 + 3 * n_max) * U32 * mg["density"].max())
    within("d color", grads["color"], og["color"],
           (m + 12 + 3 * n_max) * U32 * m * np.abs(gr).max() / 4 * y_sum)


def _hash_case(seed, dtype, log2_table):
    rng = np.random.default_rng(seed)
    enc = HashEncoding(BBOX, n_levels=5, n_features=2, log2_table_size=log2_table, base_resolution=3,
                       max_resolution=40)
    table = rng.uniform(-1, 1, enc.table_shape).astype(dtype)
    pts, _ = _points(rng, 400, dtype)
    g = rng.normal(size=(400, enc.n_outputs)).astype(dtype)
    wp_pts = wp.array(pts, dtype=WP[dtype])
    wp_table = wp.array(table, dtype=WP[dtype])
    out = enc.encode(wp_pts, wp_table).numpy()
    grad = enc.backward(wp_pts, wp_table, wp.array(g, dtype=WP[dtype])).numpy()
    return enc, pts, table, g, out, grad


@pytest.mark.parametrize("log2_table", [17, 9])  # all levels dense; the fine levels hashed (collisions)
def test_hash_encoding_float64(log2_table):
    enc, pts, table, g, out, grad = _hash_case(2, np.float64, log2_table)
    assert enc.dense.all() == (log2_table == 17)
    want, wgrad = hash_encoding_oracle(pts, table, BBOX, enc.resolutions, enc.table_size, g)
    close64("encoding", out, want)
    close64("d table", grad, wgrad)


def test_hash_encoding_float32_within_the_rounding_bound():
    """enc_l = sum_b w_b table: the level coordinate x N_l has absolute error ~ 3 u N_max, which moves
    the weights: |error| <= (8 + 3 (N_max + 3)) u max|table|. The table gradient sums w |g| over
    the points sharing a row (m of them, more with hash collisions): |error| <= (m + 8 + 3 N_max) u
    times the oracle's VJP on |g|."""
    enc, pts, table, g, out, grad = _hash_case(3, np.float32, 9)
    a64 = [a.astype(np.float64) for a in (pts, table, g)]
    want, wgrad = hash_encoding_oracle(a64[0], a64[1], BBOX, enc.resolutions, enc.table_size, a64[2])
    _, mgrad = hash_encoding_oracle(a64[0], a64[1], BBOX, enc.resolutions, enc.table_size, np.abs(a64[2]))
    n_max = int(enc.resolutions.max())
    within("encoding", out, want, (8 + 3 * (n_max + 3)) * U32 * np.abs(table).max())
    m = len(pts) * 8
    within("d table", grad, wgrad, (m + 8 + 3 * n_max) * U32 * mgrad.max())


def _mlp_case(seed, dtype, backend, sizes=(6, 16, 16, 4), n=200):
    rng = np.random.default_rng(seed)
    params = {k: v for k, v in init_mlp_params(sizes, seed, WP[dtype], wp.get_device("cpu")).items()}
    mlp = MLP(list(sizes), params, backend)
    x = rng.normal(size=(n, sizes[0])).astype(dtype)
    g = rng.normal(size=(n, sizes[-1])).astype(dtype)
    y, cache = mlp.forward(wp.array(x, dtype=WP[dtype]))
    grads, gx = mlp.backward(cache, wp.array(g, dtype=WP[dtype]), need_input_grad=True)
    grads = {k: v.numpy() for k, v in grads.items()}
    grads["x"] = gx.numpy()
    return sizes, {k: v.numpy() for k, v in params.items()}, x, g, y.numpy(), grads


@pytest.mark.parametrize("backend", ["numpy", "warp"])
def test_mlp_float64(backend):
    sizes, params, x, g, y, grads = _mlp_case(4, np.float64, backend)
    want, wgrads = mlp_oracle(x, params, sizes, g)
    close64("y", y, want)
    for k in wgrads:
        close64(f"d{k}", grads[k], wgrads[k])


@pytest.mark.parametrize("backend", ["numpy", "warp"])
def test_mlp_float32_within_the_rounding_bound(backend):
    """Layer l's products are n_l-term dot products: with the magnitudes |a_{l+1}| <= |W_l| |a_l| + |b_l|
    (ReLU is 1-Lipschitz) and |dz_{l-1}| <= |dz_l| |W_l|, every output is within (sum_l n_l + 2 L) u
    of its magnitude chain (Higham's bound for a product of matrices); a weight gradient
    dW_l = dz_l^T a_l sums N points: (N + sum_l n_l + 2 L) u |dz_l|^T |a_l|."""
    sizes, params, x, g, y, grads = _mlp_case(5, np.float32, backend)
    p64 = {k: v.astype(np.float64) for k, v in params.items()}
    want, wgrads = mlp_oracle(x.astype(np.float64), p64, sizes, g.astype(np.float64))
    L = len(sizes) - 1
    acts = [np.abs(x.astype(np.float64))]
    for l in range(L):
        acts.append(acts[-1] @ np.abs(p64[f"W{l}"]).T + np.abs(p64[f"b{l}"]))
    dz = [None] * L
    dz[L - 1] = np.abs(g.astype(np.float64))
    for l in range(L - 1, 0, -1):
        dz[l - 1] = dz[l] @ np.abs(p64[f"W{l}"])
    n_chain = sum(sizes) + 2 * L
    within("y", y, want, n_chain * U32 * acts[-1].max())
    N = x.shape[0]
    for l in range(L):
        within(f"dW{l}", grads[f"W{l}"], wgrads[f"W{l}"], (N + n_chain) * U32 * (dz[l].T @ acts[l]).max())
        within(f"db{l}", grads[f"b{l}"], wgrads[f"b{l}"], (N + n_chain) * U32 * dz[l].sum(0).max())
    within("dx", grads["x"], wgrads["x"], n_chain * U32 * (dz[0] @ np.abs(p64["W0"])).max())


@pytest.mark.parametrize("activation", ["exp", "softplus"])
def test_hashgrid_field_float64(activation):
    rng = np.random.default_rng(6)
    f = HashGridField(BBOX, n_levels=4, n_features=2, log2_table_size=10, base_resolution=3, max_resolution=24,
                      hidden=(16, 16), density_bias=-0.5, density_activation=activation, dtype=wp.float64)
    f.set_params({"table": rng.uniform(-1, 1, f.params["table"].shape)})
    pts, _ = _points(rng, 150, np.float64)
    gs, gr = rng.normal(size=150), rng.normal(size=(150, 3))
    out = f.forward(pts)
    grads = {k: v.numpy() for k, v in f.backward(pts, None, out, gs, gr).items()}
    params = {k: v.numpy() for k, v in f.params.items()}
    (s, c), og = hashgrid_field_oracle(pts, params, BBOX, f.encoding.resolutions, f.encoding.table_size, f.sizes,
                                       -0.5, activation, gs, gr)
    close64("sigma", out.sigma, s)
    close64("rgb", out.rgb, c)
    assert sorted(grads) == sorted(og)
    for k in og:
        close64(f"d{k}", grads[k], og[k])
