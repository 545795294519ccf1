"""kernels.fast_paths: the one switch that turns every CPU fast path off, and the fall-backs taken
when a fast path's own check fails (NumPy's exp not reproduced, no AVX2 for the row blend or the
sphere passes).

The switch tests replace every fast path's entry point by one that fails, then run each operation
with the switch off: they must not be reached, and the results must still match the NumPy
references (the plain Warp kernels, the CUDA route, run on the CPU)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import fast_paths
from research.checks import rounding


@pytest.fixture(autouse=True)
def _follow_env():
    fast_paths.set_enabled(None)
    yield
    fast_paths.set_enabled(None)


def _sphere_rays(rng: np.random.Generator, n_rays: int, n_samples: int):
    """float32 rays from (0, 0, -3) towards +z (spread 0.1) through the textbook spheres, with n_samples equal
    samples in [0.5, 5.5]: origins, dirs, t and delta for SphereField.render_dense."""
    o = np.tile(np.array([0.0, 0.0, -3.0], np.float32), (n_rays, 1))
    d = rng.normal(0, 0.1, (n_rays, 3)).astype(np.float32) + np.array([0, 0, 1], np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = np.tile(np.linspace(0.5, 5.5, n_samples, dtype=np.float32), (n_rays, 1))
    return o, d, t, np.full_like(t, 5.0 / n_samples)


# --------------------------------------------------------------------------- the switch itself


@pytest.mark.parametrize("value, on", [("", True), ("1", True), ("on", True), ("TRUE", True), ("yes", True),
                                       ("0", False), ("off", False), ("False", False), (" no ", False)])
def test_env_variable_turns_fast_paths_off(monkeypatch, value, on):
    monkeypatch.setenv(fast_paths.ENV, value)
    monkeypatch.setattr(fast_paths, "_versions_ok", True)
    assert fast_paths.enabled() is on
    assert fast_paths.on(wp.get_device("cpu")) is on


def test_env_variable_bad_value_is_named(monkeypatch):
    monkeypatch.setenv(fast_paths.ENV, "maybe")
    with pytest.raises(ValueError, match="DRLAB_FAST_PATHS: expected one of .* got 'maybe'"):
        fast_paths.enabled()


def test_api_overrides_env_and_context_restores(monkeypatch):
    monkeypatch.setattr(fast_paths, "_versions_ok", True)
    monkeypatch.setenv(fast_paths.ENV, "0")
    fast_paths.set_enabled(True)
    assert fast_paths.enabled()
    with fast_paths.disabled():
        assert not fast_paths.enabled()
        with fast_paths.disabled():
            assert not fast_paths.enabled()
        assert not fast_paths.enabled()
    assert fast_paths.enabled()
    fast_paths.set_enabled(None)
    assert not fast_paths.enabled()
    with pytest.raises(TypeError, match="on: expected True, False or None"):
        fast_paths.set_enabled(1)


def test_unsupported_versions_turn_fast_paths_off_with_one_warning(monkeypatch):
    assert fast_paths.unsupported_versions({"warp": "1.19.0", "numpy": "2.4.6"}) == []
    assert fast_paths.unsupported_versions({"warp": "1.19.3.dev1", "numpy": "1.24.0rc1"}) == []
    bad = fast_paths.unsupported_versions({"warp": "1.20.0", "numpy": "3.0.0"})
    assert len(bad) == 2 and bad[0].startswith("warp 1.20.0") and "1.19 <= warp < 1.20" in bad[0]
    assert fast_paths.unsupported_versions({"warp": "1.18.9", "numpy": "2.0"})[0].startswith("warp 1.18.9")
    monkeypatch.delenv(fast_paths.ENV, raising=False)
    monkeypatch.setattr(fast_paths, "_versions_ok", None)
    monkeypatch.setattr(fast_paths, "unsupported_versions", lambda: ["warp 9.0 (test)"])
    with pytest.warns(RuntimeWarning, match="fast paths off.*warp 9.0"):
        assert not fast_paths.enabled()
    assert not fast_paths.enabled()  # decided once, no second warning (pytest.warns would not see it)


def test_installed_versions_are_supported():
    # pyproject.toml pins the same range: an environment built from it must run the fast paths
    assert fast_paths.unsupported_versions() == []


# --------------------------------------------------------------------------- the switch reaches every fast path


def _refuse(name):
    def refused(*args, **kwargs):
        raise AssertionError(f"{name} was reached with the CPU fast paths off")
    return refused


@pytest.fixture
def no_fast_path(monkeypatch):
    """Every fast path's entry point fails; the switch is off."""
    from kernels.corr import onthefly, patch_cpu, window_cpu
    from kernels.points import sampling
    from kernels.splat import raster, tiles
    from kernels.stereo import costs
    from kernels.volume import composite, composite_cpu, hashgrid, mlp, spheres, spheres_cpu

    for mod, name in [(composite_cpu, "forward_kernel"), (composite_cpu, "backward_kernel"),
                      (composite, "_fill_factor"), (spheres_cpu, "kernels"), (hashgrid, "forward_kernel"),
                      (hashgrid, "backward_kernel"), (window_cpu, "sample_levels_cpu"),
                      (window_cpu, "sample_patches_cpu"), (patch_cpu, "patch_groups_cpu"),
                      (patch_cpu, "widen_rows_cpu"), (patch_cpu, "group_pixels_cpu"),
                      (onthefly, "_sample_full_product"),
                      (onthefly, "_channels_last_later"), (costs, "census_rows_f32"),
                      (raster, "_raster_forward_rows_kernel"), (raster, "_raster_forward_kernel"),
                      (tiles, "_counting_sort"), (spheres.SphereField, "_two_passes"),
                      (mlp, "_forward_blas"), (mlp, "_input_grads_blas"), (mlp, "_weight_grad_blas"),
                      (sampling, "_step_cpu_kernel")]:
        monkeypatch.setattr(mod, name, _refuse(f"{getattr(mod, '__name__', mod)}.{name}"))
    with fast_paths.disabled():
        yield


def test_volume_without_fast_paths(no_fast_path):
    from kernels.reference import volume as ref
    from kernels.volume import MLP, HashEncoding, SphereField, composite_backward, composite_forward
    from kernels.volume.mlp import init_mlp_params

    rng = np.random.default_rng(3)
    n_rays, per = 11, 9
    n = n_rays * per
    sigma, delta = rng.uniform(0, 3, n).astype(np.float32), rng.uniform(0.01, 0.2, n).astype(np.float32)
    rgb, z = rng.uniform(0, 1, (n, 3)).astype(np.float32), np.arange(n, dtype=np.float32) * 0.1
    off = np.arange(0, n + 1, per, dtype=np.int32)
    res = composite_forward(sigma, rgb, delta, z, off, (0.1, 0.2, 0.3), 1e-4)
    want = ref.composite(*(x.astype(np.float64) for x in (sigma, rgb, delta, z)), off, np.array([0.1, 0.2, 0.3]), 1e-4)
    np.testing.assert_allclose(res.rgb, want[0], rtol=2e-5, atol=2e-6)
    g_sigma, g_rgb = composite_backward(sigma, rgb, delta, z, off, res, np.ones((n_rays, 3), np.float32))
    assert np.all(np.isfinite(g_sigma)) and np.all(np.isfinite(g_rgb))
    with pytest.raises(ValueError, match="sigma"):  # the values are still checked before the launch
        composite_forward(-sigma, rgb, delta, z, off)

    field = SphereField.textbook(wp.float32)
    o, d, t, dl = _sphere_rays(rng, 8, 16)
    img, _, _ = field.render_dense(o, d, t, dl)
    assert img.shape == (8, 3) and np.all(np.isfinite(img))
    out = field.forward(rng.uniform(-1, 1, (40, 3)).astype(np.float32))
    assert np.all(np.isfinite(out.sigma))

    enc = HashEncoding(((-1, -1, -1), (1, 1, 1)), n_levels=2, n_features=2, log2_table_size=8)
    dev = wp.get_device("cpu")
    for np_t, wp_t, tol in ((np.float32, wp.float32, None), (np.float64, wp.float64, 1e-12)):
        table = enc.init_table(0, wp_t, dev, scale=1.0)
        pts = rng.uniform(-1, 1, (33, 3)).astype(np_t)
        got = enc.encode(wp.array(pts, dtype=wp_t), table).numpy()
        grad = enc.backward(wp.array(pts, dtype=wp_t), table, wp.array(np.ones_like(got), dtype=wp_t)).numpy()
        assert np.all(np.isfinite(got)) and np.all(np.isfinite(grad))
        if tol:  # float64: against the reference (float32 points fall in other cells near a boundary)
            want_enc = ref.hash_encoding(enc.bbox, enc.resolutions, enc.table_size, 2, pts, table.numpy())
            np.testing.assert_allclose(got, want_enc, rtol=tol, atol=tol)

    params = init_mlp_params([7, 16, 4], 0, wp.float32, dev)
    net = MLP([7, 16, 4], params)
    assert net.backend == "warp"
    # and it runs, the BLAS blocks refused: the Warp products, within float32's rounding of float64's
    x = rng.uniform(-1, 1, (37, 7)).astype(np.float32)
    y, cache = net.forward(wp.array(x, dtype=wp.float32))
    net.backward(cache, wp.array(np.ones((37, 4), np.float32), dtype=wp.float32), need_input_grad=True)
    p = {k: v.numpy().astype(np.float64) for k, v in params.items()}
    want = np.maximum(x.astype(np.float64) @ p["W0"].T + p["b0"], 0.0) @ p["W1"].T + p["b1"]
    bound = rounding.mlp_forward_bound(x, [p["W0"], p["W1"]], [p["b0"], p["b1"]], np.float32)
    ref_err = rounding.mlp_forward_bound(x, [p["W0"], p["W1"]], [p["b0"], p["b1"]], np.float64)  # `want`'s own
    assert np.all(np.abs(y.numpy() - want) <= bound + ref_err)


def test_corr_without_fast_paths(no_fast_path):
    from kernels.corr import correlation_pyramid, correlation_volume, lookup, lookup_onthefly, onthefly_features, lookup_onthefly_features
    from kernels.corr.volume import _backend
    from kernels._arrays import Inputs
    from kernels.reference import corr as ref
    from research.checks.corr import smooth_coords

    rng = np.random.default_rng(4)
    c, h, w, radius = 16, 9, 10, 2
    f1, f2 = rng.normal(size=(c, h, w)).astype(np.float32), rng.normal(size=(c, h, w)).astype(np.float32)
    assert _backend(Inputs("cpu", f1), None) == "warp"
    coords = smooth_coords(rng, h, w).astype(np.float32)
    pyr = correlation_pyramid(correlation_volume(f1, f2), 2)
    f2_pyr = ref.pyramid(f2.astype(np.float64), 2)
    want = ref.lookup(ref.pyramid(ref.volume(f1.astype(np.float64), f2.astype(np.float64)), 2),
                      coords.astype(np.float64), radius)
    np.testing.assert_allclose(lookup(pyr, coords, radius), want, rtol=1e-4, atol=1e-5)
    f2_pyr = [x.astype(np.float32) for x in f2_pyr]
    # pooling is linear, so the volume of the pooled features is the pooled volume
    np.testing.assert_allclose(lookup_onthefly(f1, f2_pyr, coords, radius), want, rtol=1e-4, atol=1e-5)
    feats = onthefly_features(f1, f2_pyr, feature_dtype="float16")
    assert np.all(np.isfinite(lookup_onthefly_features(feats, coords, radius)))


def test_stereo_and_splat_without_fast_paths(no_fast_path):
    import kernels.splat as ks
    from kernels.reference import splat as ref_splat
    from kernels.reference import stereo as ref_stereo
    from kernels.stereo.costs import census_transform
    from research.checks import splat as cs

    img = np.random.default_rng(5).uniform(0, 1, (12, 17)).astype(np.float32)
    np.testing.assert_array_equal(census_transform(img, 2, 3), ref_stereo.census_transform(img, 2, 3))

    scene = cs.smooth_scene(8)
    params = {k: v.astype(np.float32) for k, v in scene.params.items()}
    want = ref_splat.render({k: v.astype(np.float64) for k, v in params.items()}, scene.camera, scene.background)
    r = ks.render(ks.gaussian_inputs(*(params[k] for k in cs.PARAMS)), scene.camera,
                  scene.background.astype(np.float32))
    np.testing.assert_allclose(r.rgb, want[0], rtol=1e-4, atol=1e-5)


def test_points_without_fast_paths(no_fast_path):
    from kernels import points as kp
    from kernels.reference import points as ref

    p = np.random.default_rng(10).normal(size=(5000, 3)).astype(np.float32)
    np.testing.assert_array_equal(kp.farthest_point_sampling(p, 200, start=7),
                                  ref.farthest_point_sampling(p, 200, start=7))


# --------------------------------------------------------------------------- farthest-point sampling's C++ step


def _fps_clouds():
    """pytest.param(float32 cloud (N, 3), S, start, id=what it is): random clouds across and inside one
    block of the step, and clouds full of ties (a lattice, duplicated points, a single repeated point) whose
    argmax has many equal candidates within a block and across blocks."""
    from kernels.points.sampling import BLOCK

    rng = np.random.default_rng(11)
    g = np.arange(17, dtype=np.float32)
    lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)  # 4913 points: two blocks
    small = lattice[rng.choice(len(lattice), 40, replace=False)]
    dup = small[rng.integers(0, 40, 3 * BLOCK + 5)]  # 40 distinct points, each many times, four blocks
    return [
        pytest.param(rng.normal(size=(5000, 3)).astype(np.float32), 300, 0, id="random"),
        pytest.param(rng.uniform(-1, 1, (2 * BLOCK + 37, 3)).astype(np.float32), 500, 17,
                     id="random, N = 2 blocks + 37"),
        pytest.param(rng.normal(size=(3 * BLOCK, 3)).astype(np.float32), 64, 3 * BLOCK - 1, id="random, N = 3 blocks"),
        pytest.param(rng.normal(size=(100, 3)).astype(np.float32), 100, 5, id="random, N < one block, S = N"),
        pytest.param(rng.normal(size=(7, 3)).astype(np.float32), 7, 0, id="random, N < the 16-point group"),
        pytest.param(np.ones((1, 3), np.float32), 1, 0, id="one point"),
        pytest.param(lattice, len(lattice), 0, id="lattice, S = N"),
        pytest.param(dup, 200, 3, id="duplicated points, S past the distinct ones"),
        pytest.param(np.full((BLOCK + 9, 3), 0.5, np.float32), 20, 2, id="one repeated point"),
    ]


@pytest.mark.cpu_fast_path
@pytest.mark.parametrize("p, s, start", _fps_clouds())
def test_fps_cpu_step_is_the_warp_kernel_bit_for_bit(p, s, start, monkeypatch):
    """farthest_point_sampling's float32 step in C++ (kernels/native/fps_step.cpp) evaluates d2 and the
    running minimum as `_step_kernel` does and returns each block's first maximum, so the samples equal
    the plain kernel's, index for index, on random clouds and on clouds full of ties."""
    from kernels.points import sampling

    launched = []
    real_launch = wp.launch
    monkeypatch.setattr(wp, "launch", lambda k, *a, **kw: (launched.append(k), real_launch(k, *a, **kw))[1])
    fast_paths.set_enabled(True)  # also under DRLAB_FAST_PATHS=0 (make test's second pass)
    try:
        fast = sampling.farthest_point_sampling(p, s, start=start)
    finally:
        fast_paths.set_enabled(None)
    assert sampling._step_cpu_kernel in launched and sampling._step_kernel not in launched
    launched.clear()
    with fast_paths.disabled():
        plain = sampling.farthest_point_sampling(p, s, start=start)
    assert sampling._step_kernel in launched and sampling._step_cpu_kernel not in launched
    np.testing.assert_array_equal(fast, plain)


@pytest.mark.cpu_fast_path
def test_fps_float64_takes_the_warp_kernel(monkeypatch):
    """Only float32 clouds take the C++ step: float64 runs `_step_kernel` with the fast paths on."""
    from kernels.points import sampling
    from kernels.reference import points as ref

    p = np.random.default_rng(12).normal(size=(600, 3))
    launched = []
    real_launch = wp.launch
    monkeypatch.setattr(wp, "launch", lambda k, *a, **kw: (launched.append(k), real_launch(k, *a, **kw))[1])
    fast_paths.set_enabled(True)
    try:
        got = sampling.farthest_point_sampling(p, 50)
    finally:
        fast_paths.set_enabled(None)
    assert sampling._step_kernel in launched and sampling._step_cpu_kernel not in launched
    np.testing.assert_array_equal(got, ref.farthest_point_sampling(p, 50))


# --------------------------------------------------------------------------- fall-backs of the fast paths' own checks


@pytest.mark.cpu_fast_path
def test_composite_and_spheres_when_numpy_exp_is_not_reproduced(monkeypatch):
    """kernels._npexp's agreement check fails (another NumPy exp loop): the compositing forward keeps
    NumPy's factor pass and render_dense takes three launches with np.exp between them; the results
    are the same as with a reproduced exp, bit for bit where the exp's bits agree (they do here, or
    the forced case would not differ from the default)."""
    from kernels import _npexp
    from kernels.volume import SphereField, composite_forward
    from kernels.volume import composite_cpu, spheres_cpu

    rng = np.random.default_rng(6)
    n_rays, per = 19, 13
    n = n_rays * per
    args = (rng.uniform(0, 3, n).astype(np.float32), rng.uniform(0, 1, (n, 3)).astype(np.float32),
            rng.uniform(0.01, 0.2, n).astype(np.float32), np.arange(n, dtype=np.float32) * 0.1,
            np.arange(0, n + 1, per, dtype=np.int32))
    field = SphereField.textbook(wp.float32)
    o, d, t, dl = _sphere_rays(rng, 24, 16)

    def run():
        res = composite_forward(*args, keep_factor=False)
        return [res.rgb, res.depth, *field.render_dense(o, d, t, dl)]

    launched = []
    real_launch = wp.launch
    monkeypatch.setattr(wp, "launch", lambda k, *a, **kw: (launched.append(k), real_launch(k, *a, **kw))[1])
    default = run()
    monkeypatch.setattr(_npexp, "_agrees", False)  # the check found a difference
    assert not _npexp.numpy_agrees()
    del launched[:]
    forced = run()
    if spheres_cpu.available():
        k1, k2, k3, one = spheres_cpu.kernels()
        assert one not in launched and {k1, k2, k3} <= set(launched)
    assert composite_cpu.forward_kernel() in launched  # still the C++ forward, with NumPy's factors
    for a, b in zip(default, forced):
        np.testing.assert_array_equal(a, b)


@pytest.mark.cpu_fast_path
def test_splat_raster_without_the_row_blend(monkeypatch):
    """The row blend's availability check fails (no AVX2/FMA): the per-tile Warp kernel runs, the same bytes."""
    import kernels.splat as ks
    from kernels.splat import raster
    from research.checks import splat as cs

    scene = cs.smooth_scene(8)
    params = {k: v.astype(np.float32) for k, v in scene.params.items()}

    def render():
        return ks.render(ks.gaussian_inputs(*(params[k] for k in cs.PARAMS)), scene.camera,
                         scene.background.astype(np.float32))

    monkeypatch.setattr(raster, "_ROWS_OK", [True])
    if not raster.rowblend_available():
        pytest.skip("this CPU has no AVX2/FMA: the row blend never runs")
    with_rows = render()
    monkeypatch.setattr(raster, "_ROWS_OK", [False])
    monkeypatch.setattr(raster, "_raster_forward_rows_kernel", _refuse("the row blend"))
    without = render()
    for k in ("rgb", "alpha", "depth"):
        np.testing.assert_array_equal(getattr(with_rows, k), getattr(without, k))


@pytest.mark.cpu_fast_path
def test_spheres_without_avx2(monkeypatch):
    """spheres_cpu.available() False (no AVX2): render_dense runs the Warp passes, the same bytes."""
    from kernels.volume import SphereField, spheres_cpu
    import kernels.volume.spheres as spheres_module

    if not spheres_cpu.available():
        pytest.skip("this CPU has no AVX2: only the Warp passes exist")
    rng = np.random.default_rng(9)
    field = SphereField.textbook(wp.float32)
    o, d, t, dl = _sphere_rays(rng, 13, 12)
    want = field.render_dense(o, d, t, dl)
    monkeypatch.setattr(spheres_cpu, "available", lambda: False)
    monkeypatch.setattr(spheres_module.SphereField, "_native_passes", _refuse("spheres_cpu"))
    got = field.render_dense(o, d, t, dl)
    for a, b in zip(want, got):
        np.testing.assert_array_equal(a, b)



# --------------------------------------------------------------------------- the branches for CPUs without AVX2 / FMA
# The C++ fast paths choose their code at compile time (`#if !defined(__AVX2__) || !defined(__FMA__)`), and Warp
# compiles for the host (-march=native), so on every CI machine (all have AVX2 and FMA) those branches would never be
# compiled. Warp's `cpu_compiler_flags = ""` compiles for the generic x86-64 target (SSE2: neither AVX2 nor FMA), so
# the tests below compile them here, whatever the CPU.

_GENERIC_CHILD = r'''
import sys
import numpy as np
import warp as wp

wp.config.quiet = True
wp.config.cpu_compiler_flags = ""  # every module this process builds: the generic x86-64 target
from kernels.native import native_flag
from kernels.splat.rowblend import rowblend_available
from kernels.volume import composite as cm, composite_backward, composite_cpu, composite_forward, spheres_cpu


@wp.func_native("#if defined(__AVX2__) || defined(__FMA__)\nreturn 1;\n#else\nreturn 0;\n#endif\n")
def _has_avx2_or_fma() -> int: ...


assert native_flag(_has_avx2_or_fma) == 0, "the generic target still has AVX2 or FMA"
# the fast paths' own checks, compiled without AVX2: they say no, so the Warp kernels run
assert not spheres_cpu.available() and not rowblend_available()
# the compositing C++ has no such check: its non-AVX2 branch (element loads instead of gathers) runs and gives
# the Warp kernel's bits, as on the host build (the same float operations in the same order, contraction off)
used = []
for name in ("forward_kernel", "backward_kernel"):
    built = getattr(composite_cpu, name)
    setattr(composite_cpu, name, lambda built=built, name=name: used.append(name) or built())
rng = np.random.default_rng(1)
lens = rng.choice([0, 1, 3, 5, 7, 63, 65, 127], size=203)
off = np.concatenate([[0], np.cumsum(lens)]).astype(np.int32)
n = int(off[-1])
sigma = (rng.exponential(2.0, n) * (rng.random(n) < 0.8)).astype(np.float32)
rgb, delta = rng.random((n, 3)).astype(np.float32), (rng.random(n) * 0.1).astype(np.float32)
z = np.cumsum(delta).astype(np.float32)
cot = [rng.normal(size=s).astype(np.float32) for s in ((203, 3), 203, 203)]
out = {}
for simd in (False, True):
    cm.SIMD_FORWARD = cm.SIMD_BACKWARD = simd
    res = composite_forward(sigma, rgb, delta, z, off, (0.2, 0.5, 0.9), 1e-4)
    g = composite_backward(sigma, rgb, delta, z, off, res, *cot, (0.2, 0.5, 0.9))
    out[simd] = [res.rgb, res.depth, res.opacity, res.transmittance, res.n_used, *g]
assert sorted(set(used)) == ["backward_kernel", "forward_kernel"], used
for a, b in zip(out[False], out[True]):
    assert a.tobytes() == b.tobytes()
print("generic build: fall-backs ok")
'''


@pytest.mark.cpu_fast_path
def test_fast_paths_compiled_without_avx2_and_fma(tmp_path):
    """A process whose Warp modules are all compiled for generic x86-64: the sphere passes' and the row blend's
    availability checks, compiled there, say no (so the Warp kernels run), and the compositing C++'s non-AVX2
    branch gives the Warp kernel's bits, forward and backward."""
    import os
    import pathlib
    import subprocess
    import sys

    from kernels import cpu_target

    # the child compiles for the generic target: neither the fast-path switch nor a CPU target may reach it
    env = {k: v for k, v in os.environ.items() if k not in (fast_paths.ENV, cpu_target.ENV)}
    script = tmp_path / "generic_build.py"  # Warp reads a kernel's source from its file
    script.write_text(_GENERIC_CHILD)
    root = pathlib.Path(__file__).parents[2]
    env["PYTHONPATH"] = os.pathsep.join([str(root), *filter(None, [env.get("PYTHONPATH")])])
    run = subprocess.run([sys.executable, str(script)], cwd=root, env=env, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-4000:]
    assert "generic build: fall-backs ok" in run.stdout


@wp.func_native("#if defined(__AVX2__) && defined(__FMA__)\nreturn 1;\n#else\nreturn 0;\n#endif\n")
def _avx2_and_fma() -> int: ...


def _rho_without_avx2_kernel():
    from tests.kernels.test_vexp import rho_block

    @wp.kernel(enable_backward=False, module="unique", module_options={"cpu_compiler_flags": ""})
    def rho_plain(c: wp.array(dtype=wp.float32), lam: wp.float64, weight: wp.float64,
                  vec: wp.array(dtype=wp.float32), lane: wp.array(dtype=wp.float32), simd: wp.array(dtype=wp.int32)):
        b = wp.tid()
        if b == 0:
            simd[0] = _avx2_and_fma()
        rho_block(c, lam, weight, vec, lane, b)

    return rho_plain


def test_adcensus_rho_lanes_without_avx2_are_the_scalar_term():
    """The adcensus cost's 16-lane rho (adcensus_rho16.cpp, not switched by kernels.fast_paths) compiled without
    AVX2/FMA takes its plain loop (wp.exp a lane at a time, the scalar operations in their order): the bits of
    _robust_term, as its vector exp gives where it is compiled (tests/kernels/test_vexp.py)."""
    rng = np.random.default_rng(8)
    c = np.concatenate([rng.uniform(0.0, 4.0, 4000), rng.exponential(0.05, 4000), [0.0, 1e-45, 3.5, 1e30, np.inf]])
    c = np.concatenate([c, np.zeros(-len(c) % 16)]).astype(np.float32)
    ca = wp.array(c, dtype=wp.float32, device="cpu")
    vec, lane = (wp.zeros(len(c), dtype=wp.float32, device="cpu") for _ in range(2))
    simd = wp.full(1, 7, dtype=wp.int32, device="cpu")
    wp.launch(_rho_without_avx2_kernel(), len(c) // 16, [ca, wp.float64(0.04), wp.float64(0.3), vec, lane, simd],
              device="cpu")
    assert int(simd.numpy()[0]) == 0  # compiled without AVX2/FMA: the plain loop
    np.testing.assert_array_equal(vec.numpy().view(np.uint32), lane.numpy().view(np.uint32))


def test_pyproject_states_the_supported_range():
    """pyproject.toml's bounds on warp-lang and numpy are kernels.fast_paths.SUPPORTED."""
    import pathlib
    import re

    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    deps = tomllib.loads((pathlib.Path(__file__).parents[2] / "pyproject.toml").read_text())["project"]["dependencies"]
    for dist, key in (("warp-lang", "warp"), ("numpy", "numpy")):
        (spec,) = [d for d in deps if re.match(rf"{dist}\s*[<>=]", d)]
        lo, hi = fast_paths.SUPPORTED[key]
        want = {">=" + ".".join(map(str, lo)), "<" + ".".join(str(v) for v in (hi if hi[1:] != (0,) else hi[:1]))}
        assert set(spec[len(dist):].replace(" ", "").split(",")) == want, spec
