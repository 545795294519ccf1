"""kernels/splat/depth.py and kernels/splat/normals.py against their NumPy reference
(kernels/reference/splat_geometry.py), finite differences (research/checks/splat_geometry.py), and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import splat as ks
from kernels.lens import Lens
from kernels.reference import splat_geometry as rg
from kernels.splat import depth as kd
from kernels.splat import normals as kn
from research.checks import splat as cs
from research.checks import splat_geometry as cg
from research.gradcheck import assert_gradcheck
from tests.bad_input import assert_refused

TOL = {np.float32: dict(rtol=2e-5, atol=2e-5), np.float64: dict(rtol=1e-12, atol=1e-12)}
KEYS = cg.KEYS


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("mode", ks.MODES)
def test_median_depth_matches_the_reference(dtype, mode):
    scene, p = cg.median_scene(0, mode)
    W, H = scene.camera.width, scene.camera.height
    want, who = rg.median_depth(p.means2d, p.conics, p.opacities, p.depths, p.radii, W, H, mode)
    s = ks.splats_2d(*(getattr(p, k).astype(dtype) for k in KEYS), p.radii)
    r, tiles = ks.rasterize(s, W, H, None, mode=mode)
    med = kd.median_depth(s, tiles, r, mode=mode)
    assert med.depth.dtype == dtype
    np.testing.assert_array_equal(med.depth, want.astype(dtype))  # a splat's own z: exact
    entry = med.entry
    np.testing.assert_array_equal(entry >= 0, who >= 0)
    assert 0.2 < (who >= 0).mean() < 1  # some pixels have no splat
    # the recorded entry is the median splat's place in its tile's list
    gid = tiles.sorted_gid.numpy()
    np.testing.assert_array_equal(gid[entry[entry >= 0]], who[who >= 0])
    # the gradient: one per pixel, to that pixel's splat
    g = np.random.default_rng(1).normal(size=(H, W)).astype(dtype)
    want_g = np.bincount(who[who >= 0], weights=g[who >= 0].astype(np.float64), minlength=len(p.depths))
    np.testing.assert_allclose(kd.median_depth_backward(s, tiles, med, g), want_g, **TOL[dtype])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_expected_depth_and_normals_match_the_reference(dtype):
    rng = np.random.default_rng(2)
    depth, alpha = rng.uniform(0.1, 5.0, (9, 11)), rng.uniform(0.0, 1.0, (9, 11))
    alpha[0, :3] = 0.0
    got = kd.expected_depth(depth.astype(dtype), alpha.astype(dtype))
    np.testing.assert_allclose(got, rg.expected_depth(depth, alpha), **TOL[dtype])
    assert got.dtype == dtype and np.all(np.isfinite(got))

    cam = cg._camera(13, 11, rng)
    z = cg.bumpy_depth(rng, 13, 11)
    n = kn.normals_from_depth(z.astype(dtype), cam)
    want = rg.normals_from_depth(z, cam.K)
    np.testing.assert_allclose(n, want, **TOL[dtype])
    assert np.all(n[0] == 0) and np.all(n[:, -1] == 0)
    np.testing.assert_allclose(np.linalg.norm(n[1:-1, 1:-1], axis=-1), 1.0, rtol=1e-5)
    assert np.all(n[1:-1, 1:-1, 2] < 0)  # towards the camera

    means, quats = rng.uniform(-0.5, 0.5, (20, 3)), rng.normal(size=(20, 4))
    log_scales = rng.uniform(-2.0, -1.0, (20, 3))
    sn = kn.splat_normals(*(x.astype(dtype) for x in (means, quats, log_scales)), cam)
    np.testing.assert_allclose(sn, rg.splat_normals(means, quats, log_scales, cam.viewmat), **TOL[dtype])


def test_normals_of_a_plane_are_its_normal():
    """A plane n . P = d seen by a pinhole: its depth map's normals are n (facing the camera) everywhere
    inside the border, to rounding, whatever the intrinsics."""
    cam = ks.SplatCamera(np.eye(4), np.array([[30.0, 0, 9.1], [0, 27.0, 7.3], [0, 0, 1]]), 17, 15)
    n = np.array([0.3, -0.2, -1.0])
    n /= np.linalg.norm(n)
    x, y = np.meshgrid(np.arange(17) + 0.5, np.arange(15) + 0.5)
    rays = np.stack([(x - 9.1) / 30.0, (y - 7.3) / 27.0, np.ones_like(x)], -1)
    z = -2.0 / (rays @ n)  # n . (z r) = -2
    got = kn.normals_from_depth(z, cam)
    np.testing.assert_allclose(got[1:-1, 1:-1], np.broadcast_to(n, (13, 15, 3)), atol=1e-12)


def test_gradients():
    assert_gradcheck(cg.check_expected(0) + cg.check_depth_normals(0) + cg.check_splat_normals(0))
    assert_gradcheck([r for mode in ks.MODES for r in cg.check_median(0, mode)])


def test_consistency_loss_gradients():
    assert_gradcheck(cg.check_consistency(0, "expected") + cg.check_consistency(1, "median"))


def test_bad_input():
    cam = ks.SplatCamera(np.eye(4), np.array([[30.0, 0, 8], [0, 30.0, 7], [0, 0, 1]]), 16, 14)
    assert_refused(lambda: kn.normals_from_depth(np.ones((14, 15)), cam), r"^depth: expected shape \(14, 16\)")
    assert_refused(lambda: kn.normals_from_depth(np.ones((14, 16)), "cam"), r"^camera: expected a SplatCamera")
    fish = ks.SplatCamera(np.eye(4), cam.K, 16, 14, lens=Lens("fisheye", (0.1,)))
    assert_refused(lambda: kn.normals_from_depth(np.ones((14, 16)), fish), r"^camera: expected a pinhole camera")
    assert_refused(lambda: kn.splat_normals(np.zeros((2, 3)), np.zeros((2, 4)), np.zeros((2, 3)), cam),
                   r"^quats: expected non-zero quaternions$")
    assert_refused(lambda: kn.splat_normals(np.zeros((2, 3)), np.ones((3, 4)), np.zeros((2, 3)), cam),
                   r"^quats: expected shape \(2, 4\)")
    assert_refused(lambda: kd.expected_depth(np.ones((3, 4)), -np.ones((3, 4))), r"^alpha: expected values >= 0")
    assert_refused(lambda: kd.expected_depth(np.ones((3, 4)), np.ones((3, 5))), r"^alpha: expected shape \(3, 4\)")
    scene, p = cg.median_scene(0)
    s = ks.splats_2d(*(getattr(p, k) for k in KEYS), p.radii)
    r, tiles = ks.rasterize(s, scene.camera.width, scene.camera.height)
    assert_refused(lambda: kd.median_depth(s, tiles, r, mode="gsplat"), r"^tiles: binned with mode='3dgs'")
    med = kd.median_depth(s, tiles, r)
    assert_refused(lambda: kd.median_depth_backward(s, tiles, r, np.ones((36, 40))), r"^median: expected the MedianDepth")
    assert_refused(lambda: kd.median_depth_backward(s, tiles, med, np.ones((36, 41))),
                   r"^grad_median: expected shape \(36, 40\)")
