"""kernels/splat against its NumPy reference (kernels/reference/splat.py), finite differences, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import splat as ks
from kernels.reference import splat as ref
from research.checks import splat as cs
from research.gradcheck import assert_gradcheck

PARAMS = cs.PARAMS


def as_dtype(params: dict, dtype) -> dict:
    return {k: v.astype(dtype) for k, v in params.items()}


# --------------------------------------------------------------------------- forward vs reference

TOL = {np.float32: dict(rtol=2e-4, atol=2e-5), np.float64: dict(rtol=1e-10, atol=1e-11)}


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.usefixtures("warp_device")
def test_project_matches_reference(dtype, antialiased):
    scene = cs.smooth_scene(5, antialiased=antialiased, off_frustum=True)
    params = as_dtype(scene.params, dtype)
    want = ref.project({k: v.astype(np.float64) for k, v in params.items()}, scene.camera, antialiased=antialiased)
    g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
    p = ks.project(g, scene.camera, antialiased=antialiased)
    # Integers, but ceil(3 sqrt(lam_max)) of two computations: equal where that value is farther from an integer
    # than the two differ. The kernel's value does not depend on the CPU (Warp, no BLAS); the reference's 3x3
    # products and det (BLAS/LAPACK) move by ~1e-15 relative from one CPU to another, far inside the float32
    # kernel's own ~1e-6 distance from it, which already does not cross an integer on this scene.
    np.testing.assert_array_equal(p.radii, want["radii"])
    assert (want["radii"] > 0).sum() >= 10
    for key in ("means2d", "conics", "depths", "colors", "opacities"):
        got = getattr(p, key)
        assert isinstance(got, np.ndarray) and got.dtype == dtype
        np.testing.assert_allclose(got, want[key], **TOL[dtype], err_msg=key)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("mode, antialiased, dilation", [("3dgs", True, 0.1), ("3dgs", False, 0.0),
                                                          ("gsplat", True, 0.05)])
def test_project_and_render_match_reference_with_another_dilation(dtype, mode, antialiased, dilation):
    """The `dilation` parameter replaces the 0.3 px^2 low-pass in the conic, the radius and the
    compensation, as the NumPy reference does; and it changes them (not a no-op)."""
    scene = cs.smooth_scene(9, antialiased=antialiased, mode=mode, dilation=dilation)
    params = as_dtype(scene.params, dtype)
    p64 = {k: v.astype(np.float64) for k, v in params.items()}
    want = ref.project(p64, scene.camera, antialiased=antialiased, mode=mode, dilation=dilation)
    g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
    p = ks.project(g, scene.camera, antialiased=antialiased, mode=mode, dilation=dilation)
    np.testing.assert_array_equal(p.radii, want["radii"])
    assert (want["radii"] > 0).sum() >= 10
    for key in ("means2d", "conics", "depths", "colors", "opacities"):
        np.testing.assert_allclose(getattr(p, key), want[key], **TOL[dtype], err_msg=key)
    default = ref.project(p64, scene.camera, antialiased=antialiased, mode=mode)
    vis = want["radii"] > 0
    trace = want["conics"][vis][:, [0, 2]].sum(axis=1)  # a smaller dilation: a larger inverse covariance
    assert np.all(trace > default["conics"][vis][:, [0, 2]].sum(axis=1) * (1 + 1e-4))
    r = ks.render(g, scene.camera, scene.background.astype(dtype), antialiased=antialiased, mode=mode,
                  dilation=dilation)
    want_img = ref.render(p64, scene.camera, scene.background, antialiased=antialiased, mode=mode,
                          dilation=dilation)
    for got, w in zip((r.rgb, r.alpha, r.depth), want_img):
        np.testing.assert_allclose(got, w, **TOL[dtype])


def test_default_dilation_is_the_modes():
    """dilation=None and dilation=0.3 give bit-identical projections (the default is unchanged)."""
    scene = cs.smooth_scene(5, antialiased=True, off_frustum=True)
    g = ks.gaussian_inputs(*(as_dtype(scene.params, np.float32)[k] for k in PARAMS))
    for mode in ks.MODES:
        assert ks.DILATION_OF[mode] == ks.DILATION == 0.3
        a = ks.project(g, scene.camera, antialiased=True, mode=mode)
        b = ks.project(g, scene.camera, antialiased=True, mode=mode, dilation=0.3)
        for key in ("means2d", "conics", "depths", "radii", "colors", "opacities"):
            np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)


def test_project_sh_degree_and_culling():
    rng = np.random.default_rng(3)
    scene = cs.random_scene(rng)
    params = dict(scene.params)
    params["means"] = params["means"].copy()
    R, t = scene.camera.viewmat[:3, :3], scene.camera.viewmat[:3, 3]
    params["means"][0] = R.T @ (np.array([0.0, 0.0, -1.0]) - t)  # behind the camera
    params["means"][1] = R.T @ (np.array([0.0, 0.0, 0.005]) - t)  # in front, but nearer than near = 0.01
    params["means"][2] = R.T @ (np.array([40.0, 0.0, 4.0]) - t)  # far right of the image
    for deg in (0, 1, 2):
        want = ref.project(params, scene.camera, sh_degree=deg)
        p = ks.project(ks.gaussian_inputs(*(params[k] for k in PARAMS)), scene.camera, sh_degree=deg)
        assert list(p.radii[:3]) == [0, 0, 0]
        np.testing.assert_array_equal(p.radii, want["radii"])
        np.testing.assert_allclose(p.colors, want["colors"], rtol=1e-10, atol=1e-12)
        np.testing.assert_array_equal(p.conics[:3], 0.0)


@pytest.mark.parametrize("mode", ks.MODES)
@pytest.mark.usefixtures("warp_device")
def test_tile_binning_matches_reference(mode):
    scene = cs.smooth_scene(6, mode=mode)
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    p = ks.project(g, scene.camera, mode=mode)
    W, H = scene.camera.width, scene.camera.height
    tiles = ks.bin_tiles(ks.splats_2d(p.means2d, p.conics, p.colors, p.opacities, p.depths, p.radii), W, H, mode)
    want = ref.tile_lists(p.means2d, p.conics, p.opacities, p.radii, p.depths, W, H, mode=mode)
    ranges, gid = tiles.ranges.numpy(), tiles.sorted_gid.numpy()
    assert tiles.n_entries == sum(len(v) for v in want.values())
    assert sum(len(v) > 1 for v in want.values()) >= 4  # splats overlap on several tiles
    for t, members in want.items():
        assert list(gid[ranges[t, 0]:ranges[t, 1]]) == members, f"tile {t}"
    # Each sorted entry's gradient row lies in its splat's slice, and every row is used once.
    entry, starts, counts = tiles.sorted_entry.numpy()[:tiles.n_entries], tiles.starts.numpy(), tiles.counts.numpy()
    gid = gid[:tiles.n_entries]
    assert np.all((starts[gid] <= entry) & (entry < starts[gid] + counts[gid]))
    assert sorted(entry) == list(range(tiles.n_entries))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.usefixtures("warp_device")
def test_rasterize_matches_reference(dtype):
    scene = cs.smooth_scene(7, require_events=True)
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    p = ks.project(g, scene.camera)
    W, H = scene.camera.width, scene.camera.height
    inputs = [getattr(p, k) for k in ("means2d", "conics", "colors", "opacities", "depths")]
    want = ref.rasterize(*inputs, p.radii, W, H, scene.background)
    s = ks.splats_2d(*(a.astype(dtype) for a in inputs), p.radii)
    r, _ = ks.rasterize(s, W, H, scene.background.astype(dtype))
    for got, w in zip((r.rgb, r.alpha, r.depth), want):
        assert got.dtype == dtype
        np.testing.assert_allclose(got, w, **TOL[dtype])
    assert want[1].max() > 0.999  # some pixels reached the T < 1e-4 stop


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.usefixtures("warp_device")
def test_render_matches_reference(dtype, antialiased):
    scene = cs.smooth_scene(8, antialiased=antialiased)
    params = as_dtype(scene.params, dtype)
    want = ref.render({k: v.astype(np.float64) for k, v in params.items()}, scene.camera, scene.background,
                      antialiased=antialiased)
    r = ks.render(ks.gaussian_inputs(*(params[k] for k in PARAMS)), scene.camera, scene.background.astype(dtype),
                  antialiased=antialiased)
    for got, w in zip((r.rgb, r.alpha, r.depth), want):
        np.testing.assert_allclose(got, w, **TOL[dtype])


def test_outputs_follow_the_input_kind():
    scene = cs.smooth_scene(8)
    params = as_dtype(scene.params, np.float32)
    g_np = ks.gaussian_inputs(*(params[k] for k in PARAMS))
    g_wp = ks.gaussian_inputs(*(wp.array(params[k], dtype=wp.float32) for k in PARAMS))
    r_np, r_wp = ks.render(g_np, scene.camera), ks.render(g_wp, scene.camera)
    assert isinstance(r_np.rgb, np.ndarray) and isinstance(r_wp.rgb, wp.array)
    np.testing.assert_array_equal(r_np.rgb, r_wp.rgb.numpy())
    cot = np.ones(r_np.rgb.shape, np.float32)
    grads_np, grads_wp = ks.render_backward(g_np, r_np, cot), ks.render_backward(g_wp, r_wp, cot)
    assert set(grads_np) == set(PARAMS) | {"background", "means2d"}
    for k, v in grads_np.items():
        assert isinstance(v, np.ndarray) and isinstance(grads_wp[k], wp.array), k
        np.testing.assert_array_equal(v, grads_wp[k].numpy(), err_msg=k)


# --------------------------------------------------------------------------- gradients (float64 FD)


@pytest.mark.usefixtures("warp_device")
def test_project_gradients():
    assert_gradcheck(cs.project_checks())


@pytest.mark.usefixtures("warp_device")
def test_rasterize_gradients():
    assert_gradcheck(cs.rasterize_checks())


@pytest.mark.usefixtures("warp_device")
def test_render_gradients():
    assert_gradcheck(cs.render_checks())


def test_backward_independent_of_thread_count(monkeypatch):
    rng = np.random.default_rng(11)
    scene = cs.random_scene(rng, n=60, width=96, height=80)
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    cot = rng.normal(size=(80, 96, 3))
    grads = []
    for threads in ("1", "2", "3"):
        monkeypatch.setenv("DRLAB_THREADS", threads)
        r = ks.render(g, scene.camera, scene.background)
        grads.append(ks.render_backward(g, r, cot))
    for other in grads[1:]:
        for k in grads[0]:
            np.testing.assert_array_equal(other[k], grads[0][k], err_msg=k)


# --------------------------------------------------------------------------- the radius clamp


def _reach(means2d: np.ndarray, width: int, height: int) -> np.ndarray:
    """reach of kernels/splat/projection.py: 2 max(|u|, |u - W|, |v|, |v - H|) + TILE."""
    u, v = means2d[:, 0].astype(np.float64), means2d[:, 1].astype(np.float64)
    return np.ceil(2 * np.max(np.abs([u, u - width, v, v - height]), axis=0)) + ks.TILE


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_radius_clamp_changes_no_pixel_and_no_gradient(dtype):
    """Rasterising with the reference's unclamped radii gives the same image and gradients, bit for bit."""
    scene = cs.smooth_scene(3, big=2, require_events=True)
    cam = scene.camera
    W, H = cam.width, cam.height
    params = as_dtype(scene.params, dtype)
    p = ks.project(ks.gaussian_inputs(*(params[k] for k in PARAMS)), cam)
    want = ref.project({k: v.astype(np.float64) for k, v in params.items()}, cam)["radii"]
    clamped = want > p.radii
    assert list(np.flatnonzero(clamped)) == [1, 2]
    if dtype == np.float64:
        np.testing.assert_array_equal(p.radii, np.minimum(want, _reach(p.means2d, W, H)))
    np.testing.assert_array_equal(p.radii[clamped], _reach(p.means2d, W, H)[clamped])
    unclamped = np.where(clamped, want, p.radii).astype(np.int32)
    inputs = [p.means2d, p.conics, p.colors, p.opacities, p.depths]
    rng = np.random.default_rng(0)
    cot = [rng.normal(size=s).astype(dtype) for s in ((H, W, 3), (H, W), (H, W))]
    results = []
    for radii in (p.radii, unclamped):
        s = ks.splats_2d(*inputs, radii)
        r, tiles = ks.rasterize(s, W, H, scene.background.astype(dtype))
        results.append((tiles.n_entries, r, ks.rasterize_backward(s, W, H, scene.background.astype(dtype), tiles,
                                                                   r, *cot)))
    (n0, r0, g0), (n1, r1, g1) = results
    assert n0 == n1  # the same (tile, splat) pairs
    for key in ("rgb", "alpha", "depth"):
        np.testing.assert_array_equal(getattr(r0, key), getattr(r1, key), err_msg=key)
    for key in g0:
        np.testing.assert_array_equal(g0[key], g1[key], err_msg=key)
        assert np.all(np.isfinite(g0[key]))
    assert np.all(g0["conics"][clamped] != 0) and np.all(g0["opacities"][clamped] != 0)


def _huge_splat_scene(log_scale: float) -> cs.Scene:
    rng = np.random.default_rng(21)
    scene = cs.random_scene(rng, n=6, width=32, height=24)
    scene.params["log_scales"][0] = [log_scale, log_scale - 0.7, log_scale - 0.3]
    scene.params["opacity_logits"][0] = 0.0  # opacity 1/2
    return scene


@pytest.mark.parametrize("log_scale", [20.0, 30.0, 80.0])
def test_huge_splat_covers_the_image_with_a_nonzero_gradient(log_scale):
    """float64: a splat far larger than the image renders as the reference says (it covers every pixel)
    and keeps finite, non-zero gradients; its radius used to overflow int32."""
    scene = _huge_splat_scene(log_scale)
    cam = scene.camera
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    r = ks.render(g, cam, scene.background)
    assert 0 < r.projection.radii.numpy()[0] <= 2 * (cam.width + cam.height) + ks.TILE
    if log_scale <= 30:  # beyond, the reference's own radius (an int64) overflows
        want = ref.render(scene.params, cam, scene.background)
        for got, w in zip((r.rgb, r.alpha, r.depth), want):
            np.testing.assert_allclose(got, w, **TOL[np.float64])
    assert r.alpha.min() >= 0.5 - 1e-12  # every pixel has the opacity-1/2 splat behind or in front of the rest
    rng = np.random.default_rng(1)
    grads = ks.render_backward(g, r, rng.normal(size=r.rgb.shape), rng.normal(size=r.alpha.shape))
    for key in PARAMS:
        assert np.all(np.isfinite(grads[key])), key
        assert np.all(grads[key][0] != 0), key
    # the conic's gradient reaches the log-scales: about the conic's size, exp(-2 log_scale) (fx/z)^-2
    assert np.abs(grads["log_scales"][0]).max() < 1e3 * np.exp(-2 * (log_scale - 1.0))


@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("log_scale", [21.0, 30.0, 40.0, 60.0])
def test_huge_splat_in_float32_takes_the_wide_path(log_scale, antialiased):
    """float32: past the float32 range of det the splat's geometry is computed in float64 (module
    docstring of kernels/splat/projection.py), so it renders like the float64 kernels and its gradients
    match theirs; where the true conic is below float32's range (log-scale 60 here) it rounds to 0,
    and so do the log-scale gradients, while the opacity and colour gradients stay."""
    scene = _huge_splat_scene(log_scale)
    out = {}
    for dtype in (np.float32, np.float64):
        params = as_dtype(scene.params, dtype)
        g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
        r = ks.render(g, scene.camera, scene.background.astype(dtype), antialiased=antialiased)
        rng = np.random.default_rng(2)
        grads = ks.render_backward(g, r, rng.normal(size=r.rgb.shape).astype(dtype))
        out[dtype] = r, grads
    (r32, g32), (r64, g64) = out[np.float32], out[np.float64]
    assert r32.projection.radii.numpy()[0] == r64.projection.radii.numpy()[0] > 0
    for key in ("rgb", "alpha", "depth"):
        np.testing.assert_allclose(getattr(r32, key), getattr(r64, key), **TOL[np.float32], err_msg=key)
    for key in PARAMS:
        assert np.all(np.isfinite(g32[key])), key
        want = g64[key][0].astype(np.float32)  # what float32 can hold of the float64 gradient
        np.testing.assert_allclose(g32[key][0], want, rtol=2e-3, atol=2e-3 * np.abs(want).max(), err_msg=key)
    for key in ("opacity_logits", "sh"):
        assert np.all(g32[key][0] != 0), key
    if not antialiased:
        # With antialiasing, the compensation's two VJP terms (about +-g / (2 Sigma2d)) cancel to
        # below their rounding from about log-scale 16, in float64 too: the log-scale gradient
        # then reads 0 in both dtypes (checked equal above).
        assert np.all(g32["log_scales"][0] != 0) == (log_scale <= 40)  # 60: the conic is below float32's range


# --------------------------------------------------------------------------- empty scenes and bad input


def _camera() -> ks.SplatCamera:
    view = np.eye(4)
    view[2, 3] = 4.0
    return ks.SplatCamera(view, np.array([[40.0, 0, 16], [0, 40.0, 12], [0, 0, 1]]), 32, 24)


def _params(n: int, rng=None) -> dict:
    rng = rng or np.random.default_rng(0)
    return {"means": rng.uniform(-0.3, 0.3, (n, 3)), "log_scales": rng.uniform(-2.5, -1.5, (n, 3)),
            "quats": rng.normal(size=(n, 4)), "opacity_logits": rng.normal(size=n),
            "sh": rng.normal(0, 0.2, (n, 16, 3))}


@pytest.mark.parametrize("case", ["empty", "all_culled"])
def test_empty_image_has_zero_gradients(case):
    params = _params(0 if case == "empty" else 5)
    if case == "all_culled":
        params["means"][:, 2] = -10.0  # every splat behind the camera
    cam = _camera()
    bg = np.array([0.2, 0.4, 0.6])
    g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
    r = ks.render(g, cam, bg)
    np.testing.assert_array_equal(r.rgb, np.broadcast_to(bg, (24, 32, 3)))
    np.testing.assert_array_equal(r.alpha, 0.0)
    np.testing.assert_array_equal(r.depth, 0.0)
    grads = ks.render_backward(g, r, np.ones((24, 32, 3)), np.ones((24, 32)), np.ones((24, 32)))
    for k in PARAMS:
        assert grads[k].shape == params[k].shape
        np.testing.assert_array_equal(grads[k], 0.0)
    np.testing.assert_array_equal(grads["background"], 24 * 32)


def test_tiny_scales_stay_finite():
    params = _params(6)
    params["log_scales"][:] = -40.0  # splats far below a pixel: the dilation keeps them finite
    for aa in (False, True):
        g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
        r = ks.render(g, _camera(), antialiased=aa)
        grads = ks.render_backward(g, r, np.ones((24, 32, 3)))
        assert np.all(np.isfinite(r.rgb))
        assert all(np.all(np.isfinite(v)) for v in grads.values())


def _bad(**changes) -> dict:
    p = _params(4)
    p.update(changes)
    return p


@pytest.mark.parametrize("params, match", [
    (_bad(means=np.zeros((4, 2))), "means: expected shape"),
    (_bad(log_scales=np.zeros((3, 3))), "log_scales: expected shape"),
    (_bad(quats=np.zeros((4, 3))), "quats: expected shape"),
    (_bad(opacity_logits=np.zeros((4, 1))), "opacity_logits: expected shape"),
    (_bad(sh=np.zeros((4, 5, 3))), "sh: expected"),
    (_bad(sh=np.zeros((4, 16))), "sh: expected shape"),
    (_bad(means=np.zeros((4, 3), dtype=np.int64)), "means: expected dtype float32 or float64"),
    (_bad(log_scales=np.zeros((4, 3), dtype=np.float32)), "log_scales: expected dtype float64"),
    (_bad(means=np.full((4, 3), np.nan)), "means: expected finite values"),
    (_bad(sh=np.full((4, 16, 3), np.inf)), "sh: expected finite values"),
    (_bad(quats=np.zeros((4, 4))), "quats: quaternion 0 has zero norm"),
    (_bad(log_scales=np.full((4, 3), -np.inf)), "log_scales: expected finite values"),
    (_bad(log_scales=np.full((4, 3), 200.0)), "log_scales: "),
])
def test_bad_gaussians(params, match):
    with pytest.raises(ValueError, match=match):
        ks.gaussian_inputs(*(params[k] for k in PARAMS))


def test_warp_array_inputs():
    p = _params(4)
    means = wp.array(p["means"], dtype=wp.float64, device="cpu")
    g = ks.gaussian_inputs(means, *(p[k] for k in PARAMS[1:]))
    assert g.means is means
    with pytest.raises(ValueError, match="log_scales: expected dtype float64"):
        ks.gaussian_inputs(means, *(p[k].astype(np.float32) for k in PARAMS[1:]))


def test_bad_camera_and_options():
    K = np.array([[40.0, 0, 16], [0, 40.0, 12], [0, 0, 1]])
    with pytest.raises(ValueError, match="viewmat"):
        ks.SplatCamera(np.diag([1.0, 1.0, -1.0, 1.0]), K, 32, 24)  # a reflection
    with pytest.raises(ValueError, match="K: expected"):
        ks.SplatCamera(np.eye(4), np.array([[40.0, 1.0, 16], [0, 40.0, 12], [0, 0, 1]]), 32, 24)
    with pytest.raises(ValueError, match="width"):
        ks.SplatCamera(np.eye(4), K, 0, 24)
    with pytest.raises(ValueError, match="near, far"):
        ks.SplatCamera(np.eye(4), K, 32, 24, near=-1.0)
    g = ks.gaussian_inputs(*(_params(4)[k] for k in PARAMS))
    with pytest.raises(ValueError, match="sh_degree"):
        ks.render(g, _camera(), sh_degree=4)
    with pytest.raises(ValueError, match="background: expected shape"):
        ks.render(g, _camera(), np.zeros(4))
    with pytest.raises(ValueError, match="camera: expected a SplatCamera"):
        ks.render(g, "cam")
    r = ks.render(g, _camera())
    with pytest.raises(ValueError, match="grad_rgb: expected shape"):
        ks.render_backward(g, r, np.ones((24, 32)))
    with pytest.raises(ValueError, match="grad_alpha: expected finite values"):
        ks.render_backward(g, r, np.ones((24, 32, 3)), np.full((24, 32), np.nan))


def test_bad_splats_2d():
    n = 3
    args = dict(means2d=np.zeros((n, 2)), conics=np.tile([1.0, 0.0, 1.0], (n, 1)), colors=np.zeros((n, 3)),
                opacities=np.full(n, 0.5), depths=np.ones(n), radii=np.full(n, 3))
    ks.splats_2d(**args)
    for key, value, match in [("conics", np.tile([1.0, 2.0, 1.0], (n, 1)), "positive definite"),
                              ("opacities", np.full(n, 1.5), "opacities: expected values in"),
                              ("radii", np.full(n, -1), "radii"),
                              ("radii", np.full(n, 1.0), "radii"),
                              ("depths", np.ones(n + 1), "depths: expected shape")]:
        with pytest.raises(ValueError, match=match):
            ks.splats_2d(**dict(args, **{key: value}))
    with pytest.raises(ValueError, match="height"):
        ks.rasterize(ks.splats_2d(**args), 16, 0)


def test_value_checks_switch_and_device_counting_kernels():
    """The value checks are skipped under value_checks(False); the counting kernels that run them
    on a CUDA device count the same bad entries (launched here on the CPU)."""
    from kernels._arrays import value_checks
    from kernels.splat import projection, tiles

    bad = _bad(quats=np.zeros((4, 4)), log_scales=np.full((4, 3), 200.0))
    with value_checks(False):
        ks.gaussian_inputs(*(bad[k] for k in PARAMS))  # shapes and dtypes only
    with pytest.raises(ValueError, match="quats"):
        ks.gaussian_inputs(*(bad[k] for k in PARAMS))
    quats = np.array([[1.0, 0, 0, 0], [0, 0, 0, 0], [0, 1e-13, 0, 0], [0, 0, 3.0, 0]])
    log_scales = np.array([[0.0, 0, 0], [81.0, 0, 0], [0, -90.0, 85.0], [-80.0, 80.0, 0]])
    count = wp.zeros(2, dtype=wp.int32)
    wp.launch(projection._count_bad_kernel, dim=4, inputs=[wp.array(quats), wp.array(log_scales),
                                                           projection.LOG_SCALE_BOUND, count], device="cpu")
    assert list(count.numpy()) == [2, 3]
    conics = np.array([[1.0, 0, 1], [1.0, 2.0, 1], [-1.0, 0, 1], [1.0, 2.0, 1]])
    opacities = np.array([0.5, 1.5, 0.5, -0.1])
    radii = np.array([3, 3, 2, 0], dtype=np.int32)
    count = wp.zeros(2, dtype=wp.int32)
    wp.launch(tiles._count_invalid_kernel, dim=4, inputs=[wp.array(conics), wp.array(opacities),
                                                          wp.array(radii, dtype=wp.int32), count], device="cpu")
    assert list(count.numpy()) == [2, 2]  # splat 3's conic is not checked: radius 0
    # The same counts through the helper the CUDA branches of the checks call.
    from kernels._arrays import device_counts
    assert device_counts(projection._count_bad_kernel, 4, [wp.array(quats), wp.array(log_scales),
                                                           projection.LOG_SCALE_BOUND], wp.get_device("cpu"),
                         slots=2) == (2, 3)
    assert device_counts(tiles._count_invalid_kernel, 4, [wp.array(conics), wp.array(opacities),
                                                          wp.array(radii, dtype=wp.int32)], wp.get_device("cpu"),
                         slots=2) == (2, 2)
