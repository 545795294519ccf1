"""Readers of the stereo benchmarks' own layouts: Middlebury 2014/2021, KITTI 2012/2015, ETH3D two-view.

Each returns research.datasets.loader.StereoPair objects (their optional fields say which benchmark,
resolution, calibration and masks), the images as stored and as linear RGBA.

Middlebury 2014 / 2021 and ETH3D two-view: one folder per pair holding
  * `im0.png`, `im1.png`: the rectified left and right images (8- or 16-bit PNG, grey or colour);
  * `disp0.pfm` (Middlebury 2014 full set and 2021) or `disp0GT.pfm` (MiddEval3, ETH3D): the left
    ground-truth disparity as PFM, `inf` where unknown;
  * `mask0nocc.png` (optional; Middlebury 2014, ETH3D): 8-bit, 255 = non-occluded (Middlebury also
    writes 128 for occluded and 0 for unknown); without it (Middlebury 2021) the pair has
    `has_noc_mask=False` and only the "all" mask is meaningful;
  * `calib.txt`: one `key=value` a line, `cam0=[f 0 cx; 0 f cy; 0 0 1]`, `cam1=[...]`, `doffs`,
    `baseline`, `width`, `height`, `ndisp` required; `isint`, `vmin`, `vmax`, `dyavg`, `dymax`
    optional. Depth = baseline * f / (d + doffs), in the unit of the baseline (mm for Middlebury).
The root may be one pair's folder, a folder whose sub-folders are pairs, or a folder with one
sub-folder of pairs (MiddEval3/trainingH holding only trainingH, 2021's data/<scene>); they are read in
sorted order. Pairs under several sub-folders (MiddEval3's trainingF, trainingH, testH) are refused.

Resolution (`resolution="full" | "half" | "quarter"`, relative to the stored files): the images are
averaged over k x k blocks (k = 1, 2, 4; a trailing partial block is cropped); a reduced ground-truth
pixel is known only where all k^2 full-resolution pixels are known, and it is their mean divided by k
(disparities scale with the resolution); it is non-occluded only where all k^2 are. The calibration
scales as Middlebury's own half/quarter sets do: f, cx, cy, doffs, vmin, vmax divided by k, ndisp by k
rounded up, the baseline unchanged. Metrics are then computed at that resolution.

KITTI 2012 / 2015 stereo: the `training` folder (or its parent):
  * left/right images `image_2`/`image_3` (2015), else `colored_0`/`colored_1` (2012 colour), else
    `image_0`/`image_1` (2012 grey), files `<id>_10.png`;
  * ground truth `disp_occ_0` and `disp_noc_0` (2015) or `disp_occ` and `disp_noc` (2012), 16-bit
    grey PNG, disparity = value / 256, 0 = invalid; `disp_occ` is the "all" mask, `disp_noc` the
    non-occluded one;
  * optional `obj_map/<id>_10.png` (2015): > 0 marks the foreground objects, for D1-fg/bg. It is
    read as the devkit reads it (png++'s gray_pixel image over libpng): a palette or RGB image by
    libpng's luminance (`_devkit_gray`), 16-bit grey cut to its high byte, alpha dropped; a 16-bit
    colour map is refused;
  * optional calibration, `calib_cam_to_cam/<id>.txt` (2015: `P_rect_02`, `P_rect_03`) or
    `calib/<id>.txt` (2012: `P0`..`P3`); the focal length and baseline come from the projection
    matrices (baseline = (P_left[0, 3] - P_right[0, 3]) / f, metres). Without it the pair has no
    cameras and a NaN baseline.

Middlebury 2001/2003 (tsukuba, venus, teddy, cones: im2/im6 or im3/im4 with an 8-bit disp2/disp3 scaled
by a per-scene factor): research.datasets.middlebury2003, at the stored resolution only.

ETH3D ships its ground truth in a separate tree: for a pair folder `two_view_training/<scene>` without
disp0GT.pfm, `two_view_training_gt/<scene>` is read for disp0GT.pfm and mask0nocc.png.

`detect_format(path)` tells the layouts apart: KITTI by its folders; a calib.txt layout is ETH3D when
its ground truth lies in a separate `_gt` tree, its im0.png is grey, or its doffs is 0 (ETH3D's
principal points coincide; Middlebury's differ), and Middlebury otherwise.

Every error is a DatasetError (a ValueError) of one line naming the file, and the line of calib.txt
where one applies; nothing is written.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from research import io
from research.cameras import Camera
from research.datasets.integrity import DatasetError, read_or_fail
from research.datasets.loader import StereoPair
from research.datasets.stereo_pixels import linear_rgba

FORMATS = ("middlebury", "kitti", "eth3d", "middlebury2003")
RESOLUTIONS = {"full": 1, "half": 2, "quarter": 4}
CALIB_REQUIRED = ("cam0", "cam1", "doffs", "baseline", "width", "height", "ndisp")
CALIB_OPTIONAL = ("isint", "vmin", "vmax", "dyavg", "dymax")
KITTI_IMAGE_DIRS = (("image_2", "image_3"), ("colored_0", "colored_1"), ("image_0", "image_1"))
KITTI_GT_DIRS = (("disp_occ_0", "disp_noc_0"), ("disp_occ", "disp_noc"))
KITTI_CALIB = (("calib_cam_to_cam", ("P_rect_02", "P_rect_03")), ("calib", None))
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


# --------------------------------------------------------------------------- calib.txt


@dataclass(frozen=True)
class StereoCalib:
    """A Middlebury / ETH3D calib.txt (module docstring)."""

    cam0: np.ndarray
    cam1: np.ndarray
    doffs: float
    baseline: float
    width: int
    height: int
    ndisp: int
    vmin: float | None = None
    vmax: float | None = None
    isint: int | None = None
    path: str = ""

    def scaled(self, k: int) -> "StereoCalib":
        """The calibration of the images averaged over k x k blocks (module docstring: Resolution)."""
        if k == 1:
            return self
        K0, K1 = self.cam0.copy(), self.cam1.copy()
        K0[:2, :] /= k
        K1[:2, :] /= k
        K0[2, 2] = K1[2, 2] = 1.0
        return StereoCalib(K0, K1, self.doffs / k, self.baseline, self.width // k, self.height // k,
                           int(math.ceil(self.ndisp / k)), None if self.vmin is None else self.vmin / k,
                           None if self.vmax is None else self.vmax / k, self.isint, self.path)


def _parse_matrix(text: str) -> np.ndarray | None:
    m = re.fullmatch(r"\[(.*)\]", text.strip())
    if not m:
        return None
    rows = [r.split() for r in m.group(1).split(";")]
    if len(rows) != 3 or any(len(r) != 3 for r in rows):
        return None
    try:
        a = np.array([[float(v) for v in r] for r in rows], dtype=np.float64)
    except ValueError:
        return None
    return a if np.all(np.isfinite(a)) else None


def read_calib(path: str | Path) -> StereoCalib:
    """Parse a Middlebury / ETH3D calib.txt; DatasetError naming the file and line on any defect."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: missing (a calib.txt with {', '.join(CALIB_REQUIRED)})")
    try:
        text = path.read_text(encoding="ascii")
    except UnicodeDecodeError as e:
        raise DatasetError(f"{path}: not an ASCII calib.txt ({e.reason} at byte {e.start})") from None
    values: dict[str, Any] = {}
    lines: dict[str, int] = {}
    for no, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        key, sep, value = line.partition("=")
        key, value = key.strip(), value.strip()
        where = f"{path}: line {no}"
        if not sep or not key:
            raise DatasetError(f"{where}: expected key=value, got {line[:60]!r}")
        if key in values:
            raise DatasetError(f"{where}: {key} given twice (first on line {lines[key]})")
        if key in ("cam0", "cam1"):
            K = _parse_matrix(value)
            if K is None or K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
                raise DatasetError(f"{where}: {key}: expected a 3x3 matrix [f 0 cx; 0 f cy; 0 0 1] with f > 0, "
                                   f"got {value[:60]!r}")
            values[key] = K
        elif key in CALIB_REQUIRED or key in CALIB_OPTIONAL:
            if not re.fullmatch(_NUMBER, value):
                raise DatasetError(f"{where}: {key}: expected a number, got {value[:60]!r}")
            x = float(value)
            if key in ("width", "height", "ndisp", "isint"):
                if x != int(x) or (key != "isint" and x <= 0):
                    raise DatasetError(f"{where}: {key}: expected a positive integer, got {value!r}")
                x = int(x)
            elif key == "baseline" and not x > 0:
                raise DatasetError(f"{where}: baseline: expected a distance > 0, got {value!r}")
            values[key] = x
        else:
            values[key] = value  # other keys are kept out of the way, not refused
        lines[key] = no
    missing = [k for k in CALIB_REQUIRED if k not in values]
    if missing:
        raise DatasetError(f"{path}: no {'=, '.join(missing)}= line (a calib.txt needs {', '.join(CALIB_REQUIRED)})")
    vmin, vmax = values.get("vmin"), values.get("vmax")
    if vmin is not None and vmax is not None and vmax < vmin:
        raise DatasetError(f"{path}: line {lines['vmax']}: vmax: expected >= vmin = {vmin:g}, got {vmax:g}")
    return StereoCalib(values["cam0"], values["cam1"], float(values["doffs"]), float(values["baseline"]),
                       values["width"], values["height"], values["ndisp"], vmin, vmax, values.get("isint"), str(path))


# --------------------------------------------------------------------------- pixels


def _png_codes(path: Path) -> np.ndarray:
    """The stored uint8/uint16 codes (H, W, C) of a PNG; DatasetError naming the file otherwise."""
    return read_or_fail(io.read_png_raw, path)


def read_image(path: Path) -> np.ndarray:
    """A stored 8- or 16-bit PNG image as uint8/uint16 (H, W) grey or (H, W, 3) colour (alpha dropped)."""
    pixels = _png_codes(path)
    c = pixels.shape[2]
    if c in (1, 2):
        return np.ascontiguousarray(pixels[..., 0])
    return np.ascontiguousarray(pixels[..., :3])


def read_kitti_disparity(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A KITTI disparity PNG: (disparity = value / 256 as float32, valid = value > 0)."""
    path = Path(path)
    pixels = _png_codes(path)
    if pixels.dtype != np.uint16 or pixels.shape[2] != 1:
        bits = pixels.dtype.itemsize * 8
        raise DatasetError(f"{path}: expected a 16-bit grey PNG (KITTI disparity = value / 256, 0 = invalid), "
                           f"got {bits}-bit with {pixels.shape[2]} channel(s)")
    raw = pixels[..., 0]
    return (raw.astype(np.float32) / np.float32(256.0)), raw > 0


def _read_mask(path: Path, shape: tuple[int, int]) -> np.ndarray:
    m = read_or_fail(io.read_png_u8, path)
    if m.shape[2] != 1:
        raise DatasetError(f"{path}: expected a one-channel mask, got {m.shape[2]} channels")
    m = m[..., 0]
    if m.shape != shape:
        raise DatasetError(f"{path}: expected a {shape[1]}x{shape[0]} mask like im0.png, got {m.shape[1]}x{m.shape[0]}")
    return m


# libpng's rgb_to_gray weights (1.6, no cHRM chunk), in 1/32768: gray = (r R + g G + b B) >> 15
_LIBPNG_GRAY_WEIGHTS = (6968, 23434, 2366)


def _devkit_gray(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """The 8-bit grey image that png++'s `image<gray_pixel>` reads from the PNG at `path` (the KITTI
    devkit's IntegerImage): alpha stripped, R = G = B kept as it is, other colours (a palette is
    expanded to its RGB entries) by libpng's truncated integer luminance, 16-bit grey cut to its
    high byte. A 16-bit colour PNG is refused: libpng converts it through gamma tables that this
    does not reproduce."""
    raw = read_or_fail(io.read_png_raw, path)
    m = raw.astype(np.int64)
    if m.shape[2] in (2, 4):
        m = m[..., :-1]
    if m.shape[2] == 3:
        if raw.dtype == np.uint16:
            raise DatasetError(f"{path}: a 16-bit colour object map; expected an 8-bit or a grey PNG")
        r, g, b = m[..., 0], m[..., 1], m[..., 2]
        wr, wg, wb = _LIBPNG_GRAY_WEIGHTS
        m = np.where((r == g) & (r == b), r, (wr * r + wg * g + wb * b) >> 15)[..., None]
    m = m[..., 0]
    if raw.dtype == np.uint16:
        m = m >> 8
    if m.shape != shape:
        raise DatasetError(f"{path}: expected a {shape[1]}x{shape[0]} object map like the left image, got "
                           f"{m.shape[1]}x{m.shape[0]}")
    return m.astype(np.uint8)


def read_kitti_object_map(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the foreground (objects) of a KITTI 2015 `obj_map` PNG, its grey value > 0 as the
    devkit reads it (`_devkit_gray`); the stereo and the flow readers both use it."""
    return _devkit_gray(path, shape) > 0


def _same_size(path: Path, img: np.ndarray, shape: tuple[int, int], what: str) -> None:
    if img.shape[:2] != shape:
        raise DatasetError(f"{path}: is {img.shape[1]}x{img.shape[0]}, but {what} is {shape[1]}x{shape[0]}")


def _block_mean(img: np.ndarray, k: int) -> np.ndarray:
    if k == 1:
        return img
    H, W = img.shape[0] // k, img.shape[1] // k
    a = img[:H * k, :W * k].astype(np.float64).reshape(H, k, W, k, *img.shape[2:]).mean(axis=(1, 3))
    if img.dtype.kind == "u":
        return np.floor(a + 0.5).astype(img.dtype)
    return a.astype(img.dtype)


def _block_all(mask: np.ndarray, k: int) -> np.ndarray:
    if k == 1:
        return mask
    H, W = mask.shape[0] // k, mask.shape[1] // k
    return mask[:H * k, :W * k].reshape(H, k, W, k).all(axis=(1, 3))


# --------------------------------------------------------------------------- Middlebury / ETH3D


def _is_pair(folder: Path) -> bool:
    return (folder / "calib.txt").is_file() or (folder / "im0.png").is_file()


def _pair_folders(root: Path) -> list[Path]:
    """`root` if it is a pair, else its sub-folders that are, else those of ONE sub-folder (data/<scene>).

    Pairs under several sub-folders two levels down (MiddEval3's trainingF, trainingH, testH, ...: other
    resolutions, or no ground truth) are refused rather than mixed.
    """
    if _is_pair(root):
        return [root]
    children = sorted(p for p in root.iterdir() if p.is_dir())
    found = [c for c in children if _is_pair(c)]
    if found:
        return found
    nested = {c: [g for g in sorted(p for p in c.iterdir() if p.is_dir()) if _is_pair(g)] for c in children}
    nested = {c: g for c, g in nested.items() if g}
    if len(nested) > 1:
        raise DatasetError(f"{root}: holds pairs in {len(nested)} folders ({', '.join(c.name for c in nested)}); "
                           "pass one of them (one resolution, with ground truth)")
    return next(iter(nested.values()), [])


def _root(path: str | Path) -> Path:
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such benchmark folder")
    return root


def _resolution(resolution: str) -> int:
    if resolution not in RESOLUTIONS:
        raise ValueError(f"resolution: expected one of {tuple(RESOLUTIONS)}, got {resolution!r}")
    return RESOLUTIONS[resolution]


def load_middlebury(path: str | Path, resolution: str = "full", *, benchmark: str = "middlebury") -> list[StereoPair]:
    """Every pair under `path` in the Middlebury layout (module docstring), at `resolution` of the files."""
    k = _resolution(resolution)
    root = _root(path)
    folders = _pair_folders(root)
    if not folders:
        raise DatasetError(f"{root}: holds no {benchmark} pair (a folder with im0.png, im1.png, calib.txt and "
                           "disp0.pfm or disp0GT.pfm)")
    return [_middlebury_pair(f, k, resolution, benchmark) for f in folders]


def load_eth3d(path: str | Path, resolution: str = "full") -> list[StereoPair]:
    """ETH3D two-view pairs: the Middlebury layout with disp0GT.pfm and mask0nocc.png."""
    return load_middlebury(path, resolution, benchmark="eth3d")


def _gt_folder(folder: Path) -> Path:
    """Where a pair's ground truth lies: its own folder, or ETH3D's separate tree
    (two_view_training/<scene> -> two_view_training_gt/<scene>) when that exists and the folder holds none."""
    own = any((folder / n).is_file() for n in ("disp0.pfm", "disp0GT.pfm"))
    sibling = folder.parent.with_name(folder.parent.name + "_gt") / folder.name
    return sibling if not own and sibling.is_dir() else folder


def _middlebury_pair(folder: Path, k: int, resolution: str, benchmark: str) -> StereoPair:
    calib = read_calib(folder / "calib.txt")
    left, right = read_image(folder / "im0.png"), read_image(folder / "im1.png")
    shape = left.shape[:2]
    if shape != (calib.height, calib.width):
        raise DatasetError(f"{folder / 'calib.txt'}: says width={calib.width} height={calib.height}, but "
                           f"{folder / 'im0.png'} is {shape[1]}x{shape[0]}")
    _same_size(folder / "im1.png", right, shape, "im0.png")
    if left.ndim != right.ndim:
        raise DatasetError(f"{folder / 'im1.png'}: {'colour' if right.ndim == 3 else 'grey'}, but im0.png is "
                           f"{'colour' if left.ndim == 3 else 'grey'}")
    gt_dir = _gt_folder(folder)
    gt_path = next((gt_dir / n for n in ("disp0.pfm", "disp0GT.pfm") if (gt_dir / n).is_file()), None)
    if gt_path is None:
        raise DatasetError(f"{folder / 'disp0.pfm'}: missing (nor is there a disp0GT.pfm"
                           + (")" if gt_dir == folder else f", here or in {gt_dir})"))
    gt = read_or_fail(io.read_pfm, gt_path)
    if gt.ndim != 2:
        raise DatasetError(f"{gt_path}: expected a one-channel (Pf) disparity, got {gt.shape[2]} channels")
    _same_size(gt_path, gt, shape, "im0.png")
    if np.isnan(gt).any():
        raise DatasetError(f"{gt_path}: holds NaN (unknown disparities must be inf)")
    known = np.isfinite(gt)
    if known.any() and gt[known].min() < 0:
        raise DatasetError(f"{gt_path}: disparities must be >= 0 (or inf where unknown), found {gt[known].min():.6g}")
    mask_path = gt_dir / "mask0nocc.png"
    has_noc = mask_path.is_file()
    noc = (_read_mask(mask_path, shape) == 255) & known if has_noc else known.copy()

    if k > 1:
        left, right = _block_mean(left, k), _block_mean(right, k)
        known_k = _block_all(known, k)
        sums = _block_mean(np.where(known, gt, 0.0).astype(np.float64), k)
        gt = np.where(known_k, sums / k, np.inf).astype(np.float32)
        noc, known = _block_all(noc, k) & known_k, known_k
        calib = calib.scaled(k)
    disparity = np.where(known, gt, 0.0).astype(np.float32)
    K0, K1 = calib.cam0, calib.cam1
    f = float(K0[0, 0])
    with np.errstate(divide="ignore"):
        depth = np.where(known & (disparity + calib.doffs > 0), calib.baseline * f / (disparity + calib.doffs), 0.0)
    H, W = disparity.shape
    try:
        left_cam = Camera(K0, np.eye(4), W, H)
        c2w = np.eye(4)
        c2w[0, 3] = calib.baseline
        right_cam = Camera(K1, c2w, W, H)
    except ValueError as e:
        raise DatasetError(f"{folder / 'calib.txt'}: {e}") from None
    return StereoPair(folder.name, left_cam, right_cam, calib.baseline, linear_rgba(left), linear_rgba(right),
                      disparity, noc, known, depth.astype(np.float32), benchmark=benchmark, resolution=resolution,
                      left_image=left, right_image=right, doffs=calib.doffs, ndisp=calib.ndisp, vmin=calib.vmin,
                      vmax=calib.vmax, has_noc_mask=has_noc, source=str(folder))


# --------------------------------------------------------------------------- KITTI


def _kitti_root(path: str | Path) -> Path:
    root = _root(path)
    return root / "training" if (root / "training").is_dir() and not _kitti_dirs(root) else root


def _kitti_dirs(root: Path) -> tuple[tuple[str, str], tuple[str, str]] | None:
    imgs = next((d for d in KITTI_IMAGE_DIRS if (root / d[0]).is_dir()), None)
    gts = next((d for d in KITTI_GT_DIRS if (root / d[0]).is_dir()), None)
    return (imgs, gts) if imgs and gts else None


def read_kitti_calib(path: Path, left_dir: str) -> tuple[np.ndarray, np.ndarray]:
    """The rectified projection matrices (3, 4) of the left and right camera of a KITTI calibration file."""
    if path.parent.name == "calib_cam_to_cam":
        keys = ("P_rect_02", "P_rect_03")
    else:
        keys = ("P0", "P1") if left_dir == "image_0" else ("P2", "P3")
    found: dict[str, np.ndarray] = {}
    for no, raw in enumerate(path.read_text(encoding="ascii", errors="replace").splitlines(), start=1):
        key, sep, value = raw.partition(":")
        if sep and key.strip() in keys:
            try:
                P = np.array([float(v) for v in value.split()], dtype=np.float64)
            except ValueError:
                P = np.zeros(0)
            if P.size != 12 or not np.all(np.isfinite(P)) or P[0] <= 0:
                raise DatasetError(f"{path}: line {no}: {key.strip()}: expected 12 numbers of a 3x4 projection "
                                   "matrix with a positive focal length")
            found[key.strip()] = P.reshape(3, 4)
    missing = [k for k in keys if k not in found]
    if missing:
        raise DatasetError(f"{path}: no {', '.join(missing)} line (expected {keys[0]} and {keys[1]})")
    return found[keys[0]], found[keys[1]]


def load_kitti(path: str | Path) -> list[StereoPair]:
    """Every `<id>_10.png` pair with ground truth under a KITTI 2012/2015 `training` folder (module docstring)."""
    root = _kitti_root(path)
    dirs = _kitti_dirs(root)
    if dirs is None:
        raise DatasetError(f"{root}: not a KITTI stereo folder (expected image_2/image_3, colored_0/colored_1 or "
                           "image_0/image_1, with disp_occ_0 or disp_occ)")
    (ldir, rdir), (occ_dir, noc_dir) = dirs
    ids = sorted(p.name[:-len("_10.png")] for p in (root / occ_dir).glob("*_10.png"))
    if not ids:
        raise DatasetError(f"{root / occ_dir}: holds no <id>_10.png ground truth")
    calib_dir = next(((root / d, keys) for d, keys in KITTI_CALIB if (root / d).is_dir()), None)
    pairs = []
    for i in ids:
        name = f"{i}_10.png"
        left, right = read_image(root / ldir / name), read_image(root / rdir / name)
        shape = left.shape[:2]
        _same_size(root / rdir / name, right, shape, f"{ldir}/{name}")
        gt, known = read_kitti_disparity(root / occ_dir / name)
        _same_size(root / occ_dir / name, gt, shape, f"{ldir}/{name}")
        gt_noc, noc = read_kitti_disparity(root / noc_dir / name)
        _same_size(root / noc_dir / name, gt_noc, shape, f"{ldir}/{name}")
        if np.any(noc & ~known):
            raise DatasetError(f"{root / noc_dir / name}: {int(np.sum(noc & ~known))} pixels valid here are invalid "
                               f"in {occ_dir}/{name} (the non-occluded ground truth must be a subset)")
        fg = None
        obj = root / "obj_map" / name
        if obj.is_file():
            fg = read_kitti_object_map(obj, shape)
        left_cam = right_cam = None
        baseline, depth = float("nan"), np.zeros(shape, np.float32)
        if calib_dir is not None:
            cpath = calib_dir[0] / f"{i}.txt"
            if not cpath.is_file():
                raise DatasetError(f"{cpath}: missing (its folder holds the other pairs' calibration)")
            Pl, Pr = read_kitti_calib(cpath, ldir)
            f = float(Pl[0, 0])
            baseline = float((Pl[0, 3] - Pr[0, 3]) / f)
            if not baseline > 0:
                raise DatasetError(f"{cpath}: the projection matrices give a baseline of {baseline:.6g}, expected > 0")
            K = Pl[:, :3].copy()
            H, W = shape
            c2w = np.eye(4)
            c2w[0, 3] = baseline
            try:
                left_cam, right_cam = Camera(K, np.eye(4), W, H), Camera(Pr[:, :3].copy(), c2w, W, H)
            except ValueError as e:
                raise DatasetError(f"{cpath}: {e}") from None
            with np.errstate(divide="ignore"):
                depth = np.where(known, baseline * f / np.where(known, gt, 1.0), 0.0).astype(np.float32)
        pairs.append(StereoPair(i, left_cam, right_cam, baseline, linear_rgba(left), linear_rgba(right),
                                np.where(known, gt, 0.0).astype(np.float32), noc, known, depth, benchmark="kitti",
                                left_image=left, right_image=right, foreground=fg,
                                source=str(root / ldir / name)))
    return pairs


# --------------------------------------------------------------------------- any


def detect_format(path: str | Path) -> str | None:
    """"kitti", "middlebury" or "eth3d" when `path` holds that layout (module docstring), else None."""
    root = Path(path)
    if not root.is_dir():
        return None
    if _kitti_dirs(root) or ((root / "training").is_dir() and _kitti_dirs(root / "training")):
        return "kitti"
    from research.datasets.middlebury2003 import scene_folders

    if scene_folders(root):
        return "middlebury2003"
    folders = _pair_folders(root)
    if not folders:
        return None
    if _gt_folder(folders[0]) != folders[0]:
        return "eth3d"  # ETH3D's separate ground-truth tree
    try:
        grey = read_image(folders[0] / "im0.png").ndim == 2
        doffs = read_calib(folders[0] / "calib.txt").doffs
    except (DatasetError, FileNotFoundError):
        return "middlebury"  # the reader will then name what is wrong
    return "eth3d" if grey or doffs == 0 else "middlebury"


def load_benchmark(path: str | Path, fmt: str | None = None, resolution: str = "full",
                   scale: float | None = None) -> list[StereoPair]:
    """The pairs of a benchmark folder in format `fmt` (detected when None); `scale`: Middlebury 2001/2003's
    ground-truth scale, overriding its table (research.datasets.middlebury2003)."""
    if fmt is not None and fmt not in FORMATS:
        raise ValueError(f"format: expected one of {FORMATS}, got {fmt!r}")
    _resolution(resolution)
    _root(path)
    fmt = fmt or detect_format(path)
    if fmt is None:
        raise DatasetError(f"{path}: not a stereo benchmark folder (Middlebury/ETH3D: im0.png, im1.png, calib.txt; "
                           "KITTI: image_2/image_3 or colored_0/colored_1 with disp_occ_0 or disp_occ)")
    if fmt == "kitti":
        if resolution != "full":
            raise ValueError(f"resolution: KITTI's sparse ground truth is evaluated at full resolution only, "
                             f"got {resolution!r}")
        return load_kitti(path)
    if fmt == "middlebury2003":
        if resolution != "full":
            raise ValueError(f"resolution: Middlebury 2001/2003 pairs are evaluated at their stored size only, "
                             f"got {resolution!r}")
        from research.datasets.middlebury2003 import load_middlebury2003

        return load_middlebury2003(path, scale)
    if scale is not None:
        raise ValueError(f"scale: applies to the middlebury2003 format only, got format {fmt!r}")
    return load_middlebury(path, resolution, benchmark=fmt)
