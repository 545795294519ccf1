"""COLMAP / Mip-NeRF 360 folders (research.datasets.colmap): fixtures written by pycolmap's own writer."""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from research.cameras import look_at
from research.datasets import detect_format, load_colmap
from research.datasets.colmap import c2w_from_colmap, colmap_from_c2w, default_factor

sys.path.insert(0, str(Path(__file__).parent))
from realdata_fixtures import COLMAP_PARAMS, smoke_run, write_colmap  # noqa: E402


def test_pose_conversion_both_directions_to_1e9():
    rng = np.random.default_rng(1)
    for _ in range(20):
        c2w = look_at(rng.normal(size=3) * 3, rng.normal(size=3) * 0.1)
        R, t = colmap_from_c2w(c2w)
        assert np.abs(c2w_from_colmap(R, t) - c2w).max() < 1e-9
        # cam_from_world maps the camera centre to the origin and the look direction to +z
        assert np.abs(R @ c2w[:3, 3] + t).max() < 1e-9 and np.abs(R @ c2w[:3, 2] - [0, 0, 1]).max() < 1e-9
        R2, t2 = colmap_from_c2w(c2w_from_colmap(R, t))
        assert np.abs(R2 - R).max() < 1e-9 and np.abs(t2 - t).max() < 1e-9


@pytest.mark.parametrize("text", [False, True], ids=["binary", "text"])
@pytest.mark.parametrize("model", list(COLMAP_PARAMS))
def test_each_model_binary_and_text_reads_back_to_1e9(tmp_path, model, text):
    root = tmp_path / "scene"
    cams = write_colmap(root, model=model, text=text, factors=(1,))
    assert detect_format(root) == "colmap"
    ds = load_colmap(root)
    p = COLMAP_PARAMS[model]
    fx, fy, cx, cy = (p[0], p[0], p[1], p[2]) if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL") else p[:4]
    assert len(ds.views) == len(cams)
    for v, c in zip(ds.views, cams):  # names img_00 ... sort as the cameras
        assert np.abs(v.camera.c2w - c.c2w).max() < 1e-9
        assert np.allclose(v.camera.K, [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], atol=1e-12, rtol=0)
    assert ds.points.shape == (50, 3) and ds.point_colors.shape == (50, 3)
    assert ds.point_colors.min() >= 0 and ds.point_colors.max() <= 1


def test_llffhold_split_factor_and_points_bound(tmp_path):
    root = tmp_path / "garden"  # an outdoor Mip-NeRF 360 scene: images_4 by default
    write_colmap(root, n=17, width=64, height=48, factors=(1, 2, 4))
    ds = load_colmap(root)
    assert default_factor("garden") == 4 and default_factor("room") == 2 and default_factor("mine") == 1
    assert [v.name for v in ds.split_views("test")] == ["img_00.png", "img_08.png", "img_16.png"]
    assert len(ds.split_views("train")) == 14 and ds.protocol.name == "mipnerf360"
    assert "images_4" in ds.protocol.description and ds.protocol.background is None
    cam = ds.split_views("test")[0].camera
    assert (cam.width, cam.height) == (16, 12) and abs(cam.fx - 18.0 / 4) < 1e-12
    full = load_colmap(root, factor=1).split_views("test")[0].camera
    assert np.abs(full.c2w - cam.c2w).max() == 0 and (full.width, full.height) == (64, 48)
    # bound: the 1st-99th percentile box of the points (uniform in [-1, 1]^3), padded 5 %
    assert np.all(ds.bbox[0] > -1.2) and np.all(ds.bbox[0] < -0.8) and np.all(ds.bbox[1] > 0.8)
    split = ds.load_split("test")
    assert split.rgba.shape == (3, 12, 16, 4) and np.all(split.rgba[..., 3] == 1) and split.depth is None


def test_rounded_images_n_sizes_are_accepted(tmp_path):
    root = tmp_path / "scene"
    write_colmap(root, width=18, height=14, factors=(1, 4))  # images_4 at ceil(18/4) x ceil(14/4) = 5 x 4
    cam = load_colmap(root, factor=4).views[0].camera
    assert (cam.width, cam.height) == (5, 4) and abs(cam.fx - 18.0 * 5 / 18) < 1e-12


@pytest.mark.timeout(240)
@pytest.mark.parametrize("experiment", ["fit_splats", "fit_nerf"])
def test_experiment_smoke_on_a_mipnerf360_folder(tmp_path, experiment):
    root = tmp_path / "bonsai"  # indoor: images_2
    write_colmap(root, n=9, width=32, height=24, factors=(1, 2), text=True)
    m, out = smoke_run(experiment, root, tmp_path)
    assert m["data"]["format"] == "colmap" and m["data"]["scene"] == "bonsai"
    assert m["data"]["protocol"] == "mipnerf360" and m["data"]["resolution"] == "images_2 (16x12)"
    assert "llffhold 8" in m["eval_protocol"] and "bonsai" in (out / "table.md").read_text()
    if experiment == "fit_splats":
        assert m["init"] == "sfm" and m["init_points"] == 50 and math.isfinite(m["test_psnr"])
    else:
        assert "from the SfM points" in (out / "table.md").read_text()
        assert m["dataset"]["bbox"] == json.loads(json.dumps(load_colmap(root).bbox.tolist()))


def test_comparison_refuses_rows_of_another_protocol(tmp_path):
    from research import comparison

    row = dict(method="m", ssim=0.5, psnr=20.0, train_s=1.0, fps=1.0, size_bytes=1, size_note="x", device="cpu")
    a = comparison.MethodRow(**row, eval_protocol="Mip-NeRF 360 protocol (3DGS): ...", dataset_hash="h",
                             dataset="bonsai (colmap, mipnerf360)")
    b = comparison.MethodRow(**row, eval_protocol="NeRF-synthetic protocol: ...", dataset_hash="h",
                             dataset="bonsai (colmap, mipnerf360)")
    with pytest.raises(ValueError, match="evaluation protocols differ"):
        comparison.comparison_table([a, b])
    c = comparison.MethodRow(**{**row, "method": "n"}, eval_protocol=a.eval_protocol, dataset_hash="h",
                             dataset="lego (blender, nerf-synthetic)")
    with pytest.raises(ValueError, match="dataset labels differ"):
        comparison.comparison_table([a, c])
    assert "`bonsai (colmap, mipnerf360)`" in comparison.comparison_table([a, a])


def test_jpeg_photographs_as_in_mipnerf360(tmp_path):
    """Mip-NeRF 360's images are JPEGs named like _DSC8679.JPG: read as opaque sRGB through OpenImageIO."""
    import OpenImageIO as oiio
    import pycolmap

    root = tmp_path / "stump"
    write_colmap(root, n=3, factors=(1,), width=16, height=12)
    d = root / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(d))
    rng = np.random.default_rng(0)
    pixels = {}
    for image in rec.images.values():
        image.name = image.name.replace(".png", ".JPG")
        yy, xx = np.mgrid[0:12, 0:16]
        base = rng.uniform(40, 200, 3)  # a smooth ramp: JPEG keeps it (it would smear random noise)
        img = np.clip(base + np.stack([4 * xx, 5 * yy, 2 * (xx + yy)], -1), 0, 255).astype(np.uint8)
        spec = oiio.ImageSpec(16, 12, 3, "uint8")
        spec.attribute("Compression", "jpeg:100")
        out = oiio.ImageOutput.create(str(root / "images" / image.name))
        assert out.open(str(root / "images" / image.name), spec)
        assert out.write_image(img) and out.close()
        pixels[image.name] = img
    rec.write_binary(str(d))
    ds = load_colmap(root, factor=1)
    split = ds.load_split("test")
    assert split.names[0].endswith("img_00.JPG") and np.all(split.srgb[..., 3] == 1)
    # JPEG (lossy, chroma subsampled) of a smooth ramp: within a few levels of the written pixels
    assert np.abs(split.srgb[0, ..., :3] * 255 - pixels["img_00.JPG"]).max() < 6


def test_hand_written_text_model_as_colmap_writes_and_users_edit_it(tmp_path):
    """A text model written by hand as COLMAP's format allows: comment and blank lines, CRLF line ends,
    two cameras shared by nine images, image ids out of order, POINTS2D lines empty or not, image names
    in sub-folders (cam0/0001.png), no rigs.txt / frames.txt (models of COLMAP before 3.12), and an
    extra model under sparse/1 (sparse/0 is read)."""
    from scipy.spatial.transform import Rotation

    from realdata_fixtures import ring_cameras, write_rgba

    root = tmp_path / "scene"
    d = root / "sparse" / "0"
    d.mkdir(parents=True)
    (root / "sparse" / "1").mkdir()
    (d / "cameras.txt").write_text("# Camera list with one line of data per camera:\r\n#   CAMERA_ID, MODEL, WIDTH, "
                                   "HEIGHT, PARAMS[]\r\n\r\n1 PINHOLE 16 12 18 19 8.5 5.5\r\n"
                                   "2 SIMPLE_PINHOLE 16 12 17 8 6\r\n")
    cams, rng = ring_cameras(9, 16, 12), np.random.default_rng(0)
    lines = ["# Image list with two lines of data per image:", "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, "
             "NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)", ""]
    for k in (5, 2, 8, 0, 1, 7, 3, 6, 4):
        R, t = colmap_from_c2w(cams[k].c2w)
        x, y, z, w = Rotation.from_matrix(R).as_quat()
        name = f"cam{k % 2}/{k:04d}.png"
        write_rgba(root / "images" / name, rng, 16, 12, alpha=False)
        lines += [" ".join(map(repr, [k + 10, *map(float, (w, x, y, z, *t)), 1 + k % 2])) + f" {name}",
                  "" if k % 3 else "1.5 2.5 -1 3.5 4.5 -1", ""]
    (d / "images.txt").write_text("\n".join(lines) + "\n")
    pts = rng.uniform(-1, 1, (20, 3))
    rows = [f"{i + 1} {x:.17g} {y:.17g} {z:.17g} 10 20 30 0.5" for i, (x, y, z) in enumerate(pts)]
    (d / "points3D.txt").write_text("# 3D point list\n\n" + "\n".join(rows) + "\n")
    ds = load_colmap(root, factor=1)
    names = sorted(f"cam{k % 2}/{k:04d}.png" for k in range(9))
    assert [v.name for v in ds.views] == names
    for v in ds.views:
        k = int(v.name[5:9])
        fx, fy, cx, cy = (18.0, 19.0, 8.5, 5.5) if k % 2 == 0 else (17.0, 17.0, 8.0, 6.0)
        assert np.abs(v.camera.c2w - cams[k].c2w).max() < 1e-9
        np.testing.assert_array_equal(v.camera.K, [[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    np.testing.assert_allclose(np.sort(ds.points, axis=0), np.sort(pts, axis=0), rtol=0, atol=1e-12)
    assert ds.load_split("train").rgba.shape == (7, 12, 16, 4)


@pytest.mark.parametrize("stem,line,bad", [
    ("images", 5, "1 a b c d e f g 1 img_00.png"),  # pose not numbers
    ("images", 5, "1 1 0 0 0 0 0 0 7 img_00.png"),  # a camera id the model lacks
    ("points3D", 4, "1 a b c 1 2 3 0.5"),
    ("cameras", 4, "1 PINHOLE 16 12 18"),  # too few parameters
], ids=["image-pose", "image-camera", "point", "camera-params"])
def test_a_model_pycolmap_refuses_is_named_by_its_file(tmp_path, stem, line, bad):
    from research.datasets import DatasetError

    root = tmp_path / "scene"
    write_colmap(root, n=3, text=True, factors=(1,))
    f = root / "sparse" / "0" / f"{stem}.txt"
    lines = f.read_text().splitlines()
    lines[line - 1] = bad
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=re.escape(f"{f}: pycolmap cannot read the model (")):
        load_colmap(root, factor=1)
