"""kernels/tsdf integration: the Warp kernel against its NumPy reference (kernels/reference/tsdf.py) in
float32 and float64, against Open3D's UniformTSDFVolume on the same voxels (when installed), the kind
rule, split launches against one launch, the memory refusal, the frustum test and bad input.

TSDF integration has no backward pass (kernels/tsdf/__init__.py says why), so there is no gradient check.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import tsdf as kt
from kernels.reference.tsdf import integrate_reference

DTYPES = [np.float32, np.float64]


def look_at(centre, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World-to-camera (OpenCV axes) of a camera at `centre` looking at `target`."""
    c = np.asarray(centre, dtype=np.float64)
    f = np.asarray(target) - c
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    R = np.stack([r, np.cross(f, r), f])
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = R, -R @ c
    return w2c


def sphere_depth(K, w2c, H, W, radius=0.5):
    """z-depth of the sphere of `radius` at the origin (0 where a ray misses), and a random colour image."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    unit = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    R, t = w2c[:3, :3], w2c[:3, 3]
    c = -R.T @ t
    dw = unit @ R
    b = dw @ c
    disc = b * b - (c @ c - radius * radius)
    s = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where(disc > 0, s * unit[..., 2], 0.0)


K = np.array([[40.0, 0.0, 20.3], [0.0, 42.0, 15.1], [0.0, 0.0, 1.0]])
H, W = 30, 40
POSES = [look_at((1.9, 0.4, 0.7)), look_at((-0.5, 1.7, -0.9)), look_at((0.3, -2.1, 0.2))]
ORIGIN = np.array([-0.8, -0.77, -0.81])
SHAPE = (18, 17, 19)
VOXEL = 0.09
TRUNC = 0.27


def fused(dtype, color=True, views=POSES):
    vol = kt.TSDFVolume(ORIGIN, VOXEL, SHAPE, TRUNC, dtype=dtype, color=color)
    rng = np.random.default_rng(3)
    ref = (np.ones(SHAPE, dtype), np.zeros(SHAPE, dtype), np.zeros((*SHAPE, 3), dtype) if color else None)
    uvs = []
    for w2c in views:
        d = sphere_depth(K, w2c, H, W).astype(dtype)
        rgb = rng.random((H, W, 3)).astype(dtype) if color else None
        kt.integrate(vol, d, K, w2c, rgb=rgb)
        *ref, uv = integrate_reference(*ref, ORIGIN, VOXEL, TRUNC, d, K, w2c, rgb)
        uvs.append(uv)
    return vol, ref, uvs


def on_pixel_border(uvs, eps):
    """Voxels whose projection lies within eps of a pixel border in some view (the pixel there depends on
    rounding, so float32 kernel and reference may pick different pixels)."""
    out = np.zeros(SHAPE, dtype=bool)
    for uv in uvs:
        frac = np.abs(uv - np.round(uv))
        out |= np.nan_to_num(frac, nan=1.0).min(axis=-1) < eps
    return out


@pytest.mark.usefixtures("warp_device")
@pytest.mark.parametrize("dtype", DTYPES)
def test_integrate_matches_the_reference(dtype):
    vol, (t_ref, w_ref, c_ref), uvs = fused(dtype)
    got = vol.numpy()
    assert got["tsdf"].dtype == dtype and got["weight"].shape == SHAPE
    assert 0.05 < (w_ref > 0).mean() < 0.9 and w_ref.max() >= 2  # voxels seen once and several times
    # float64: the same operations up to contraction; float32 also skips voxels on a pixel border.
    keep = ~on_pixel_border(uvs, 1e-4) if dtype == np.float32 else np.ones(SHAPE, dtype=bool)
    assert keep.mean() > 0.99
    tol = 1e-12 if dtype == np.float64 else 2e-6  # a few float32 roundings of values in [-1, 1]
    np.testing.assert_array_equal(got["weight"][keep], w_ref[keep])
    np.testing.assert_allclose(got["tsdf"][keep], t_ref[keep], rtol=0, atol=tol)
    np.testing.assert_allclose(got["color"][keep], c_ref[keep], rtol=0, atol=tol)
    assert np.all(got["tsdf"] <= 1) and np.all(got["tsdf"] >= -1)


def test_integrate_matches_open3d():
    o3d = pytest.importorskip("open3d", reason="open3d not installed (the [bench] extra: pip install open3d-cpu)")
    integ = o3d.pipelines.integration
    n = 20
    origin = np.array([-0.9, -0.9, -0.9])
    h = 1.8 / n
    vol = kt.TSDFVolume(origin, h, (n, n, n), 3 * h)
    ref = integ.UniformTSDFVolume(length=1.8, resolution=n, sdf_trunc=3 * h,
                                  color_type=integ.TSDFVolumeColorType.NoColor, origin=origin)
    # Open3D puts pixel centres at integer coordinates: its principal point is ours minus 1/2.
    intr = o3d.camera.PinholeCameraIntrinsic(W, H, K[0, 0], K[1, 1], K[0, 2] - 0.5, K[1, 2] - 0.5)
    uvs = []
    for w2c in POSES:
        d = sphere_depth(K, w2c, H, W).astype(np.float32)
        kt.integrate(vol, d, K, w2c)
        img = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.zeros((H, W, 3), np.uint8)), o3d.geometry.Image(d), depth_scale=1.0,
            depth_trunc=1e9, convert_rgb_to_intensity=False)
        ref.integrate(img, intr, w2c)
        uvs.append(integrate_reference(np.ones((n,) * 3), np.zeros((n,) * 3), None, origin, h, 3 * h, d, K, w2c)[3])
    tw = np.asarray(ref.extract_volume_tsdf()).reshape(n, n, n, 2)  # Open3D's voxel index (i n + j) n + k
    got = vol.numpy()
    border = np.zeros((n,) * 3, dtype=bool)
    for uv in uvs:  # Open3D's float32 projection may pick the neighbouring pixel there
        border |= np.nan_to_num(np.abs(uv - np.round(uv)), nan=1.0).min(axis=-1) < 1e-3
    keep = ~border
    assert keep.mean() > 0.95 and (got["weight"] > 0).mean() > 0.05
    np.testing.assert_array_equal(got["weight"][keep], tw[..., 1][keep])
    seen = keep & (got["weight"] > 0)
    np.testing.assert_allclose(got["tsdf"][seen], tw[..., 0][seen], rtol=0, atol=1e-5)


def test_split_launches_equal_one_launch(monkeypatch):
    one = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("DRLAB_THREADS", threads)
        vol, _, _ = fused(np.float32)
        one[threads] = vol.numpy()
    for k in one["1"]:
        np.testing.assert_array_equal(one["1"][k], one["2"][k])


def test_volume_kind_and_device():
    vol = kt.TSDFVolume(ORIGIN, VOXEL, SHAPE, TRUNC)
    assert isinstance(vol.tsdf, wp.array) and vol.tsdf.shape == (np.prod(SHAPE),)
    d = wp.array(sphere_depth(K, POSES[0], H, W).astype(np.float32), dtype=wp.float32, device="cpu")
    kt.integrate(vol, d, K, POSES[0])  # a wp.array depth map on the volume's device
    ref = kt.TSDFVolume(ORIGIN, VOXEL, SHAPE, TRUNC)
    kt.integrate(ref, d.numpy(), K, POSES[0])
    np.testing.assert_array_equal(vol.numpy()["tsdf"], ref.numpy()["tsdf"])
    assert vol.nbytes == kt.volume_bytes(SHAPE, np.float32, False) == np.prod(SHAPE) * 8


def test_a_volume_larger_than_memory_is_refused_with_its_size():
    with pytest.raises(ValueError, match=r"shape: a TSDF volume of 600x600x600 voxels \(float64, with colour\) "
                                         r"needs 8.64 GB \(8640000000 bytes\); only 1 GB is available on cpu "
                                         r"\(max_bytes\)"):
        kt.TSDFVolume(ORIGIN, 0.01, (600, 600, 600), 0.04, dtype=np.float64, color=True, max_bytes=10**9)
    # the default limit is the memory the device has available
    avail = kt.available_bytes("cpu")
    side = int(round((avail / 8) ** (1 / 3))) + 64
    with pytest.raises(ValueError, match=rf"voxels \(float32\) needs .* only .* is available on cpu: use a larger"):
        kt.TSDFVolume(ORIGIN, 0.01, (side, side, side), 0.04)
    with pytest.raises(ValueError, match=r"more than the \(2\^31 - 1\) / 3"):
        kt.TSDFVolume(ORIGIN, 0.01, (2000, 2000, 2000), 0.04, max_bytes=10**14)


def test_sees_volume():
    vol = kt.TSDFVolume(ORIGIN, VOXEL, SHAPE, TRUNC)
    assert kt.sees_volume(vol, K, POSES[0], W, H)
    away = look_at((0.0, 0.0, 3.0), target=(0.0, 0.0, 6.0), up=(0.0, 1.0, 0.0))  # looks away from the box
    assert not kt.sees_volume(vol, K, away, W, H)
    aside = look_at((3.0, 3.0, 0.0), target=(3.0, 8.0, 0.0))  # the box is far to the side of the frustum
    assert not kt.sees_volume(vol, K, aside, W, H)


def test_bad_input_is_refused_before_any_kernel():
    vol = kt.TSDFVolume(ORIGIN, VOXEL, SHAPE, TRUNC)
    good = sphere_depth(K, POSES[0], H, W).astype(np.float32)
    before = vol.numpy()["tsdf"].copy()
    cases = [
        (dict(depth=np.zeros((0, 5), np.float32)), r"depth: expected a non-empty \(H, W\) array"),
        (dict(depth=np.zeros((H, W), np.float32)), "depth: no pixel has a measurement"),
        (dict(depth=np.where(good > 0, np.nan, good).astype(np.float32)), "depth: .*(NaN|finite)"),
        (dict(depth=good, K=np.diag([0.0, 1.0, 1.0])), "K: expected focal lengths > 0"),
        (dict(depth=good, w2c=np.diag([1.0, 1.0, 2.0, 1.0])), "w2c"),
        (dict(depth=good, rgb=np.zeros((H, W, 3), np.float32)), "rgb: the volume keeps no colour"),
    ]
    for kw, msg in cases:
        args = {"depth": good, "K": K, "w2c": POSES[0], **kw}
        with pytest.raises(ValueError, match=msg):
            kt.integrate(vol, args["depth"], args["K"], args["w2c"], rgb=args.get("rgb"))
    away = look_at((0.0, 0.0, 3.0), target=(0.0, 0.0, 6.0), up=(0.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="w2c: this camera sees nothing of the volume"):
        kt.integrate(vol, good, K, away)
    np.testing.assert_array_equal(vol.numpy()["tsdf"], before)
    colored = kt.TSDFVolume(ORIGIN, VOXEL, SHAPE, TRUNC, color=True)
    with pytest.raises(ValueError, match=r"rgb: the volume keeps colour"):
        kt.integrate(colored, good, K, POSES[0])
    with pytest.raises(ValueError, match=r"rgb: expected shape"):
        kt.integrate(colored, good, K, POSES[0], rgb=np.zeros((H, W), np.float32))
    for kw, msg in [(dict(voxel_size=0.0), "voxel_size"), (dict(truncation=-1.0), "truncation"),
                    (dict(shape=(1, 4, 4)), r"shape\[0\]"), (dict(shape=(4, 4)), "shape: expected three"),
                    (dict(origin=[0.0, np.nan, 0.0]), "origin"), (dict(dtype=np.int32), "dtype")]:
        args = {"origin": ORIGIN, "voxel_size": VOXEL, "shape": SHAPE, "truncation": TRUNC, **kw}
        with pytest.raises(ValueError, match=msg):
            kt.TSDFVolume(args["origin"], args["voxel_size"], args["shape"], args["truncation"],
                          dtype=kw.get("dtype", np.float32))
    with pytest.raises(ValueError, match="volume: expected a kernels.tsdf.TSDFVolume"):
        kt.integrate("volume", good, K, POSES[0])
