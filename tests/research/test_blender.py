"""NeRF-synthetic / nerfstudio folders (research.datasets.blender), and fit_splats/fit_nerf on them."""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from research import io
from research.datasets import detect_format, load_blender
from research.datasets.formats import protocol_target_linear, protocol_target_srgb
from research.metrics import srgb_on_black

sys.path.insert(0, str(Path(__file__).parent))
from realdata_fixtures import smoke_run, write_blender  # noqa: E402


@pytest.mark.parametrize("variant", [None, "global", "frame"], ids=["camera_angle_x", "nerfstudio-global",
                                                                     "nerfstudio-per-frame"])
def test_cameras_round_trip_to_1e9(tmp_path, variant):
    cams = write_blender(tmp_path / "lego", nerfstudio=variant)
    ds = load_blender(tmp_path / "lego")
    assert ds.format == "blender" and ds.scene == "lego" and detect_format(tmp_path / "lego") == "blender"
    for split, expected in cams.items():
        views = ds.split_views(split)
        assert len(views) == len(expected)
        for v, c in zip(views, expected):
            assert np.abs(v.camera.c2w - c.c2w).max() < 1e-9 and np.abs(v.camera.K - c.K).max() < 1e-9
            assert np.abs(v.camera.to_nerf() - c.to_nerf()).max() < 1e-9  # and back to OpenGL


def test_official_float32_precision_is_read_and_the_cameras_accept_it(tmp_path):
    """transform_matrix stored as the official files store it (float32 values; one frame off orthonormal by
    1.25e-6 like lego's frame 88, which the old 1e-6 checks refused): the reader accepts it, the cameras
    come back orthonormal to 1e-15 within storage precision of the written ones, and the splatting and
    ray cameras accept both the reader's view matrices and the raw float32 ones."""
    from kernels.rotation import orthonormality_error
    from kernels.splat import SplatCamera
    from kernels.volume.rays import check_camera
    from research.splats.model import splat_camera

    cams = write_blender(tmp_path / "lego", float32=True)
    doc = json.loads((tmp_path / "lego" / "transforms_train.json").read_text())
    raw = [np.asarray(f["transform_matrix"], dtype=np.float64) for f in doc["frames"]]
    assert all(np.array_equal(M, M.astype(np.float32)) for M in raw)  # float32 values, as in the official file
    errs = [orthonormality_error(M[:3, :3]) for M in raw]
    assert 1.1e-6 < errs[0] < 1.4e-6 and max(errs[1:]) < 2e-7  # frame 0: the lego frame 88 case
    ds = load_blender(tmp_path / "lego")
    for split, expected in cams.items():
        for v, c in zip(ds.split_views(split), expected):
            assert orthonormality_error(v.camera.R) < 1e-15
            assert np.abs(v.camera.c2w - c.c2w).max() < 3e-6 and np.abs(v.camera.K - c.K).max() < 1e-9
            sc = splat_camera(v.camera)
            assert orthonormality_error(sc.viewmat[:3, :3]) < 1e-15
    # the raw float32 matrix, as a caller might hand it over: OpenGL c2w -> OpenCV w2c, inverted as a rigid map
    c2w = raw[0] @ np.diag([1.0, -1.0, -1.0, 1.0])
    w2c = np.eye(4)
    w2c[:3, :3] = c2w[:3, :3].T
    w2c[:3, 3] = -c2w[:3, :3].T @ c2w[:3, 3]
    assert orthonormality_error(w2c[:3, :3]) > 1e-6
    cam0 = ds.split_views("train")[0].camera
    sc = SplatCamera(w2c, cam0.K, cam0.width, cam0.height)
    assert orthonormality_error(sc.viewmat[:3, :3]) < 1e-15 and np.abs(sc.viewmat - w2c).max() < 3e-6
    M, _ = check_camera(w2c, [cam0.fx, cam0.fy, cam0.cx, cam0.cy])
    assert orthonormality_error(M[:3, :3]) < 1e-15 and np.abs(M - w2c).max() < 3e-6


def test_pixels_white_protocol_and_linear_contract(tmp_path):
    write_blender(tmp_path / "lego")
    ds = load_blender(tmp_path / "lego")
    assert ds.protocol.name == "nerf-synthetic" and ds.protocol.background == (1.0, 1.0, 1.0)
    split = ds.load_split("test")
    raw = io.read_png_u8(tmp_path / "lego" / "test" / "r_0.png").astype(np.float64) / 255.0
    assert np.abs(split.srgb[0] - raw).max() < 1e-7
    # the Split contract: linear, premultiplied
    expected = io.srgb_to_linear(raw[..., :3]) * raw[..., 3:]
    assert np.abs(split.rgba[0, ..., :3] - expected).max() < 1e-6
    # the NeRF/3DGS target: sRGB composited on white in sRGB
    target = raw[..., :3] * raw[..., 3:] + (1.0 - raw[..., 3:])
    assert np.abs(protocol_target_srgb(split, ds.protocol)[0] - target).max() < 1e-6
    assert np.all(protocol_target_srgb(split, ds.protocol)[0, :3] == 1.0)  # the transparent band is white
    lin = protocol_target_linear(split, ds.protocol)
    assert np.abs(srgb_on_black(lin[0]) - target).max() < 1e-5  # what metrics compares gives the target back


def test_downscale_is_a_box_average_with_scaled_intrinsics(tmp_path):
    write_blender(tmp_path / "lego")
    full, half = load_blender(tmp_path / "lego"), load_blender(tmp_path / "lego", factor=2)
    a, b = full.split_views("train")[0].camera, half.split_views("train")[0].camera
    assert (b.width, b.height) == (8, 8) and abs(b.fx - a.fx / 2) < 1e-12 and abs(b.cx - a.cx / 2) < 1e-12
    big, small = full.load_split("train").srgb[0], half.load_split("train").srgb[0]
    assert np.abs(small - big.reshape(8, 2, 8, 2, 4).mean(axis=(1, 3))).max() < 1e-6


def test_bound_declared_or_from_the_cameras(tmp_path):
    write_blender(tmp_path / "lego")
    ds = load_blender(tmp_path / "lego")
    # cameras at radius ~4.1 looking at the origin with a 50 degree field: the box is centred near it
    assert np.abs(ds.bbox.mean(axis=0)).max() < 0.3
    half = (ds.bbox[1] - ds.bbox[0]) / 2
    assert np.allclose(half, half[0]) and 1.5 < half[0] < 2.2
    doc = json.loads((tmp_path / "lego" / "transforms_train.json").read_text())
    doc["aabb"] = [[-1, -2, -3], [1, 2, 3]]
    (tmp_path / "lego" / "transforms_train.json").write_text(json.dumps(doc))
    assert load_blender(tmp_path / "lego").bbox.tolist() == [[-1, -2, -3], [1, 2, 3]]


def test_content_hash_follows_the_files(tmp_path):
    write_blender(tmp_path / "lego")
    h1 = load_blender(tmp_path / "lego").manifest["content_hash"]
    assert load_blender(tmp_path / "lego").manifest["content_hash"] == h1
    img = io.read_png_u8(tmp_path / "lego" / "test" / "r_1.png")
    img[5, 5, 0] ^= 1
    io.write_png_u8(tmp_path / "lego" / "test" / "r_1.png", img)
    assert load_blender(tmp_path / "lego").manifest["content_hash"] != h1


def test_a_folder_given_by_a_relative_path_or_through_a_link(tmp_path, monkeypatch):
    """The same dataset (cameras, content hash) whether the folder is named absolutely, relatively or
    through a symbolic link to it (a data/ folder of links to the datasets is a common layout)."""
    write_blender(tmp_path / "real" / "lego")
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "lego").symlink_to(tmp_path / "real" / "lego", target_is_directory=True)
    want = load_blender(tmp_path / "real" / "lego")
    monkeypatch.chdir(tmp_path)
    for path in (Path("real/lego"), tmp_path / "data" / "lego", Path("data/lego")):
        got = load_blender(path)
        assert got.manifest["content_hash"] == want.manifest["content_hash"], path
        assert [v.name for v in got.views] == [v.name for v in want.views]
        np.testing.assert_array_equal(got.views[0].camera.c2w, want.views[0].camera.c2w)
        np.testing.assert_array_equal(got.load_split("test").rgba, want.load_split("test").rgba)


@pytest.mark.timeout(240)
@pytest.mark.parametrize("experiment", ["fit_splats", "fit_nerf"])
def test_experiment_smoke_on_a_blender_folder(tmp_path, experiment):
    write_blender(tmp_path / "lego", views={"train": 5, "test": 2})
    m, out = smoke_run(experiment, tmp_path / "lego", tmp_path, fields=("grid", "pe_mlp"))
    assert m["data"]["format"] == "blender" and m["data"]["scene"] == "lego"
    assert m["data"]["protocol"] == "nerf-synthetic" and m["data"]["background"] == [1.0, 1.0, 1.0]
    assert m["eval_protocol"].startswith("NeRF-synthetic protocol") and "white" in m["eval_protocol"]
    table = (out / "table.md").read_text()
    assert "lego" in table and "NeRF-synthetic protocol" in table
    if experiment == "fit_splats":
        assert m["init"] == "random" and math.isfinite(m["test_psnr"]) and m["test_psnr"] > 5
    else:
        assert m["noise_floor"] is None
        assert all(math.isfinite(f["eval"]["mean"]["psnr"]) and "depth_mae" not in f["eval"]["mean"]
                   for f in m["fields"].values())


def test_a_drlab_dataset_read_as_blender_agrees_with_the_drlab_loader(tmp_path):
    """`drlab dataset` writes NeRF-synthetic transforms: both readers give the same cameras and box."""
    from research.datasets import DatasetConfig, generate, load

    root = generate(DatasetConfig("spheres", views=3, res=24, spp=2, seed=1), tmp_path / "ds", show_progress=False)
    assert detect_format(root) == "drlab"
    ours, theirs = load(root), load_blender(root)
    for split in ("train", "val", "test"):
        a, b = ours.split_views(split), theirs.split_views(split)
        assert len(a) == len(b)
        for u, v in zip(a, b):
            assert np.abs(u.camera.c2w - v.camera.c2w).max() < 1e-9 and np.abs(u.camera.K - v.camera.K).max() < 1e-9
    assert np.array_equal(ours.bbox, theirs.bbox)  # the scene box declared in cameras.json
    # pixels: the PNG (8-bit sRGB of the EXR, straight alpha, colour clipped to [0, 1]) agrees with the EXR
    # up to 8-bit quantisation, in linear premultiplied values (the Split contract of both readers)
    s_png, s_exr = theirs.load_split("train"), ours.load_split("train")
    a = s_exr.rgba[..., 3:]
    expected = np.clip(np.where(a > 0, s_exr.rgba[..., :3] / np.maximum(a, 1e-12), 0.0), 0.0, 1.0) * a
    # bound: sRGB step 0.5/255 times the steepest slope of the decoding curve (2.27) plus alpha step 0.5/255
    assert np.abs(s_png.rgba[..., :3] - expected).max() < 0.5 / 255 * 2.27 + 0.5 / 255 + 1e-6
    assert np.abs(s_png.rgba[..., 3] - s_exr.rgba[..., 3]).max() <= 0.5 / 255 + 1e-6


@pytest.mark.parametrize("model,keys,lens_model", [
    ("OPENCV", {"k1": -0.12, "k2": 0.03, "p1": 0.002, "p2": -0.001}, "opencv"),
    ("OPENCV", {"k1": -0.1, "k2": 0.02, "k3": 0.004, "p1": 0.001, "p2": 0.0}, "opencv"),
    ("OPENCV_FISHEYE", {"k1": 0.05, "k2": -0.01, "k3": 0.002, "k4": -0.0005}, "fisheye"),
    (None, {"is_fisheye": True, "k1": 0.05, "k2": -0.01}, "fisheye"),  # instant-ngp's colmap2nerf
], ids=["opencv", "opencv-k3", "fisheye", "instant-ngp-fisheye"])
def test_nerfstudio_distortion_is_read_as_the_lens(tmp_path, model, keys, lens_model):
    """nerfstudio's camera_model and k1..k4, p1, p2 (what colmap2nerf / ns-process-data write): the cameras
    carry the lens and project as OpenCV does (cv2.projectPoints, cv2.fisheye.projectPoints)."""
    import cv2

    root = tmp_path / "ns"
    write_blender(root, nerfstudio="global")
    for split in ("train", "val", "test"):
        p = root / f"transforms_{split}.json"
        doc = json.loads(p.read_text())
        p.write_text(json.dumps({**doc, **({"camera_model": model} if model else {}), **keys}))
    ds = load_blender(root, factor=2)
    X = np.random.default_rng(3).uniform(-0.8, 0.8, (20, 3))
    for v in ds.views:
        cam = v.camera
        assert cam.lens is not None and cam.lens.model == lens_model and cam.width == 8
        xc = (X - cam.center) @ cam.R  # camera-frame points (OpenCV frame)
        K = cam.K
        if lens_model == "fisheye":
            d = np.array([keys.get(k, 0.0) for k in ("k1", "k2", "k3", "k4")])
            uv = cv2.fisheye.projectPoints(xc[None], np.zeros(3), np.zeros(3), K, d)[0][0]
        else:
            d = np.array([keys.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")])
            uv = cv2.projectPoints(xc, np.zeros(3), np.zeros(3), K, d)[0][:, 0]
        np.testing.assert_allclose(cam.project(X)[0], uv, rtol=0, atol=1e-6)


@pytest.mark.parametrize("extra,message", [
    ({"camera_model": "EQUIRECTANGULAR"}, r"frame 0: camera_model 'EQUIRECTANGULAR' is not supported \(expected one "
                                          r"of OPENCV, .*OPENCV_FISHEYE\)"),
    ({"camera_model": "OPENCV", "k1": 0.1, "k4": 0.01}, r"frame 0: k4 = 0.01 \(nerfstudio's r\^8 radial term\) is "
                                                         r"not supported for a perspective camera"),
    ({"camera_model": "OPENCV_FISHEYE", "p1": 0.01}, r"frame 0: p1, p2 = 0.01, 0: a OPENCV_FISHEYE camera has no "
                                                      r"tangential terms"),
    ({"k1": "0.1"}, r"frame 0: k1 must be a finite number, got '0.1'"),
], ids=["equirectangular", "perspective-k4", "fisheye-tangential", "k1-text"])
def test_nerfstudio_lenses_drlab_cannot_hold_are_refused(tmp_path, extra, message):
    root = tmp_path / "ns"
    write_blender(root, nerfstudio="global")
    p = root / "transforms_train.json"
    p.write_text(json.dumps({**json.loads(p.read_text()), **extra}))
    with pytest.raises(ValueError, match=re.escape(str(p)) + ": " + message):
        load_blender(root)


def test_file_path_spellings_extra_keys_and_rgb_pngs(tmp_path):
    """file_path with and without "./" and ".png" (the NeRF loader appends ".png"; nerfstudio writes it),
    extra per-frame keys (rotation, time), and an RGB PNG among the RGBA ones (read as opaque)."""
    from realdata_fixtures import write_rgba

    root = tmp_path / "lego"
    cams = write_blender(root, float32=True)
    for split in ("train", "val", "test"):
        p = root / f"transforms_{split}.json"
        doc = json.loads(p.read_text())
        for i, frame in enumerate(doc["frames"]):
            frame["file_path"] = [frame["file_path"][2:], frame["file_path"] + ".png", frame["file_path"]][i % 3]
            frame["time"] = 0.25 * i
        p.write_text(json.dumps(doc))
    write_rgba(root / "train" / "r_1.png", np.random.default_rng(9), 16, 16, alpha=False)
    ds = load_blender(root)
    for split, expected in cams.items():
        for v, c in zip(ds.split_views(split), expected):
            assert np.abs(v.camera.c2w - c.c2w).max() < 1e-5 and np.abs(v.camera.K - c.K).max() < 1e-9
    train = ds.load_split("train")
    assert train.rgba.shape == (4, 16, 16, 4) and np.all(train.rgba[1, ..., 3] == 1.0)


def test_instant_ngp_camera_angle_y_gives_fl_y(tmp_path):
    """instant-ngp's transforms: camera_angle_x and camera_angle_y (non-square pixels), no fl_x / fl_y."""
    root = tmp_path / "ngp"
    write_blender(root)
    fy = 20.0
    for split in ("train", "val", "test"):
        p = root / f"transforms_{split}.json"
        p.write_text(json.dumps({**json.loads(p.read_text()), "camera_angle_y": 2 * math.atan(8.0 / fy)}))
    ds = load_blender(root)
    angle_x = json.loads((root / "transforms_train.json").read_text())["camera_angle_x"]
    for v in ds.views:
        assert v.camera.fy == pytest.approx(fy, rel=1e-12)
        assert v.camera.fx == pytest.approx(8.0 / math.tan(angle_x / 2), rel=1e-12)
