"""Reliability of the NeRF-synthetic and COLMAP readers and of fit_splats/fit_nerf on such data.

Three tables, each case id naming the input:

* BLENDER_BAD / COLMAP_BAD: a tiny fixture (tests/research/realdata_fixtures.py) broken one way,
  each raising a one-line DatasetError (a ValueError) that names the file (and the frame or camera).
* EXPERIMENT_BAD: fit_splats / fit_nerf command lines on such data: exit status 2, one line on stderr
  naming the option or file, before any kernel runs and without creating --out.
* Faults: an image truncated, or replaced by another size, after the folder was opened: the split
  load fails with one line naming the image.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import sys

import numpy as np
import pytest

from research import io
from research.datasets import DatasetError, load_blender, load_colmap, open_dataset

sys.path.insert(0, str(Path(__file__).parent))
from realdata_fixtures import write_blender, write_colmap  # noqa: E402


def _edit_json(path: Path, fn) -> None:
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))


def _scale_transform(doc):
    doc["frames"][1]["transform_matrix"] = (np.asarray(doc["frames"][1]["transform_matrix"]) *
                                            np.diag([2.0, 2.0, 2.0, 1.0])).tolist()


def _reflect_transform(doc):
    doc["frames"][0]["transform_matrix"] = (np.asarray(doc["frames"][0]["transform_matrix"]) @
                                            np.diag([-1.0, 1.0, 1.0, 1.0])).tolist()


def _resize(root: Path, rel: str, w: int, h: int) -> None:
    io.write_png_u8(root / rel, np.zeros((h, w, 4), np.uint8))


# (id, how the fixture is broken, load options, expected message: a regex)
BLENDER_BAD = [
    ("missing-transforms_test", lambda r: (r / "transforms_test.json").unlink(), {},
     r"transforms_test\.json: missing"),
    ("image-listed-but-absent", lambda r: (r / "train" / "r_2.png").unlink(), {},
     r"transforms_train\.json: frame 2: image .*train/r_2\.png is listed but missing"),
    ("non-rotation-scaled-transform", lambda r: _edit_json(r / "transforms_train.json", _scale_transform), {},
     r"transforms_train\.json: frame 1 \(\./train/r_1\): transform_matrix: rotation part is not orthonormal"),
    ("reflection-in-transform", lambda r: _edit_json(r / "transforms_test.json", _reflect_transform), {},
     r"transforms_test\.json: frame 0 .*determinant -1"),
    ("mismatched-image-sizes", lambda r: _resize(r, "test/r_1.png", 16, 12), {},
     r"test/r_1\.png: image is 16x12, but .*train/r_0\.png is 16x16"),
    ("frame-without-transform_matrix",
     lambda r: _edit_json(r / "transforms_val.json", lambda d: d["frames"][0].pop("transform_matrix")), {},
     r"transforms_val\.json: frame 0 has no transform_matrix"),
    ("frame-without-file_path",
     lambda r: _edit_json(r / "transforms_train.json", lambda d: d["frames"][3].pop("file_path")), {},
     r"transforms_train\.json: frame 3 has no file_path"),
    ("no-camera_angle_x-nor-fl_x",
     lambda r: _edit_json(r / "transforms_train.json", lambda d: d.pop("camera_angle_x")), {},
     r"transforms_train\.json: frame 0 .*neither camera_angle_x nor fl_x"),
    ("negative-fl_x", lambda r: _edit_json(r / "transforms_train.json", lambda d: d.update(fl_x=-3)), {},
     r"transforms_train\.json: frame 0: fl_x must be a finite number > 0, got -3"),
    ("declared-w-disagrees-with-image", lambda r: _edit_json(r / "transforms_test.json", lambda d: d.update(w=32)),
     {}, r"transforms_test\.json: frame 0: w = 32 but its image is 16x16"),
    ("invalid-json", lambda r: (r / "transforms_train.json").write_text("{frames: "), {},
     r"transforms_train\.json: not valid JSON"),
    ("no-frames", lambda r: _edit_json(r / "transforms_test.json", lambda d: d.update(frames=[])), {},
     r"transforms_test\.json: lists no frames"),
    ("bad-aabb", lambda r: _edit_json(r / "transforms_train.json", lambda d: d.update(aabb=[[1, 1, 1], [0, 0, 0]])),
     {}, r"transforms_train\.json: the scene box must be .*min < max"),
    ("not-a-png-under-a-png-name", lambda r: (r / "train" / "r_1.png").write_bytes(b"\x89PNG\r\n\x1a\nxxxx"), {},
     r"train/r_1\.png: cannot be read as an image \(.*end of file"),
    ("factor-not-dividing-the-size", lambda r: None, {"factor": 3},
     r"train/r_0\.png: image is 16x16, not divisible by the downscale factor 3"),
    ("factor-zero", lambda r: None, {"factor": 0}, r"factor: expected a downscale factor, an integer >= 1, got 0"),
]


@pytest.mark.parametrize("case", BLENDER_BAD, ids=[c[0] for c in BLENDER_BAD])
def test_blender_bad_input(tmp_path, case):
    _, breaks, options, expected = case
    root = tmp_path / "lego"
    write_blender(root)
    breaks(root)
    with pytest.raises(ValueError) as e:  # DatasetError, or ValueError naming the argument
        load_blender(root, **options)
    msg = str(e.value)
    assert "\n" not in msg and re.search(expected, msg), msg


def _source_pixels(rng, channels: int, dtype=np.uint8) -> np.ndarray:
    top = np.iinfo(dtype).max
    a = rng.integers(0, top + 1, (16, 16, channels), dtype=np.int64).astype(dtype)
    if channels in (2, 4):
        a[0, :, -1] = 0  # transparent, half-transparent and opaque pixels: straight alpha must stay straight
        a[1, :, -1] = top // 2
    return a


def _encode(root: Path, encoding: str, rng) -> np.ndarray:
    """train/r_1 rewritten in `encoding`; returns what a decoder must give: straight sRGB RGBA in [0, 1]."""
    from PIL import Image

    path = root / "train" / "r_1.png"
    if encoding == "rgba-16bit":
        a = _source_pixels(rng, 4, np.uint16)
        io.write_png_u16(path, a)
        return a / 65535.0
    if encoding == "rgb-no-alpha":
        a = _source_pixels(rng, 3)
        io.write_png_u8(path, a)
        return np.concatenate([a / 255.0, np.ones((16, 16, 1))], axis=2)
    if encoding in ("grey", "grey-alpha"):
        a = _source_pixels(rng, 1 if encoding == "grey" else 2)
        io.write_png_u8(path, a)
        alpha = a[..., 1:] / 255.0 if encoding == "grey-alpha" else np.ones((16, 16, 1))
        return np.concatenate([np.repeat(a[..., :1] / 255.0, 3, axis=2), alpha], axis=2)
    if encoding == "paletted-with-transparency":  # mode P with a tRNS chunk: PNG colour type 3
        palette = rng.integers(0, 256, (16, 3), dtype=np.uint8)
        trns = rng.integers(0, 256, 16, dtype=np.uint8)
        index = rng.integers(0, 16, (16, 16), dtype=np.uint8)
        im = Image.fromarray(index, mode="P")
        im.putpalette(palette.ravel().tolist())
        im.save(path, transparency=trns.tobytes())
        assert Image.open(path).mode == "P"
        return np.concatenate([palette[index] / 255.0, trns[index][..., None] / 255.0], axis=2)
    assert encoding == "jpeg", encoding
    a = _source_pixels(rng, 3)
    path.unlink()
    jpg = path.with_suffix(".jpg")
    Image.fromarray(a).save(jpg, quality=95)
    doc = json.loads((root / "transforms_train.json").read_text())
    doc["frames"][1]["file_path"] = "./train/r_1.jpg"  # an explicit extension is used as given
    (root / "transforms_train.json").write_text(json.dumps(doc))
    decoded = np.asarray(Image.open(jpg).convert("RGB"))  # the reference decoder (Pillow's libjpeg)
    return np.concatenate([decoded / 255.0, np.ones((16, 16, 1))], axis=2)


ENCODINGS = ["rgba-16bit", "rgb-no-alpha", "grey", "grey-alpha", "paletted-with-transparency", "jpeg"]


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_blender_reads_every_png_and_jpeg_encoding_as_its_reference_decoder(tmp_path, encoding):
    """Images in the encodings the reference loaders (imageio / PIL in the NeRF and nerfstudio code) accept
    are read, not refused: 16-bit, no alpha (opaque), grey, grey + alpha, paletted with tRNS, JPEG. Values:
    straight (unassociated) sRGB in [0, 1], exactly the stored code / (2^bits - 1); the JPEG within one code
    of Pillow's decode (libjpeg builds may differ by one in the inverse DCT's rounding)."""
    from research.datasets.external import read_srgb

    root = tmp_path / "lego"
    write_blender(root)
    expected = _encode(root, encoding, np.random.default_rng(3))
    path = root / "train" / ("r_1.jpg" if encoding == "jpeg" else "r_1.png")
    got = read_srgb(path)
    assert got.shape == (16, 16, 4) and got.dtype == np.float32
    tol = 1.0 / 255 + 1e-6 if encoding == "jpeg" else 1e-6  # 1e-6: float32 rounding of code / (2^bits - 1)
    assert np.abs(got - expected).max() <= tol
    view = load_blender(root).load_split("train")  # and the folder loads, the view at its size
    assert view.rgba.shape == (4, 16, 16, 4) and np.isfinite(view.rgba).all()


def _rewrite_camera_model(root: Path, old: str, new: str) -> None:
    p = root / "sparse" / "0" / "cameras.txt"
    text = p.read_text()
    assert f" {old}" in text
    p.write_text(text.replace(f" {old}", f" {new}"))


def _colmap_fixture(root: Path, case_id: str) -> None:
    write_colmap(root, text=True)


COLMAP_BAD = [
    ("missing-sparse-0", lambda r: __import__("shutil").rmtree(r / "sparse"), {},
     r"sparse/0: missing \(expected a COLMAP sparse model"),
    ("unknown-camera-model", lambda r: _rewrite_camera_model(r, "PINHOLE", "PINHOLE_FANCY"), {},
     r"cameras\.txt: camera 1: unknown camera model 'PINHOLE_FANCY'"),
    ("unsupported-camera-model-FOV", lambda r: _rewrite_camera_model(r, "PINHOLE 16 12 18 19 8.5 5.5",
                                                                     "FOV 16 12 18 19 8.5 5.5 0.1"), {},
     r"cameras\.txt: camera 1: camera model FOV is not supported"),
    ("image-listed-but-absent", lambda r: (r / "images" / "img_03.png").unlink(), {"factor": 1},
     r"images\.txt: image 'img_03\.png' is listed but .*images/img_03\.png is missing"),
    ("images_N-folder-missing", lambda r: None, {"factor": 4}, r"images_4: missing \(the images at 1/4"),
    ("image-size-not-the-camera's", lambda r: _resize(r, "images/img_05.png", 20, 12), {"factor": 1},
     r"images/img_05\.png: image is 20x12, but camera 1 \(16x12\) at 1/1 expects about 16x12"),
    ("points3D-missing", lambda r: (r / "sparse" / "0" / "points3D.txt").unlink(), {},
     r"sparse/0/points3D\.bin: missing \(nor points3D\.txt\)"),
    ("one-registered-image", lambda r: _keep_images(r, 1), {}, r"images\.txt: 1 registered image\(s\)"),
    ("not-a-folder", lambda r: __import__("shutil").rmtree(r), {}, r"scene: no such dataset folder"),
]


def _keep_images(root: Path, n: int) -> None:
    import pycolmap

    d = root / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(d))
    for image_id in sorted(rec.images)[n:]:
        rec.deregister_frame(rec.images[image_id].frame_id)
    rec.write_text(str(d))


@pytest.mark.parametrize("case", COLMAP_BAD, ids=[c[0] for c in COLMAP_BAD])
def test_colmap_bad_input(tmp_path, case):
    case_id, breaks, options, expected = case
    root = tmp_path / "scene"
    _colmap_fixture(root, case_id)
    breaks(root)
    with pytest.raises(DatasetError) as e:
        load_colmap(root, **options)
    msg = str(e.value)
    assert "\n" not in msg and re.search(expected, msg), msg


def test_open_dataset_names_the_format_option(tmp_path):
    with pytest.raises(ValueError, match=r"^--format: expected one of .*got 'nerfies'$"):
        open_dataset(tmp_path, "nerfies")


# (id, fixture, experiment, arguments after --data, expected stderr line: a regex)
EXPERIMENT_BAD = [
    ("colmap-format-on-a-blender-folder", "blender", "fit_splats", ["--format", "colmap"],
     r"lego/sparse/0: missing \(expected a COLMAP sparse model"),
    ("blender-format-on-a-colmap-folder", "colmap", "fit_nerf", ["--format", "blender"],
     r"transforms_train\.json: missing"),
    ("resolution-on-the-render-cache", "empty", "fit_splats", ["--resolution", "2"],
     r"--resolution: applies to a --data folder in Blender, COLMAP or LLFF format"),
    ("resolution-zero", "blender", "fit_nerf", ["--resolution", "0"], r"--resolution: expected an integer >= 1, got 0"),
    ("images-too-small-for-ssim", "colmap", "fit_splats", ["--resolution", "2"],
     r"--data: the test images of .* are 8x6 at this resolution; SSIM needs at least 11x11"),
    ("init-depth-without-depth", "blender", "fit_splats", ["--init", "depth"],
     r"--init depth: .* has no ground-truth depth"),
    ("init-sfm-without-points", "blender", "fit_splats", ["--init", "sfm"], r"--init sfm: .* has no SfM points"),
    ("image-listed-but-absent", "blender-missing-image", "fit_nerf", [],
     r"transforms_test\.json: frame 1: image .*test/r_1\.png is listed but missing"),
]


@pytest.mark.parametrize("case", EXPERIMENT_BAD, ids=[c[0] for c in EXPERIMENT_BAD])
def test_experiment_bad_input_exits_2_before_any_work(tmp_path, capsys, case):
    import importlib

    _, fixture, experiment, extra, expected = case
    if fixture.startswith("blender"):
        data = tmp_path / "lego"
        write_blender(data)
        if fixture == "blender-missing-image":
            (data / "test" / "r_1.png").unlink()
    elif fixture == "colmap":
        data = tmp_path / "room"
        write_colmap(data, factors=(1, 2))
    else:
        data = tmp_path / "cache"
        data.mkdir()
    out = tmp_path / "out"
    main = importlib.import_module(f"experiments.{experiment}").main
    rc = main(["--smoke", "--no-progress", "--data", str(data), "--out", str(out), *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and re.search(expected, err), err
    assert not out.exists() and not list(tmp_path.glob("out.partial-*"))


# Faults after the folder was opened: (id, fixture, what happens to the file, expected regex)
def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[:60])


FAULTS = [
    ("blender-image-truncated", "blender", "test/r_0.png", _truncate,
     r"test/r_0\.png: (not a readable image|corrupt or truncated).*end of file"),
    ("blender-image-resized", "blender", "test/r_0.png", lambda p: io.write_png_u8(p, np.zeros((8, 8, 4), np.uint8)),
     r"test/r_0\.png: image changed on disk: now 8x8"),
    ("colmap-image-resized", "colmap", "images/img_00.png",
     lambda p: io.write_png_u8(p, np.zeros((6, 8, 3), np.uint8)), r"images/img_00\.png: image changed on disk"),
]


@pytest.mark.parametrize("case", FAULTS, ids=[c[0] for c in FAULTS])
def test_fault_after_open_is_one_line_naming_the_image(tmp_path, case):
    _, fixture, rel, fault, expected = case
    if fixture == "blender":
        write_blender(tmp_path / "d")
        ds = load_blender(tmp_path / "d")
    else:
        write_colmap(tmp_path / "d", factors=(1,))
        ds = load_colmap(tmp_path / "d")
    fault(tmp_path / "d" / rel)
    with pytest.raises(ValueError) as e:
        ds.load_split("test")
    msg = str(e.value)
    assert "\n" not in msg and re.search(expected, msg), msg
