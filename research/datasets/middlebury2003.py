"""Reader of the classic Middlebury 2001/2003 stereo pairs (tsukuba, venus, teddy, cones).

Layout: one folder per scene, holding the left and right images and the left ground truth as 8-bit
images, in one of three namings:
  * `im2`, `im6` (left, right), `disp2` (venus, teddy, cones, ...);
  * `im3`, `im4`, `disp3` (tsukuba, as repackaged);
  * `scene1.row3.col3`, `scene1.row3.col4`, `truedisp.row3.col3` (tsukuba as the 2001 release names it).
The images are 8-bit PNG or binary PPM/PGM (the sets' "png" and "ppm" archives), grey or colour, kept
exactly as stored; `.png` is read when both exist. The ground truth is an 8-bit grey image (PNG or
binary PGM) storing the disparity times a per-scene scale, 0 = unknown:

    d = value / scale,  known where value > 0.

The scales of the known scenes (SCALES, from the data sets' own descriptions): tsukuba 16, venus 8,
teddy 4 and cones 4 (the quarter-size 450x375 versions); `scale=` overrides them, and a scene not in
the table needs it. The disparity range each scene was evaluated with (NDISP): tsukuba 16, venus 20,
teddy and cones 60 (quarter size).

These sets ship no calibration (no depth: baseline NaN, cameras None) and, here, no occlusion masks:
`noc` equals `mask` (every pixel with known ground truth) and `has_noc_mask` is False, so a protocol
over "nonocc" would in fact be over all known pixels; research.stereo.matching's "middlebury2003" protocol
names its one mask "all" for that reason.

The root may be one scene's folder or a folder whose sub-folders are scenes (read in sorted order).
Every error is a DatasetError (a ValueError) of one line naming the file: a missing image, an image
of the wrong bit depth or channel count, images or ground truth of different sizes, an unknown scene
without a scale, a ground truth above 255 / scale that an 8-bit file cannot hold.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from research import io
from research.datasets.integrity import DatasetError, read_or_fail
from research.datasets.loader import StereoPair
from research.datasets.stereo_pixels import linear_rgba

SCALES = {"tsukuba": 16, "venus": 8, "teddy": 4, "cones": 4}
NDISP = {"tsukuba": 16, "venus": 20, "teddy": 60, "cones": 60}
NAMINGS = (("im2", "im6", "disp2"), ("im3", "im4", "disp3"),
           ("scene1.row3.col3", "scene1.row3.col4", "truedisp.row3.col3"))  # (left, right, ground truth) stems
IMAGE_EXTS = (".png", ".ppm", ".pgm")
GT_EXTS = (".png", ".pgm")
BENCHMARK = "middlebury2003"


def _naming(folder: Path) -> tuple[str, str, str] | None:
    """(left file name, right file name, ground-truth stem) of the first naming whose images are there."""
    for left, right, gt in NAMINGS:
        for ext in IMAGE_EXTS:
            if (folder / (left + ext)).is_file() and (folder / (right + ext)).is_file():
                return left + ext, right + ext, gt
    return None


def is_scene(folder: Path) -> bool:
    """Whether `folder` holds one scene in this layout (a left/right image pair and a disparity file)."""
    n = _naming(folder)
    return n is not None and any((folder / f"{n[2]}{ext}").is_file() for ext in GT_EXTS)


def scene_folders(root: str | Path) -> list[Path]:
    """`root` if it is a scene, else its sub-folders that are (sorted); [] when neither."""
    root = Path(root)
    if not root.is_dir():
        return []
    if is_scene(root):
        return [root]
    return [c for c in sorted(p for p in root.iterdir() if p.is_dir()) if is_scene(c)]


def _read_u8(path: Path, what: str) -> np.ndarray:
    """An 8-bit PNG, PGM or PPM as uint8 (H, W, C); DatasetError naming the file otherwise."""
    if path.suffix.lower() in (".pgm", ".ppm"):
        pixels = read_or_fail(lambda p: io._oiio_read(p, "pnm", None)[0], path)
    else:
        pixels = read_or_fail(io.read_png_raw, path)
    if pixels.dtype != np.uint8:
        raise DatasetError(f"{path}: expected an 8-bit {what}, got {pixels.dtype.itemsize * 8}-bit")
    return pixels


def _image(path: Path) -> np.ndarray:
    px = _read_u8(path, "image")
    if px.shape[2] in (1, 2):
        return np.ascontiguousarray(px[..., 0])
    return np.ascontiguousarray(px[..., :3])


def read_scene(folder: str | Path, scale: float | None = None) -> StereoPair:
    """One scene folder (module docstring) as a StereoPair; `scale` overrides the table SCALES."""
    folder = Path(folder)
    naming = _naming(folder)
    if naming is None:
        raise DatasetError(f"{folder / 'im2.png'}: missing (a Middlebury 2001/2003 scene holds im2 and im6, im3 and "
                           "im4, or scene1.row3.col3 and scene1.row3.col4, as .png or .ppm)")
    lname, rname, gname = naming
    gt_path = next((folder / f"{gname}{ext}" for ext in GT_EXTS if (folder / f"{gname}{ext}").is_file()),
                   folder / f"{gname}.png")
    if scale is None:
        if folder.name not in SCALES:
            raise DatasetError(f"{gt_path}: unknown scene {folder.name!r}: its disparity scale is not in the table "
                               f"({', '.join(f'{k} {v}' for k, v in SCALES.items())}); give the scale")
        scale = SCALES[folder.name]
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise ValueError(f"scale: expected a finite number > 0, got {scale!r}")
    left, right = _image(folder / lname), _image(folder / rname)
    if right.shape != left.shape:
        raise DatasetError(f"{folder / rname}: is {right.shape[1]}x{right.shape[0]}"
                           f"{' colour' if right.ndim == 3 else ' grey'}, but {lname} is "
                           f"{left.shape[1]}x{left.shape[0]}{' colour' if left.ndim == 3 else ' grey'}")
    raw = _read_u8(gt_path, "disparity map")
    if raw.shape[2] != 1:
        raise DatasetError(f"{gt_path}: expected a one-channel disparity map, got {raw.shape[2]} channels")
    raw = raw[..., 0]
    if raw.shape != left.shape[:2]:
        raise DatasetError(f"{gt_path}: is {raw.shape[1]}x{raw.shape[0]}, but {lname} is "
                           f"{left.shape[1]}x{left.shape[0]}")
    known = raw > 0
    if not known.any():
        raise DatasetError(f"{gt_path}: holds no known disparity (every value is 0)")
    disparity = np.where(known, raw.astype(np.float32) / np.float32(scale), 0.0).astype(np.float32)
    H, W = disparity.shape
    ndisp = NDISP.get(folder.name, int(math.ceil(float(disparity.max()) + 1)))
    return StereoPair(folder.name, None, None, float("nan"), linear_rgba(left), linear_rgba(right), disparity,
                      known.copy(), known, np.zeros((H, W), np.float32), benchmark=BENCHMARK, left_image=left,
                      right_image=right, ndisp=int(ndisp), has_noc_mask=False, source=str(folder))


def load_middlebury2003(path: str | Path, scale: float | None = None) -> list[StereoPair]:
    """Every scene under `path` (one scene folder, or a folder of them); `scale` overrides SCALES for all."""
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such benchmark folder")
    folders = scene_folders(root)
    if not folders:
        raise DatasetError(f"{root}: holds no Middlebury 2001/2003 scene (a folder with im2, im6 and disp2, im3, "
                           "im4 and disp3, or scene1.row3.col3, scene1.row3.col4 and truedisp.row3.col3; images "
                           ".png or .ppm, disparity .png or .pgm)")
    return [read_scene(f, scale) for f in folders]
