"""kernels.volume fields: soft spheres, voxel grid, hash encoding, positional encoding, MLP, neural fields.

Forward passes against NumPy references written from the module docstrings (float32 and
float64); backward passes through float64 finite differences (research.checks.volume).
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import warp as wp

from kernels.volume import (GridField, HashEncoding, HashGridField, MLP, PEMLPField, PositionalEncoding, SphereField,
                            Workspace)
from kernels._arrays import value_checks
from kernels.reference import volume as ref_volume
from kernels.volume.mlp import init_mlp_params
from research.checks import rounding
from research.checks.volume import BOX, check_grid, check_neural, check_spheres, neural_field
from research.gradcheck import assert_gradcheck

DTYPES = [(np.float32, wp.float32, 2e-5), (np.float64, wp.float64, 1e-12)]


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def grid_reference(field, p, d):
    return ref_volume.grid(field.params["density"].numpy(), field.params["color"].numpy(), field.resolution,
                           field.bbox, field.sh_degree, field.density_bias, field.density_scale,
                           field.density_activation, p, d)


def hash_reference(enc: HashEncoding, p, table):
    return ref_volume.hash_encoding(enc.bbox, enc.resolutions, enc.table_size, enc.n_features, p, table)


# --------------------------------------------------------------------------- soft spheres

@pytest.mark.parametrize("np_t, wp_t, tol", DTYPES)
@pytest.mark.usefixtures("warp_device")
def test_spheres_forward(np_t, wp_t, tol):
    rng = np.random.default_rng(0)
    field = SphereField.textbook(wp_t)
    # Inside, near and far from the spheres (far points: density < 1e-6, unnormalised colour).
    p = np.concatenate([rng.uniform([-2, -1.5, 2.5], [2.5, 1.5, 6.5], (50, 3)), [[9.0, 9.0, 9.0]]]).astype(np_t)
    out = field.forward(p)
    P = {k: v.astype(np.float64) for k, v in field.params_numpy().items()}
    ref = ref_volume.spheres(p.astype(np.float64), P["centers"], P["radii"], P["colors"], P["sharpness"])
    assert ref[0][-1] < 1e-6
    np.testing.assert_allclose(out.sigma, ref[0], rtol=tol, atol=tol * 1e-3)
    np.testing.assert_allclose(out.rgb, ref[1], rtol=tol, atol=tol * 1e-3)
    # wp.array points: wp.array outputs, the same numbers.
    out_wp = field.forward(wp.array(p))
    assert isinstance(out_wp.sigma, wp.array) and isinstance(out_wp.rgb, wp.array)
    np.testing.assert_array_equal(out_wp.sigma.numpy(), out.sigma)
    np.testing.assert_array_equal(out_wp.rgb.numpy(), out.rgb)


@pytest.mark.usefixtures("warp_device")
def test_spheres_gradients():
    assert_gradcheck(check_spheres(seeds=(0, 1, 2)))


# --------------------------------------------------------------------------- voxel grid

@pytest.mark.parametrize("np_t, wp_t, tol", DTYPES)
@pytest.mark.parametrize("sh_degree, activation", [(None, "softplus"), (1, "exp"), (2, "softplus")])
@pytest.mark.usefixtures("warp_device")
def test_grid_forward(np_t, wp_t, tol, sh_degree, activation):
    rng = np.random.default_rng(1)
    field = GridField(BOX, (4, 3, 5), sh_degree=sh_degree, density_bias=0.3, density_scale=2.5,
                      density_activation=activation, dtype=wp_t)
    field.set_params({"density": rng.normal(size=field.params["density"].shape).astype(np_t),
                      "color": rng.normal(size=field.params["color"].shape).astype(np_t)})
    p = rng.uniform(BOX[0] - 0.2, BOX[1] + 0.2, (60, 3)).astype(np_t)  # some outside: sigma = rgb = 0
    d = unit(rng.normal(size=(60, 3))).astype(np_t)
    out = field.forward(p, d if sh_degree is not None else None)
    ref = grid_reference(field, p.astype(np.float64), d.astype(np.float64))
    outside = np.any((p < BOX[0]) | (p > BOX[1]), axis=1)
    assert 0 < outside.sum() < len(p)
    np.testing.assert_allclose(out.sigma, ref[0], rtol=tol, atol=tol)
    np.testing.assert_allclose(out.rgb, ref[1], rtol=tol, atol=tol)


@pytest.mark.parametrize("sh_degree, activation", [(None, "softplus"), (1, "exp"), (2, "softplus")])
@pytest.mark.usefixtures("warp_device")
def test_grid_gradients(sh_degree, activation):
    assert_gradcheck(check_grid(seeds=(0, 1, 2), sh_degree=sh_degree, activation=activation))


@pytest.mark.usefixtures("warp_device")
def test_grid_total_variation():
    from kernels.volume.grid import add_tv_grad
    from research.checks.volume import check_tv

    # 2 x 2 x 1 vertices (x fastest) [[0, 1], [2, 4]]: x-differences 1, 2 and y-differences 2, 3.
    assert ref_volume.total_variation(np.array([0.0, 1.0, 2.0, 4.0]), (2, 2, 1)) == 1 + 4 + 4 + 9
    res = (3, 4, 2)
    g = wp.zeros((24, 2), dtype=wp.float64)
    add_tv_grad(wp.array(np.ones((24, 2)) * 3.0, dtype=wp.float64), res, 1.0, g)
    assert np.all(g.numpy() == 0.0)  # a constant field has no variation
    with pytest.raises(ValueError, match=r"grad: expected an output buffer of shape \(24, 2\)"):
        add_tv_grad(wp.zeros((24, 2), dtype=wp.float64), res, 1.0, wp.zeros(24, dtype=wp.float64))
    with pytest.raises(ValueError, match=r"values: expected a wp.array of shape \(24,\) or \(24, C\)"):
        add_tv_grad(np.zeros((24, 2)), res, 1.0, g)
    assert_gradcheck(check_tv(seeds=(0, 1, 2)))


def test_grid_vertex_values_are_reproduced():
    """At a vertex the trilinear value is that vertex's value exactly."""
    field = GridField(BOX, (3, 3, 3), dtype=wp.float64)
    rng = np.random.default_rng(0)
    field.set_params({"density": rng.normal(size=27), "color": rng.normal(size=(27, 3))})
    v = np.array([[1, 2, 0]])  # ix, iy, iz
    p = BOX[0] + v * (BOX[1] - BOX[0]) / 2.0
    out = field.forward(p)
    idx = 1 + 3 * (2 + 3 * 0)
    assert out.sigma[0] == pytest.approx(ref_volume.softplus(field.params["density"].numpy()[idx]), rel=1e-12)


# --------------------------------------------------------------------------- hash encoding

@pytest.mark.parametrize("n_features", [2, 3], ids=["two_features", "three_features"])  # the kernel's two paths
@pytest.mark.parametrize("np_t, wp_t, tol", DTYPES)
@pytest.mark.usefixtures("warp_device")
def test_hash_encoding_forward(np_t, wp_t, tol, n_features):
    enc = HashEncoding(BOX, n_levels=4, n_features=n_features, log2_table_size=7, base_resolution=2, max_resolution=20)
    assert enc.dense.tolist()[0] == 1 and enc.dense.tolist()[-1] == 0  # both dense and hashed levels
    rng = np.random.default_rng(2)
    table = rng.normal(size=enc.table_shape).astype(np_t)
    p = rng.uniform(BOX[0] - 0.1, BOX[1] + 0.1, (40, 3)).astype(np_t)
    ref = hash_reference(enc, p.astype(np.float64), table.astype(np.float64))
    got = enc.encode(wp.array(p, dtype=wp_t), wp.array(table, dtype=wp_t)).numpy()
    np.testing.assert_allclose(got, ref, rtol=tol * 10, atol=tol * 10)


@pytest.mark.parametrize("n_features", [2, 3], ids=["two_features", "three_features"])  # the backward's two paths
@pytest.mark.parametrize("layout", ["point_major", "feature_major"])
def test_hash_encoding_backward_is_the_adjoint_of_the_forward(n_features, layout):
    # enc is linear in the table, enc = M table, so <G, M t> = <M^T G, t> for any G and t (float64);
    # the cotangent is read through its strides, row-major or as the transposed (L F, N) array.
    enc = HashEncoding(BOX, n_levels=4, n_features=n_features, log2_table_size=7, base_resolution=2, max_resolution=20)
    rng = np.random.default_rng(7)
    table = rng.normal(size=enc.table_shape)
    p = wp.array(rng.uniform(BOX[0] - 0.1, BOX[1] + 0.1, (300, 3)), dtype=wp.float64)
    g = rng.normal(size=(300, enc.n_outputs))
    g_wp = wp.array(g, dtype=wp.float64) if layout == "point_major" else \
        wp.array(np.ascontiguousarray(g.T), dtype=wp.float64).transpose()
    out = enc.encode(p, wp.array(table, dtype=wp.float64)).numpy()
    np.testing.assert_allclose(out, hash_reference(enc, p.numpy(), table), rtol=1e-12, atol=1e-12)
    grad = enc.backward(p, wp.array(table, dtype=wp.float64), g_wp).numpy()
    assert np.sum(g * out) == pytest.approx(np.sum(grad * table), rel=1e-12)
    # and entry by entry: the gradient of a single table entry is the sum of its trilinear weights x G
    for row, f in ((0, 0), (enc.table_size + 5, n_features - 1), (3 * enc.table_size + 17, 0)):
        e = np.zeros(enc.table_shape)
        e[row, f] = 1.0
        m = hash_reference(enc, p.numpy(), e)
        assert grad[row, f] == pytest.approx(np.sum(m * g), rel=1e-12, abs=1e-12)


def test_hash_encoding_runs_of_points_split_over_threads_match_the_reference():
    # 5001 points = 312 runs of BLOCK points and a short one, x 4 levels: launched as several chunks,
    # the last run of each level shorter than the others.
    from kernels.volume.hashgrid import BLOCK
    enc = HashEncoding(BOX, n_levels=4, n_features=2, log2_table_size=7, base_resolution=2, max_resolution=20)
    rng = np.random.default_rng(11)
    table = rng.normal(size=enc.table_shape)
    n = 312 * BLOCK + 9
    p = rng.uniform(BOX[0] - 0.1, BOX[1] + 0.1, (n, 3))
    got = enc.encode(wp.array(p, dtype=wp.float64), wp.array(table, dtype=wp.float64)).numpy()
    np.testing.assert_allclose(got, hash_reference(enc, p, table), rtol=1e-12, atol=1e-12)


def _mixed_levels_inputs(enc, rng, n, np_t, wp_t):
    """n points around the box (some outside it, clamped) and a random table, for an encoding with both
    dense and hashed levels."""
    assert 0 < enc.dense.sum() < enc.n_levels
    p = wp.array(rng.uniform(BOX[0] - 0.2, BOX[1] + 0.2, (n, 3)).astype(np_t), dtype=wp_t)
    table = wp.array(rng.normal(size=enc.table_shape).astype(np_t), dtype=wp_t)
    return p, table


@pytest.mark.parametrize("np_t, wp_t", [(np.float32, wp.float32), (np.float64, wp.float64)])
def test_hash_encoding_cpu_cpp_forward_equals_the_warp_kernel(np_t, wp_t):
    # The CPU encode with F = 2 runs kernels.volume.hashgrid_cpu (C++, 8 points at a time): bit for bit the
    # sums of the Warp kernel, on dense and hashed levels, with points outside the box (clamped) and runs
    # whose last group of points is short (n = 8 k + 5 points, runs of BLOCK).
    from kernels.launch import launch_split
    from kernels.volume.hashgrid import BLOCK, _hash_forward_kernel
    enc = HashEncoding(BOX, n_levels=6, n_features=2, log2_table_size=9, base_resolution=3, max_resolution=40)
    rng, n = np.random.default_rng(17), 8 * 611 + 5
    p, table = _mixed_levels_inputs(enc, rng, n, np_t, wp_t)
    got = enc.encode(p, table).numpy()
    want = wp.empty((enc.n_outputs, n), dtype=wp_t)
    launch_split(_hash_forward_kernel, -(-n // BLOCK) * enc.n_levels,
                 [enc._normalised(p, None), *enc._static(wp_t, p.device), table, want, BLOCK], device=p.device)
    np.testing.assert_array_equal(got, want.numpy().T)


@pytest.mark.parametrize("np_t, wp_t", [(np.float32, wp.float32), (np.float64, wp.float64)])
def test_hash_encoding_cpu_cpp_scatter_equals_the_warp_kernel(np_t, wp_t):
    # The CPU scatter with F = 2 runs kernels.volume.hashgrid_cpu: the same additions in the same order as
    # the Warp kernel, so the same table gradient bit for bit, with a table small enough (2^5 rows a level)
    # that many points, and corners of one point, add into the same rows.
    from kernels.volume.hashgrid import BLOCK, _hash_backward_kernel
    enc = HashEncoding(BOX, n_levels=5, n_features=2, log2_table_size=5, base_resolution=2, max_resolution=30)
    rng, n = np.random.default_rng(19), 8 * 377 + 3
    p, table = _mixed_levels_inputs(enc, rng, n, np_t, wp_t)
    g = wp.array(rng.normal(size=(enc.n_outputs, n)).astype(np_t), dtype=wp_t).transpose()
    got = enc.backward(p, table, g).numpy()
    want = wp.zeros(enc.table_shape, dtype=wp_t)
    x = enc._normalised(p, None)
    for l in range(enc.n_levels):
        wp.launch(_hash_backward_kernel, dim=-(-n // BLOCK), inputs=[x, *enc._static(wp_t, p.device), g, want, l, BLOCK])
    np.testing.assert_array_equal(got, want.numpy())


def test_hash_encoding_backward_into_a_buffer():
    # `out` is overwritten (not added to), gives the fresh array's gradient bit for bit, and a wrong
    # buffer is refused before any launch.
    enc = HashEncoding(BOX, n_levels=4, n_features=2, log2_table_size=7, base_resolution=2, max_resolution=20)
    rng = np.random.default_rng(12)
    table = wp.array(rng.normal(size=enc.table_shape), dtype=wp.float32)
    p = wp.array(rng.uniform(BOX[0], BOX[1], (700, 3)), dtype=wp.float32)
    g = wp.array(rng.normal(size=(700, enc.n_outputs)), dtype=wp.float32)
    fresh = enc.backward(p, table, g).numpy()
    buf = wp.array(np.full(enc.table_shape, np.nan), dtype=wp.float32)
    assert enc.backward(p, table, g, out=buf) is buf
    np.testing.assert_array_equal(buf.numpy(), fresh)
    for bad in (wp.zeros(enc.table_shape, dtype=wp.float64), wp.zeros((enc.table_shape[0], 3), dtype=wp.float32),
                np.zeros(enc.table_shape, np.float32)):
        with pytest.raises(ValueError, match="out"):
            enc.backward(p, table, g, out=bad)


def test_hash_grid_field_backward_with_a_workspace():
    # The table's gradient is a view into the workspace (reused by the next call), equal bit for bit to
    # the gradient without one; the MLP's gradients are unaffected.
    from kernels.volume import Workspace
    field = HashGridField(BOX, n_levels=4, log2_table_size=8, base_resolution=2, max_resolution=16, seed=3)
    rng = np.random.default_rng(13)
    p = rng.uniform(BOX[0], BOX[1], (500, 3)).astype(np.float32)
    out = field.forward(p)
    gs, gr = rng.normal(size=500).astype(np.float32), rng.normal(size=(500, 3)).astype(np.float32)
    ref = {k: v.numpy().copy() for k, v in field.backward(p, None, out, gs, gr).items()}
    ws = Workspace()
    for _ in range(2):  # the second call reuses the buffer, which then holds the first call's values
        got = field.backward(p, None, out, gs, gr, workspace=ws)
        for k in ref:
            np.testing.assert_array_equal(got[k].numpy(), ref[k])
    assert ws.nbytes() >= field.params["table"].capacity
    with pytest.raises(ValueError, match="workspace"):
        field.backward(p, None, out, gs, gr, workspace=object())


def test_level_resolutions_follow_the_geometric_progression():
    enc = HashEncoding(BOX, n_levels=16, base_resolution=16, max_resolution=2048)
    b = np.exp((np.log(2048) - np.log(16)) / 15)
    np.testing.assert_array_equal(enc.resolutions, np.floor(16 * b ** np.arange(16) + 1e-9).astype(int))
    assert enc.resolutions[0] == 16 and enc.resolutions[-1] == 2048


# --------------------------------------------------------------------------- positional encoding and MLP

@pytest.mark.parametrize("np_t, wp_t, tol", DTYPES)
@pytest.mark.usefixtures("warp_device")
def test_positional_encoding(np_t, wp_t, tol):
    pe = PositionalEncoding(BOX, n_freqs=4)
    rng = np.random.default_rng(3)
    p = rng.uniform(BOX[0], BOX[1], (30, 3)).astype(np_t)
    got = pe.encode(wp.array(p, dtype=wp_t)).numpy()
    ref = ref_volume.positional_encoding(p.astype(np.float64), BOX, 4)
    assert got.shape == (30, 27)
    np.testing.assert_allclose(got[:, :3], ref[:, :3], atol=tol)
    np.testing.assert_allclose(got[:, 3:], ref[:, 3:], atol=tol * 20)


@pytest.mark.parametrize("np_t, wp_t, tol", DTYPES)
@pytest.mark.parametrize("backend", ["numpy", "warp"])
def test_mlp_forward(np_t, wp_t, tol, backend, warp_device):
    if backend == "numpy" and not warp_device.is_cpu:
        pytest.skip("the numpy backend runs on the CPU only")
    sizes = [5, 16, 16, 4]
    params = init_mlp_params(sizes, 0, wp_t, warp_device)
    mlp = MLP(sizes, params, backend)
    x = np.random.default_rng(4).normal(size=(33, 5)).astype(np_t)
    y, _ = mlp.forward(wp.array(x, dtype=wp_t))
    ref = ref_volume.mlp({k: v.numpy().astype(np.float64) for k, v in params.items()}, x.astype(np.float64), 3)
    np.testing.assert_allclose(y.numpy(), ref, rtol=tol * 10, atol=tol * 10)


@pytest.mark.parametrize("np_t, wp_t, tol", DTYPES)
def test_mlp_numpy_backend_split_products(np_t, wp_t, tol):
    # Enough rows that the products run as row blocks on the launch threads and dW sums several
    # blocks (kernels.volume.mlp._rows_matmul, _weight_grad_blas); the result must not depend on
    # the thread count.
    from kernels.volume import mlp as mlp_mod

    n = 2 * mlp_mod._BLAS_BLOCK + 123
    sizes = [7, 16, 4]
    params = init_mlp_params(sizes, 1, wp_t, wp.get_device("cpu"))
    rng = np.random.default_rng(5)
    x = rng.normal(size=(n, 7)).astype(np_t)
    g = rng.normal(size=(n, 4)).astype(np_t)
    p64 = {k: v.numpy().astype(np.float64) for k, v in params.items()}
    z0 = x.astype(np.float64) @ p64["W0"].T + p64["b0"]
    a1 = np.maximum(z0, 0.0)
    dz0 = (g.astype(np.float64) @ p64["W1"]) * (z0 > 0)
    want = {"W1": g.astype(np.float64).T @ a1, "b1": g.sum(0), "W0": dz0.T @ x.astype(np.float64), "b0": dz0.sum(0)}
    results = []
    for threads in ("1", "2"):
        os.environ["DRLAB_THREADS"] = threads
        try:
            mlp = MLP(sizes, params, "numpy")
            y, cache = mlp.forward(wp.array(x, dtype=wp_t))
            grads, gx = mlp.backward(cache, wp.array(g, dtype=wp_t), need_input_grad=True)
            # the same dL/dx stored feature-major ((n_in, N) contiguous, seen as its transpose)
            grads_t, gx_t = mlp.backward(cache, wp.array(g, dtype=wp_t), need_input_grad=True,
                                         input_grad_feature_major=True)
        finally:
            del os.environ["DRLAB_THREADS"]
        np.testing.assert_allclose(y.numpy(), a1 @ p64["W1"].T + p64["b1"], rtol=tol * 10, atol=tol * 10)
        for k, v in want.items():
            np.testing.assert_allclose(grads[k].numpy(), v, rtol=tol * 10, atol=tol * 10 * np.abs(v).max())
        np.testing.assert_allclose(gx.numpy(), dz0 @ p64["W0"], rtol=tol * 10, atol=tol * 10)
        assert gx_t.shape == (n, 7) and not gx_t.is_contiguous and gx_t.transpose().is_contiguous
        # The feature-major dL/dx is another BLAS call (W0^T src^T instead of src W0) on the same
        # computed src = dL/dz0: no BLAS promises the two round alike (they differ by 1 ulp on AMD
        # AVX2), only that each is within gamma_16 |src| |W0| of the exact product
        # (research.checks.rounding), so they differ by at most twice that. |src| <= |dz0| + the
        # rounding of g W1 (k = 4, the mask is exact).
        src_mag = np.abs(dz0) + rounding.affine_bound(g, p64["W1"].T, None, np_t)
        bound = 2.0 * rounding.gamma(16, np_t) * (src_mag @ np.abs(p64["W0"]))
        assert np.all(np.abs(gx_t.numpy().astype(np.float64) - gx.numpy()) <= bound)
        # The weight gradients are the same calls on the same arrays in both backward passes.
        for k in grads:
            np.testing.assert_array_equal(grads_t[k].numpy(), grads[k].numpy())
        results.append([y.numpy(), gx.numpy(), *(grads[k].numpy() for k in sorted(grads))])
    # Bit-equal whatever the thread count, by drlab's construction: the row blocks and the dW blocks
    # do not depend on it, each is one single-threaded BLAS call of the same shape on the same data,
    # and the dW blocks are added in block order (kernels.volume.mlp._row_blocks, _weight_grad_blas).
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("np_t, wp_t", [(np.float32, wp.float32), (np.float64, wp.float64)])
def test_mlp_numpy_backend_blocks_within_rounding_bound(np_t, wp_t):
    # Row blocks of _SUB_ROWS rows, the last one longer (kernels.volume.mlp._row_blocks): every output
    # within the rigorous forward error bound of a two-layer ReLU MLP evaluated in np_t, whatever
    # kernel BLAS picks per block shape (research.checks.rounding.mlp_forward_bound), and one long
    # product (another BLAS kernel) within twice that of the blocked result.
    from kernels.volume import mlp as mlp_mod

    sizes = [64, 64, 4]
    n = 3 * mlp_mod._SUB_ROWS + 300
    params = init_mlp_params(sizes, 2, wp_t, wp.get_device("cpu"))
    x = np.random.default_rng(8).normal(size=(n, 64)).astype(np_t)
    y, _ = MLP(sizes, params, "numpy").forward(wp.array(x, dtype=wp_t))
    p = {k: v.numpy() for k, v in params.items()}
    p64 = {k: v.astype(np.float64) for k, v in p.items()}
    exact = np.maximum(x.astype(np.float64) @ p64["W0"].T + p64["b0"], 0.0) @ p64["W1"].T + p64["b1"]
    bound = rounding.mlp_forward_bound(x, [p["W0"], p["W1"]], [p["b0"], p["b1"]], np_t)
    # `exact` is itself float64 arithmetic, within the float64 bound of the true value
    ref_err = rounding.mlp_forward_bound(x, [p["W0"], p["W1"]], [p["b0"], p["b1"]], np.float64)
    assert np.all(np.abs(y.numpy() - exact) <= bound + ref_err)
    long = np.maximum(x @ p["W0"].T + p["b0"], np_t(0.0)) @ p["W1"].T + p["b1"]
    assert np.all(np.abs(y.numpy().astype(np.float64) - long) <= 2.0 * bound)
    # the bound is not vacuous: below 1e-4 relative in float32, 1e-12 in float64
    assert bound.max() < (1e-4 if np_t == np.float32 else 1e-12) * np.abs(exact).max()


def test_mlp_backends_agree_on_the_backward():
    sizes = [6, 12, 12, 4]
    params = init_mlp_params(sizes, 1, wp.float64, wp.get_device("cpu"))
    rng = np.random.default_rng(5)
    x = wp.array(rng.normal(size=(50, 6)), dtype=wp.float64)
    g = wp.array(rng.normal(size=(50, 4)), dtype=wp.float64)
    out = {}
    for backend in ("numpy", "warp"):
        mlp = MLP(sizes, params, backend)
        _, cache = mlp.forward(x)
        grads, gx = mlp.backward(cache, g, need_input_grad=True)
        out[backend] = {**{k: v.numpy() for k, v in grads.items()}, "x": gx.numpy()}
    for k in out["numpy"]:
        np.testing.assert_allclose(out["warp"][k], out["numpy"][k], rtol=1e-12, atol=1e-12)


# --------------------------------------------------------------------------- neural fields

@pytest.mark.parametrize("kind", ["hashgrid", "pe_mlp"])
@pytest.mark.parametrize("np_t, wp_t, tol", DTYPES)
@pytest.mark.usefixtures("warp_device")
def test_neural_field_forward(kind, np_t, wp_t, tol):
    f64 = neural_field(kind, 0)
    kw = dict(hidden=(8, 8), density_bias=-0.5, seed=0, dtype=wp_t)
    if kind == "hashgrid":
        field = HashGridField(BOX, n_levels=3, n_features=2, log2_table_size=6, base_resolution=2, max_resolution=8,
                              table_init_scale=1.0, **kw)
    else:
        field = PEMLPField(BOX, n_freqs=2, **kw)
    field.set_params({k: v.astype(np_t) for k, v in f64.params_numpy().items()})
    rng = np.random.default_rng(6)
    p = rng.uniform(BOX[0] - 0.1, BOX[1] + 0.1, (40, 3)).astype(np_t)
    out = field.forward(p)
    P = f64.params_numpy()
    p64 = p.astype(np.float64)
    if kind == "hashgrid":
        enc = hash_reference(field.encoding, p64, P["table"])
    else:
        enc = ref_volume.positional_encoding(p64, BOX, 2)
    sigma, rgb = ref_volume.neural_head(ref_volume.mlp(P, enc, 3), p64, BOX, -0.5, "exp")
    np.testing.assert_allclose(out.sigma, sigma, rtol=tol * 20, atol=tol * 20)
    np.testing.assert_allclose(out.rgb, rgb, rtol=tol * 20, atol=tol * 20)


@pytest.mark.parametrize("kind, backend", [("hashgrid", "numpy"), ("hashgrid", "warp"), ("pe_mlp", "numpy")])
def test_neural_field_gradients(kind, backend, warp_device):
    if backend == "numpy" and not warp_device.is_cpu:
        pytest.skip("the numpy backend runs on the CPU only")
    assert_gradcheck(check_neural(kind, seeds=(0, 1), backend=backend))


@pytest.mark.parametrize("kind", ["hashgrid", "pe_mlp"])
def test_neural_field_recycles_its_intermediate_blocks(kind):
    # The encoding, activations and their gradients come from the field's pool (kernels.volume.mlp.empty_array):
    # after a call whose results are dropped, the next call takes the same blocks back, and every value is
    # overwritten (blocks filled with NaN bytes in between change nothing, bit for bit).
    field = (HashGridField(BOX, log2_table_size=12, seed=2) if kind == "hashgrid" else PEMLPField(BOX, seed=2))
    rng = np.random.default_rng(21)
    n = 5000  # (n, 64) float32 activations: above HostPool.MIN_BYTES
    p = rng.uniform(BOX[0] - 0.1, BOX[1] + 0.1, (n, 3)).astype(np.float32)
    gs, gr = rng.normal(size=n).astype(np.float32), rng.normal(size=(n, 3)).astype(np.float32)

    def run():
        out = field.forward(p)
        g = field.backward(p, None, out, gs, gr)
        return [out.sigma.copy(), out.rgb.copy()] + [g[k].numpy().copy() for k in sorted(g)]

    first = run()
    kept = field.pool.nbytes()
    assert kept >= n * 64 * 4 * 2  # at least the two hidden layers' activations
    for owner in field.pool._owners.values():
        owner[:] = 0xFF  # NaN in every float
    second = run()
    assert field.pool.nbytes() == kept
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------- bad input

def test_field_bad_input():
    field = GridField(BOX, (3, 3, 3), sh_degree=1, dtype=wp.float64)
    p = np.zeros((4, 3))
    with pytest.raises(ValueError, match="dirs: the grid field is view-dependent"):
        field.forward(p)
    with pytest.raises(ValueError, match="points: expected shape"):
        field.forward(np.zeros((4, 2)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="points: expected dtype float64"):
        field.forward(p.astype(np.float32), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="dirs: expected shape"):
        field.forward(p, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="points: expected finite values"):
        field.forward(np.full((4, 3), np.nan), np.zeros((4, 3)))
    with value_checks(False):  # only the value check is off
        field.forward(np.full((4, 3), np.nan), np.zeros((4, 3)))
        with pytest.raises(ValueError, match="points: expected dtype float64"):
            field.forward(p.astype(np.float32), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"points: expected dtype float64 \(the field's\), got float32"):
        field.forward(wp.array(p.astype(np.float32)), wp.array(np.zeros((4, 3))))
    with pytest.raises(ValueError, match="sh_degree"):
        GridField(BOX, (3, 3, 3), sh_degree=3)
    with pytest.raises(ValueError, match="resolution: expected at least 2"):
        GridField(BOX, (1, 3, 3))
    with pytest.raises(ValueError, match="density_activation"):
        GridField(BOX, (3, 3, 3), density_activation="relu")
    with pytest.raises(ValueError, match="params: unknown parameter"):
        field.set_params({"sigma": np.zeros(27)})
    with pytest.raises(ValueError, match="density: expected shape"):
        field.set_params({"density": np.zeros(26)})
    with pytest.raises(ValueError, match="radii: expected values >= 0"):
        SphereField([[0, 0, 0]], [-1.0], [[1, 1, 1]], [5.0])
    with pytest.raises(ValueError, match="colors: expected shape"):
        SphereField([[0, 0, 0]], [1.0], [[1, 1]], [5.0])
    with pytest.raises(ValueError, match="max_resolution"):
        HashEncoding(BOX, base_resolution=32, max_resolution=16)
    with pytest.raises(ValueError, match="grad_sigma: expected shape"):
        out = field.forward(p, np.zeros((4, 3)))
        field.backward(p, np.zeros((4, 3)), out, np.zeros(5), None)
    with pytest.raises(ValueError, match="backend"):
        HashGridField(BOX, backend="torch")


@pytest.mark.parametrize("make", [lambda: GridField(BOX, (3, 4, 5), dtype=wp.float64),
                                  lambda: SphereField.textbook(wp.float64)])
def test_backward_into_a_workspace_matches_fresh_gradients(make):
    field = make()
    rng = np.random.default_rng(11)
    lo, hi = (BOX[0], BOX[1]) if field.name == "grid" else ([-1, -1, 3], [1, 1, 5])  # the spheres sit near z = 4
    pts = rng.uniform(lo, hi, (40, 3))
    out = field.forward(pts)
    ws = Workspace()
    for seed in (1, 2):  # the second call reuses buffers that hold the first call's gradients
        g = np.random.default_rng(seed)
        gs, gr = g.normal(size=40), g.normal(size=(40, 3))
        fresh = field.backward(pts, None, out, gs, gr)
        reused = field.backward(pts, None, out, gs, gr, ws)
        for name in fresh:
            np.testing.assert_array_equal(reused[name].numpy(), fresh[name].numpy())
    with pytest.raises(ValueError, match="workspace: expected a kernels.volume.Workspace"):
        field.backward(pts, None, out, gs, gr, object())


@pytest.mark.parametrize("np_t, wp_t, tol", [(np.float32, wp.float32, 2e-6), (np.float64, wp.float64, 1e-14)])
def test_sphere_forward_one_kernel_agrees_with_cpu_two_pass_path(monkeypatch, np_t, wp_t, tol):
    # SphereField.forward on the CPU takes the falloffs exp(-s_k m_k) from NumPy between two passes;
    # the one-kernel forward (what runs on CUDA), forced on the CPU, gives the same values to rounding.
    import kernels.volume.spheres as spheres_module

    field = SphereField.textbook(wp_t)
    pts = np.random.default_rng(8).uniform([-2.0, -1.5, 2.5], [2.5, 1.5, 6.0], (3000, 3)).astype(np_t)
    pts[0] = (0.0, 0.0, 4.0)  # inside a sphere: m = 0
    two_pass = field.forward(pts)
    monkeypatch.setattr(spheres_module, "_FUSED_ON_CPU", True)
    one = field.forward(pts)
    np.testing.assert_allclose(two_pass.sigma, one.sigma, rtol=tol, atol=tol)
    np.testing.assert_allclose(two_pass.rgb, one.rgb, rtol=tol, atol=tol)


@pytest.mark.parametrize("block", [1, 2, 299, 10 ** 9], ids=["one_value", "two_values", "uneven", "one_block"])
def test_sphere_cpu_passes_give_the_same_values_in_any_block_size(monkeypatch, block):
    # The CPU passes run in blocks of falloff values (bounded memory); the block size changes nothing.
    import kernels.volume.spheres as spheres_module

    field = SphereField.textbook(wp.float32)
    rng = np.random.default_rng(9)
    pts = rng.uniform([-2.0, -1.5, 2.5], [2.5, 1.5, 6.0], (1001, 3)).astype(np.float32)
    o = rng.normal(0.0, 0.2, (37, 3)).astype(np.float32)
    d = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (37, 1))
    t = np.tile(np.linspace(1.0, 6.0, 21, dtype=np.float32), (37, 1))
    dl = np.full((37, 21), 0.25, np.float32)
    ref_field, ref_render = field.forward(pts), field.render_dense(o, d, t, dl, t_threshold=1e-3)
    monkeypatch.setattr(spheres_module, "_FALLOFF_BLOCK", block)
    got_field, got_render = field.forward(pts), field.render_dense(o, d, t, dl, t_threshold=1e-3)
    np.testing.assert_array_equal(got_field.sigma, ref_field.sigma)
    np.testing.assert_array_equal(got_field.rgb, ref_field.rgb)
    for a, b in zip(got_render, ref_render):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("n", [1, 3, 4, 5, 4999])
@pytest.mark.parametrize("np_t, wp_t", [(np.float32, wp.float32), (np.float64, wp.float64)])
@pytest.mark.cpu_fast_path
def test_sphere_forward_cpu_passes_equal_numpy_bit_for_bit(monkeypatch, np_t, wp_t, n):
    # The CPU forward (quads of points in vec4 lanes, NumPy's exp between the passes) against the
    # same formula written in NumPy with the same operations in the same order: equal bit for bit,
    # for point counts that are and are not multiples of 4, and in blocks of a few quads.
    import kernels.volume.spheres as spheres_module

    field = SphereField.textbook(wp_t)
    pts = np.random.default_rng(12).uniform([-2.0, -1.5, 2.5], [2.5, 1.5, 6.0], (n, 3)).astype(np_t)
    pts[0] = (0.0, 0.0, 4.0)  # inside a sphere: m = 0
    P = field.params_numpy()
    sig = np.zeros(n, np_t)
    col = np.zeros((n, 3), np_t)
    for c, r, k, s in zip(P["centers"], P["radii"], P["colors"], P["sharpness"]):
        dx, dy, dz = (pts[:, a] - c[a] for a in range(3))
        dist = np.sqrt(dx * dx + dy * dy + dz * dz)
        dk = s * np.exp(-s * np.maximum(np_t(0), dist - r))
        sig = sig + dk
        col = col + dk[:, None] * k
    norm = sig > np_t(1e-6)
    col[norm] = col[norm] / sig[norm, None]
    for block in (10 ** 9, 2 * 4 * 3):
        monkeypatch.setattr(spheres_module, "_FALLOFF_BLOCK", block)
        out = field.forward(pts)
        assert out.sigma.dtype == np_t
        np.testing.assert_array_equal(out.sigma, sig)
        np.testing.assert_array_equal(out.rgb, col)


def test_sphere_packed_parameters_follow_in_place_updates():
    # The CPU passes reuse the packed (vec4) parameters while the parameters' values are unchanged;
    # an in-place update (what an optimiser does) must be seen by the next call.
    field = SphereField.textbook(wp.float32)
    pts = np.random.default_rng(13).uniform([-2.0, -1.5, 2.5], [2.5, 1.5, 6.0], (257, 3)).astype(np.float32)
    first = field.forward(pts)
    for name, delta in (("radii", 0.05), ("centers", 0.1), ("colors", -0.1), ("sharpness", 0.5)):
        field.params[name].numpy()[0] += delta  # in place, as an optimiser step
        fresh = SphereField(*(field.params_numpy()[k] for k in ("centers", "radii", "colors", "sharpness")),
                            dtype=wp.float32)
        got, want = field.forward(pts), fresh.forward(pts)
        np.testing.assert_array_equal(got.sigma, want.sigma)
        np.testing.assert_array_equal(got.rgb, want.rgb)
        o, d = np.zeros((3, 3), np.float32), np.tile(np.array([0, 0, 1], np.float32), (3, 1))
        t = np.tile(np.linspace(1, 6, 8, dtype=np.float32), (3, 1))
        for a, b in zip(field.render_dense(o, d, t, np.full_like(t, 0.5)), fresh.render_dense(o, d, t, np.full_like(t, 0.5))):
            np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first.sigma, field.forward(pts).sigma)
