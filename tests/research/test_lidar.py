"""research/lidar: the scanner against analytic ranges, ICP recovering known transforms (point-to-point and
point-to-plane, robust weights against outliers), Open3D's ICP on the same registration, the voxel map,
odometry on a short Mitsuba sequence, and bad input (empty or NaN clouds, a scan with no returns, a
degenerate neighbourhood)."""

from __future__ import annotations

import numpy as np
import pytest

from research.lidar import baselines, odometry, registration, scanner, scene
from research.poses.align import rotation_angle_deg
from research.poses.se3 import ate, se3_exp


def _boxes_cloud(seed: int, n: int = 1500) -> np.ndarray:
    """Points on the faces of three boxes of different sizes and orientations (every DoF constrained)."""
    rng = np.random.default_rng(seed)
    out = []
    for c, h, yaw in (([0, 0, 0], [2.0, 1.0, 0.7], 0.2), ([3, 1, 0.5], [0.5, 0.8, 1.2], -0.5),
                      ([-2, 2, -0.3], [0.6, 0.6, 0.6], 1.0)):
        u = rng.uniform(-1, 1, size=(n // 3, 3))
        ax = rng.integers(0, 3, n // 3)
        u[np.arange(n // 3), ax] = rng.choice([-1.0, 1.0], n // 3)  # onto a face
        cz, sz = np.cos(yaw), np.sin(yaw)
        R = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1.0]])
        out.append((u * h) @ R.T + c)
    return np.concatenate(out)


def _errors(T, T_true):
    E = np.linalg.inv(T_true) @ T
    return rotation_angle_deg(E[:3, :3]), float(np.linalg.norm(E[:3, 3]))


T_TRUE = se3_exp([0.25, -0.15, 0.1, 0.03, -0.02, 0.08])  # 0.32 m, 5 degrees


@pytest.mark.parametrize("metric", registration.METRICS)
def test_icp_recovers_a_known_transform(metric):
    target_pts = _boxes_cloud(0)
    source = (target_pts - T_TRUE[:3, 3]) @ T_TRUE[:3, :3]  # T_TRUE maps the source onto the target
    cfg = registration.IcpConfig(metric=metric, robust="none", convergence=1e-10)
    res = registration.register(source, registration.make_target(target_pts, metric), max_distance=1.0, config=cfg)
    rot, trans = _errors(res.T, T_TRUE)
    assert res.converged and rot < 1e-6 and trans < 1e-6 and res.pairs == len(source)


def test_robust_weights_resist_outliers():
    rng = np.random.default_rng(1)
    target_pts = _boxes_cloud(1)
    source = (target_pts - T_TRUE[:3, 3]) @ T_TRUE[:3, :3] + rng.normal(0, 0.005, target_pts.shape)
    # 25% of the source replaced by points on a phantom wall 0.5 m off the target's geometry
    k = len(source) // 4
    source[:k] = np.c_[rng.uniform(-2, 2, k), np.full(k, -1.6), rng.uniform(-1, 1, k)]
    target = registration.make_target(target_pts, "point")
    err = {}
    for robust, scale in (("none", 1.0), ("huber", 0.05), ("gm", 0.01)):
        cfg = registration.IcpConfig(robust=robust, convergence=1e-9, max_iterations=200)
        err[robust] = _errors(registration.register(source, target, max_distance=1.0, kernel_scale=scale,
                                                    config=cfg).T, T_TRUE)
    assert err["gm"][1] < 0.01 and err["gm"][0] < 0.2
    assert err["none"][1] > 3 * err["gm"][1] and err["huber"][1] < err["none"][1]


@pytest.mark.parametrize("metric", registration.METRICS)
def test_open3d_agrees_on_a_single_registration(metric):
    if baselines.missing_open3d():
        pytest.skip(baselines.missing_open3d())
    rng = np.random.default_rng(2)
    target_pts = _boxes_cloud(2)
    source = (target_pts - T_TRUE[:3, 3]) @ T_TRUE[:3, :3] + rng.normal(0, 0.01, target_pts.shape)
    source = source[rng.permutation(len(source))[:1000]]
    init = se3_exp([0.2, -0.1, 0.05, 0.02, 0.0, 0.05])
    # The same objective for both: the same pairs (within 0.3 m), no robust kernel, the target normals by
    # PCA over the same 10 nearest (drlab's and Open3D's normals then agree up to sign).
    T_o3d, _ = baselines.open3d_icp(source, target_pts, init, max_distance=0.3, metric=metric, normal_k=10,
                                    max_iterations=500, relative_change=1e-14)
    cfg = registration.IcpConfig(metric=metric, robust="none", convergence=1e-10, max_iterations=200)
    res = registration.register(source, registration.make_target(target_pts, metric, 10), init,
                                max_distance=0.3, config=cfg)
    rot, trans = _errors(res.T, T_o3d)
    assert rot < 1e-3 and trans < 1e-4
    assert _errors(res.T, T_TRUE)[1] < 5e-3


def test_scanner_ranges_are_the_distances_to_the_walls():
    spec = scene.HallSpec(length=20.0, width=10.0, height=4.0, n_boxes=0, n_pillars=0, n_kerbs=0)
    caster = scanner.RayCaster(lambda: scene.hall_scene_dict(spec, 0))
    sc = scanner.Scanner(beams=8, azimuth_steps=36, range_noise=0.0, min_range=0.1, max_range=100.0)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, -2.0, 1.5]
    s = scanner.scan(caster, sc, pose, 0.0, seed=0, frame=0)
    assert len(s.points) == 8 * 36  # a closed hall: every ray returns
    d = s.points / np.linalg.norm(s.points, axis=1, keepdims=True)
    lo, hi = np.array([-10.0, -5.0, 0.0]) - pose[:3, 3], np.array([10.0, 5.0, 4.0]) - pose[:3, 3]
    with np.errstate(divide="ignore"):
        t = np.where(d > 0, hi / d, np.where(d < 0, lo / d, np.inf))
    np.testing.assert_allclose(np.linalg.norm(s.points, axis=1), t.min(axis=1), rtol=1e-5)
    noisy = scanner.scan(caster, scanner.Scanner(beams=8, azimuth_steps=36, range_noise=0.02, min_range=0.1,
                                                 max_range=100.0), pose, 0.0, seed=0, frame=0)
    assert 0.01 < np.std(np.linalg.norm(noisy.points, axis=1) - np.linalg.norm(s.points, axis=1)) < 0.03
    assert np.all(np.diff(noisy.times[:36]) > 0) and noisy.times.max() < 0.1


def test_voxel_downsample_and_map():
    p = np.array([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2], [1.1, 0.1, 0.1], [0.3, 0.1, 0.4]])
    np.testing.assert_array_equal(odometry.voxel_downsample(p, 1.0), p[[0, 2]])
    m = odometry.VoxelMap(1.0, 2, 5.0)
    m.update(p, np.zeros(3))
    m.update(np.array([[0.5, 0.5, 0.5], [9.0, 0.0, 0.0]]), np.zeros(3))
    np.testing.assert_array_equal(m.points, p[[0, 1, 2]])  # voxel 0 keeps its first two; 9 m is out of range


def test_odometry_on_a_short_sequence():
    spec = scene.HallSpec()
    caster = scanner.RayCaster(lambda: scene.hall_scene_dict(spec, 3))
    sc = scanner.Scanner(beams=16, azimuth_steps=240)
    ts, poses = scene.street_path(spec, 6, 3)
    scans = scanner.scan_sequence(caster, sc, ts, poses, 3)
    # Point-to-point is not asserted on so short a run: the floor's beam rings move with the sensor and pull
    # its pairs towards zero motion while the map holds only a few scans (the experiment measures it).
    for mode, metric in (("scan2map", "plane"), ("scan2scan", "plane")):
        cfg = odometry.OdometryConfig(mode=mode, icp=registration.IcpConfig(metric=metric), max_range=sc.max_range)
        odo = odometry.run_odometry([s.points for s in scans], cfg, start_pose=poses[0])
        assert ate(np.array(odo.poses), poses).rmse < 0.05, (mode, metric)


# --------------------------------------------------------------------------- bad input

GOOD = _boxes_cloud(4, 300)


def test_bad_clouds_raise_naming_the_argument():
    target = registration.make_target(GOOD, "point")
    with pytest.raises(ValueError, match="source: expected a non-empty cloud"):
        registration.register(np.zeros((0, 3)), target, max_distance=1.0)
    bad = GOOD.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="source: expected finite coordinates"):
        registration.register(bad, target, max_distance=1.0)
    with pytest.raises(ValueError, match="target: expected finite coordinates"):
        registration.make_target(bad, "plane")
    with pytest.raises(ValueError, match="target: expected a non-empty cloud"):
        registration.make_target(np.zeros((0, 3)), "point")
    with pytest.raises(ValueError, match="max_distance: expected a positive"):
        registration.register(GOOD, target, max_distance=0.0)
    with pytest.raises(registration.RegistrationError, match="correspondences within max_distance"):
        registration.register(GOOD + 50.0, target, max_distance=1.0)


def test_a_scan_with_no_returns_is_refused():
    spec = scene.HallSpec(length=4.0, width=4.0, height=2.0, n_boxes=0, n_pillars=0, n_kerbs=0)
    caster = scanner.RayCaster(lambda: scene.hall_scene_dict(spec, 0))
    sc = scanner.Scanner(beams=4, elevation_deg=(-10.0, 10.0), azimuth_steps=16, max_range=5.0)
    outside = np.eye(4)
    outside[:3, 3] = [0.0, 0.0, 50.0]  # above the hall, the beams look past it: nothing returns
    empty = scanner.scan(caster, sc, outside, 0.0, seed=0, frame=0)
    assert len(empty.points) == 0
    odo = odometry.Odometry(odometry.OdometryConfig())
    odo.register_frame(GOOD)
    with pytest.raises(ValueError, match=r"scans\[1\]: no returns"):
        odo.register_frame(empty.points, name="scans[1]")
    with pytest.raises(ValueError, match=r"scans\[2\]: expected finite coordinates"):
        odo.register_frame(np.full((5, 3), np.nan), name="scans[2]")


def test_degenerate_neighbourhoods_are_refused():
    line = np.c_[np.linspace(0, 5, 50), np.zeros(50), np.zeros(50)]
    with pytest.raises(ValueError, match="target: every neighbourhood is degenerate"):
        registration.make_target(line, "plane")
    rng = np.random.default_rng(5)
    plane = np.c_[rng.uniform(-3, 3, (400, 2)), np.zeros(400)]  # one plane: sliding in it is free
    target = registration.make_target(plane, "plane")
    with pytest.raises(registration.RegistrationError, match="normal equations: degenerate"):
        registration.register(plane + [0, 0, 0.05], target, max_distance=1.0,
                               config=registration.IcpConfig(metric="plane", robust="none"))
