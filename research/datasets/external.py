"""What the readers of external dataset formats share (research.datasets.blender, colmap, llff, middlebury_mview).

Images in straight-alpha sRGB (PNG or JPEG), their downscaling and their conversion to the Split
contract (linear, premultiplied), the downscale factor's check, a content hash over the files read,
a scene bound and up direction from the cameras, and the every-8th-image test split of LLFF and
Mip-NeRF 360 (LLFFHOLD, llffhold_protocol). Which reader a folder needs is
research.datasets.formats, which imports the readers; the readers import this module, never that one.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from research import io
from research.cameras import Camera
from research.datasets.integrity import DatasetError
from research.datasets.loader import Protocol, Split, View


LLFFHOLD = 8  # every 8th image by name is a test view (NeRF's and 3DGS's llffhold)


def llffhold_protocol(name: str, method: str, factor: int, width: int, height: int, note: str = "") -> Protocol:
    """The llffhold protocol of `method` (e.g. "LLFF protocol (NeRF)") on the photographs at 1/factor
    (width x height): its test views, folder and metrics; `note` ("...; ") goes before the metrics module."""
    folder = image_folder_name(factor)
    return Protocol(name, "train", "test", f"{folder} ({width}x{height})", None,
                    f"{method}: every {LLFFHOLD}th image by name is a test view (llffhold {LLFFHOLD}); {folder}; "
                    f"opaque photographs; PSNR and SSIM (11x11 Gaussian window, sigma 1.5) on sRGB in [0,1]; "
                    f"{note}research.metrics")


def check_factor(factor: object) -> int:
    if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
        raise ValueError(f"factor: expected a downscale factor, an integer >= 1, got {factor!r}")
    return int(factor)


def image_folder_name(factor: int) -> str:
    """The folder of the photographs at 1/factor size in COLMAP / Mip-NeRF 360 and LLFF captures."""
    return "images" if factor == 1 else f"images_{factor}"


def image_folder(root: Path, factor: int) -> Path:
    """root's images/ (factor 1) or images_<factor>/; DatasetError naming the folders present if it is missing."""
    folder = root / image_folder_name(factor)
    if not folder.is_dir():
        present = sorted(p.name for p in root.iterdir() if p.is_dir() and p.name.startswith("images"))
        raise DatasetError(f"{folder}: missing (the images at 1/{factor}; folders present: "
                           f"{', '.join(present) or 'none'}; choose --resolution accordingly)")
    return folder


def read_srgb(path: Path) -> np.ndarray:
    """An 8- or 16-bit PNG or a JPEG as straight-alpha sRGB RGBA float32 in [0, 1] (alpha 1 if absent)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".png":
            x = io.read_png(path, linear=False)
        elif suffix in (".jpg", ".jpeg"):
            pixels, spec = io._oiio_read(path, "jpeg", None)
            if pixels.dtype != np.uint8:
                raise DatasetError(f"{path}: expected an 8-bit JPEG, got pixel format {spec.format}")
            x = pixels.astype(np.float32) / np.float32(255.0)
        else:
            raise DatasetError(f"{path}: expected a .png, .jpg or .jpeg image")
    except (ValueError, OSError) as e:  # OpenImageIO's messages can span lines: one line, naming the file
        msg = " ".join(str(e).split())
        raise DatasetError(msg if str(path) in msg else f"{path}: {msg}") from None
    c = x.shape[2]
    if c == 1:
        x = np.repeat(x, 3, axis=2)
    elif c == 2:
        x = np.concatenate([np.repeat(x[..., :1], 3, axis=2), x[..., 1:]], axis=2)
    if x.shape[2] == 3:
        x = np.concatenate([x, np.ones_like(x[..., :1])], axis=2)
    return np.ascontiguousarray(x[..., :4], dtype=np.float32)


def downscale(img: np.ndarray, factor: int, path: Path) -> np.ndarray:
    """Box average over factor x factor blocks of the straight values (OpenCV's INTER_AREA at an
    integer factor, what the NeRF code uses for its half-resolution images)."""
    if factor == 1:
        return img
    h, w = img.shape[:2]
    if h % factor or w % factor:
        raise DatasetError(f"{path}: image is {w}x{h}, not divisible by the downscale factor {factor}")
    return img.reshape(h // factor, factor, w // factor, factor, -1).mean(axis=(1, 3), dtype=np.float64) \
        .astype(np.float32)


def split_from_srgb(cameras: list[Camera], srgb: list[np.ndarray], names: list[str]) -> Split:
    """The Split contract (linear premultiplied RGBA; no depth, no mask) from straight sRGB images."""
    s = np.stack(srgb) if srgb else np.zeros((0, 1, 1, 4), np.float32)
    alpha = s[..., 3:]
    rgba = np.concatenate([io.srgb_to_linear(s[..., :3]) * alpha, alpha], axis=-1).astype(np.float32)
    return Split(cameras, rgba, None, None, names, srgb=s)


def read_views(selected: list[View], files: Mapping[str, Path], factor: int = 1) -> list[np.ndarray]:
    """Each view's image from files[view.name] (read_srgb, then downscale), checked against its camera's size
    (the reader checked the sizes without the pixels; a file rewritten since then is a DatasetError)."""
    images = []
    for v in selected:
        path = files[v.name]
        im = downscale(read_srgb(path), factor, path)
        if im.shape[:2] != (v.camera.height, v.camera.width):
            raise DatasetError(f"{path}: image changed on disk: now {im.shape[1]}x{im.shape[0]}")
        images.append(im)
    return images


def load_split(selected: list[View], files: Mapping[str, Path], factor: int = 1) -> Split:
    """The Split of the selected views: read_views, then split_from_srgb."""
    return split_from_srgb([v.camera for v in selected], read_views(selected, files, factor),
                           [str(files[v.name]) for v in selected])


def content_hash(root: Path, files: Iterable[Path]) -> str:
    """SHA-256 over (path relative to root, bytes) of every file read, in sorted order."""
    h = hashlib.sha256()
    for f in sorted(set(files)):
        h.update(str(f.relative_to(root)).encode())
        h.update(b"\0")
        with open(f, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def bound_from_cameras(cameras: list[Camera]) -> np.ndarray:
    """A box for an inward-looking capture: the cube centred where the optical axes come closest to
    each other (least squares), of half-size d tan(fov_x / 2) with d the median camera distance to
    that point -- what a camera's field of view spans there (1.45 for NeRF-synthetic's cameras at
    radius 4.03 with camera_angle_x 0.69, whose objects lie within 1.5)."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c in cameras:
        d = c.R[:, 2]
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c.center
    if np.linalg.cond(A) > 1e8:  # parallel axes (a forward-facing capture): the point before the mean camera
        centres = np.array([c.center for c in cameras])
        spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) or 1.0
        focus = centres.mean(0) + spread * np.mean([c.R[:, 2] for c in cameras], axis=0)
    else:
        focus = np.linalg.solve(A, b)
    dist = float(np.median([np.linalg.norm(c.center - focus) for c in cameras]))
    half = dist * float(np.median([(c.width / 2.0) / c.fx for c in cameras]))
    if not np.isfinite(half) or half <= 0:
        raise DatasetError("cameras: cannot derive a scene bound (the cameras coincide)")
    return np.array([focus - half, focus + half])


def up_from_cameras(cameras: list[Camera]) -> np.ndarray:
    """The mean of the cameras' image-up directions (-y of the OpenCV frame), normalised."""
    up = -np.mean([c.R[:, 1] for c in cameras], axis=0)
    n = float(np.linalg.norm(up))
    return up / n if n > 1e-9 else np.array([0.0, 0.0, 1.0])
