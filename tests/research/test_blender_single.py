"""nerfstudio's single transforms.json (no split files): research.datasets.blender's split rule."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from research.datasets import DatasetError, detect_format, load_blender, open_dataset

sys.path.insert(0, str(Path(__file__).parent))
from realdata_fixtures import ring_cameras, write_rgba  # noqa: E402


def write_single(root: Path, n: int, size: int = 16, shuffle: bool = True, seed: int = 0):
    """A nerfstudio folder: images/frame_<k>.png and one transforms.json with global intrinsics, its frames
    listed out of order (nerfstudio sorts them by file_path); returns the cameras in name order."""
    rng = np.random.default_rng(seed)
    cams = ring_cameras(n, size, size)
    frames = []
    for k, cam in enumerate(cams):
        write_rgba(root / "images" / f"frame_{k:05d}.png", rng, size, size, alpha=False)
        frames.append({"file_path": f"images/frame_{k:05d}.png", "transform_matrix": cam.to_nerf().tolist()})
    order = rng.permutation(n) if shuffle else np.arange(n)
    doc = {"fl_x": cams[0].fx, "fl_y": cams[0].fy, "cx": cams[0].cx, "cy": cams[0].cy, "w": size, "h": size,
           "camera_model": "OPENCV", "frames": [frames[i] for i in order]}
    (root / "transforms.json").write_text(json.dumps(doc, indent=1))
    return cams


def test_single_transforms_every_8th_frame_by_name_is_test(tmp_path):
    cams = write_single(tmp_path / "capture", 19)
    assert detect_format(tmp_path / "capture") == "blender"
    ds = open_dataset(tmp_path / "capture", "blender")
    assert ds.protocol.name == "nerfstudio-interval8"
    test, train = ds.split_views("test"), ds.split_views("train")
    assert len(test) == 3 and len(train) == 16  # frames 0, 8, 16 of 19
    by_split = {"test": [0, 8, 16], "train": [k for k in range(19) if k % 8]}
    for split, views in (("test", test), ("train", train)):
        for v, k in zip(views, by_split[split]):
            assert np.abs(v.camera.c2w - cams[k].c2w).max() < 1e-9 and np.abs(v.camera.K - cams[k].K).max() < 1e-9
    pixels = ds.load_split("test")
    assert pixels.rgba.shape == (3, 16, 16, 4) and np.all(pixels.rgba[..., 3] == 1.0)


def test_split_files_win_over_a_single_transforms_json(tmp_path):
    write_single(tmp_path / "capture", 9)
    single = load_blender(tmp_path / "capture")
    doc = json.loads((tmp_path / "capture" / "transforms.json").read_text())
    for split, frames in (("train", doc["frames"][:6]), ("test", doc["frames"][6:])):
        (tmp_path / "capture" / f"transforms_{split}.json").write_text(json.dumps({**doc, "frames": frames}))
    split_files = load_blender(tmp_path / "capture")
    assert len(single.split_views("test")) == 2 and len(split_files.split_views("test")) == 3
    assert split_files.protocol.name == "nerf-synthetic"


def test_single_transforms_json_with_one_frame_is_refused(tmp_path):
    write_single(tmp_path / "capture", 1)
    with pytest.raises(DatasetError, match=r"transforms\.json: 1 frame; the split"):
        load_blender(tmp_path / "capture")
