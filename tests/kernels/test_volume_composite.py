"""kernels.volume.composite: forward vs a NumPy reference, FD gradients, a Dr.Jit AD oracle, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels._arrays import value_checks
from kernels.reference import volume as ref_volume
from kernels.volume import CompositeResult, Workspace, composite_backward, composite_forward, dense_offsets
from kernels.volume.composite import composite_buffers
from research.checks.volume import check_composite, composite_inputs
from research.gradcheck import assert_gradcheck


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("t_threshold", [0.0, 1e-4, 0.05])
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.usefixtures("warp_device")
def test_forward_matches_reference(dtype, t_threshold, seed):
    inp = composite_inputs(seed)
    args = [inp[k].astype(dtype) for k in ("sigma", "rgb", "delta", "z")]
    bg = inp["background"].astype(dtype) if seed == 0 else np.array([0.1, 0.2, 0.3], dtype)
    res = composite_forward(*args, inp["ray_offsets"], bg, t_threshold)
    ref = ref_volume.composite(*(a.astype(np.float64) for a in args), inp["ray_offsets"], bg.astype(np.float64),
                               t_threshold)
    tol = 1e-5 if dtype == np.float32 else 1e-13
    np.testing.assert_allclose(res.rgb, ref[0], rtol=tol, atol=tol)
    np.testing.assert_allclose(res.depth, ref[1], rtol=tol, atol=tol)
    np.testing.assert_allclose(res.opacity, ref[2], rtol=tol, atol=tol)
    np.testing.assert_array_equal(res.n_used, ref[3])
    assert isinstance(res.rgb, np.ndarray) and res.rgb.dtype == dtype  # NumPy in, NumPy out


@pytest.mark.parametrize("dtype", [wp.float32, wp.float64])
def test_wp_arrays_in_give_wp_arrays_out_identical_to_numpy(dtype):
    inp = composite_inputs(0)
    np_t = wp.dtype_to_numpy(dtype)
    host = [inp[k].astype(np_t) for k in ("sigma", "rgb", "delta", "z")] + [inp["ray_offsets"]]
    dev = [wp.array(x, dtype=dtype if x.dtype.kind == "f" else wp.int32) for x in host]
    bg = inp["background"].astype(np_t)
    cot = [np.random.default_rng(1).normal(size=s).astype(np_t) for s in ((7, 3), 7, 7)]
    res_np = composite_forward(*host, bg)
    res_wp = composite_forward(*dev, wp.array(bg, dtype=dtype))
    assert all(isinstance(getattr(res_wp, k), wp.array) for k in vars(res_wp))
    for k in ("rgb", "depth", "opacity", "transmittance", "n_used"):
        np.testing.assert_array_equal(getattr(res_wp, k).numpy(), getattr(res_np, k))
    g_np = composite_backward(*host, res_np, *cot, bg)
    g_wp = composite_backward(*dev, res_wp, *(wp.array(c, dtype=dtype) for c in cot), bg)
    for a, b in zip(g_wp, g_np):
        assert isinstance(a, wp.array) and isinstance(b, np.ndarray)
        np.testing.assert_array_equal(a.numpy(), b)


def test_early_termination_stops_at_threshold():
    inp = composite_inputs(0)
    off = inp["ray_offsets"]
    args = [inp[k] for k in ("sigma", "rgb", "delta", "z")]
    full = composite_forward(*args, off, t_threshold=0.0)
    early = composite_forward(*args, off, t_threshold=1e-4)
    counts = np.diff(off)
    np.testing.assert_array_equal(full.n_used, counts)
    # Ray 4 holds a sample with sigma 200: its transmittance falls below 1e-4 right after it.
    assert early.n_used[4] == 4 < counts[4]
    assert early.transmittance[4] < 1e-4
    # The skipped samples carry weight < T < 1e-4, so the outputs barely move.
    np.testing.assert_allclose(early.rgb, full.rgb, atol=1e-4)


def test_empty_ray_returns_background_with_zero_gradient():
    sigma = np.array([1.0, 2.0])
    rgb = np.full((2, 3), 0.5)
    delta = np.array([0.5, 0.5])
    z = np.array([1.0, 2.0])
    offsets = np.array([0, 0, 2], dtype=np.int32)  # ray 0 has no sample (it missed the box)
    bg = np.array([0.2, 0.4, 0.6])
    res = composite_forward(sigma, rgb, delta, z, offsets, bg)
    np.testing.assert_array_equal(res.rgb[0], bg)
    assert res.depth[0] == 0.0 and res.opacity[0] == 0.0
    g = np.ones((2, 3))
    gs, gr = composite_backward(sigma, rgb, delta, z, offsets, res, g, np.ones(2), np.ones(2), bg)
    assert np.all(np.isfinite(gs)) and np.all(np.isfinite(gr))


@pytest.mark.usefixtures("warp_device")
def test_gradients_match_finite_differences():
    assert_gradcheck(check_composite(seeds=(0, 1, 2), t_threshold=1e-4))
    assert_gradcheck(check_composite(seeds=(3, 4), t_threshold=0.0))


def test_terminated_samples_get_zero_gradient():
    inp = composite_inputs(0)
    args = [inp[k] for k in ("sigma", "rgb", "delta", "z")]
    off = inp["ray_offsets"]
    res = composite_forward(*args, off, inp["background"], 1e-4)
    rng = np.random.default_rng(0)
    gs, gr = composite_backward(*args, off, res, rng.normal(size=(7, 3)), rng.normal(size=7), rng.normal(size=7),
                                inp["background"])
    stop = off[4] + res.n_used[4]
    assert np.all(gs[stop:off[5]] == 0.0) and np.all(gr[stop:off[5]] == 0.0)
    assert np.all(gs[off[4]:stop] != 0.0)


def test_float32_backward_close_to_float64():
    inp = composite_inputs(1)
    rng = np.random.default_rng(5)
    cot = (rng.normal(size=(7, 3)), rng.normal(size=7), rng.normal(size=7))
    grads = {}
    for dt in (np.float32, np.float64):
        args = [inp[k].astype(dt) for k in ("sigma", "rgb", "delta", "z")]
        bg = inp["background"].astype(dt)
        res = composite_forward(*args, inp["ray_offsets"], bg, 1e-4)
        grads[dt] = composite_backward(*args, inp["ray_offsets"], res, *(c.astype(dt) for c in cot), bg)
    for a, b in zip(grads[np.float32], grads[np.float64]):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


# --------------------------------------------------------------------------- Dr.Jit oracle

def drjit_composite_grads(sigma, rgb, delta, z, bg, t_threshold, g_rgb, g_depth, g_opacity):
    """Dense (R, S) compositing written with Dr.Jit's LLVM AD arrays; gradients by dr.backward."""
    dr = pytest.importorskip("drjit")
    try:
        from drjit.llvm.ad import Bool, Float64
        Float64(1.0)
    except Exception as exc:  # pragma: no cover - depends on the machine's libLLVM
        pytest.skip(f"Dr.Jit LLVM backend unavailable: {exc}")
    n_rays, n_samples = sigma.shape
    # One differentiable leaf per sample column (no gathers: their scatter adjoints JIT slowly).
    sig = [Float64(sigma[:, k]) for k in range(n_samples)]
    cols = [[Float64(rgb[:, k, c]) for c in range(3)] for k in range(n_samples)]
    for k in range(n_samples):
        dr.enable_grad(sig[k], *cols[k])
    T = dr.full(Float64, 1.0, n_rays)
    C = [dr.zeros(Float64, n_rays) for _ in range(3)]
    D = dr.zeros(Float64, n_rays)
    active = dr.full(Bool, True, n_rays)
    for k in range(n_samples):
        active = active & (T >= t_threshold)
        alpha = dr.select(active, 1.0 - dr.exp(-sig[k] * Float64(delta[:, k])), 0.0)
        w = T * alpha
        for c in range(3):
            C[c] = C[c] + w * cols[k][c]
        D = D + w * Float64(z[:, k])
        T = T * (1.0 - alpha)
        dr.eval(T, active, D, *C)  # small per-sample kernels: one LLVM compile, reused
    loss = dr.sum(D * Float64(g_depth)) + dr.sum((1.0 - T) * Float64(g_opacity))
    for c in range(3):
        loss = loss + dr.sum((C[c] + T * bg[c]) * Float64(g_rgb[:, c]))
    dr.backward(loss)
    g_sig = np.stack([np.array(dr.grad(sig[k])) for k in range(n_samples)], axis=1)
    g_col = np.stack([np.stack([np.array(dr.grad(cols[k][c])) for c in range(3)], axis=-1)
                      for k in range(n_samples)], axis=1)
    return g_sig, g_col


@pytest.mark.parametrize("seed, t_threshold", [(0, 1e-4), (1, 0.0)])
def test_gradients_agree_with_drjit_autodiff(seed, t_threshold):
    rng = np.random.default_rng(seed)
    n_rays, n_samples = 32, 16
    sigma = rng.uniform(0.0, 4.0, (n_rays, n_samples))
    sigma[::3, 7] = 300.0  # every third ray terminates early when t_threshold > 0
    rgb = rng.uniform(0.0, 1.0, (n_rays, n_samples, 3))
    delta = rng.uniform(0.02, 0.3, (n_rays, n_samples))
    z = np.cumsum(delta, axis=1) + 1.0
    bg = rng.uniform(0.0, 1.0, 3)
    g_rgb, g_depth, g_opacity = rng.normal(size=(n_rays, 3)), rng.normal(size=n_rays), rng.normal(size=n_rays)

    off = dense_offsets(n_rays, n_samples)
    flat = (sigma.ravel(), rgb.reshape(-1, 3), delta.ravel(), z.ravel())
    res = composite_forward(*flat, off, bg, t_threshold)
    gs, gr = composite_backward(*flat, off, res, g_rgb, g_depth, g_opacity, bg)
    d_sig, d_col = drjit_composite_grads(sigma, rgb, delta, z, bg, t_threshold, g_rgb, g_depth, g_opacity)
    if t_threshold > 0:
        assert (res.n_used < n_samples).sum() >= n_rays // 3
    np.testing.assert_allclose(gs.reshape(n_rays, n_samples), d_sig, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(gr.reshape(n_rays, n_samples, 3), d_col, rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------- bad input

def _valid(n=6):
    rng = np.random.default_rng(0)
    return dict(sigma=rng.uniform(0, 1, n), rgb=rng.uniform(0, 1, (n, 3)), delta=np.full(n, 0.1),
                z=np.linspace(1, 2, n), ray_offsets=np.array([0, 2, 6], dtype=np.int32))


@pytest.mark.parametrize("change, match", [
    (dict(rgb=np.zeros((5, 3))), "rgb: expected shape"),
    (dict(rgb=np.zeros((6, 4))), "rgb: expected shape"),
    (dict(sigma=np.zeros((6, 1))), "sigma: expected shape"),
    (dict(delta=np.zeros(5)), "delta: expected shape"),
    (dict(sigma=np.array([1.0, -0.1, 1, 1, 1, 1])), "sigma: expected values >= 0"),
    (dict(sigma=np.array([1.0, np.nan, 1, 1, 1, 1])), "sigma: expected finite values >= 0, found NaN"),
    (dict(rgb=np.full((6, 3), np.inf)), "rgb: expected finite values, found NaN or infinite"),
    (dict(delta=np.full(6, -0.1)), "delta: expected values >= 0"),
    (dict(ray_offsets=np.array([0, 4, 2, 6])), "ray_offsets: expected non-decreasing"),
    (dict(ray_offsets=np.zeros((2, 2), np.int32)), r"ray_offsets: expected shape \(R\+1,\)"),
    (dict(ray_offsets=np.array([0, 2, 5])), "ray_offsets: expected non-decreasing offsets from 0"),
    (dict(ray_offsets=np.array([0.0, 2.0, 6.0])), "ray_offsets: expected an integer array"),
    (dict(rgb=np.zeros((6, 3), np.float32)), "rgb: expected dtype float64 like the other inputs, got float32"),
    (dict(sigma=np.arange(6)), "sigma: expected dtype float32 or float64, got int64"),
    (dict(z=[1.0] * 6), "z: expected a NumPy array or a wp.array, got list"),
])
def test_bad_input_raises(change, match):
    args = {**_valid(), **change}
    with pytest.raises(ValueError, match=match):
        composite_forward(**args)


def test_bad_background_and_threshold():
    with pytest.raises(ValueError, match="background: expected shape"):
        composite_forward(**_valid(), background=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="t_threshold"):
        composite_forward(**_valid(), t_threshold=1.5)
    with pytest.raises(ValueError, match="background: expected finite values"):
        composite_forward(**_valid(), background=[0.0, np.nan, 0.0])


def test_backward_bad_cotangent():
    v = _valid()
    res = composite_forward(**v)
    with pytest.raises(ValueError, match="grad_rgb: expected shape"):
        composite_backward(**v, result=res, grad_rgb=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="grad_depth: expected finite values"):
        composite_backward(**v, result=res, grad_depth=np.array([np.nan, 0.0]))


# --------------------------------------------------------------------------- reused buffers

def test_forward_stores_the_exponential_factors_it_used():
    inp = composite_inputs(0)
    args = [inp[k] for k in ("sigma", "rgb", "delta", "z")]
    res = composite_forward(*args, inp["ray_offsets"], t_threshold=1e-4)
    factor, n_used = res.factor, res.n_used
    for r, (a, b) in enumerate(zip(inp["ray_offsets"][:-1], inp["ray_offsets"][1:])):
        used = slice(a, a + n_used[r])  # entries past early termination are not written
        # rtol of a few ulp, not equality: NumPy's vectorised exp need not round as the C library's does.
        np.testing.assert_allclose(factor[used], np.exp(-inp["sigma"][used] * inp["delta"][used]), rtol=4e-16)
        assert n_used[r] <= b - a
    assert np.any(n_used < np.diff(inp["ray_offsets"])) and np.any(n_used > 0)


def test_out_buffers_give_the_same_results_and_are_returned():
    inp = composite_inputs(1)
    args = [inp[k] for k in ("sigma", "rgb", "delta", "z")]
    off, bg = inp["ray_offsets"], inp["background"]
    rng = np.random.default_rng(5)
    n_rays, n = len(off) - 1, len(inp["sigma"])
    cot = (rng.normal(size=(n_rays, 3)), rng.normal(size=n_rays), rng.normal(size=n_rays))
    fresh = composite_forward(*args, off, bg)
    fresh_g = composite_backward(*args, off, fresh, *cot, bg)

    ws = Workspace()
    for _ in range(2):  # the second round reuses buffers holding the first round's values
        buf = CompositeResult(ws.array("rgb", (n_rays, 3), wp.float64), ws.array("d", (n_rays,), wp.float64),
                              ws.array("a", (n_rays,), wp.float64), ws.array("t", (n_rays,), wp.float64),
                              ws.array("n", (n_rays,), wp.int32), ws.array("f", (n,), wp.float64))
        res = composite_forward(*args, off, bg, out=buf)
        assert res.rgb.ptr == buf.rgb.ptr and res.factor.ptr == buf.factor.ptr
        out = (ws.array("gs", (n,), wp.float64), ws.array("gc", (n, 3), wp.float64))
        out[0].fill_(np.nan)  # every entry must be written, terminated samples included
        out[1].fill_(np.nan)
        g = composite_backward(*args, off, res, *cot, bg, out=out)
        assert g[0].ptr == out[0].ptr and g[1].ptr == out[1].ptr
        for a, b in zip((res.rgb, res.depth, res.opacity, res.n_used), (fresh.rgb, fresh.depth, fresh.opacity,
                                                                       fresh.n_used)):
            np.testing.assert_array_equal(a.numpy(), b)
        np.testing.assert_array_equal(g[0].numpy(), fresh_g[0])
        np.testing.assert_array_equal(g[1].numpy(), fresh_g[1])


def test_bad_out_buffers():
    v = _valid()
    res = composite_forward(**v)
    good = composite_buffers(Workspace(), 2, 6, wp.float64)
    bad = CompositeResult(good.rgb, good.depth, good.opacity, good.transmittance, good.n_used,
                          wp.empty(5, dtype=wp.float64, device="cpu"))
    with pytest.raises(ValueError, match=r"out.factor: expected an output buffer of shape \(6,\)"):
        composite_forward(**v, out=bad)
    with pytest.raises(ValueError, match="out.rgb: expected a wp.array output buffer, got ndarray"):
        composite_forward(**v, out=res)  # NumPy results are not buffers
    with pytest.raises(ValueError, match="out: expected a pair"):
        composite_backward(**v, result=res, out=wp.empty(6, dtype=wp.float64, device="cpu"))
    with pytest.raises(ValueError, match="out\\[1\\]: expected an output buffer of shape \\(6, 3\\) and dtype float64"):
        composite_backward(**v, result=res, out=(wp.empty(6, dtype=wp.float64, device="cpu"),
                                                 wp.empty((6, 3), dtype=wp.float32, device="cpu")))
    with pytest.raises(ValueError, match="out\\[0\\]: expected a wp.array"):
        composite_backward(**v, result=res, out=(np.empty(6), wp.empty((6, 3), dtype=wp.float64, device="cpu")))


def test_workspace_grows_and_hands_out_views():
    ws = Workspace("cpu")
    a = ws.array("x", (10, 3), wp.float32)
    assert a.shape == (10, 3) and a.is_contiguous
    b = ws.array("x", (4, 3), wp.float32)  # smaller: a view of the same memory
    assert b.shape == (4, 3) and b.ptr == a.ptr
    c = ws.array("x", (11, 3), wp.float32)  # larger: grown by half again, so 12 more rows fit without reallocating
    assert c.shape == (11, 3) and ws.array("x", (15, 3), wp.float32).ptr == c.ptr
    assert ws.nbytes() == 15 * 3 * 4
    d = ws.array("x", (4,), wp.float64)  # another layout reallocates
    assert d.shape == (4,) and d.dtype == wp.float64
    assert ws.array("empty", (0, 3), wp.float32).shape == (0, 3)
    with pytest.raises(ValueError, match="shape"):
        ws.array("x", (-1,), wp.float32)


def test_value_checks_off_leaves_shape_and_dtype_checks():
    """Inside value_checks(False) bad values pass through (the caller vouches for them); bad shapes do not."""
    v = _valid()
    nan_sigma = {**v, "sigma": np.array([1.0, np.nan, 1, 1, 1, 1])}
    bad_order = {**v, "ray_offsets": np.array([0, 4, 2, 6])}
    with value_checks(False):
        composite_forward(**nan_sigma)
        composite_forward(**{**v, "ray_offsets": np.array([0, 2, 6], np.int32)}, background=(0.0, np.inf, 0.0))
        with pytest.raises(ValueError, match="rgb: expected shape"):
            composite_forward(**{**v, "rgb": np.zeros((5, 3))})
        with pytest.raises(ValueError, match="rgb: expected dtype float64"):
            composite_forward(**{**v, "rgb": np.zeros((6, 3), np.float32)})
    for bad in (nan_sigma, bad_order):  # and back on afterwards
        with pytest.raises(ValueError):
            composite_forward(**bad)


@pytest.mark.parametrize("dtype, max_ulp", [(np.float32, 2.5), (np.float64, 1.0)], ids=["float32", "float64"])
def test_cpu_factors_within_stated_rounding_of_exact_exp(dtype, max_ulp):
    # The CPU forward fills exp(-sigma delta) with NumPy's vectorised exp (module docstring).
    from kernels.volume import composite_forward, dense_offsets

    rng = np.random.default_rng(3)
    rays, samples = 64, 300
    n = rays * samples
    sigma = rng.uniform(0.0, 40.0, n).astype(dtype)
    delta = rng.uniform(0.0, 0.05, n).astype(dtype)
    res = composite_forward(sigma, rng.uniform(0, 1, (n, 3)).astype(dtype), delta, np.ones(n, dtype),
                            dense_offsets(rays, samples), t_threshold=0.0)
    x = -(sigma * delta)  # the product as the kernel forms it, rounded in `dtype`
    exact = np.exp(x.astype(np.longdouble))
    ulp = np.abs(res.factor.astype(np.longdouble) - exact) / np.spacing(exact.astype(dtype)).astype(np.longdouble)
    assert float(ulp.max()) <= max_ulp


@pytest.mark.parametrize("dtype, rtol", [(np.float32, 2e-6), (np.float64, 1e-14)])
@pytest.mark.parametrize("t_threshold", [0.0, 1e-4, 0.05])
def test_in_kernel_exponential_path_agrees(monkeypatch, dtype, rtol, t_threshold):
    """The kernel's own exp(-sigma delta) (what runs on CUDA; here forced on the CPU) against the
    NumPy factor pass: the same samples used, outputs within the rounding of the two exponentials."""
    import kernels.volume.composite as comp

    inp = composite_inputs(2)
    args = [inp[k].astype(dtype) for k in ("sigma", "rgb", "delta", "z")]
    off, bg = inp["ray_offsets"], inp["background"].astype(dtype)
    ref = composite_forward(*args, off, bg, t_threshold)
    monkeypatch.setattr(comp, "_fill_factor", lambda *a, **k: 0)
    got = composite_forward(*args, off, bg, t_threshold)
    np.testing.assert_array_equal(got.n_used, ref.n_used)
    for name in ("rgb", "depth", "opacity", "transmittance"):
        np.testing.assert_allclose(getattr(got, name), getattr(ref, name), rtol=rtol, atol=rtol)
    used = np.concatenate([np.arange(a, a + u) for a, u in zip(off[:-1], ref.n_used)])
    np.testing.assert_allclose(got.factor[used], ref.factor[used], rtol=rtol)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_split_launches_match_one_thread_bit_for_bit(monkeypatch, dtype):
    """Enough rays for several chunks per thread (composite._launch: recorded launches whose size and
    offset change chunk by chunk): outputs and gradients on 2 and 3 threads, twice each, equal one thread's."""
    import kernels.volume.composite as comp

    rng = np.random.default_rng(7)
    counts = rng.integers(0, 257, 3000)  # mean 128 samples: min chunk ~1024 rays, so 2 threads pull 3+ chunks
    off = np.concatenate(([0], np.cumsum(counts))).astype(np.int32)
    n, rays = int(off[-1]), counts.shape[0]
    sigma = rng.uniform(0.0, 3.0, n).astype(dtype)
    args = [sigma, rng.uniform(0, 1, (n, 3)).astype(dtype), rng.uniform(0, 0.05, n).astype(dtype),
            rng.uniform(1, 2, n).astype(dtype), off]
    cot = [rng.normal(size=s).astype(dtype) for s in ((rays, 3), rays, rays)]
    assert len(comp.guided_bounds(rays, 2, comp._min_chunk(rays, n))) > 2

    def run(threads: str) -> list[np.ndarray]:
        monkeypatch.setenv("DRLAB_THREADS", threads)
        res = composite_forward(*args, (0.1, 0.2, 0.3), 1e-4)
        g = composite_backward(*args, res, *cot, (0.1, 0.2, 0.3))
        return [res.rgb, res.depth, res.opacity, res.transmittance, res.n_used, *g]

    ref = run("1")
    for threads in ("2", "3", "2"):
        for a, b in zip(run(threads), ref):
            np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------- the CPU SIMD forward

def _simd_case(kind, n_rays, seed=0):
    rng = np.random.default_rng(seed)
    if kind == "packed":
        lens = rng.integers(0, 201, size=n_rays)
    elif kind == "odd":
        lens = rng.choice([0, 1, 3, 5, 7, 63, 65, 127], size=n_rays)
    else:
        lens = np.full(n_rays, 64)
    off = np.concatenate([[0], np.cumsum(lens)]).astype(np.int32)
    n = int(off[-1])
    sigma = (rng.exponential(2.0, n) * (rng.random(n) < 0.8)).astype(np.float32)
    rgb = rng.random((n, 3)).astype(np.float32)
    delta = (rng.random(n) * 0.1).astype(np.float32)
    z = np.cumsum(delta).astype(np.float32)
    return sigma, rgb, delta, z, off


@pytest.mark.parametrize("threads", ["1", "2"])
@pytest.mark.parametrize("kind,n_rays", [("packed", 3001), ("odd", 2003), ("dense", 5)])
@pytest.mark.cpu_fast_path
def test_cpu_simd_kernels_equal_the_warp_kernels_bitwise(monkeypatch, threads, kind, n_rays):
    from kernels.volume import composite as cm
    from kernels.volume import composite_cpu

    monkeypatch.setenv("DRLAB_THREADS", threads)
    used = {"forward": 0, "backward": 0}
    for name in used:
        built = getattr(composite_cpu, f"{name}_kernel")
        monkeypatch.setattr(composite_cpu, f"{name}_kernel",
                            lambda name=name, built=built: used.__setitem__(name, used[name] + 1) or built())
    sigma, rgb, delta, z, off = _simd_case(kind, n_rays)
    rng = np.random.default_rng(1)
    per_ray_bg = rng.random((n_rays, 3)).astype(np.float32)
    cot = (rng.normal(size=(n_rays, 3)).astype(np.float32), rng.normal(size=n_rays).astype(np.float32),
           rng.normal(size=n_rays).astype(np.float32))
    for t_threshold in (0.0, 1e-4, 0.3):
        for bg in ((0.2, 0.5, 0.9), per_ray_bg):
            for checks in (True, False):
                got, grads = {}, {}
                for simd in (False, True):
                    monkeypatch.setattr(cm, "SIMD_FORWARD", simd)
                    monkeypatch.setattr(cm, "SIMD_BACKWARD", simd)
                    before = dict(used)
                    with value_checks(checks):
                        got[simd] = composite_forward(sigma, rgb, delta, z, off, bg, t_threshold)
                        grads[simd] = composite_backward(sigma, rgb, delta, z, off, got[simd], *cot, bg)
                    # the SIMD kernels ran exactly when asked
                    assert used == {k: v + int(simd) for k, v in before.items()}
                a, b = got[False], got[True]
                for k in ("rgb", "depth", "opacity", "transmittance", "n_used"):
                    assert getattr(a, k).tobytes() == getattr(b, k).tobytes(), (k, t_threshold, checks)
                for r in range(n_rays):  # factors: only the processed entries are defined
                    s = slice(off[r], off[r] + a.n_used[r])
                    assert a.factor[s].tobytes() == b.factor[s].tobytes()
                for ga, gb in zip(grads[False], grads[True]):
                    assert ga.tobytes() == gb.tobytes(), (t_threshold, checks)
    assert np.any(a.n_used < np.diff(off))  # termination happened


@pytest.mark.parametrize("which", ["rgb", "z"])
def test_cpu_simd_forward_flags_a_bad_value_after_termination(which):
    n = 1000
    sigma, rgb = np.ones(n, np.float32), np.ones((n, 3), np.float32)
    delta, z = np.full(n, 0.01, np.float32), np.ones(n, np.float32)
    if which == "rgb":
        rgb[997, 1] = np.nan
    else:
        z[998] = np.inf
    off = np.array([0, 3, 500, 1000], np.int32)
    res = None
    with pytest.raises(ValueError, match=which):
        res = composite_forward(sigma, rgb, delta, z, off, t_threshold=0.3)
    assert res is None


# --------------------------------------------------------------------------- the fused exp (kernels._npexp)

def _numpy_runs_its_simd_exp():
    """NumPy's float32 exp is its AVX2+FMA3 / AVX512F loop (the one kernels._npexp reproduces) on x86-64 CPUs
    with those features; elsewhere it is the C library's expf."""
    import platform

    feats = getattr(getattr(np, "_core", np.core), "_multiarray_umath").__cpu_features__
    simd = feats.get("AVX512F") or (feats.get("AVX2") and feats.get("FMA3"))
    return platform.machine() in ("x86_64", "AMD64") and bool(simd)


def test_npexp_gives_numpy_exp_bits_on_every_exponent_and_edge():
    from kernels import _npexp

    if not _numpy_runs_its_simd_exp():
        pytest.skip("NumPy runs the C library's expf here (the fused forward then keeps NumPy's pass)")
    rng = np.random.default_rng(7)
    x = np.concatenate([_npexp.check_set().view(np.uint32), rng.integers(0, 2**32, 1 << 20, dtype=np.uint32),
                        np.arange(0xC2C00000, 0xC2D00000, 16, dtype=np.uint32)]).view(np.float32)  # subnormal results
    with np.errstate(all="ignore"):
        want = np.exp(x)
    got = _npexp.exp(x)
    bad = np.flatnonzero(got.view(np.uint32) != want.view(np.uint32))
    assert bad.size == 0, [(hex(int(x.view(np.uint32)[i])), got[i], want[i]) for i in bad[:5]]
    assert _npexp.numpy_agrees()
    # the check set reaches every region: subnormal, zero, inf and NaN results, both signs of every exponent
    r = want.view(np.uint32)
    assert np.any((r > 0) & (r < 0x00800000)) and np.any(r == 0) and np.any(r == 0x7F800000) and np.any(np.isnan(want))


def test_npexp_check_notices_a_different_exp(monkeypatch):
    from kernels import _npexp

    # an exp one ulp off in a single place: the check set must see it
    x = _npexp.check_set()
    real = _npexp.exp
    target = int(np.flatnonzero(x == np.float32(-0.5))[0]) if np.any(x == np.float32(-0.5)) else len(x) // 3

    def off_by_one(v):
        y = real(v)
        if v.shape == x.shape:
            y.view(np.uint32)[target] ^= 1
        return y

    monkeypatch.setattr(_npexp, "exp", off_by_one)
    monkeypatch.setattr(_npexp, "_agrees", None)
    assert not _npexp.numpy_agrees()


def _forward_backward(sigma, rgb, delta, z, off, bg, thr, cot):
    res = composite_forward(sigma, rgb, delta, z, off, bg, thr)
    grads = composite_backward(sigma, rgb, delta, z, off, res, *cot, bg)
    return [res.rgb, res.depth, res.opacity, res.transmittance, res.n_used, res.factor, *grads]


@pytest.mark.parametrize("threads", ["1", "2"])
@pytest.mark.parametrize("kind,n_rays", [("packed", 1501), ("odd", 1003), ("dense", 13)])
@pytest.mark.cpu_fast_path
def test_fused_exp_forward_equals_numpy_pass_bitwise(monkeypatch, threads, kind, n_rays):
    """The forward with the factors evaluated in the kernel (FUSED_EXP) against NumPy's pass before the
    kernel: every output byte, every factor (past termination too) and both gradients; and which ran."""
    from kernels import _npexp
    from kernels.volume import composite as cm

    if not _npexp.numpy_agrees():
        pytest.skip("NumPy's exp is another loop here: the fused path is off (test_fused_exp_falls_back...)")
    monkeypatch.setenv("DRLAB_THREADS", threads)
    fills = []
    real_fill = cm._fill_factor
    monkeypatch.setattr(cm, "_fill_factor", lambda *a: fills.append(1) or real_fill(*a))
    sigma, rgb, delta, z, off = _simd_case(kind, n_rays, seed=3)
    sigma[::97] *= 400.0  # factors down to subnormals and 0
    rng = np.random.default_rng(2)
    cot = (rng.normal(size=(n_rays, 3)).astype(np.float32), rng.normal(size=n_rays).astype(np.float32),
           rng.normal(size=n_rays).astype(np.float32))
    for thr in (0.0, 1e-4, 0.3):
        for bg in ((0.2, 0.5, 0.9), rng.random((n_rays, 3)).astype(np.float32)):
            for checks in (True, False):
                out = {}
                for fused in (False, True):
                    monkeypatch.setattr(cm, "FUSED_EXP", fused)
                    fills.clear()
                    with value_checks(checks):
                        out[fused] = _forward_backward(sigma, rgb, delta, z, off, bg, thr, cot)
                    assert len(fills) == int(not fused)
                for a, b in zip(out[False], out[True]):
                    assert a.tobytes() == b.tobytes(), (thr, checks)


@pytest.mark.cpu_fast_path
def test_fused_exp_falls_back_to_numpy_pass(monkeypatch):
    """Where the lanes' exp does not give np.exp's bits (another NumPy loop), or the offsets do not cover the
    samples (value checks off), the forward keeps NumPy's pass: all N factors, the same outputs."""
    from kernels import _npexp
    from kernels.volume import composite as cm

    fills = []
    real_fill = cm._fill_factor
    monkeypatch.setattr(cm, "_fill_factor", lambda *a: fills.append(1) or real_fill(*a))
    sigma, rgb, delta, z, off = _simd_case("packed", 301, seed=4)
    ref = composite_forward(sigma, rgb, delta, z, off)
    monkeypatch.setattr(_npexp, "_agrees", False)
    fills.clear()
    got = composite_forward(sigma, rgb, delta, z, off)
    assert len(fills) == 1
    for k in ("rgb", "depth", "opacity", "transmittance", "n_used", "factor"):
        assert getattr(got, k).tobytes() == getattr(ref, k).tobytes(), k
    monkeypatch.setattr(_npexp, "_agrees", None)
    # offsets ending before the last sample (value checks off): every factor still filled, by the pass
    short = off.copy()
    short[-1] = short[-2]
    fills.clear()
    with value_checks(False):
        got = composite_forward(sigma, rgb, delta, z, short)
    assert len(fills) == 1
    # the same NumPy float32 product, negation and exp loop on the same values, in blocks instead of
    # one call: each element's bits do not depend on the block (NumPy's SIMD loops mask the tail
    # instead of switching to another algorithm, and its scalar fallback is per element)
    with np.errstate(over="ignore"):
        assert got.factor.tobytes() == np.exp(-(sigma * delta)).tobytes()


@pytest.mark.parametrize("name", ["sigma", "delta"])
@pytest.mark.parametrize("bad", [np.nan, -1.0, np.inf])
def test_fused_forward_rejects_a_bad_value_after_termination(name, bad):
    n = 1000
    arrays = {"sigma": np.ones(n, np.float32), "delta": np.full(n, 0.01, np.float32)}
    arrays[name][998] = bad  # in the last ray, after its early termination at 0.3
    rgb, z = np.ones((n, 3), np.float32), np.ones(n, np.float32)
    off = np.array([0, 3, 500, 1000], np.int32)
    assert composite_forward(np.ones(n, np.float32), rgb, np.full(n, 0.01, np.float32), z, off,
                             t_threshold=0.3).n_used[2] < 500
    with pytest.raises(ValueError, match=name):
        composite_forward(arrays["sigma"], rgb, arrays["delta"], z, off, t_threshold=0.3)


def _long_case(n_rays, seed=0):
    """Rays of 250-400 samples: groups of eight rays beyond the forward's factor ring (composite_cpu.RING)."""
    rng = np.random.default_rng(seed)
    off = np.concatenate([[0], np.cumsum(rng.integers(250, 401, size=n_rays))]).astype(np.int32)
    n = int(off[-1])
    delta = (rng.random(n) * 0.02).astype(np.float32)
    return (rng.exponential(1.0, n).astype(np.float32), rng.random((n, 3)).astype(np.float32), delta,
            np.cumsum(delta).astype(np.float32), off)


_OUTPUTS = ("rgb", "depth", "opacity", "transmittance", "n_used")


@pytest.mark.parametrize("threads", ["1", "2"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("kind,n_rays", [("packed", 1501), ("odd", 1003), ("dense", 13), ("long", 203)])
@pytest.mark.cpu_fast_path
def test_forward_without_factor_equals_keep_factor_bitwise(monkeypatch, threads, dtype, kind, n_rays):
    """keep_factor=False: every output byte of keep_factor=True's, `factor` None; in float32 on the CPU the SIMD
    forward holds the factors in its ring (groups of at most RING samples) and allocates no N-sized array."""
    from kernels import _npexp
    from kernels.volume import composite as cm

    monkeypatch.setenv("DRLAB_THREADS", threads)
    rings = []
    real_no_factor = cm._no_factor
    monkeypatch.setattr(cm, "_no_factor", lambda dev: rings.append(1) or real_no_factor(dev))
    sigma, rgb, delta, z, off = _long_case(n_rays, seed=5) if kind == "long" else _simd_case(kind, n_rays, seed=5)
    sigma[::89] *= 400.0  # factors down to subnormals and 0
    sigma, rgb, delta, z = (x.astype(dtype) for x in (sigma, rgb, delta, z))
    rng = np.random.default_rng(6)
    in_ring = dtype == np.float32 and kind != "long" and _npexp.numpy_agrees()
    for thr in (0.0, 1e-4, 0.3):
        for bg in ((0.2, 0.5, 0.9), rng.random((n_rays, 3)).astype(dtype)):
            for checks in (True, False):
                with value_checks(checks):
                    kept = composite_forward(sigma, rgb, delta, z, off, bg, thr)
                    rings.clear()
                    bare = composite_forward(sigma, rgb, delta, z, off, bg, thr, keep_factor=False)
                assert len(rings) == int(in_ring), (thr, checks)
                assert bare.factor is None and kept.factor is not None
                for k in _OUTPUTS:
                    assert getattr(bare, k).tobytes() == getattr(kept, k).tobytes(), (k, thr, checks)


@pytest.mark.parametrize("fused,simd", [(False, True), (True, False)])
def test_forward_without_factor_on_the_other_paths(monkeypatch, fused, simd):
    """NumPy's pass (FUSED_EXP off) and the Warp kernel (SIMD_FORWARD off) fill a scratch that is not returned."""
    from kernels.volume import composite as cm

    sigma, rgb, delta, z, off = _simd_case("packed", 301, seed=8)
    kept = composite_forward(sigma, rgb, delta, z, off, t_threshold=1e-4)
    monkeypatch.setattr(cm, "FUSED_EXP", fused)
    monkeypatch.setattr(cm, "SIMD_FORWARD", simd)
    bare = composite_forward(sigma, rgb, delta, z, off, t_threshold=1e-4, keep_factor=False)
    assert bare.factor is None
    for k in _OUTPUTS:
        assert getattr(bare, k).tobytes() == getattr(kept, k).tobytes(), k


def test_forward_without_factor_into_workspace_buffers():
    """With `out` buffers (composite_buffers(..., keep_factor=False): factor None): the same outputs, and the
    workspace holds no factor buffer."""
    sigma, rgb, delta, z, off = _simd_case("packed", 700, seed=9)
    ws = Workspace("cpu")
    kept = composite_forward(sigma, rgb, delta, z, off)
    bufs = composite_buffers(ws, 700, sigma.shape[0], wp.float32, keep_factor=False)
    assert bufs.factor is None
    got = composite_forward(*(wp.array(x, device="cpu") for x in (sigma, rgb, delta, z, off)), out=bufs,
                            keep_factor=False)
    assert got.factor is None and got.rgb.ptr == bufs.rgb.ptr
    for k in _OUTPUTS:
        assert getattr(got, k).numpy().tobytes() == getattr(kept, k).tobytes(), k
    assert "composite.factor" not in ws._buffers
    with pytest.raises(ValueError, match="keep_factor"):
        composite_forward(sigma, rgb, delta, z, off, keep_factor=1)


def test_backward_refuses_a_result_without_factors(monkeypatch):
    """composite_backward on a keep_factor=False result: a ValueError naming it, before any kernel runs."""
    from kernels.volume import composite as cm

    sigma, rgb, delta, z, off = _simd_case("packed", 64, seed=10)
    res = composite_forward(sigma, rgb, delta, z, off, keep_factor=False)
    monkeypatch.setattr(cm, "_launch", lambda *a, **k: pytest.fail("a kernel ran"))
    with pytest.raises(ValueError, match=r"keep_factor=False.*result\.factor is None"):
        composite_backward(sigma, rgb, delta, z, off, res, np.ones((64, 3), np.float32))


@pytest.mark.parametrize("name", ["sigma", "delta", "rgb"])
def test_forward_without_factor_still_rejects_bad_values(name):
    n = 1000
    arrays = {"sigma": np.ones(n, np.float32), "delta": np.full(n, 0.01, np.float32),
              "rgb": np.ones((n, 3), np.float32)}
    arrays[name][998] = np.nan  # in the last ray, after its early termination at 0.3
    off = np.array([0, 3, 500, 1000], np.int32)
    with pytest.raises(ValueError, match=name):
        composite_forward(arrays["sigma"], arrays["rgb"], arrays["delta"], np.ones(n, np.float32), off,
                          t_threshold=0.3, keep_factor=False)
