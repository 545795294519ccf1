"""LLFF forward-facing folders (research.datasets.llff): fixtures written in the exact layout
(poses_bounds.npy rows [down, right, back | t | hwf] + near, far; images_N/ PNGs), NeRF's protocol."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from research import io
from research.datasets import DatasetError, detect_format, open_dataset
from research.datasets.llff import load_llff, recenter
from tests.research.realdata_fixtures import smoke_run

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def llff_row(c2w_cv: np.ndarray, hwf: tuple[float, float, float], near: float, far: float) -> np.ndarray:
    """One poses_bounds.npy row of an OpenCV camera-to-world: LLFF's columns (down, right, back) = (y, x, -z)."""
    R, t = c2w_cv[:3, :3], c2w_cv[:3, 3]
    M = np.column_stack([R[:, 1], R[:, 0], -R[:, 2], t, hwf])
    return np.concatenate([M.reshape(-1), [near, far]])


def write_llff(root: Path, c2ws: list[np.ndarray], full=(64, 48), focal=50.0, factors=(8,), bounds=None,
               names=None, seed=0) -> dict[int, dict[str, np.ndarray]]:
    """poses_bounds.npy for the cameras (full-size hwf) and random PNGs at each factor; returns the pixels."""
    W, H = full
    bounds = [(2.0 + 0.1 * i, 20.0 + i) for i in range(len(c2ws))] if bounds is None else bounds
    rows = np.stack([llff_row(c, (H, W, focal), *b) for c, b in zip(c2ws, bounds)])
    root.mkdir(parents=True, exist_ok=True)
    np.save(root / "poses_bounds.npy", rows)
    names = names or [f"image{i:03d}.png" for i in range(len(c2ws))]
    rng = np.random.default_rng(seed)
    pixels: dict[int, dict[str, np.ndarray]] = {}
    for f in factors:
        folder = root / ("images" if f == 1 else f"images_{f}")
        folder.mkdir(exist_ok=True)
        pixels[f] = {}
        for name in names:
            img = rng.integers(0, 256, (H // f, W // f, 3), dtype=np.uint8)
            io.write_png_u8(folder / name, img)
            pixels[f][name] = img
    return pixels


def level_rig(n: int) -> list[np.ndarray]:
    """Forward-facing cameras, all with the world's axes (OpenGL: looking down -z), centres summing to 0
    so that NeRF's mean pose is the identity and recentring changes nothing."""
    c2ws = []
    for i in range(n):
        M = GL_TO_CV.copy()  # OpenCV camera-to-world of the identity OpenGL pose
        a = 2 * math.pi * i / n
        M[:3, 3] = [0.3 * math.cos(a), 0.2 * math.sin(a), 0.0]
        c2ws.append(M)
    return c2ws


def test_hand_derived_camera(tmp_path):
    """One row by hand: R_llff = [down, right, back] of an upright camera looking down -z."""
    rows = []
    for t in ([0.5, 0.0, 0.0], [-0.5, 0.0, 0.0]):
        M = np.array([[0.0, 1.0, 0.0, t[0], 48.0], [-1.0, 0.0, 0.0, t[1], 64.0], [0.0, 0.0, 1.0, t[2], 50.0]])
        rows.append(np.concatenate([M.reshape(-1), [4.0, 40.0]]))
    root = tmp_path / "hand"
    root.mkdir()
    np.save(root / "poses_bounds.npy", np.stack(rows))
    (root / "images_8").mkdir()
    for i in range(2):
        io.write_png_u8(root / "images_8" / f"{i}.png", np.zeros((6, 8, 3), np.uint8))
    ds = load_llff(root)
    sc = 1.0 / (4.0 * 0.75)
    cam = ds.views[1].camera  # "1.png", centre (-0.5, 0, 0) scaled
    expected = np.eye(4)
    expected[:3, :3] = np.diag([1.0, -1.0, -1.0])  # OpenCV: x right, y down (world -y), z forward (world -z)
    expected[:3, 3] = [-0.5 * sc, 0.0, 0.0]
    assert np.abs(cam.c2w - expected).max() < 1e-12
    assert np.allclose(cam.K, [[50.0 / 8, 0, 4.0], [0, 50.0 / 8, 3.0], [0, 0, 1]], atol=1e-12)
    assert (cam.width, cam.height) == (8, 6)
    assert np.allclose(ds.near_far, [[4 * sc, 40 * sc]] * 2) and math.isclose(ds.near_far.min(), 1 / 0.75)
    # a world point straight ahead of the camera at z-depth 2 projects to the image centre
    uv, z = cam.project(cam.center + [0.0, 0.0, -2.0])
    assert np.allclose(uv, [4.0, 3.0]) and math.isclose(z, 2.0)


def test_round_trip_level_rig_scale_and_factor(tmp_path):
    c2ws = level_rig(4)
    write_llff(tmp_path / "s", c2ws, factors=(4, 8))
    assert detect_format(tmp_path / "s") == "llff"
    ds = open_dataset(tmp_path / "s", "llff")  # default factor 8
    sc = 1.0 / (2.0 * 0.75)
    for v, c in zip(ds.views, c2ws):
        want = c.copy()
        want[:3, 3] *= sc
        assert np.abs(v.camera.c2w - want).max() < 1e-12
        assert (v.camera.width, v.camera.height) == (8, 6) and math.isclose(v.camera.fx, 50.0 / 8)
    cam4 = load_llff(tmp_path / "s", factor=4).views[0].camera
    assert (cam4.width, cam4.height) == (16, 12) and math.isclose(cam4.fx, 50.0 / 4) and cam4.cx == 8.0
    assert ds.protocol.name == "llff" and ds.protocol.resolution == "images_8 (8x6)"
    assert ds.protocol.background is None and "LPIPS not computed" in ds.protocol.description
    assert ds.points is None and ds.ndc.near == 1.0 and ds.ndc.size == (8, 6)


def test_recentring_removes_a_rigid_motion_of_the_rig(tmp_path):
    """A whole rig moved by a rotation and translation reads back the same cameras (NeRF's recentring)."""
    from research.poses.se3 import se3_exp

    c2ws = level_rig(5)
    G = se3_exp(np.array([0.4, -0.2, 1.0, 0.3, -0.5, 0.2]))
    write_llff(tmp_path / "a", c2ws, factors=(8,))
    write_llff(tmp_path / "b", [G @ c for c in c2ws], factors=(8,))
    a, b = load_llff(tmp_path / "a"), load_llff(tmp_path / "b")
    for va, vb in zip(a.views, b.views):
        assert np.abs(va.camera.c2w - vb.camera.c2w).max() < 1e-9
    # recenter: the mean pose of the result is the identity
    gl = np.stack([v.camera.c2w @ GL_TO_CV for v in b.views])
    again = recenter(gl)
    assert np.abs(again - gl).max() < 1e-9


def test_llffhold_8_and_names_sorted(tmp_path):
    names = [f"IMG_{k}.png" for k in np.random.default_rng(3).permutation(np.arange(100, 117))]
    c2ws = level_rig(17)
    pixels = write_llff(tmp_path / "s", c2ws, names=names, factors=(8,))
    ds = load_llff(tmp_path / "s")
    order = sorted(names)
    assert [v.name for v in ds.views] == order
    assert [v.name for v in ds.split_views("test")] == [order[0], order[8], order[16]]
    assert len(ds.split_views("train")) == 14
    # row i of poses_bounds.npy is the i-th name in sorted order
    sc = 1.0 / (2.0 * 0.75)
    assert np.allclose(ds.views[8].camera.center, c2ws[8][:3, 3] * sc)
    test = ds.load_split("test")
    assert test.rgba.shape == (3, 6, 8, 4) and np.all(test.rgba[..., 3] == 1) and test.depth is None
    assert np.array_equal(np.round(test.srgb[1, ..., :3] * 255).astype(np.uint8), pixels[8][order[8]])


def _rows(root: Path) -> np.ndarray:
    return np.load(root / "poses_bounds.npy")


@pytest.mark.parametrize("case", ["missing_folder", "count", "not_rotation", "reflection", "shape", "bounds",
                                  "size", "no_poses"])
def test_bad_input_is_refused_in_one_line_naming_the_file(tmp_path, case):
    root = tmp_path / "s"
    write_llff(root, level_rig(4), factors=(8,))
    rows = _rows(root)
    factor, expect = None, None
    if case == "missing_folder":
        factor, expect = 4, r"images_4: missing .*folders present: images_8"
    elif case == "count":
        (root / "images_8" / "image003.png").unlink()
        expect = r"images_8: 3 images, but .*poses_bounds.npy holds 4 poses"
    elif case == "not_rotation":
        M = rows[2, :15].reshape(3, 5)
        M[:, 0] *= 1.001  # a scaled axis
        rows[2, :15] = M.reshape(-1)
        expect = r"poses_bounds.npy: row 2 \(image002.png\): the 3x3 pose part is not a rotation"
    elif case == "reflection":
        M = rows[1, :15].reshape(3, 5)
        M[:, [0, 1]] = M[:, [1, 0]]  # (right, down, back): left-handed
        rows[1, :15] = M.reshape(-1)
        expect = r"row 1 \(image001.png\): the 3x3 pose part is not a rotation.*det"
    elif case == "shape":
        rows = rows[:, :15]
        expect = r"poses_bounds.npy: expected an \(N, 17\) array"
    elif case == "bounds":
        rows[3, 15:] = [5.0, 4.0]
        expect = r"row 3: bounds must satisfy 0 < near < far"
    elif case == "size":
        io.write_png_u8(root / "images_8" / "image001.png", np.zeros((9, 8, 3), np.uint8))
        expect = r"image001.png: image is 8x9, but .* expects about 8x6"
    elif case == "no_poses":
        (root / "poses_bounds.npy").unlink()
        expect = r"poses_bounds.npy: missing"
    if case not in ("no_poses",):
        np.save(root / "poses_bounds.npy", rows)
    with pytest.raises(DatasetError, match=expect) as e:
        load_llff(root, factor=factor)
    assert "\n" not in str(e.value)


def test_poses_bounds_beside_sparse_is_llff_unless_colmap_is_asked_for(tmp_path):
    root = tmp_path / "fern"
    write_llff(root, level_rig(3), factors=(8,))
    (root / "sparse" / "0").mkdir(parents=True)  # as the LLFF release: cameras.bin, points3D.bin, no images.bin
    assert detect_format(root) == "llff"
    assert open_dataset(root, "llff").format == "llff"
    with pytest.raises(DatasetError, match="sparse"):
        open_dataset(root, "colmap")


def test_ndc_box_holds_every_pixel_ray_and_depth_is_the_ndc_parameter(tmp_path):
    from research.nerf.render import camera_rays

    write_llff(tmp_path / "s", level_rig(4), factors=(8,))
    ds = load_llff(tmp_path / "s")
    box = ds.ndc.bbox_for([v.camera for v in ds.views])
    assert box[0, 2] == -1 and box[1, 2] == 1 and np.all(box[0, :2] < -1) and np.all(box[1, :2] > 1)
    for v in ds.views:
        o, u, zs = camera_rays(v.camera, np.float64, ds.ndc)
        assert np.allclose(o[:, 2], -1.0) and np.allclose(np.linalg.norm(u, axis=1), 1.0)
        for t in (0.0, 1.0):  # every ray from the near plane to infinity stays in the box
            p = o + (t / zs)[:, None] * u
            assert np.all(p >= box[0] - 1e-12) and np.all(p <= box[1] + 1e-12)
        # a world point X on a pixel's ray sits at NDC parameter t = 1 + near / X_z (linear in disparity),
        # i.e. at o' + t d' with d' = u / z_scale; the renderer's depth (z_scale per unit) is that t
        ow, dw = v.camera.rays(normalize=False)
        X = (ow + 3.7 * dw).reshape(-1, 3)
        t = 1.0 + 1.0 / X[:, 2]
        assert np.allclose(ds.ndc.points(X), o + (t / zs)[:, None] * u, atol=1e-12)


def test_frustum_init_points_lie_between_the_bounds(tmp_path):
    from research.splats.model import points_in_frusta

    write_llff(tmp_path / "s", level_rig(4), factors=(8,))
    ds = load_llff(tmp_path / "s")
    train = ds.load_split("train")
    idx = [i for i, v in enumerate(ds.views) if v.split == "train"]
    pts, cols = points_in_frusta(train.cameras, train.rgba, ds.near_far[idx], 2000, seed=0)
    assert pts.shape == cols.shape == (2000, 3) and cols.min() >= 0 and cols.max() <= 1
    inside = np.zeros(len(pts), bool)
    for cam, (n, f) in zip(train.cameras, ds.near_far[idx]):
        uv, z = cam.project(pts)
        ok = (z >= n - 1e-9) & (z <= f + 1e-9) & (uv[:, 0] >= 0) & (uv[:, 0] <= cam.width) & \
            (uv[:, 1] >= 0) & (uv[:, 1] <= cam.height)
        inside |= ok
    assert inside.all()
    assert np.all(pts >= ds.bbox[0] - 1e-9) and np.all(pts <= ds.bbox[1] + 1e-9)


@pytest.mark.timeout(240)
@pytest.mark.parametrize("experiment", ["fit_splats", "fit_nerf"])
def test_experiment_smoke_on_an_llff_folder(tmp_path, experiment):
    root = tmp_path / "fern"
    write_llff(root, level_rig(9), full=(128, 96), focal=100.0, factors=(8,))
    m, out = smoke_run(experiment, root, tmp_path)
    assert m["data"]["format"] == "llff" and m["data"]["protocol"] == "llff"
    assert m["data"]["resolution"] == "images_8 (16x12)" and "llffhold 8" in m["eval_protocol"]
    if experiment == "fit_splats":
        assert m["init"] == "frustum" and math.isfinite(m["test_psnr"])
    else:
        assert m["dataset"]["ndc"]["near"] == 1.0 and m["dataset"]["bbox"][0][2] == -1.0
        assert "in NDC" in (out / "table.md").read_text()
        assert math.isfinite(m["fields"]["grid"]["eval"]["mean"]["psnr"])


def test_upper_case_jpg_names_and_float32_poses_bounds(tmp_path):
    """fern's layout: IMG_xxxx.JPG names (upper-case extension) and poses_bounds.npy stored as float32 or
    float64; the float32 file gives the same cameras to float32 precision."""
    root = tmp_path / "fern"
    write_llff(root, level_rig(9), factors=(8,), names=[f"IMG_{4026 + i}.JPG" for i in range(9)])
    ds64 = load_llff(root)
    pb = root / "poses_bounds.npy"
    np.save(pb, np.load(pb).astype(np.float32))
    ds32 = load_llff(root)
    assert [v.name for v in ds32.views] == [f"IMG_{4026 + i}.JPG" for i in range(9)]
    for a, b in zip(ds64.views, ds32.views):
        assert np.abs(a.camera.c2w - b.camera.c2w).max() < 1e-6 and np.abs(a.camera.K - b.camera.K).max() < 1e-6
    assert ds32.load_split("test").rgba.shape == (2, 6, 8, 4)


def test_a_mipnerf360_folder_with_poses_bounds_is_read_as_colmap(tmp_path):
    """Mip-NeRF 360's scenes ship poses_bounds.npy beside sparse/0: cameras all around the object are not
    a forward-facing (NDC) capture, so the folder is detected as COLMAP; a forward-facing one stays LLFF."""
    from tests.research.realdata_fixtures import write_colmap

    root = tmp_path / "garden"
    cams = write_colmap(root, n=9, factors=(1, 4))
    rows = np.stack([llff_row(c.c2w, (12.0, 16.0, 18.0), 1.0, 10.0) for c in cams])
    np.save(root / "poses_bounds.npy", rows)
    assert detect_format(root) == "colmap"
    assert open_dataset(root, detect_format(root)).format == "colmap"
    assert open_dataset(root, "llff", 4).format == "llff"  # still readable as LLFF when asked for
    fern = tmp_path / "fern"
    write_llff(fern, level_rig(3), factors=(8,))
    write_colmap(fern, n=3, factors=())
    assert detect_format(fern) == "llff"
