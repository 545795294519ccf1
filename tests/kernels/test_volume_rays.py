"""kernels.volume.rays and kernels.volume.field_points: pinhole rays against the NumPy reference, the
camera and point gradients against finite differences (the checks registered for `drlab gradcheck`)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels.reference import volume as ref
from kernels.volume import GridField, SphereField, render_rays
from kernels.volume.rays import (camera_rays, camera_rays_backward, pixel_centers, render_backward_camera,
                                 render_backward_rays)
from research.checks.volume import (BOX, camera_field, camera_setup, check_camera_rays, check_field_points,
                                    check_render_camera)
from research.gradcheck import assert_gradcheck
from research.poses.se3 import se3_exp


@pytest.mark.parametrize("np_t,tol", [(np.float32, 2e-6), (np.float64, 1e-14)])
@pytest.mark.usefixtures("warp_device")
def test_camera_rays_match_reference(np_t, tol):
    w2c, intrinsics, _ = camera_setup(3)
    pixels = pixel_centers(7, 5)
    o, d, z = camera_rays(w2c, intrinsics, pixels.astype(np_t))
    assert o.dtype == np_t and isinstance(o, np.ndarray)
    ro, rd, rz = ref.camera_rays(w2c, intrinsics, pixels)
    np.testing.assert_allclose(o, ro, atol=tol * 10)
    np.testing.assert_allclose(d, rd, atol=tol)
    np.testing.assert_allclose(z, rz, atol=tol)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=tol)


def test_camera_rays_wp_in_wp_out_and_depth_is_z():
    w2c, intrinsics, _ = camera_setup(4)
    pixels = pixel_centers(6, 4)
    o, d, z = camera_rays(w2c, intrinsics, wp.array(pixels, dtype=wp.float64))
    assert all(isinstance(x, wp.array) for x in (o, d, z))
    # A point at distance s along each ray has camera z-depth s * z_scale.
    s = 2.5
    X = o.numpy() + s * d.numpy()
    zc = (X @ w2c[:3, :3].T + w2c[:3, 3])[:, 2]
    np.testing.assert_allclose(zc, s * z.numpy(), rtol=1e-12)


def test_pixel_centers_order():
    np.testing.assert_array_equal(pixel_centers(3, 2), [[0.5, 0.5], [1.5, 0.5], [2.5, 0.5],
                                                        [0.5, 1.5], [1.5, 1.5], [2.5, 1.5]])


@pytest.mark.usefixtures("warp_device")
def test_camera_rays_gradients():
    assert_gradcheck(check_camera_rays(seeds=(0, 1, 2)))


@pytest.mark.parametrize("kind", ["spheres", "grid_rgb", "grid_sh2"])
@pytest.mark.usefixtures("warp_device")
def test_field_point_gradients(kind):
    assert_gradcheck(check_field_points(kind, seeds=(0, 1)))


@pytest.mark.parametrize("kind", ["spheres", "grid_rgb", "grid_sh2"])
@pytest.mark.usefixtures("warp_device")
def test_render_camera_gradients_colour_depth_opacity(kind):
    assert_gradcheck(check_render_camera(kind, seeds=(0, 1)))


def test_a_wrong_pose_gradient_is_caught():
    """The rotation part's sign flipped must fail the same check (the check can fail)."""
    import kernels.volume.rays as rays
    from research.gradcheck import check_vjp

    w2c, intrinsics, pixels = camera_setup(0)

    def f(xi, intrinsics):
        o, d, z = camera_rays(se3_exp(xi) @ w2c, intrinsics, pixels)
        return {"origins": o, "dirs": d, "z_scale": z}

    def wrong(inp, cot):
        g = rays.camera_rays_backward(w2c, inp["intrinsics"], pixels, cot["origins"], cot["dirs"], cot["z_scale"])
        return {"xi": np.concatenate([g.xi[:3], -g.xi[3:]]), "intrinsics": g.intrinsics}

    results = check_vjp(f, wrong, {"xi": np.zeros(6), "intrinsics": intrinsics})
    assert not results[0].passed and results[1].passed


def test_depth_cotangent_counts_only_processed_samples():
    """With grad_depth = 1 alone, dL/dz_scale = sum_{k < n_used} t_k w_k = D / z_scale, also when the
    rays terminate early (samples past the stop get no gradient)."""
    field = camera_field("spheres", 0)
    w2c, intrinsics, pixels = camera_setup(0)
    o, d, z = camera_rays(w2c, intrinsics, pixels)
    for t_threshold in (0.0, 0.5):
        r = render_rays(field, o, d, BOX, n_samples=32, z_scale=z, t_threshold=t_threshold)
        if t_threshold:
            assert np.any(r.composite.n_used.numpy() < np.diff(r.samples.ray_offsets.numpy()))
        go, gd, gz = render_backward_rays(field, r, grad_depth=np.ones(len(o)))
        np.testing.assert_allclose(gz.numpy(), r.depth / z, rtol=1e-12)
        g = render_backward_camera(field, r, w2c, intrinsics, pixels, grad_rgb=np.ones((len(o), 3)))
        assert np.all(np.isfinite(g.xi)) and np.all(np.isfinite(g.intrinsics))


def test_float32_camera_gradient_close_to_float64():
    w2c, intrinsics, pixels = camera_setup(1)
    res = {}
    for dt in (wp.float32, wp.float64):
        np_t = np.float32 if dt == wp.float32 else np.float64
        field = SphereField(*(v for v in camera_field("spheres", 1).params_numpy().values()), dtype=dt)
        o, d, z = camera_rays(w2c, intrinsics, pixels.astype(np_t))
        r = render_rays(field, o, d, BOX, n_samples=16, z_scale=z, t_threshold=0.0)
        res[dt] = render_backward_camera(field, r, w2c, intrinsics, pixels.astype(np_t),
                                         grad_rgb=np.ones((len(o), 3), np_t), grad_depth=np.ones(len(o), np_t))
    # float32 against float64 (the float64 FD checks test the formula): sums over rays x samples in float32
    np.testing.assert_allclose(res[wp.float32].xi, res[wp.float64].xi, rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(res[wp.float32].intrinsics, res[wp.float64].intrinsics, rtol=1e-3, atol=1e-5)


def test_split_launch_equals_one_thread(monkeypatch):
    w2c, intrinsics, _ = camera_setup(2)
    pixels = pixel_centers(40, 30)
    g = np.random.default_rng(0).normal(size=(len(pixels), 3))
    out = {}
    for threads in ("1", "3"):
        monkeypatch.setenv("DRLAB_THREADS", threads)
        o, d, z = camera_rays(w2c, intrinsics, pixels)
        gr = camera_rays_backward(w2c, intrinsics, pixels, g, g, g[:, 0])
        out[threads] = (o, d, z, gr.xi, gr.intrinsics)
    for a, b in zip(out["1"], out["3"]):
        np.testing.assert_array_equal(a, b)


def test_grid_field_camera_gradient_runs_on_float32():
    field = GridField(BOX, (4, 4, 4), sh_degree=1, dtype=wp.float32)
    w2c, intrinsics, pixels = camera_setup(0)
    o, d, z = camera_rays(w2c, intrinsics, pixels.astype(np.float32))
    r = render_rays(field, o, d, BOX, n_samples=8, z_scale=z)
    g = render_backward_camera(field, r, w2c, intrinsics, pixels.astype(np.float32), grad_rgb=np.ones((8, 3), np.float32))
    assert np.all(np.isfinite(g.xi))


def test_per_pixel_rows_sum_to_the_gradient_and_are_jacobian_rows():
    """Rows of per_pixel sum to the total; with a one-hot cotangent each row is that pixel's Jacobian row
    (compared with a central difference of the pixel's own output)."""
    from research.poses.se3 import se3_exp

    w2c, intrinsics, pixels = camera_setup(5)
    rng = np.random.default_rng(0)
    g = rng.normal(size=(len(pixels), 3))
    total = camera_rays_backward(w2c, intrinsics, pixels, g, g, g[:, 0])
    rows = camera_rays_backward(w2c, intrinsics, pixels, g, g, g[:, 0], per_pixel=True)
    assert rows.xi.shape == (len(pixels), 6) and rows.intrinsics.shape == (len(pixels), 4)
    np.testing.assert_allclose(rows.xi.sum(0), total.xi, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(rows.intrinsics.sum(0), total.intrinsics, rtol=1e-12, atol=1e-12)
    # d dirs[p, 0] / d xi_4 for every p at once: cotangent e_0 on every pixel's direction.
    e0 = np.zeros((len(pixels), 3))
    e0[:, 0] = 1.0
    J = camera_rays_backward(w2c, intrinsics, pixels, None, e0, None, per_pixel=True).xi[:, 4]
    h = 1e-6
    step = np.zeros(6)
    step[4] = h
    fd = (camera_rays(se3_exp(step) @ w2c, intrinsics, pixels)[1][:, 0]
          - camera_rays(se3_exp(-step) @ w2c, intrinsics, pixels)[1][:, 0]) / (2 * h)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-9)
