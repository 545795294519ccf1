"""research/surface: mesh scores on a hand case and against SciPy / Open3D, surface sampling, PLY files,
the Mitsuba ground truth, and fusion of an analytic sphere's depth maps (drlab beside Open3D)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from research.bench.tsdf import sphere_views
from research.cameras import Camera
from research.surface import depth as sdepth, fusion, groundtruth, mesh, metrics


def test_metrics_hand_case():
    pred = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    gt = np.array([[0.0, 0.0, 0.1], [1.0, 0.0, 0.3], [5.0, 0.0, 0.0]])
    up = np.tile([0.0, 0.0, 1.0], (3, 1))
    side = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    m = metrics.surface_metrics(pred, side, gt, up, [0.2, 0.5])
    # pred -> gt: 0.1, 0.3; gt -> pred: 0.1, 0.3, 4.0
    assert m["accuracy"] == pytest.approx(0.2) and m["completeness"] == pytest.approx(4.4 / 3)
    assert m["chamfer"] == pytest.approx(0.5 * (0.2 + 4.4 / 3))
    t02, t05 = m["per_threshold"]
    assert (t02["precision"], t02["recall"]) == (0.5, pytest.approx(1 / 3))
    assert t02["fscore"] == pytest.approx(2 * 0.5 * (1 / 3) / (0.5 + 1 / 3))
    assert (t05["precision"], t05["recall"]) == (1.0, pytest.approx(2 / 3))
    # normals: pred 0 matches gt 0 (|cos| 1), pred 1 matches gt 1 (0); gt 0 -> pred 0 (1), gt 1, 2 -> pred 1 (0)
    assert m["normal_consistency"] == pytest.approx(0.5 * (0.5 + 1 / 3))
    empty = metrics.surface_metrics(np.zeros((0, 3)), np.zeros((0, 3)), gt, up, [0.2])
    assert empty["chamfer"] == np.inf and empty["per_threshold"][0]["fscore"] == 0.0
    with pytest.raises(ValueError, match="gt: expected at least one"):
        metrics.surface_metrics(pred, side, np.zeros((0, 3)), np.zeros((0, 3)), [0.2])


def test_metrics_distances_agree_with_scipy_and_open3d():
    rng = np.random.default_rng(0)
    a, b = rng.random((3000, 3)), rng.random((2000, 3)) * 1.1
    na, nb = rng.normal(size=(3000, 3)), rng.normal(size=(2000, 3))
    m = metrics.surface_metrics(a, na, b, nb, [0.02])
    d_ab, _ = cKDTree(b).query(a)
    d_ba, _ = cKDTree(a).query(b)
    np.testing.assert_allclose(m["pred_distances"], d_ab, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(m["gt_distances"], d_ba, rtol=1e-12, atol=1e-15)
    assert m["per_threshold"][0]["precision"] == np.mean(d_ab < 0.02)
    o3d = pytest.importorskip("open3d", reason="open3d not installed (the [bench] extra: pip install open3d-cpu)")
    pa = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(a))
    pb = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(b))
    np.testing.assert_allclose(m["pred_distances"], np.asarray(pa.compute_point_cloud_distance(pb)), rtol=1e-9)


def test_sample_mesh_is_uniform_in_area():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [3, 0, 1], [0, 2, 1]])
    f = np.array([[0, 1, 2], [3, 4, 5]])  # areas 0.5 and 3: one in 7 samples on the first
    p, n = mesh.sample_mesh(v, f, 40_000, seed=0)
    first = p[:, 2] == 0
    assert abs(first.mean() - 1 / 7) < 4 * np.sqrt((1 / 7) * (6 / 7) / 40_000)
    assert np.all(p[first, :2].sum(axis=1) <= 1 + 1e-12) and np.all(p[first] >= 0)  # inside the triangle
    assert np.all(p[~first, 0] / 3 + p[~first, 1] / 2 <= 1 + 1e-12)
    np.testing.assert_allclose(n[first], np.tile([0, 0, 1.0], (first.sum(), 1)))
    # uniform inside a triangle: the mean is the centroid
    np.testing.assert_allclose(p[first].mean(axis=0), [1 / 3, 1 / 3, 0], atol=0.01)
    assert mesh.mesh_area(v, f) == pytest.approx(3.5)
    with pytest.raises(ValueError, match="faces: expected a non-empty"):
        mesh.sample_mesh(v, np.zeros((0, 3), int), 10, 0)


def test_ply_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    v, f = rng.random((50, 3)), rng.integers(0, 50, size=(80, 3))
    path = mesh.write_ply(tmp_path / "sub" / "m.ply", v, f, colors=rng.random((50, 3)))
    assert [p.name for p in path.parent.iterdir()] == ["m.ply"]  # no temporary file left
    v2, f2 = mesh.read_ply(path)
    np.testing.assert_array_equal(v2, v.astype(np.float32))
    np.testing.assert_array_equal(f2, f)
    with pytest.raises(ValueError, match=r"faces: expected vertex indices in \[0, 50\)"):
        mesh.write_ply(tmp_path / "bad.ply", v, f + 1)
    assert not (tmp_path / "bad.ply").exists()
    o3d = pytest.importorskip("open3d", reason="open3d not installed (the [bench] extra: pip install open3d-cpu)")
    m = o3d.io.read_triangle_mesh(str(path))
    np.testing.assert_array_equal(np.asarray(m.triangles), f)
    np.testing.assert_allclose(np.asarray(m.vertices), v, atol=1e-6)


def test_ground_truth_samples_lie_on_the_mitsuba_spheres():
    from research.datasets.scenes import get_scene

    pts, nrm, info = groundtruth.sample_scene_surface("spheres", 3000, seed=0)
    spheres = get_scene("spheres").build()
    centres = np.array([spheres[k]["center"] for k in ("red", "green", "blue")])
    radii = np.array([spheres[k]["radius"] for k in ("red", "green", "blue")])
    gap = np.abs(np.linalg.norm(pts[:, None] - centres[None], axis=2) - radii[None])
    k = gap.argmin(axis=1)
    assert gap.min(axis=1).max() < 1e-5  # float32 sampling on the true spheres
    radial = (pts - centres[k]) / radii[k, None]
    np.testing.assert_allclose(np.abs(np.sum(radial * nrm, axis=1)), 1.0, atol=1e-4)
    assert sum(s["samples"] for s in info.values()) == 3000
    share = np.bincount(k, minlength=3) / 3000
    np.testing.assert_allclose(share, radii**2 / (radii**2).sum(), atol=1e-3)  # in proportion to area


def test_observed_keeps_what_a_camera_sees():
    K, poses, depths = sphere_views(1, 64)
    cam = Camera(K=K, c2w=np.linalg.inv(poses[0]), width=64, height=64)
    rng = np.random.default_rng(0)
    p = rng.normal(size=(4000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)  # the unit sphere that the depth map shows
    seen = groundtruth.observed(p, [cam], depths, tolerance=0.05)  # pixels ~0.03 wide at the sphere
    facing = (p @ (cam.center / np.linalg.norm(cam.center))) > 0.7  # well inside the visible cap
    back = (p @ (cam.center / np.linalg.norm(cam.center))) < 0
    assert seen[facing].mean() > 0.97 and not seen[back].any()


def test_expected_depth():
    d = sdepth.expected_depth(np.array([[1.0, 0.2, 3.0]]), np.array([[0.5, 0.1, 1.0]]))
    np.testing.assert_array_equal(d, np.array([[2.0, 0.0, 3.0]], dtype=np.float32))


def test_fusion_of_a_sphere_is_close_and_matches_open3d():
    K, poses, depths = sphere_views(6, 48)
    cams = [Camera(K=K, c2w=np.linalg.inv(T), width=48, height=48) for T in poses]
    bbox = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    h = 0.06
    origin, shape = fusion.fusion_grid(bbox, h, 4 * h)
    np.testing.assert_allclose(origin / h, np.round(origin / h), atol=1e-12)  # on multiples of h
    assert np.all(origin <= bbox[0] - 5 * h + 1e-12) and np.all(origin + np.array(shape) * h >= bbox[1] + 5 * h)
    away = Camera(K=K, c2w=np.linalg.inv(poses[0]) @ np.diag([-1.0, 1.0, -1.0, 1.0]), width=48, height=48)
    fused = fusion.fuse(np.concatenate([depths, depths[:1]]), cams + [away], bbox, h, 4 * h)
    assert fused.views == 6 and fused.skipped == ["view 6: sees nothing of the volume"]
    r = np.linalg.norm(fused.vertices, axis=1)
    # linear interpolation between voxels: a second-order bias (0.003 at this h); up to about h / 2 where
    # the six views meet at grazing angles
    assert abs(np.mean(r - 1)) < 0.1 * h and np.abs(r - 1).max() < 0.8 * h and len(fused.faces) > 1000
    o3d = pytest.importorskip("open3d", reason="open3d not installed (the [bench] extra: pip install open3d-cpu)")
    ref = fusion.fuse_open3d(depths, cams, bbox, h, 4 * h)
    assert ref.vertices.shape == fused.vertices.shape and ref.faces.shape == fused.faces.shape
    a, b = np.sort(fused.vertices, axis=0), np.sort(ref.vertices, axis=0)
    np.testing.assert_allclose(a, b, atol=1e-4)  # the same vertices (Open3D computes in float32)
    assert o3d is not None
