"""Middlebury multi-view stereo folders (Seitz et al., CVPR 2006: temple, dino and their rings).

Layout (the release, e.g. templeRing/):

    templeR0001.png ... templeR0047.png    the photographs (640x480 RGB, opaque)
    templeR_par.txt                        the calibration, one camera per image
    templeR_ang.txt                        latitude and longitude of each view (not needed; not read)
    README.txt                             the object's tight bounding box (read when present)

`<name>_par.txt`: the first line is the number of cameras n, then n lines, one per image:

    imgname.png k11 k12 k13 k21 k22 k23 k31 k32 k33 r11 r12 r13 r21 r22 r23 r31 r32 r33 t1 t2 t3

K and R row-major. The projection of a world point X is x ~ K (R X + t): R, t map world to camera
(world-to-camera), and the camera frame is OpenCV's (+x right, +y down, +z forward; the release says
"the image origin is top-left, with x increasing horizontally, y vertically"). drlab's Camera holds
camera-to-world, so c2w = [[R^T, -R^T t], [0, 1]] (the camera centre is -R^T t).

Pixel centres: the file's pixel (i, j) is taken to be centred at (i, j), the convention of the
calibration toolboxes and of the multi-view stereo codes that read these files (PMVS, OpenMVG's
Middlebury loader use x = K(RX + t) directly as integer pixel indices); drlab centres pixel (i, j) at
(i + 0.5, j + 0.5) (research.cameras), so cx and cy are moved by +0.5 (`PIXEL_CENTRE_OFFSET`). The
release does not state it; the choice moves every projection by half a pixel, 0.02 degrees of view
direction at templeRing's focal length of 1520 px.

Refused, each in one line naming the file (and the line, for a camera): no `*_par.txt` or several; a
first line that is not a positive count; a count that differs from the number of camera lines; a
camera line without exactly 22 fields (name and 21 numbers); a number that does not parse or is not
finite; a name listed twice; an image listed but missing; images of different sizes; K not upper
triangular with k33 = 1 (k21, k31, k32 must be 0); a focal length k11 or k22 <= 0; skew (k12 != 0:
drlab's rasterisers and ray generators are skew-free pinholes, so skew is refused, not supported); a
principal point outside the image; R not a rotation (kernels/rotation.py's one check: max
|R^T R - I| <= 1e-5 and det R > 0, which 6-8 digit text passes; templeRing's rotations are stored with
17-20 digits).

Protocol ("middlebury-mview-hold8"): the cameras sorted by image name, every 8th (index % 8 == 0) is
a test view, the rest train (the llffhold 8 rule of the Mip-NeRF 360 / 3DGS evaluations; templeRing:
6 test views, 41 train). The photographs are opaque RGB: nothing is composited. Their background is
the black cloth of the capture rig (real pixels, dark but not exactly 0, with shadows and the
object's dark border): it is trained and scored like every other pixel, and splats render on a
black background. PSNR and SSIM on sRGB in [0, 1] over the whole image (research.metrics).
`object_box` (README.txt's tight bounding box, when the file has one) lets a caller also score only
the pixels whose rays cross that box (`box_mask`), a region given by the dataset itself.

Scene bound: README.txt's bounding box when present, else `external.bound_from_cameras`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kernels.rotation import checked_rotation
from research.cameras import Camera
from research.datasets import external
from research.datasets.integrity import DatasetError
from research.datasets.loader import Dataset, Protocol, Split, View, _image_size

PAR_SUFFIX = "_par.txt"
HOLD = 8  # every 8th camera by name is a test view
PIXEL_CENTRE_OFFSET = 0.5  # the file's pixel (i, j) is centred at (i, j); drlab's at (i + 0.5, j + 0.5)
_FIELDS = 22
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_BOX = re.compile(r"bounding box[^(]*\(\s*(" + _NUMBER + r")\s+(" + _NUMBER + r")\s+(" + _NUMBER + r")\s*\)\s*\(\s*("
                  + _NUMBER + r")\s+(" + _NUMBER + r")\s+(" + _NUMBER + r")\s*\)", re.IGNORECASE | re.DOTALL)


@dataclass(frozen=True)
class ParEntry:
    """One camera of a *_par.txt file, as stored: x ~ K (R X + t), the file's pixel convention."""

    name: str
    K: np.ndarray  # (3, 3)
    R: np.ndarray  # (3, 3) world-to-camera rotation (re-orthonormalised by the rotation check)
    t: np.ndarray  # (3,)
    line: int  # 1-based line number in the file


def find_par(root: Path) -> Path:
    """The one `*_par.txt` in `root`; DatasetError naming the folder when there is none or several."""
    found = sorted(p for p in root.glob(f"*{PAR_SUFFIX}") if p.is_file())
    if not found:
        raise DatasetError(f"{root}: no *{PAR_SUFFIX} (a Middlebury multi-view folder has <name>{PAR_SUFFIX} "
                           "beside its images)")
    if len(found) > 1:
        raise DatasetError(f"{root}: several *{PAR_SUFFIX} files ({', '.join(p.name for p in found)}); expected one")
    return found[0]


def _check_K(where: str, K: np.ndarray) -> None:
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[2, 2] != 1.0:
        raise DatasetError(f"{where}: K is not upper triangular with k33 = 1 (k21, k31, k32 = {K[1, 0]:g}, "
                           f"{K[2, 0]:g}, {K[2, 1]:g}; k33 = {K[2, 2]:g})")
    if K[0, 0] <= 0.0 or K[1, 1] <= 0.0:
        raise DatasetError(f"{where}: focal lengths k11, k22 must be > 0, got {K[0, 0]:g}, {K[1, 1]:g}")
    if K[0, 1] != 0.0:
        raise DatasetError(f"{where}: skew k12 = {K[0, 1]:g} is not supported (drlab's cameras are skew-free "
                           "pinholes)")


def read_par(path: str | Path) -> list[ParEntry]:
    """Parse a Middlebury *_par.txt exactly (module docstring); DatasetError in one line on any fault."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot be read ({' '.join(str(e).split())})") from None
    lines = [(k + 1, ln.split()) for k, ln in enumerate(text.splitlines()) if ln.strip()]
    if not lines:
        raise DatasetError(f"{path}: empty (expected the number of cameras on the first line)")
    first_no, first = lines[0]
    if len(first) != 1 or not first[0].isdigit() or int(first[0]) < 1:
        raise DatasetError(f"{path}: line {first_no}: expected the number of cameras (an integer >= 1), got "
                           f"{' '.join(first)!r}")
    count = int(first[0])
    body = lines[1:]
    if len(body) != count:
        raise DatasetError(f"{path}: count mismatch: the first line says {count} cameras, the file lists {len(body)}")
    entries, seen = [], {}
    for no, fields in body:
        name = fields[0]
        where = f"{path}: line {no} ({name})"
        if len(fields) != _FIELDS:
            raise DatasetError(f"{where}: expected {_FIELDS} fields (image name, 9 of K, 9 of R, 3 of t), got "
                               f"{len(fields)}")
        try:
            v = np.array([float(x) for x in fields[1:]], dtype=np.float64)
        except ValueError:
            bad = next(x for x in fields[1:] if not _is_float(x))
            raise DatasetError(f"{where}: {bad!r} is not a number") from None
        if not np.all(np.isfinite(v)):
            raise DatasetError(f"{where}: contains a non-finite number")
        if name in seen:
            raise DatasetError(f"{where}: image {name!r} is listed twice (also on line {seen[name]})")
        seen[name] = no
        K, R, t = v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:21]
        _check_K(where, K)
        try:
            R = checked_rotation("R", R)
        except ValueError as e:
            raise DatasetError(f"{where}: {' '.join(str(e).split())}") from None
        entries.append(ParEntry(name, K, R, t, no))
    return entries


def _is_float(x: str) -> bool:
    try:
        float(x)
    except ValueError:
        return False
    return True


def camera_from_par(entry: ParEntry, width: int, height: int) -> Camera:
    """drlab's Camera (OpenCV camera-to-world; pixel centres at +0.5) of a par entry."""
    K = entry.K.copy()
    K[0, 2] += PIXEL_CENTRE_OFFSET
    K[1, 2] += PIXEL_CENTRE_OFFSET
    c2w = np.eye(4)
    c2w[:3, :3] = entry.R.T
    c2w[:3, 3] = -entry.R.T @ entry.t
    return Camera(K, c2w, width, height)


def par_line(name: str, camera: Camera) -> str:
    """The *_par.txt line of a drlab Camera (the inverse of `camera_from_par`; 17 significant digits)."""
    K = np.asarray(camera.K, dtype=np.float64).copy()
    K[0, 2] -= PIXEL_CENTRE_OFFSET
    K[1, 2] -= PIXEL_CENTRE_OFFSET
    w2c = camera.w2c
    values = [*K.ravel(), *w2c[:3, :3].ravel(), *w2c[:3, 3]]
    return " ".join([name, *(f"{x:.17g}" for x in values)])


def read_object_box(root: Path) -> np.ndarray | None:
    """README.txt's "bounding box ... (x y z) (x y z)" as a (2, 3) box, or None when there is none."""
    readme = root / "README.txt"
    if not readme.is_file():
        return None
    m = _BOX.search(readme.read_text(errors="replace"))
    if m is None:
        return None
    box = np.array([float(x) for x in m.groups()], dtype=np.float64).reshape(2, 3)
    if not np.all(box[1] > box[0]):
        raise DatasetError(f"{readme}: the bounding box must have min < max per axis, got {box.tolist()}")
    return box


def box_mask(camera: Camera, box: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels whose ray through the pixel centre crosses the box (slab test)."""
    o, d = camera.rays(normalize=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0, t1 = (box[0] - o) * inv, (box[1] - o) * inv
    lo = np.nanmax(np.minimum(t0, t1), axis=-1)
    hi = np.nanmin(np.maximum(t0, t1), axis=-1)
    return (hi >= np.maximum(lo, 0.0)) & (hi > 0)


def middlebury_protocol(width: int, height: int, n_test: int, n_train: int) -> Protocol:
    return Protocol("middlebury-mview-hold8", "train", "test", f"{width}x{height}", None,
                    f"Middlebury multi-view: cameras by image name, every {HOLD}th (index % {HOLD} == 0) a test view "
                    f"({n_test} test / {n_train} train); {width}x{height}; opaque photographs, the black cloth "
                    "background scored like every pixel; PSNR and SSIM (11x11 Gaussian window, sigma 1.5) on sRGB "
                    "in [0,1]; research.metrics")


def load_middlebury_mview(path: str | Path, factor: int = 1) -> Dataset:
    """Read a Middlebury multi-view folder (module docstring) as a research.datasets Dataset.

    `factor` downscales by box averaging (K scaled). The calibration, names and sizes are checked
    here; pixels are read by `Dataset.load_split`.
    """
    factor = external.check_factor(factor)
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such dataset folder")
    par = find_par(root)
    entries = sorted(read_par(par), key=lambda e: e.name)
    files, size0 = {}, None
    for e in entries:
        img = root / e.name
        if not img.is_file():
            raise DatasetError(f"{par}: line {e.line}: image {e.name!r} is listed but {img} is missing")
        size = _image_size(img)
        if size0 is None:
            size0 = (img, size)
        elif size != size0[1]:
            raise DatasetError(f"{img}: image is {size[0]}x{size[1]}, but {size0[0].name} is {size0[1][0]}x"
                               f"{size0[1][1]} (every image of the folder must have one size)")
        if size[0] % factor or size[1] % factor:
            raise DatasetError(f"{img}: image is {size[0]}x{size[1]}, not divisible by the downscale factor {factor}")
        cx, cy = e.K[0, 2] + PIXEL_CENTRE_OFFSET, e.K[1, 2] + PIXEL_CENTRE_OFFSET
        if not (0.0 < cx < size[0] and 0.0 < cy < size[1]):
            raise DatasetError(f"{par}: line {e.line} ({e.name}): the principal point ({e.K[0, 2]:g}, {e.K[1, 2]:g}) "
                               f"is outside the {size[0]}x{size[1]} image")
        files[e.name] = img
    assert size0 is not None
    w, h = size0[1]
    views = []
    for i, e in enumerate(entries):
        cam = camera_from_par(e, w, h)
        if factor > 1:
            cam = Camera(np.diag([1.0 / factor, 1.0 / factor, 1.0]) @ cam.K, cam.c2w, w // factor, h // factor)
        views.append(View(e.name, "test" if i % HOLD == 0 else "train", cam, root))
    if len(views) < 2:
        raise DatasetError(f"{par}: {len(views)} camera; the protocol (every {HOLD}th a test view) needs at least 2")
    cams = [v.camera for v in views]
    box = read_object_box(root)
    bbox = box if box is not None else external.bound_from_cameras(cams)

    def load_views(selected: list[View]) -> Split:
        return external.load_split(selected, files, factor)

    read = [par] + list(files.values()) + ([root / "README.txt"] if box is not None else [])
    n_test = sum(v.split == "test" for v in views)
    manifest = {"format": "middlebury_mview", "content_hash": external.content_hash(root, read), "factor": factor,
                "root": str(root), "par": par.name, "object_box": None if box is None else box.tolist()}
    return Dataset(root, manifest, views, bbox, external.up_from_cameras(cams), format="middlebury_mview",
                   scene=root.resolve().name,
                   protocol=middlebury_protocol(cams[0].width, cams[0].height, n_test, len(views) - n_test),
                   split_loader=load_views)


def scene_radius(cameras: list[Camera]) -> float:
    """The median distance of the camera centres from their centroid (the unit of camera-centre errors)."""
    c = np.array([cam.center for cam in cameras])
    r = float(np.median(np.linalg.norm(c - c.mean(axis=0), axis=1)))
    if not (math.isfinite(r) and r > 0):
        raise ValueError("cameras: the centres coincide; no scene radius")
    return r
