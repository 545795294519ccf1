"""COLMAP models with lens distortion (SIMPLE_RADIAL, RADIAL, OPENCV and the fisheyes OPENCV_FISHEYE,
SIMPLE_RADIAL_FISHEYE, RADIAL_FISHEYE, SIMPLE_FISHEYE, FISHEYE) read as they are:
fixtures written by pycolmap's own writer, binary and text; the cameras carry the lens and project
as COLMAP does; a distorted folder trains through its lens with no undistortion step."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from kernels.lens import Lens
from research.datasets import load_colmap
from research.datasets.colmap import colmap_from_c2w
from research.datasets.integrity import DatasetError

sys.path.insert(0, str(Path(__file__).parent))
from realdata_fixtures import ring_cameras, write_rgba  # noqa: E402

MODELS = {  # params of a 32x24 camera, and the lens drlab should read
    "SIMPLE_RADIAL": ([30.0, 16.0, 12.0, -0.12], Lens("opencv", (-0.12,))),
    "RADIAL": ([30.0, 16.0, 12.0, -0.12, 0.03], Lens("opencv", (-0.12, 0.03))),
    "OPENCV": ([30.0, 31.0, 16.5, 11.5, -0.12, 0.03, 0.002, -0.001], Lens("opencv", (-0.12, 0.03, 0.002, -0.001))),
    "OPENCV_FISHEYE": ([30.0, 31.0, 16.5, 11.5, 0.05, -0.01, 0.002, -0.0005], Lens("fisheye", (0.05, -0.01, 0.002,
                                                                                             -0.0005))),
    "SIMPLE_RADIAL_FISHEYE": ([30.0, 16.0, 12.0, 0.04], Lens("fisheye", (0.04,))),
    "RADIAL_FISHEYE": ([30.0, 16.5, 11.5, 0.04, -0.008], Lens("fisheye", (0.04, -0.008))),
    "SIMPLE_FISHEYE": ([30.0, 16.0, 12.0], Lens("fisheye")),
    "FISHEYE": ([30.0, 31.0, 16.5, 11.5], Lens("fisheye")),
}


def write_model(root: Path, model: str, params: list[float], text: bool, n: int = 9, width: int = 32,
                height: int = 24, factors=(1,)) -> object:
    """A Mip-NeRF 360-style folder with one `model` camera, written by pycolmap; returns the Reconstruction."""
    import pycolmap

    rng = np.random.default_rng(0)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=width, height=height, params=params,
                                                    camera_id=1))
    for k, cam in enumerate(ring_cameras(n, width, height)):
        R, t = colmap_from_c2w(cam.c2w)
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"img_{k:02d}.png", camera_id=1, image_id=k + 1),
                                         pycolmap.Rigid3d(pycolmap.Rotation3d(R), t))
        for f in factors:
            folder = root / ("images" if f == 1 else f"images_{f}")
            write_rgba(folder / f"img_{k:02d}.png", rng, math.ceil(width / f), math.ceil(height / f), alpha=False)
    for p in rng.uniform(-1.0, 1.0, (50, 3)):
        rec.add_point3D(p, pycolmap.Track(), rng.integers(0, 256, 3).astype(np.uint8))
    d = root / "sparse" / "0"
    d.mkdir(parents=True, exist_ok=True)
    (rec.write_text if text else rec.write_binary)(str(d))
    return rec


@pytest.mark.parametrize("text", [False, True], ids=["binary", "text"])
@pytest.mark.parametrize("model", list(MODELS))
def test_distorted_models_are_read_as_they_are(tmp_path, model, text):
    params, lens = MODELS[model]
    rec = write_model(tmp_path / "scene", model, params, text)
    ds = load_colmap(tmp_path / "scene", factor=1)
    cam_c = rec.cameras[1]
    X = np.random.default_rng(1).uniform(-0.8, 0.8, (20, 3))
    for v in ds.views:
        assert v.camera.lens == lens
        image = next(im for im in rec.images.values() if im.name == v.name)
        xc = image.cam_from_world() * X  # COLMAP's own projection of the same points
        uv, _ = v.camera.project(X)
        np.testing.assert_allclose(uv, cam_c.img_from_cam(xc), rtol=0, atol=1e-9)


def test_zero_distortion_is_a_pinhole_and_a_fisheye_is_not(tmp_path):
    write_model(tmp_path / "a", "OPENCV", [30.0, 31.0, 16.5, 11.5, 0.0, 0.0, 0.0, 0.0], text=False)
    assert all(v.camera.lens is None for v in load_colmap(tmp_path / "a", factor=1).views)
    write_model(tmp_path / "b", "OPENCV_FISHEYE", [30.0, 31.0, 16.5, 11.5, 0.0, 0.0, 0.0, 0.0], text=False)
    assert all(v.camera.lens == Lens("fisheye") for v in load_colmap(tmp_path / "b", factor=1).views)


@pytest.mark.parametrize("model,params", [("FULL_OPENCV", [30.0, 31.0, 16.5, 11.5] + [0.01] * 8),
                                          ("FOV", [30.0, 31.0, 16.5, 11.5, 0.9]),
                                          ("THIN_PRISM_FISHEYE", [30.0, 31.0, 16.5, 11.5] + [0.01] * 8),
                                          ("RAD_TAN_THIN_PRISM_FISHEYE", [30.0, 31.0, 16.5, 11.5] + [0.01] * 12)])
@pytest.mark.parametrize("text", [False, True], ids=["binary", "text"])
def test_other_models_are_refused_by_name(tmp_path, model, params, text):
    write_model(tmp_path / "s", model, params, text=text)
    ext = "txt" if text else "bin"
    with pytest.raises(DatasetError, match=rf"cameras\.{ext}: camera 1: camera model {model} is not supported "
                                           r"\(expected one of SIMPLE_PINHOLE, .*, SIMPLE_FISHEYE, FISHEYE\)"):
        load_colmap(tmp_path / "s", factor=1)


def test_a_distorted_folder_trains_through_its_lens(tmp_path):
    from research.splats import model as sm, train as st

    root = tmp_path / "scene"
    write_model(root, "OPENCV_FISHEYE", MODELS["OPENCV_FISHEYE"][0], text=False)
    ds = load_colmap(root, factor=1)
    split = ds.load_split("train")
    assert all(sm.splat_camera(c).lens == MODELS["OPENCV_FISHEYE"][1] for c in split.cameras)
    model = sm.from_points(ds.points, ds.point_colors)
    cfg = st.TrainConfig(iterations=5, log_every=1)
    result = st.train(model, split.cameras, split.rgba[..., :3], sm.scene_extent(split.cameras), cfg, progress=False)
    assert all(math.isfinite(h["loss"]) for h in result.history)
    assert not np.array_equal(result.model.means, model.means)  # the lens route's gradients moved the splats
