"""kernels.volume.render and research.nerf.render: end-to-end images, z-depth, misses, FD gradients, array kinds."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels.reference import volume as ref_volume
from kernels.volume import GridField, OccupancyGrid, SphereField, Workspace, render_backward, render_rays
from kernels.volume.render import render_samples
from research.cameras import Camera
from research.checks.volume import BOX, check_render
from research.gradcheck import assert_gradcheck
from research.nerf.render import render_image


@pytest.mark.parametrize("np_t, wp_t, tol", [(np.float32, wp.float32, 1e-5), (np.float64, wp.float64, 1e-12)])
@pytest.mark.usefixtures("warp_device")
def test_render_rays_matches_reference(np_t, wp_t, tol):
    rng = np.random.default_rng(0)
    field = SphereField.textbook(wp_t)
    box = np.array([[-2.0, -1.5, 2.0], [2.5, 1.5, 6.5]])
    o = np.zeros((30, 3))
    d = np.concatenate([rng.normal([0, 0, 1], 0.3, (28, 3)), [[0, 1, 0.1], [0, 0, -1]]])  # the last two miss
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    bg = np.array([0.1, 0.2, 0.3])
    res = render_rays(field, o.astype(np_t), d.astype(np_t), box, n_samples=48, background=bg, t_threshold=0.0)
    P = {k: v.astype(np.float64) for k, v in field.params_numpy().items()}
    ref = ref_volume.render_spheres(o, d.astype(np_t).astype(np.float64), box, 48, P["centers"], P["radii"],
                                    P["colors"], P["sharpness"], bg)
    np.testing.assert_allclose(res.rgb, ref, rtol=tol * 10, atol=tol * 10)
    np.testing.assert_array_equal(res.rgb[-2:], np.tile(bg.astype(np_t), (2, 1)))
    # wp.array rays give wp.array images with the same numbers; so do the samples rendered again.
    res_wp = render_rays(field, wp.array(o.astype(np_t)), wp.array(d.astype(np_t)), box, n_samples=48, background=bg,
                         t_threshold=0.0)
    assert isinstance(res_wp.rgb, wp.array) and isinstance(res_wp.depth, wp.array)
    np.testing.assert_array_equal(res_wp.rgb.numpy(), res.rgb)
    again = render_samples(field, res_wp.samples, background=bg, t_threshold=0.0)
    np.testing.assert_array_equal(again.rgb.numpy(), res.rgb)


def test_render_image_depth_is_z_depth_of_an_opaque_box():
    """A box of huge density seen face-on: z-depth = distance to the front face for every pixel hitting it."""
    field = GridField(BOX, (3, 3, 3), density_bias=0.0, dtype=wp.float64)
    field.set_params({"density": np.full(27, 5e3), "color": np.full((27, 3), 2.0)})
    cam = Camera.from_fov(70.0, 40, 30, np.array([[1, 0, 0, 0.05], [0, 1, 0, 0.02], [0, 0, 1, -3.0], [0, 0, 0, 1]]))
    step = 0.002
    img = render_image(cam, field, BOX, step=step, background=(0.0, 0.0, 1.0), chunk=500)
    assert img.rgb.shape == (30, 40, 3) and img.depth.shape == (30, 40) and img.opacity.shape == (30, 40)
    # Pixels whose ray enters through the front face z = -0.6 (centre of the image).
    o, d = cam.rays(normalize=True)
    t_front = (BOX[0, 2] - o[..., 2]) / d[..., 2]
    hit_xy = o[..., :2] + t_front[..., None] * d[..., :2]
    front = np.all((hit_xy > BOX[0, :2] + 0.01) & (hit_xy < BOX[1, :2] - 0.01), axis=-1)
    assert front.sum() > 100
    z_front = BOX[0, 2] - (-3.0)
    # The first sample sits half a step in; its weight is 1 - exp(-5000 * 0.002) ~ 1.
    np.testing.assert_allclose(img.depth[front], z_front + 0.5 * step * np.cos(np.arccos(d[front][:, 2])), atol=2e-4)
    np.testing.assert_allclose(img.opacity[front], 1.0, atol=1e-4)
    np.testing.assert_allclose(img.rgb[front], 1.0 / (1.0 + np.exp(-2.0)), atol=1e-4)
    miss = img.opacity == 0.0
    assert miss.sum() > 0
    np.testing.assert_array_equal(img.rgb[miss], np.tile([0.0, 0.0, 1.0], (miss.sum(), 1)))
    np.testing.assert_array_equal(img.depth[miss], 0.0)


def test_ray_missing_the_box_returns_background_with_zero_gradient():
    field = GridField(BOX, (3, 3, 3), dtype=wp.float64)
    rng = np.random.default_rng(0)
    field.set_params({"density": rng.normal(size=27), "color": rng.normal(size=(27, 3))})
    o = np.array([[5.0, 5.0, 5.0], [0.0, 0.0, -3.0]])
    d = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # both point away from the box
    bg = np.array([0.3, 0.6, 0.9])
    res = render_rays(field, o, d, BOX, n_samples=8, background=bg)
    np.testing.assert_array_equal(res.rgb, np.tile(bg, (2, 1)))
    assert res.samples.n_samples == 0
    grads = render_backward(field, res, np.ones((2, 3)), np.ones(2), np.ones(2))
    assert all(np.all(g.numpy() == 0.0) for g in grads.values())


def test_occupancy_grid_skips_empty_space_without_changing_the_image():
    """A dense block in an empty box: after a few updates the grid skips most samples, same image."""
    field = GridField(BOX, (9, 9, 9), dtype=wp.float64)
    raw = np.full((9, 9, 9), -30.0)  # softplus(-30) ~ 1e-13: empty
    raw[3:6, 2:6, 3:7] = 8.0
    field.set_params({"density": raw.ravel(), "color": np.random.default_rng(0).normal(size=(729, 3))})
    grid = OccupancyGrid(BOX, (16, 16, 16), decay=0.99, threshold=1e-3)
    for seed in range(6):  # max over several random points per cell
        grid.update_from(field.density, seed=seed, dtype=wp.float64)
    assert 0.02 < grid.occupied_fraction() < 0.4
    cam = Camera.from_fov(60.0, 32, 32, np.array([[1, 0, 0, 0.1], [0, 1, 0, 0.0], [0, 0, 1, -3.0], [0, 0, 0, 1]]))
    full = render_image(cam, field, BOX, step=0.01)
    skipped = render_image(cam, field, BOX, step=0.01, occupancy=grid)
    assert skipped.n_samples < 0.5 * full.n_samples
    assert full.opacity.max() > 0.9
    np.testing.assert_allclose(skipped.depth[full.opacity < 1e-9], 0.0, atol=1e-9)
    # Occupancy is estimated from a few random points per cell, so a cell that only grazes the block's
    # trilinear ramp can be marked empty: a few silhouette pixels differ slightly, the rest agree.
    err = np.abs(skipped.rgb - full.rgb)
    assert err.max() < 0.02 and np.mean(err > 1e-6) < 0.01


@pytest.mark.parametrize("kind", ["grid", "hashgrid", "pe_mlp"])
@pytest.mark.usefixtures("warp_device")
def test_end_to_end_gradients(kind):
    assert_gradcheck(check_render(kind, seeds=(0, 1)))


def test_render_bad_input():
    field = GridField(BOX, (3, 3, 3), dtype=wp.float64)
    o, d = np.zeros((2, 3)), np.array([[0, 0, 1.0], [0, 0, 1.0]])
    with pytest.raises(ValueError, match="near < far"):
        render_rays(field, o, d, BOX, near=2.0, far=1.0, n_samples=4)
    with pytest.raises(ValueError, match="origins: expected dtype float64"):
        render_rays(field, o.astype(np.float32), d.astype(np.float32), BOX, n_samples=4)
    with pytest.raises(ValueError, match="camera"):
        render_image("not a camera", field, BOX, n_samples=4)
    with pytest.raises(ValueError, match="sampling: unknown options"):
        render_rays(field, o, d, BOX, n_samples=4, steps=0.1)
    res = render_rays(field, o, d, BOX, n_samples=4)
    for bad in (float("nan"), float("inf")):
        with pytest.raises(ValueError, match="sigma_l1: expected a finite number"):
            render_backward(field, res, np.ones((2, 3)), sigma_l1=bad)


def test_workspace_renders_and_gradients_match_fresh_buffers():
    field = GridField(BOX, (4, 4, 4), dtype=wp.float64)
    rng = np.random.default_rng(3)
    field.set_params({"density": rng.normal(1.0, 1.0, 64), "color": rng.normal(size=(64, 3))})
    ws = Workspace()
    for n_rays in (20, 35, 12):  # the workspace grows, then hands out a shorter view
        o = rng.uniform(-0.6, 0.6, (n_rays, 3)) + np.array([0.0, 0.0, -3.0])  # in front of BOX
        d = rng.normal([0.0, 0.0, 1.0], 0.2, (n_rays, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        g = rng.normal(size=(n_rays, 3))
        plain = render_rays(field, o, d, BOX, n_samples=16, background=(0.2, 0.3, 0.4))
        reused = render_rays(field, o, d, BOX, n_samples=16, background=(0.2, 0.3, 0.4), workspace=ws)
        assert reused.samples.n_samples > 4 * n_rays
        np.testing.assert_array_equal(reused.rgb.numpy(), plain.rgb)  # workspace views, NumPy
        np.testing.assert_array_equal(reused.depth.numpy(), plain.depth)
        g_plain = render_backward(field, plain, g, sigma_l1=0.1)
        g_reused = render_backward(field, reused, g, sigma_l1=0.1, workspace=ws)
        for name in g_plain:
            np.testing.assert_array_equal(g_reused[name].numpy(), g_plain[name].numpy())
    with pytest.raises(ValueError, match="workspace: expected a kernels.volume.Workspace"):
        render_rays(field, o, d, BOX, n_samples=16, workspace=object())


@pytest.mark.parametrize("thr", [0.0, 0.3], ids=["no_termination", "early_termination"])
@pytest.mark.parametrize("np_t, wp_t, tol", [(np.float32, wp.float32, 1e-5), (np.float64, wp.float64, 1e-12)])
def test_sphere_render_dense_matches_reference_and_general_path(np_t, wp_t, tol, thr):
    # SphereField.render_dense: the fused forward of render_samples on dense_samples.
    from kernels.volume.sampling import dense_samples

    rng = np.random.default_rng(4)
    field = SphereField.textbook(wp_t)
    n_rays, n_s = 40, 37
    o = rng.normal(0.0, 0.2, (n_rays, 3))
    d = rng.normal([0, 0, 1], 0.3, (n_rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = np.sort(rng.uniform(1.0, 6.0, (n_rays, n_s)), axis=1)
    delta = np.diff(t, axis=1, append=t[:, -1:] + 1e-3)
    bg = np.array([0.1, 0.2, 0.3])
    o, d, t, delta = (x.astype(np_t) for x in (o, d, t, delta))
    rgb, depth, opacity = field.render_dense(o, d, t, delta, background=bg, t_threshold=thr)
    # Plain NumPy: the points as dense_samples forms them, the field and the compositing references.
    x = (o[:, None, :] + t[:, :, None] * d[:, None, :]).reshape(-1, 3).astype(np.float64)
    P = {k: v.astype(np.float64) for k, v in field.params_numpy().items()}
    sigma, col = ref_volume.spheres(x, P["centers"], P["radii"], P["colors"], P["sharpness"])
    offsets = np.arange(n_rays + 1) * n_s
    ref_rgb, ref_depth, ref_op, _ = ref_volume.composite(sigma, col, delta.reshape(-1).astype(np.float64),
                                                         t.reshape(-1).astype(np.float64), offsets, bg, thr)
    np.testing.assert_allclose(rgb, ref_rgb, rtol=tol * 10, atol=tol * 10)
    np.testing.assert_allclose(depth, ref_depth, rtol=tol * 10, atol=tol * 10 * 6)
    np.testing.assert_allclose(opacity, ref_op, rtol=tol * 10, atol=tol * 10)
    # On the CPU the general path's numbers bit for bit (test_sphere_render_dense_equals_the_general_path_bitwise).
    general = render_samples(field, dense_samples(o, d, t, delta), background=bg, t_threshold=thr)
    np.testing.assert_array_equal(rgb, general.rgb)
    np.testing.assert_array_equal(depth, general.depth)
    np.testing.assert_array_equal(opacity, general.opacity)
    # wp.array rays give wp.array results with the same numbers.
    rgb_wp, _, _ = field.render_dense(*(wp.array(a) for a in (o, d, t, delta)), background=bg, t_threshold=thr)
    assert isinstance(rgb_wp, wp.array)
    np.testing.assert_array_equal(rgb_wp.numpy(), rgb)


def _sphere_rays(rng, n_rays, n_s, np_t):
    """Rays through the textbook spheres' box with sorted random samples: origins, directions, t, delta."""
    o = rng.normal(0.0, 0.2, (n_rays, 3))
    d = rng.normal([0, 0, 1], 0.3, (n_rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = np.sort(rng.uniform(1.0, 6.0, (n_rays, n_s)), axis=1)
    delta = np.diff(t, axis=1, append=t[:, -1:] + 1e-3)
    return [x.astype(np_t) for x in (o, d, t, delta)]


# render_dense's CPU paths: (C++ passes, one launch a chunk calling NumPy's exp loop, Warp quads)
_DENSE_PATHS = {"cpp_fused": (True, True, True), "cpp_passes": (True, False, True), "quads": (False, True, True),
                "single": (False, True, False)}


@pytest.mark.parametrize("path", list(_DENSE_PATHS))
@pytest.mark.parametrize("n_s", [1, 4, 37, 64])
@pytest.mark.parametrize("thr", [0.0, 1e-3, 0.3], ids=["no_termination", "late_termination", "early_termination"])
@pytest.mark.parametrize("np_t, wp_t", [(np.float32, wp.float32), (np.float64, wp.float64)])
def test_sphere_render_dense_equals_the_general_path_bitwise(monkeypatch, np_t, wp_t, thr, n_s, path):
    # On the CPU render_dense evaluates the sphere falloffs and the compositing factors
    # exp(-(sigma delta)) with NumPy's exp, as SphereField.forward and composite_forward do, with the
    # same operations in the same order: its image, depth and opacity are those of render_samples on
    # dense_samples bit for bit (what experiments/volume_render_spheres relies on), with NumPy inputs
    # (read in place, contiguous or not) and wp.array inputs, in one block or several.
    import kernels.volume.spheres as spheres_module
    from kernels.volume.sampling import dense_samples

    native, fused, quads = _DENSE_PATHS[path]
    if native and wp_t == wp.float64:
        pytest.skip("the C++ passes are float32; float64 runs the Warp passes (the quads and single cases)")
    monkeypatch.setattr(spheres_module, "_NATIVE_ON_CPU", native)
    monkeypatch.setattr(spheres_module, "_FUSED_EXP_ON_CPU", fused)
    monkeypatch.setattr(spheres_module, "_QUADS_ON_CPU", quads)
    rng = np.random.default_rng(12)
    field = SphereField.textbook(wp_t)
    n_rays = 45
    o, d, t, delta = _sphere_rays(rng, n_rays, n_s, np_t)
    for bg in ((0.0, 0.0, 0.0), (0.1, 0.2, 0.3)):
        general = render_samples(field, dense_samples(o, d, t, delta), background=bg, t_threshold=thr)
        want = tuple(x.numpy() for x in (general.rgb, general.depth, general.opacity))  # (wp.arrays)
        got = field.render_dense(o, d, t, delta, background=bg, t_threshold=thr)
        strided = field.render_dense(np.asfortranarray(o), d, np.asfortranarray(t), delta, background=bg,
                                     t_threshold=thr)
        on_device = field.render_dense(*(wp.array(x) for x in (o, d, t, delta)), background=bg, t_threshold=thr)
        for w, g, s, dv in zip(want, got, strided, on_device):
            assert g.dtype == np_t
            assert w.tobytes() == g.tobytes() == s.tobytes() == dv.numpy().tobytes()
    monkeypatch.setattr(spheres_module, "_FALLOFF_BLOCK", 7 * n_s * 3)  # 7 rays a block
    blocked = field.render_dense(o, d, t, delta, background=bg, t_threshold=thr)
    for w, b in zip(want, blocked):
        assert w.tobytes() == b.tobytes()


@pytest.mark.parametrize("fused", [True, False], ids=["one_launch", "three_launches"])
@pytest.mark.cpu_fast_path
def test_sphere_render_dense_cpp_passes_equal_the_warp_passes(monkeypatch, fused):
    # render_dense's float32 CPU passes in C++ (kernels.volume.spheres_cpu: eight rays in vector lanes)
    # give the Warp passes' image, depth and opacity bit for bit: sample counts in fours and not, rays
    # not a multiple of eight, early termination, t and delta per ray or one row broadcast, chunks on
    # 1 to 3 threads and small blocks; and they ran (their kernels were launched).
    import kernels.volume.spheres as spheres_module
    from kernels import _npexp
    from kernels.volume import spheres_cpu

    if not spheres_cpu.available():
        pytest.skip("this CPU has no AVX2: render_dense runs the Warp passes")
    if fused and not _npexp.numpy_agrees():
        pytest.skip("kernels._npexp's exp differs from this NumPy's np.exp: render_dense takes three launches")
    monkeypatch.setattr(spheres_module, "_FUSED_EXP_ON_CPU", fused)
    launched = []
    real_launch = wp.launch

    def spy(kernel, *args, **kwargs):
        launched.append(kernel)
        return real_launch(kernel, *args, **kwargs)

    monkeypatch.setattr(wp, "launch", spy)
    k1, k2, k3, one = spheres_cpu.kernels()
    rng = np.random.default_rng(16)
    field = SphereField.textbook(wp.float32)
    for n_s in (1, 3, 4, 8, 37, 64):
        o, d, t, delta = _sphere_rays(rng, 45, n_s, np.float32)
        row_t, row_d = (np.broadcast_to(x[0], x.shape) for x in (t, delta))
        for thr in (0.0, 1e-4, 0.3):
            for bg in ((0.0, 0.0, 0.0), (0.1, 0.2, 0.3)):
                for tt, dd in ((t, delta), (row_t, row_d)):
                    monkeypatch.setattr(spheres_module, "_NATIVE_ON_CPU", False)
                    want = [x.tobytes() for x in field.render_dense(o, d, tt, dd, background=bg, t_threshold=thr)]
                    monkeypatch.setattr(spheres_module, "_NATIVE_ON_CPU", True)
                    del launched[:]
                    got = [x.tobytes() for x in field.render_dense(o, d, tt, dd, background=bg, t_threshold=thr)]
                    assert got == want, (n_s, thr, bg)
                    assert (one in launched) if fused else ({k1, k2, k3} <= set(launched)), (n_s, launched)
                    on_device = field.render_dense(*(wp.array(x) for x in (o, d, tt, dd)), background=bg,
                                                   t_threshold=thr)
                    assert [x.numpy().tobytes() for x in on_device] == want
    # small chunks (one group of eight rays) on 1 to 3 threads, and blocks of one group
    for n_s in (8, 37):
        o, d, t, delta = _sphere_rays(rng, 45, n_s, np.float32)
        monkeypatch.setattr(spheres_module, "_CHUNK_VALUES", 1)
        monkeypatch.setattr(spheres_module, "_CHUNK_VALUES_ONE_LAUNCH", 1)
        for threads in (1, 2, 3):
            monkeypatch.setattr(spheres_module, "default_threads", lambda threads=threads: threads)
            monkeypatch.setattr(spheres_module, "_NATIVE_ON_CPU", True)
            monkeypatch.setattr(spheres_module, "_FALLOFF_BLOCK", 1 << 21)
            got = [x.tobytes() for x in field.render_dense(o, d, t, delta, background=bg, t_threshold=0.3)]
            monkeypatch.setattr(spheres_module, "_FALLOFF_BLOCK", 1)
            blocked = [x.tobytes() for x in field.render_dense(o, d, t, delta, background=bg, t_threshold=0.3)]
            monkeypatch.setattr(spheres_module, "_NATIVE_ON_CPU", False)
            want = [x.tobytes() for x in field.render_dense(o, d, t, delta, background=bg, t_threshold=0.3)]
            assert got == want == blocked, (n_s, threads)


@pytest.mark.parametrize("np_t, wp_t", [(np.float32, wp.float32), (np.float64, wp.float64)])
def test_sphere_cpu_passes_are_the_same_in_any_chunks(monkeypatch, np_t, wp_t):
    # The CPU passes of render_dense and SphereField.forward cut their items into chunks, each run
    # through every pass by one launch thread: one chunk, many small chunks on 1 to 3 threads and
    # several blocks give the same outputs bit for bit.
    import kernels.volume.spheres as spheres_module

    rng = np.random.default_rng(14)
    field = SphereField.textbook(wp_t)
    pts = rng.uniform([-2.0, -1.5, 2.5], [2.5, 1.5, 6.0], (4999, 3)).astype(np_t)
    renders = {n_s: _sphere_rays(rng, 61, n_s, np_t) for n_s in (8, 37)}

    def outputs():
        out = field.forward(pts)
        res = [np.asarray(out.sigma).tobytes(), np.asarray(out.rgb).tobytes()]
        for thr in (0.0, 0.3):
            res += [x.tobytes() for n_s in renders
                    for x in field.render_dense(*renders[n_s], background=(0.1, 0.2, 0.3), t_threshold=thr)]
        return res

    monkeypatch.setattr(spheres_module, "default_threads", lambda: 1)
    want = outputs()
    # chunks of 2 or 1 rays (24 or 111 values a ray), and of 5 quads of points
    monkeypatch.setattr(spheres_module, "_CHUNK_VALUES", 64)
    for threads in (1, 2, 3):
        monkeypatch.setattr(spheres_module, "default_threads", lambda threads=threads: threads)
        assert outputs() == want
    monkeypatch.setattr(spheres_module, "_FALLOFF_BLOCK", 4 * 8 * 3 * 5)  # blocks of 5 rays (of 8 samples), 40 quads
    assert outputs() == want


@pytest.mark.parametrize("n_s", [5, 64])
@pytest.mark.parametrize("np_t, wp_t", [(np.float32, wp.float32), (np.float64, wp.float64)])
def test_sphere_render_dense_reads_broadcast_rows_of_t_and_delta_in_place(monkeypatch, np_t, wp_t, n_s):
    # t and delta given as one row broadcast to every ray (np.broadcast_to: row stride 0) are read
    # without a copy, with the same outputs bit for bit as the tiled arrays, and checked as them.
    import kernels.volume.spheres as spheres_module

    rng = np.random.default_rng(13)
    field = SphereField.textbook(wp_t)
    n_rays = 33
    o, d, _, _ = _sphere_rays(rng, n_rays, n_s, np_t)
    t_row = np.sort(rng.uniform(1.0, 6.0, n_s)).astype(np_t)
    dl_row = np.diff(t_row, append=t_row[-1] + 1e-3).astype(np_t)
    tiled = [np.tile(x, (n_rays, 1)) for x in (t_row, dl_row)]
    broadcast = [np.broadcast_to(x, (n_rays, n_s)) for x in (t_row, dl_row)]
    for fused in (False, True):  # the CPU passes, and the one-kernel version (CUDA's) forced on the CPU
        monkeypatch.setattr(spheres_module, "_FUSED_ON_CPU", fused)
        for thr in (0.0, 0.3):
            want = field.render_dense(o, d, *tiled, background=(0.1, 0.2, 0.3), t_threshold=thr)
            got = field.render_dense(o, d, *broadcast, background=(0.1, 0.2, 0.3), t_threshold=thr)
            for w, g in zip(want, got):
                assert w.tobytes() == g.tobytes()
    bad_t, bad_dl = t_row.copy(), dl_row.copy()
    bad_t[2], bad_dl[1] = np.nan, -0.5
    with pytest.raises(ValueError, match="^t: expected finite values"):
        field.render_dense(o, d, np.broadcast_to(bad_t, (n_rays, n_s)), broadcast[1])
    with pytest.raises(ValueError, match="^delta: "):
        field.render_dense(o, d, broadcast[0], np.broadcast_to(bad_dl, (n_rays, n_s)))


@pytest.mark.parametrize("thr", [0.0, 0.3], ids=["no_termination", "early_termination"])
@pytest.mark.parametrize("np_t, wp_t, tol", [(np.float32, wp.float32, 2e-6), (np.float64, wp.float64, 1e-14)])
def test_sphere_render_dense_fused_kernel_agrees_with_cpu_two_pass_path(monkeypatch, np_t, wp_t, tol, thr):
    # The fused kernel (what runs on CUDA), forced on the CPU, against the CPU path (NumPy's exp of
    # the sphere falloffs and compositing factors between the passes): the same image to the rounding
    # of the exponentials.
    import kernels.volume.spheres as spheres_module

    rng = np.random.default_rng(6)
    field = SphereField.textbook(wp_t)
    n_rays, n_s = 50, 29
    args = _sphere_rays(rng, n_rays, n_s, np_t)
    two_pass = field.render_dense(*args, background=(0.1, 0.2, 0.3), t_threshold=thr)
    monkeypatch.setattr(spheres_module, "_FUSED_ON_CPU", True)
    fused = field.render_dense(*args, background=(0.1, 0.2, 0.3), t_threshold=thr)
    for a, b in zip(two_pass, fused):
        np.testing.assert_allclose(a, b, rtol=tol, atol=tol)


@pytest.mark.parametrize("n_s", [4, 24, 64])
@pytest.mark.parametrize("thr", [0.0, 1e-3, 0.3], ids=["no_termination", "late_termination", "early_termination"])
@pytest.mark.parametrize("np_t, wp_t", [(np.float32, wp.float32), (np.float64, wp.float64)])
def test_sphere_render_dense_quads_equal_the_one_at_a_time_passes(monkeypatch, np_t, wp_t, thr, n_s):
    # With S % 4 == 0 the CPU passes take four samples at a time (vec4 lanes): the same operations
    # per sample in the same order, so the image, depth and opacity are those of one sample at a
    # time bit for bit, whatever the termination point and the block size.
    import kernels.volume.spheres as spheres_module

    rng = np.random.default_rng(11)
    field = SphereField.textbook(wp_t)
    n_rays = 45
    args = _sphere_rays(rng, n_rays, n_s, np_t)
    quads = field.render_dense(*args, background=(0.1, 0.2, 0.3), t_threshold=thr)
    monkeypatch.setattr(spheres_module, "_FALLOFF_BLOCK", 7 * n_s * 3)  # 7 rays a block
    blocked = field.render_dense(*args, background=(0.1, 0.2, 0.3), t_threshold=thr)
    monkeypatch.setattr(spheres_module, "_QUADS_ON_CPU", False)
    single = field.render_dense(*args, background=(0.1, 0.2, 0.3), t_threshold=thr)
    for a, b, c in zip(quads, blocked, single):
        assert a.dtype == np_t
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, c)


def test_sphere_render_dense_in_place_inputs_reject_a_mixed_dtype():
    # render_dense reads NumPy inputs in place (_floats_in_place); a mixed dtype still gets a.floats' error
    field = SphereField.textbook(wp.float32)
    o = np.zeros((4, 3), np.float32)
    d = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (4, 1))
    t = np.tile(np.linspace(1.0, 6.0, 8, dtype=np.float32), (4, 1))
    delta = np.full((4, 8), 0.5, np.float64)
    with pytest.raises(ValueError, match="delta: expected dtype float32 like the other inputs, got float64"):
        field.render_dense(o, d, t, delta)


@pytest.mark.parametrize("np_t, wp_t", [(np.float32, wp.float32), (np.float64, wp.float64)])
def test_render_without_factor_equals_the_backpropagatable_render_and_refuses_backward(np_t, wp_t):
    """keep_factor=False (render_image's renders): the same rgb, depth and opacity bit for bit as keep_factor=True,
    no per-sample factors, and render_backward / render_backward_rays refuse the result with a ValueError."""
    from kernels.volume.rays import render_backward_rays
    from research.nerf.render import camera_rays as nerf_camera_rays

    field = GridField(BOX, (4, 4, 4), dtype=wp_t)
    rng = np.random.default_rng(4)
    field.set_params({"density": rng.normal(2.0, 1.0, 64).astype(np_t), "color": rng.normal(size=(64, 3)).astype(np_t)})
    cam = Camera.from_fov(60.0, 24, 18, np.array([[1, 0, 0, 0.05], [0, 1, 0, 0.02], [0, 0, 1, -3.0], [0, 0, 0, 1]]))
    img = render_image(cam, field, BOX, step=0.01, background=(0.1, 0.2, 0.3), chunk=100)  # keep_factor=False inside
    o, d, zs = nerf_camera_rays(cam, np_t)
    ws = Workspace()
    for s in range(0, o.shape[0], 100):
        e = min(s + 100, o.shape[0])
        kw = dict(step=0.01, z_scale=zs[s:e], background=(0.1, 0.2, 0.3), workspace=ws)
        kept = render_rays(field, o[s:e], d[s:e], BOX, **kw)
        assert kept.composite.factor is not None
        rgb, depth, opacity = kept.rgb.numpy().copy(), kept.depth.numpy().copy(), kept.opacity.numpy().copy()
        bare = render_rays(field, o[s:e], d[s:e], BOX, keep_factor=False, **kw)
        assert bare.composite.factor is None
        for a, b in ((bare.rgb.numpy(), rgb), (bare.depth.numpy(), depth), (bare.opacity.numpy(), opacity)):
            assert a.tobytes() == b.tobytes()
        assert rgb.astype(np.float64).tobytes() == img.rgb.reshape(-1, 3)[s:e].tobytes()
        assert depth.astype(np.float64).tobytes() == img.depth.reshape(-1)[s:e].tobytes()
    with pytest.raises(ValueError, match="keep_factor=False"):
        render_backward(field, bare, np.ones((e - s, 3), np_t))
    with pytest.raises(ValueError, match="keep_factor=False"):
        render_backward_rays(field, bare, grad_depth=np.ones(e - s, np_t))
    with pytest.raises(ValueError, match="keep_factor"):
        render_rays(field, o[:4], d[:4], BOX, step=0.01, keep_factor=None)
