"""Loading and validating a dataset directory written by research.datasets.generate.

`load(path)` verifies the files against manifest.json's SHA-256 hashes
(research.datasets.integrity; `verify_hashes=False` skips that, for tools that need
it), reads cameras.json, checks that the NeRF transforms agree with the OpenCV
cameras, and that image headers match the camera sizes. Pixels are read on demand
(`Dataset.load_split`). `load_stereo` and `load_flow` verify the same way.
Ground truth is checked for meaning as it is read: depth >= 0, disparity >= 0,
a finite positive baseline, finite flow. Every error names the offending file.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import OpenImageIO as oiio

from research import io
from research.cameras import Camera
from research.datasets.integrity import DatasetError, verify

SPLITS = ("train", "val", "test")




@dataclass(frozen=True)
class View:
    name: str  # e.g. "train/r_004"
    split: str
    camera: Camera
    root: Path

    def path(self, suffix: str) -> Path:
        return self.root / f"{self.name}{suffix}"


@dataclass
class Split:
    cameras: list[Camera]
    rgba: np.ndarray  # (N, H, W, 4) linear, premultiplied, float32
    depth: np.ndarray | None  # (N, H, W) z-depth, 0 where no surface; None for photographs (no ground truth)
    mask: np.ndarray | None  # (N, H, W) bool; None for photographs
    names: list[str] = field(default_factory=list)
    srgb: np.ndarray | None = None  # (N, H, W, 4) straight-alpha sRGB in [0, 1] as in the files (external data)


@dataclass(frozen=True)
class Protocol:
    """How a dataset's paper evaluates novel views (external datasets; research.datasets.blender, colmap).

    `background`: the RGB (sRGB, in [0, 1]) that images with alpha are composited on, in sRGB as the
    NeRF, instant-ngp and 3DGS evaluations do, for training and scoring alike; None: opaque images.
    `description`: one line naming the dataset, split, resolution, background and metrics; it is the
    `eval_protocol` of the results, so research.comparison refuses to mix rows of other protocols.
    """

    name: str  # "nerf-synthetic" or "mipnerf360"
    train_split: str
    test_split: str
    resolution: str  # e.g. "400x400 (the files at 1/2)", "images_4 (1237x822)"
    background: tuple[float, float, float] | None
    description: str


@dataclass
class Dataset:
    root: Path
    manifest: dict[str, Any]
    views: list[View]
    bbox: np.ndarray  # (2, 3) min and max corners
    up: np.ndarray
    # Optional, for datasets read from other formats (research.datasets.blender, colmap):
    format: str = "drlab"  # "drlab", "blender" or "colmap"
    scene: str = ""  # the scene's name (the folder's name for external data)
    protocol: Protocol | None = None  # None: drlab's own (research.metrics.EVAL_PROTOCOL)
    points: np.ndarray | None = None  # (P, 3) SfM points (COLMAP), world coordinates
    point_colors: np.ndarray | None = None  # (P, 3) their sRGB colours in [0, 1]
    ndc: Any = None  # research.nerf.ndc.NDC: forward-facing data (LLFF) whose fields live in NDC
    near_far: np.ndarray | None = None  # (V, 2) per-view z-depth bounds in the views' order (LLFF), or None
    split_loader: Callable[[list[View]], Split] | None = field(default=None, repr=False)

    def split_views(self, split: str) -> list[View]:
        if split not in SPLITS:
            raise ValueError(f"split: expected one of {SPLITS}, got {split!r}")
        return [v for v in self.views if v.split == split]

    def load_split(self, split: str, limit: int | None = None) -> Split:
        views = self.split_views(split)[:limit]
        if self.split_loader is not None:
            return self.split_loader(views)
        rgba = np.stack([_checked(io.read_exr, v.path(".exr"), v.camera, 4) for v in views])
        depth = np.stack([_nonnegative(_checked(io.read_exr, v.path("_depth.exr"), v.camera, 1), v.path("_depth.exr"),
                                       "depth") for v in views])
        mask = np.stack([_checked(io.read_png_u8, v.path("_mask.png"), v.camera, 1) for v in views]) > 127
        return Split([v.camera for v in views], rgba, depth, mask, [v.name for v in views])


def _checked(reader, path: Path, cam: Camera, channels: int) -> np.ndarray:
    arr = reader(path)
    if channels == 1 and arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    expected = (cam.height, cam.width) + (() if channels == 1 else (channels,))
    if arr.shape != expected:
        raise DatasetError(f"{path}: expected an image of shape {expected}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DatasetError(f"{path}: contains non-finite values")
    return arr


def _nonnegative(arr: np.ndarray, path: Path, what: str) -> np.ndarray:
    if arr.size and arr.min() < 0:
        raise DatasetError(f"{path}: {what} must be >= 0, found {float(arr.min()):.6g}")
    return arr


def _read_json(path: Path) -> Any:
    if not path.exists():
        raise DatasetError(f"{path}: missing")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise DatasetError(f"{path}: not valid JSON ({e})") from None


def _image_size(path: Path) -> tuple[int, int]:
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        reason = " ".join(oiio.geterror().split())  # OpenImageIO's message can span lines: one line
        raise DatasetError(f"{path}: cannot be read as an image ({reason})")
    try:
        spec = inp.spec()
        return spec.width, spec.height
    finally:
        inp.close()


def _open(path: str | Path, verify_hashes: bool) -> Path:
    root = Path(path)
    if not root.is_dir():
        partial = root.with_name(root.name + ".partial")
        hint = f" (an interrupted run left {partial}; finish it with --resume)" if partial.exists() else ""
        raise DatasetError(f"{root}: no such dataset directory{hint}")
    if verify_hashes:
        verify(root)
    return root


def load(path: str | Path, *, verify_hashes: bool = True) -> Dataset:
    """Open and validate a dataset directory (see module docstring)."""
    root = _open(path, verify_hashes)
    manifest = _read_json(root / "manifest.json")
    files = manifest.get("files", {}) if isinstance(manifest, dict) else {}
    for rel in files:
        if not (root / rel).is_file():
            raise DatasetError(f"{root / rel}: listed in manifest.json but missing")

    cams_path = root / "cameras.json"
    cams_doc = _read_json(cams_path)
    views = []
    for entry in cams_doc.get("views", []):
        name = entry.get("name", "?")
        try:
            cam = Camera.from_dict(entry)
        except ValueError as e:
            raise DatasetError(f"{cams_path}: view {name}: {e}") from None
        views.append(View(name, entry.get("split", ""), cam, root))
    if not views:
        raise DatasetError(f"{cams_path}: lists no views")

    by_name = {v.name: v for v in views}
    for split in SPLITS:
        tpath = root / f"transforms_{split}.json"
        doc = _read_json(tpath)
        for frame in doc.get("frames", []):
            stem = str(frame.get("file_path", "")).removesuffix(".png")
            if stem not in by_name:
                raise DatasetError(f"{tpath}: frame {stem!r} is not in cameras.json")
            try:
                cam = Camera.from_nerf(frame["transform_matrix"], doc["w"], doc["h"], fl_x=doc["fl_x"],
                                       fl_y=doc["fl_y"], cx=doc["cx"], cy=doc["cy"])
            except (KeyError, ValueError) as e:
                raise DatasetError(f"{tpath}: frame {stem}: {e}") from None
            ref = by_name[stem].camera
            if not (np.allclose(cam.c2w, ref.c2w, atol=1e-9) and np.allclose(cam.K, ref.K, atol=1e-9)):
                raise DatasetError(f"{tpath}: frame {stem} disagrees with cameras.json")

    for v in views:
        for suffix in (".png", ".exr", "_depth.exr", "_normal.exr", "_mask.png"):
            p = v.path(suffix)
            if not p.is_file():
                raise DatasetError(f"{p}: missing")
            size = _image_size(p)
            if size != (v.camera.width, v.camera.height):
                raise DatasetError(f"{p}: image is {size[0]}x{size[1]}, camera expects "
                                   f"{v.camera.width}x{v.camera.height}")

    scene = cams_doc.get("scene", {})
    try:
        bbox = np.array([scene["bbox_min"], scene["bbox_max"]], dtype=np.float64)
        up = np.array(scene["up"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as e:
        raise DatasetError(f"{cams_path}: bad scene record ({e})") from None
    if bbox.shape != (2, 3) or not np.all(np.isfinite(bbox)) or np.any(bbox[1] <= bbox[0]):
        raise DatasetError(f"{cams_path}: scene bounding box must be finite with min < max, got {bbox.tolist()}")
    return Dataset(root, manifest, views, bbox, up)


@dataclass
class StereoPair:
    """A rectified pair with ground truth: a Mitsuba pair (`load_stereo`) or a benchmark's
    (research.datasets.stereo_benchmarks, `benchmark` names it).

    For a benchmark pair, `left`/`right` hold the stored pixels converted to linear RGBA (sRGB
    decoded, alpha 1) so that the contract above holds, and `left_image`/`right_image` the pixels as
    stored (uint8 or uint16, grey or RGB), which is what a matcher should see; `mask` is "ground truth
    known" (Middlebury's finite disparities, KITTI's disp_occ), `noc` the non-occluded part of it;
    `depth` is baseline * f / (d + doffs) where the ground truth is known (in the calibration's units,
    millimetres for Middlebury), 0 elsewhere. A benchmark without calibration files (KITTI without
    its calib folder) has cameras None and a NaN baseline, and its depth is all 0.
    """

    name: str
    left_camera: Camera | None
    right_camera: Camera | None
    baseline: float
    left: np.ndarray  # (H, W, 4) linear premultiplied RGBA
    right: np.ndarray
    disparity: np.ndarray  # (H, W) ground-truth left disparity, 0 where no surface
    noc: np.ndarray  # (H, W) bool: surface visible in both views
    mask: np.ndarray  # (H, W) bool: surface hit in the left view
    depth: np.ndarray  # (H, W) left z-depth
    # Optional, set by the benchmark readers (defaults describe a Mitsuba pair):
    benchmark: str = "mitsuba"  # "middlebury", "kitti" or "eth3d" for a benchmark pair
    resolution: str = "full"  # "full", "half" or "quarter" of the stored files (Middlebury, ETH3D)
    left_image: np.ndarray | None = None  # the stored pixels, uint8/uint16, (H, W) or (H, W, 3)
    right_image: np.ndarray | None = None
    doffs: float = 0.0  # x-difference of the principal points, cx1 - cx0 (Middlebury calib.txt)
    ndisp: int | None = None  # the benchmark's disparity-range bound (calib.txt), at this resolution
    vmin: float | None = None  # tight bounds of the ground truth disparities (calib.txt)
    vmax: float | None = None
    has_noc_mask: bool = True  # False where the benchmark ships no non-occlusion mask (noc == mask then)
    foreground: np.ndarray | None = None  # (H, W) bool, KITTI 2015's object map > 0 (D1-fg/bg)
    source: str = ""  # the folder or file the pair was read from


def load_stereo(path: str | Path, *, verify_hashes: bool = True) -> list[StereoPair]:
    """Rectified pairs written with --stereo."""
    root = _open(path, verify_hashes) / "stereo"
    doc = _read_json(root / "stereo.json")
    baseline = doc.get("baseline") if isinstance(doc, dict) else None
    if isinstance(baseline, bool) or not isinstance(baseline, (int, float)) or not (0 < baseline < math.inf):
        raise DatasetError(f"{root / 'stereo.json'}: baseline must be a finite distance > 0, got {baseline!r}")
    out = []
    for p in doc.get("pairs", []):
        stem = root / p["name"]
        try:
            lc, rc = Camera.from_dict(p["left"]), Camera.from_dict(p["right"])
        except (KeyError, ValueError) as e:
            raise DatasetError(f"{root / 'stereo.json'}: pair {p.get('name')}: {e}") from None
        out.append(StereoPair(
            p["name"], lc, rc, float(baseline),
            _checked(io.read_exr, Path(f"{stem}_left.exr"), lc, 4),
            _checked(io.read_exr, Path(f"{stem}_right.exr"), rc, 4),
            _nonnegative(_checked(io.read_pfm, Path(f"{stem}_disp.pfm"), lc, 1), Path(f"{stem}_disp.pfm"),
                         "disparity"),
            _checked(io.read_png_u8, Path(f"{stem}_noc.png"), lc, 1) > 127,
            _checked(io.read_png_u8, Path(f"{stem}_mask.png"), lc, 1) > 127,
            _nonnegative(_checked(io.read_exr, Path(f"{stem}_left_depth.exr"), lc, 1),
                         Path(f"{stem}_left_depth.exr"), "depth"),
        ))
    if not out:
        raise DatasetError(f"{root / 'stereo.json'}: lists no pairs")
    return out


@dataclass
class FlowSequence:
    """Frames and forward flow. drlab's own sequences fill the first five fields; benchmark readers
    (research.datasets.flow_benchmarks) have no cameras (an empty list) and no depth (None), and fill the
    optional fields below."""

    cameras: list[Camera]
    frames: np.ndarray  # (N, H, W, 4) linear premultiplied RGBA
    depth: np.ndarray | None  # (N, H, W); None where the data has no depth (benchmarks)
    flow: np.ndarray  # (N - 1, H, W, 2): frame k -> k + 1, (x right, y down) pixels
    valid: np.ndarray  # (N - 1, H, W) bool: ground truth known and the pixel visible in frame k + 1
    name: str = ""  # the sequence or pair a benchmark names it by
    occluded: np.ndarray | None = None  # (N - 1, H, W) bool: ground truth known, pixel occluded in frame k + 1
    invalid: np.ndarray | None = None  # (N - 1, H, W) bool: pixels the protocol leaves out of every region
    valid_all: np.ndarray | None = None  # (N - 1, H, W) bool: ground truth known, occluded or not (KITTI flow_occ)
    foreground: np.ndarray | None = None  # (N - 1, H, W) bool: KITTI 2015 obj_map's objects (Fl-fg; the rest Fl-bg)


def load_flow(path: str | Path, *, verify_hashes: bool = True) -> FlowSequence:
    """The camera-path sequence written with --flow."""
    root = _open(path, verify_hashes) / "flow"
    doc = _read_json(root / "flow.json")
    frames = doc.get("frames", [])
    if len(frames) < 2:
        raise DatasetError(f"{root / 'flow.json'}: needs at least two frames")
    cams, rgba, depth, flow, valid = [], [], [], [], []
    for k, f in enumerate(frames):
        stem = root / f["name"]
        try:
            cam = Camera.from_dict(f)
        except ValueError as e:
            raise DatasetError(f"{root / 'flow.json'}: frame {f.get('name')}: {e}") from None
        cams.append(cam)
        rgba.append(_checked(io.read_exr, Path(f"{stem}.exr"), cam, 4))
        depth.append(_nonnegative(_checked(io.read_exr, Path(f"{stem}_depth.exr"), cam, 1), Path(f"{stem}_depth.exr"),
                                  "depth"))
        if k < len(frames) - 1:
            flow.append(_checked(io.read_flo, Path(f"{stem}_flow.flo"), cam, 2))
            valid.append(_checked(io.read_png_u8, Path(f"{stem}_valid.png"), cam, 1) > 127)
    return FlowSequence(cams, np.stack(rgba), np.stack(depth), np.stack(flow), np.stack(valid))
