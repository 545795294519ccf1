"""Tests for research.cameras: projection, rays, conversions, poses and validation."""

import math

import numpy as np
import pytest

from research.cameras import Camera, intrinsics_from_fov, look_at, orbit_poses, smooth_path


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def random_camera(seed, width=40, height=30):
    rng = np.random.default_rng(seed)
    c2w = np.eye(4)
    c2w[:3, :3] = random_rotation(rng)
    c2w[:3, 3] = rng.normal(size=3)
    K = np.array([[rng.uniform(30, 60), 0.0, rng.uniform(15, 25)], [0, rng.uniform(30, 60), rng.uniform(10, 20)], [0, 0, 1]])
    return Camera(K, c2w, width, height)


@pytest.mark.parametrize("seed", range(4))
def test_backproject_then_project_lands_on_pixel_centres(seed):
    cam = random_camera(seed)
    rng = np.random.default_rng(100 + seed)
    depth = rng.uniform(0.5, 5.0, size=(cam.height, cam.width))
    pts = cam.backproject(depth)
    uv, z = cam.project(pts)
    u, v = cam.pixel_centers()
    np.testing.assert_allclose(uv[..., 0], u, atol=1e-9)
    np.testing.assert_allclose(uv[..., 1], v, atol=1e-9)
    np.testing.assert_allclose(z, depth, rtol=1e-12)


def test_pixel_centres_are_at_half_integers():
    cam = Camera.from_fov(60.0, 4, 3, np.eye(4))
    u, v = cam.pixel_centers()
    assert u[0, 0] == 0.5 and v[0, 0] == 0.5 and u[-1, -1] == 3.5 and v[-1, -1] == 2.5
    # The principal point (W/2, H/2) projects straight along +z.
    d = cam.camera_directions(np.array(2.0), np.array(1.5))
    np.testing.assert_allclose(d, [0.0, 0.0, 1.0], atol=1e-15)


def test_rays_match_explicit_formula_and_depth_parameterisation():
    cam = random_camera(7)
    o, d = cam.rays(normalize=False)
    depth = np.full((cam.height, cam.width), 2.5)
    np.testing.assert_allclose(o + 2.5 * d, cam.backproject(depth), atol=1e-12)
    o, dn = cam.rays()
    np.testing.assert_allclose(np.linalg.norm(dn, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("hwc,hwc->hw", dn, d / np.linalg.norm(d, axis=-1, keepdims=True)), 1.0, atol=1e-12)
    # cos(theta) relation between ray distance and z-depth
    ray_dist = 2.5 * np.linalg.norm(d, axis=-1)
    np.testing.assert_allclose(2.5 / ray_dist, cam.ray_cosines(), rtol=1e-12)


def test_opencv_axes_identity_pose():
    cam = Camera.from_fov(90.0, 10, 10, np.eye(4))
    uv, z = cam.project(np.array([[1.0, 0.0, 5.0], [0.0, 1.0, 5.0]]))
    assert uv[0, 0] > 5.0 and math.isclose(uv[0, 1], 5.0)  # +x is image right
    assert uv[1, 1] > 5.0 and math.isclose(uv[1, 0], 5.0)  # +y is image down
    assert np.all(z == 5.0)
    uv, _ = cam.project(np.array([[0.0, 0.0, -1.0]]))
    assert np.all(np.isnan(uv))


@pytest.mark.parametrize("seed", range(3))
def test_mitsuba_round_trip(seed):
    cam = random_camera(seed)
    cam = Camera(np.array([[45.0, 0, 18.0], [0, 45.0, 16.0], [0, 0, 1]]), cam.c2w, cam.width, cam.height)
    p = cam.mitsuba_intrinsics()
    back = Camera.from_mitsuba(cam.to_mitsuba(), cam.width, cam.height, p["fov"], p["fov_axis"],
                               p["principal_point_offset_x"], p["principal_point_offset_y"])
    np.testing.assert_allclose(back.K, cam.K, atol=1e-10)
    np.testing.assert_allclose(back.c2w, cam.c2w, atol=1e-14)
    # Mitsuba's camera x axis points image-left, y up.
    np.testing.assert_allclose(cam.to_mitsuba()[:3, 0], -cam.R[:, 0])
    np.testing.assert_allclose(cam.to_mitsuba()[:3, 1], -cam.R[:, 1])


def test_mitsuba_fov_axes():
    tw = np.eye(4)
    for axis, n in (("x", 40), ("y", 30), ("smaller", 30), ("larger", 40)):
        cam = Camera.from_mitsuba(tw, 40, 30, 50.0, axis)
        assert math.isclose(cam.fx, (n / 2) / math.tan(math.radians(25.0)))
    with pytest.raises(ValueError, match="fov_axis"):
        Camera.from_mitsuba(tw, 40, 30, 50.0, "diagonal")


@pytest.mark.parametrize("seed", range(3))
def test_nerf_round_trip_and_axes(seed):
    cam = Camera(intrinsics_from_fov(55.0, 40, 30), random_camera(seed).c2w, 40, 30)
    M = cam.to_nerf()
    back = Camera.from_nerf(M, 40, 30, camera_angle_x=math.radians(cam.fov_x_deg))
    np.testing.assert_allclose(back.K, cam.K, atol=1e-10)
    np.testing.assert_allclose(back.c2w, cam.c2w, atol=1e-14)
    # OpenGL camera looks down -z; +y is image up.
    np.testing.assert_allclose(M[:3, 2], -cam.R[:, 2])
    np.testing.assert_allclose(M[:3, 1], -cam.R[:, 1])


def test_scaled_keeps_pixel_centre_geometry():
    cam = random_camera(3, 40, 30)
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (20, 15)
    # The image corner (0, 0) and the far corner (W, H) map to the same rays.
    for cc, hh in (((0, 0), (0, 0)), ((40, 30), (20, 15))):
        np.testing.assert_allclose(
            cam.camera_directions(np.array(float(cc[0])), np.array(float(cc[1]))),
            half.camera_directions(np.array(float(hh[0])), np.array(float(hh[1]))), atol=1e-12)


def test_look_at_points_camera_at_target_with_up_upward():
    M = look_at([0, -5, 1], [0, 0, 1], up=[0, 0, 1])
    cam = Camera.from_fov(60, 20, 20, M)
    uv, z = cam.project(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]))
    np.testing.assert_allclose(uv[0], [10.0, 10.0], atol=1e-12)
    assert math.isclose(z[0], 5.0)
    assert uv[1, 1] < 10.0  # higher world point appears higher in the image (smaller v)
    with pytest.raises(ValueError, match="up"):
        look_at([0, 0, 5], [0, 0, 0], up=[0, 0, 1])


@pytest.mark.parametrize("hemisphere", [True, False])
def test_orbit_poses_cover_sphere_and_look_at_centre(hemisphere):
    center = np.array([0.5, -0.2, 0.3])
    poses = orbit_poses(64, 3.0, center, hemisphere=hemisphere, seed=1)
    eyes = np.array([P[:3, 3] for P in poses])
    np.testing.assert_allclose(np.linalg.norm(eyes - center, axis=1), 3.0, rtol=1e-12)
    for P in poses:
        cam = Camera.from_fov(50, 32, 32, P)
        uv, _ = cam.project(center[None])
        np.testing.assert_allclose(uv[0], [16.0, 16.0], atol=1e-9)
    heights = eyes[:, 2] - center[2]
    if hemisphere:
        assert heights.min() > 0
    else:
        assert heights.min() < -2.5 and heights.max() > 2.5
    # Deterministic for a seed, different for another seed.
    assert np.array_equal(np.array(poses), np.array(orbit_poses(64, 3.0, center, hemisphere=hemisphere, seed=1)))
    assert not np.allclose(np.array(poses), np.array(orbit_poses(64, 3.0, center, hemisphere=hemisphere, seed=2)))


def test_smooth_path_has_small_smooth_steps():
    poses = smooth_path(20, 4.0, sweep_deg=20.0)
    eyes = np.array([P[:3, 3] for P in poses])
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert steps.max() < 0.1 and steps.min() > 0.02
    # Second differences (curvature of the arc and the wobble) stay well below the steps.
    assert np.linalg.norm(np.diff(eyes, 2, axis=0), axis=1).max() < 0.5 * steps.min()


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(K=np.diag([-10.0, 10.0, 1.0])), "K"),
        (dict(K=np.diag([10.0, 0.0, 1.0])), "K"),
        (dict(K=np.array([[10.0, 0, 5], [0, 10, np.nan], [0, 0, 1]])), "K"),
        (dict(K=np.eye(2)), "K"),
        (dict(c2w=np.diag([1.0, 1.0, -1.0, 1.0])), "c2w"),
        (dict(c2w=np.diag([2.0, 1.0, 1.0, 1.0])), "c2w"),
        (dict(c2w=np.full((4, 4), np.inf)), "c2w"),
        (dict(width=0), "width"),
        (dict(height=2.5), "height"),
    ],
)
def test_bad_camera_input_names_the_field(kwargs, field):
    base = dict(K=np.array([[10.0, 0, 5], [0, 10, 5], [0, 0, 1]]), c2w=np.eye(4), width=10, height=10)
    base.update(kwargs)
    with pytest.raises(ValueError, match=field):
        Camera(**base)


def test_camera_dict_round_trip():
    cam = random_camera(9)
    back = Camera.from_dict(cam.to_dict())
    assert np.array_equal(back.K, cam.K) and np.array_equal(back.c2w, cam.c2w)
    assert (back.width, back.height) == (cam.width, cam.height)
    with pytest.raises(ValueError, match="K"):
        Camera.from_dict({"width": 1, "height": 1, "c2w": np.eye(4).tolist()})


def test_every_pose_reader_uses_the_one_rotation_check():
    """Camera, check_pose, from_nerf, the trajectory and COLMAP readers share kernels/rotation.py: a float32
    pipeline's 1.25e-6 passes (the old 1e-6 copy refused it) and comes back orthonormal; 2e-5 is refused by name."""
    from kernels.rotation import checked_rigid, orthonormality_error
    from research.poses import se3 as P
    from research.cameras import check_pose
    from research.datasets.colmap import c2w_from_colmap

    S = np.array([[0.0, 1.0, -1.0], [1.0, 0.0, 1.0], [-1.0, 1.0, 0.0]])
    c2w = look_at((3.0, 1.0, 2.0), (0.0, 0.0, 0.0))
    drifted = c2w.copy()
    drifted[:3, :3] = c2w[:3, :3] @ (np.eye(3) + 6.25e-7 * S)
    drifted = drifted.astype(np.float32).astype(np.float64)
    assert orthonormality_error(drifted[:3, :3]) > 1e-6
    clean = checked_rigid("c2w", drifted)
    assert orthonormality_error(clean[:3, :3]) < 1e-15 and np.abs(clean - c2w).max() < 1e-6
    K = intrinsics_from_fov(50.0, 16, 16)
    assert np.array_equal(Camera(K, drifted, 16, 16).c2w, clean)
    assert np.array_equal(check_pose("c2w", drifted), clean)
    assert orthonormality_error(Camera.from_nerf(drifted, 16, 16, camera_angle_x=0.8).R) < 1e-15
    assert np.array_equal(P.check_trajectory("c2w", [drifted, c2w]), [clean, c2w])
    assert orthonormality_error(c2w_from_colmap(drifted[:3, :3].T, drifted[:3, 3])[:3, :3]) < 1e-15
    bad = c2w.copy()
    bad[:3, :3] = c2w[:3, :3] @ (np.eye(3) + 1e-5 * S)
    for call, name in ((lambda: Camera(K, bad, 16, 16), "c2w"), (lambda: check_pose("pose", bad), "pose"),
                       (lambda: Camera.from_nerf(bad, 16, 16, camera_angle_x=0.8), "transform_matrix"),
                       (lambda: P.check_trajectory("traj", [c2w, bad]), r"traj\[1\]")):
        with pytest.raises(ValueError, match=rf"^{name}: rotation part is not orthonormal \(max \|R\^T R - I\| = 2e-05, "
                                             r"tolerance 1e-05\)"):
            call()
