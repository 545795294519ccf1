"""NeRF-synthetic ("Blender") and nerfstudio-style folders: `transforms_{train,val,test}.json` and images.

Layout (the NeRF release; `drlab dataset` writes the same, so nerfstudio and instant-ngp read it):

    transforms_train.json  transforms_test.json  [transforms_val.json]
    train/r_0.png ...      (file_path "./train/r_0", with or without ".png", relative to the folder)

Each transforms file holds `frames` with `file_path` and an OpenGL camera-to-world
`transform_matrix` (+x right, +y up, +z backward; converted to drlab's OpenCV convention by
research.cameras.Camera.from_nerf). Intrinsics: NeRF's `camera_angle_x` (horizontal field of view,
radians; square pixels, centred principal point), or nerfstudio's `fl_x`, `fl_y`, `cx`, `cy`, `w`,
`h`, given once at the top of the file or per frame (a frame's own values win); instant-ngp's
`camera_angle_y` gives fl_y where fl_y is absent. Without `w`/`h` the image's own size is used;
every image of the folder must have the same size.

Lens (nerfstudio's `camera_model` and `k1`, `k2`, `k3`, `k4`, `p1`, `p2`, top level or per frame, the
frame's winning; absent coefficients are 0, an absent camera_model is "OPENCV", nerfstudio's default
perspective camera, or "OPENCV_FISHEYE" where instant-ngp's `"is_fisheye": true` is given). The
cameras carry it (research.cameras.Camera.lens, kernels/lens.py), as the COLMAP reader's do:

    camera_model                                           drlab lens
    OPENCV, PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL  opencv (k1, k2, p1, p2, k3); none when all are 0
    OPENCV_FISHEYE                                          fisheye (k1, k2, k3, k4)

nerfstudio's perspective k4 (an r^8 radial term), p1/p2 on a fisheye and any other camera_model
(EQUIRECTANGULAR, FISHEYE624, ...) are refused, naming the file, the frame and the key.

nerfstudio's single `transforms.json` (no split files beside it) is read too, with the same keys; its
split rule is nerfstudio's `interval` evaluation mode with interval 8 (the llffhold 8 of Mip-NeRF 360
and 3DGS): the frames sorted by `file_path`, every 8th (index % 8 == 0) is a test view, the rest
train; protocol "nerfstudio-interval8", scored as NeRF-synthetic (on white; opaque images are
unchanged by it).

Images: RGBA PNGs (RGB and JPEG also read, as opaque), straight alpha, sRGB. `factor` downscales by
box averaging of the straight RGBA (OpenCV's INTER_AREA at an integer factor, as the NeRF code
makes its half-resolution images), the intrinsics scaled alike. The protocol ("nerf-synthetic":
NeRF, instant-ngp and 3DGS) trains on the train split and scores the test split with the images
composited on white in sRGB: `srgb * alpha + (1 - alpha)`.

Scene bound: a declared box (`"aabb": [[x, y, z], [x, y, z]]` in transforms_train.json or transforms.json, or the
scene record of a drlab cameras.json beside it), else `external.bound_from_cameras`.

Errors (research.datasets.DatasetError, a ValueError; one line naming the file): a missing
transforms_train.json or transforms_test.json (when there is no single transforms.json), a single
transforms.json with fewer than 2 frames, a frame without `file_path` or `transform_matrix`, a
transform whose rotation part is not a rotation, an image listed but absent, images of different
sizes, a size not divisible by `factor`, a lens the table above does not hold. "A rotation" is
kernels/rotation.py's one check: max |R^T R - I| <= 1e-5 and det R > 0. The official files store
float32 matrices (max |R^T R - I| up to about 1.3e-6 in lego's transforms_train.json), which pass
and are re-orthonormalised (the polar factor).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from kernels.lens import Lens
from research.cameras import Camera
from research.datasets import external
from research.datasets.integrity import DatasetError
from research.datasets.loader import SPLITS, Dataset, Protocol, Split, View, _image_size

WHITE = (1.0, 1.0, 1.0)
SINGLE_TRANSFORMS = "transforms.json"
EVAL_INTERVAL = 8  # a single transforms.json: every 8th frame (by file_path) is a test view
_INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y")
_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
PERSPECTIVE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL")
FISHEYE_MODELS = ("OPENCV_FISHEYE",)


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise DatasetError(f"{path}: not valid JSON ({e})") from None


def _image_path(root: Path, tpath: Path, index: int, frame: dict[str, Any]) -> Path:
    fp = frame.get("file_path")
    if not isinstance(fp, str) or not fp:
        raise DatasetError(f"{tpath}: frame {index} has no file_path")
    # Lexically normalised ("./train/r_0" -> "train/r_0"), not resolved: a root given as a relative path
    # or through a symbolic link keeps its files under it (content_hash takes them relative to the root).
    p = Path(os.path.normpath(root / fp))
    if p.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        p = p.with_name(p.name + ".png")
    if not p.is_file():
        raise DatasetError(f"{tpath}: frame {index}: image {p} is listed but missing")
    return p


def _number(tpath: Path, index: int, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
        raise DatasetError(f"{tpath}: frame {index}: {key} must be a finite number > 0, got {value!r}")
    return float(value)


def _lens(tpath: Path, index: int, doc: dict[str, Any], frame: dict[str, Any]) -> Lens | None:
    """The frame's lens (module docstring's table), None for a pinhole; DatasetError otherwise."""
    fisheye = frame.get("is_fisheye", doc.get("is_fisheye", False)) is True  # instant-ngp's spelling
    model = frame.get("camera_model", doc.get("camera_model", "OPENCV_FISHEYE" if fisheye else "OPENCV"))
    if model not in PERSPECTIVE_MODELS + FISHEYE_MODELS:
        raise DatasetError(f"{tpath}: frame {index}: camera_model {model!r} is not supported (expected one of "
                           f"{', '.join(PERSPECTIVE_MODELS + FISHEYE_MODELS)})")
    k = {}
    for key in _DISTORTION:
        value = frame.get(key, doc.get(key, 0.0))
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise DatasetError(f"{tpath}: frame {index}: {key} must be a finite number, got {value!r}")
        k[key] = float(value)
    if model in FISHEYE_MODELS:
        if k["p1"] or k["p2"]:
            raise DatasetError(f"{tpath}: frame {index}: p1, p2 = {k['p1']:g}, {k['p2']:g}: a {model} camera has no "
                               "tangential terms")
        return Lens("fisheye", (k["k1"], k["k2"], k["k3"], k["k4"]))
    if k["k4"]:
        raise DatasetError(f"{tpath}: frame {index}: k4 = {k['k4']:g} (nerfstudio's r^8 radial term) is not supported "
                           "for a perspective camera (expected k1, k2, k3, p1, p2)")
    coeffs = (k["k1"], k["k2"], k["p1"], k["p2"], k["k3"])
    return Lens("opencv", coeffs) if any(coeffs) else None


def _camera(tpath: Path, index: int, doc: dict[str, Any], frame: dict[str, Any], size: tuple[int, int],
            factor: int) -> Camera:
    """The frame's camera at the file's size `size` (w, h), then downscaled by `factor`."""
    intr = {k: frame.get(k, doc.get(k)) for k in _INTRINSICS}
    w, h = size
    for key, actual in (("w", w), ("h", h)):
        if intr[key] is not None and int(intr[key]) != actual:
            raise DatasetError(f"{tpath}: frame {index}: {key} = {intr[key]} but its image is {w}x{h}")
    if "transform_matrix" not in frame:
        raise DatasetError(f"{tpath}: frame {index} has no transform_matrix")
    try:
        if intr["fl_x"] is None and intr["camera_angle_x"] is None:
            raise ValueError("neither camera_angle_x nor fl_x is given")
        fl_x = None if intr["fl_x"] is None else _number(tpath, index, "fl_x", intr["fl_x"])
        angle = None if intr["camera_angle_x"] is None else _number(tpath, index, "camera_angle_x",
                                                                      intr["camera_angle_x"])
        fl_y = None if intr["fl_y"] is None else _number(tpath, index, "fl_y", intr["fl_y"])
        if fl_y is None and intr["camera_angle_y"] is not None:  # instant-ngp: the vertical field of view
            fl_y = (h / 2.0) / math.tan(_number(tpath, index, "camera_angle_y", intr["camera_angle_y"]) / 2.0)
        cam = Camera.from_nerf(frame["transform_matrix"], w, h, camera_angle_x=angle, fl_x=fl_x, fl_y=fl_y,
                               cx=None if intr["cx"] is None else float(intr["cx"]),
                               cy=None if intr["cy"] is None else float(intr["cy"]))
    except (ValueError, TypeError) as e:
        if isinstance(e, DatasetError):
            raise
        raise DatasetError(f"{tpath}: frame {index} ({frame.get('file_path')}): {e}") from None
    lens = _lens(tpath, index, doc, frame)
    if factor == 1 and lens is None:
        return cam
    S = np.diag([1.0 / factor, 1.0 / factor, 1.0])
    return Camera(S @ cam.K, cam.c2w, w // factor, h // factor, lens)


def _declared_box(root: Path, train_doc: dict[str, Any], train_file: Path) -> np.ndarray | None:
    if "aabb" in train_doc:
        box = np.asarray(train_doc["aabb"], dtype=np.float64)
        where = train_file
    elif (root / "cameras.json").is_file():
        scene = _read_json(root / "cameras.json").get("scene", {})
        if "bbox_min" not in scene:
            return None
        box = np.asarray([scene["bbox_min"], scene.get("bbox_max")], dtype=np.float64)
        where = root / "cameras.json"
    else:
        return None
    if box.shape != (2, 3) or not np.all(np.isfinite(box)) or np.any(box[1] <= box[0]):
        raise DatasetError(f"{where}: the scene box must be [[min x, y, z], [max x, y, z]] with min < max, "
                           f"got {box.tolist()}")
    return box


def nerf_synthetic_protocol(width: int, height: int, factor: int) -> Protocol:
    res = f"{width}x{height}" + (f" (the files at 1/{factor})" if factor > 1 else "")
    return Protocol("nerf-synthetic", "train", "test", res, WHITE,
                    f"NeRF-synthetic protocol (NeRF, instant-ngp, 3DGS): test split at {res}; RGBA composited on "
                    "white in sRGB; PSNR and SSIM (11x11 Gaussian window, sigma 1.5) on sRGB clipped to [0,1]; "
                    "research.metrics")


def nerfstudio_protocol(width: int, height: int, factor: int) -> Protocol:
    res = f"{width}x{height}" + (f" (the files at 1/{factor})" if factor > 1 else "")
    return Protocol("nerfstudio-interval8", "train", "test", res, WHITE,
                    f"nerfstudio single transforms.json: frames sorted by file_path, every {EVAL_INTERVAL}th "
                    f"(index % {EVAL_INTERVAL} == 0) is a test view, the rest train; {res}; RGBA composited on white "
                    "in sRGB (opaque images unchanged); PSNR and SSIM (11x11 Gaussian window, sigma 1.5) on sRGB "
                    "clipped to [0,1]; research.metrics")


def _frame_lists(root: Path, single: bool):
    """(split, transforms file, its document, [(index in the file, frame)]) for every split present.

    Split files: each file's frames in their order. A single transforms.json: its frames sorted by
    file_path, every EVAL_INTERVAL-th (index % EVAL_INTERVAL == 0) in test, the rest in train.
    """
    paths = [root / SINGLE_TRANSFORMS] if single else [root / f"transforms_{s}.json" for s in SPLITS]
    out = []
    for tpath in paths:
        if not tpath.is_file():
            continue
        doc = _read_json(tpath)
        frames = doc.get("frames") if isinstance(doc, dict) else None
        if not isinstance(frames, list) or not frames:
            raise DatasetError(f"{tpath}: lists no frames")
        for i, frame in enumerate(frames):
            if not isinstance(frame, dict):
                raise DatasetError(f"{tpath}: frame {i} is not an object")
        indexed = list(enumerate(frames))
        if not single:
            out.append((tpath.stem[len("transforms_"):], tpath, doc, indexed))
            continue
        for i, frame in indexed:
            _image_path(root, tpath, i, frame)  # a frame without file_path: its error before the sort
        indexed.sort(key=lambda f: str(f[1]["file_path"]))
        if len(indexed) < 2:
            raise DatasetError(f"{tpath}: {len(indexed)} frame; the split (every {EVAL_INTERVAL}th frame for test) "
                               "needs at least 2")
        test = [f for k, f in enumerate(indexed) if k % EVAL_INTERVAL == 0]
        train = [f for k, f in enumerate(indexed) if k % EVAL_INTERVAL != 0]
        out += [("train", tpath, doc, train), ("test", tpath, doc, test)]
    return out


def load_blender(path: str | Path, factor: int = 1) -> Dataset:
    """Read a NeRF-synthetic / nerfstudio folder (module docstring) as a research.datasets Dataset.

    Headers and cameras are checked here; pixels are read by `Dataset.load_split`.
    """
    factor = external.check_factor(factor)
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such dataset folder")
    single = not any((root / f"transforms_{s}.json").is_file() for s in SPLITS) and \
        (root / SINGLE_TRANSFORMS).is_file()
    if not single:
        for required in ("train", "test"):
            if not (root / f"transforms_{required}.json").is_file():
                raise DatasetError(f"{root / f'transforms_{required}.json'}: missing (a NeRF-synthetic folder has "
                                   f"transforms_train.json and transforms_test.json; a nerfstudio folder has "
                                   f"{SINGLE_TRANSFORMS})")
    views: list[View] = []
    files: dict[str, Path] = {}
    read: list[Path] = []
    ref: tuple[Path, tuple[int, int]] | None = None
    train_doc: dict[str, Any] = {}
    for split, tpath, doc, frames in _frame_lists(root, single):
        if split == "train":
            train_doc = doc
        if tpath not in read:
            read.append(tpath)
        for i, frame in frames:
            img = _image_path(root, tpath, i, frame)
            size = _image_size(img)
            if ref is None:
                ref = (img, size)
            elif size != ref[1]:
                raise DatasetError(f"{img}: image is {size[0]}x{size[1]}, but {ref[0]} is {ref[1][0]}x{ref[1][1]} "
                                   "(every image of the folder must have one size)")
            if size[0] % factor or size[1] % factor:
                raise DatasetError(f"{img}: image is {size[0]}x{size[1]}, not divisible by the downscale factor "
                                   f"{factor}")
            cam = _camera(tpath, i, doc, frame, size, factor)
            name = f"{split}/{i:04d}"
            views.append(View(name, split, cam, root))
            files[name] = img
            read.append(img)
    assert ref is not None
    cams = [v.camera for v in views]
    bbox = _declared_box(root, train_doc, root / (SINGLE_TRANSFORMS if single else "transforms_train.json"))
    if bbox is None:
        bbox = external.bound_from_cameras([v.camera for v in views if v.split == "train"] or cams)
    width, height = cams[0].width, cams[0].height

    def load_views(selected: list[View]) -> Split:
        return external.load_split(selected, files, factor)

    manifest = {"format": "blender", "content_hash": external.content_hash(root, read), "factor": factor,
                "root": str(root)}
    protocol = (nerfstudio_protocol if single else nerf_synthetic_protocol)(width, height, factor)
    return Dataset(root, manifest, views, bbox, external.up_from_cameras(cams), format="blender",
                   scene=root.resolve().name, protocol=protocol,
                   split_loader=load_views)
