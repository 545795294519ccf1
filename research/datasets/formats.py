"""Which reader a data folder needs, and the evaluation targets of a dataset's protocol.

`detect_format(path)`: "drlab" (a folder written by `drlab dataset`: manifest.json), "blender"
(NeRF-synthetic / nerfstudio: transforms_train.json, or nerfstudio's single transforms.json), "llff"
(LLFF forward-facing: poses_bounds.npy, even beside a sparse/ folder; `--format colmap` reads that
as COLMAP), "colmap" (a COLMAP layout: sparse/0 or sparse/ holding a model; also a poses_bounds.npy
beside sparse/ whose cameras do not all face one way, `llff.faces_one_way`: Mip-NeRF 360's scenes
ship both, and are read as the 3DGS evaluation reads them), "middlebury_mview" (a Middlebury
multi-view folder: one *_par.txt), or None (not a dataset folder: the experiments then treat --data
as the cache root of their own renders, as before). `open_dataset(path, fmt, factor)` loads it.

The protocol's targets (`protocol_srgb`, `protocol_target_srgb`, `protocol_target_linear`): the
images composited on the protocol's background in sRGB, as the NeRF/3DGS evaluations do. What the
readers themselves share (images in straight-alpha sRGB, the Split contract, content hash, scene
bound) is research.datasets.external, which this dispatch imports nothing from.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from research import io
from research.datasets.loader import Dataset, Protocol, Split

FORMATS = ("drlab", "blender", "colmap", "llff", "middlebury_mview")


def detect_format(path: str | Path) -> str | None:
    """The format of the dataset folder `path` (module docstring), or None when it is none of them."""
    root = Path(path)
    if not root.is_dir():
        return None
    if (root / "manifest.json").is_file() and (root / "cameras.json").is_file():
        return "drlab"
    if (root / "transforms_train.json").is_file() or (root / "transforms.json").is_file():
        return "blender"
    if (root / "poses_bounds.npy").is_file():
        from research.datasets.llff import faces_one_way

        if (root / "sparse").is_dir() and not faces_one_way(root / "poses_bounds.npy"):
            return "colmap"  # Mip-NeRF 360: poses_bounds.npy of cameras all around, beside the COLMAP model
        return "llff"
    if (root / "sparse").is_dir():
        return "colmap"
    if any(p.is_file() for p in root.glob("*_par.txt")):
        return "middlebury_mview"
    return None


def open_dataset(path: str | Path, fmt: str, factor: int | None = None) -> Dataset:
    """Load `path` as format `fmt`; `factor`: the downscale factor (None: the dataset's protocol)."""
    if fmt not in FORMATS:
        raise ValueError(f"--format: expected one of {FORMATS}, got {fmt!r}")
    if fmt == "drlab":
        from research.datasets.loader import load

        if factor not in (None, 1):
            raise ValueError(f"--resolution: drlab datasets are read at their rendered size; got {factor}")
        return load(path)
    if fmt == "blender":
        from research.datasets.blender import load_blender

        return load_blender(path, factor=1 if factor is None else factor)
    if fmt == "llff":
        from research.datasets.llff import load_llff

        return load_llff(path, factor=factor)
    if fmt == "middlebury_mview":
        from research.datasets.middlebury_mview import load_middlebury_mview

        return load_middlebury_mview(path, factor=1 if factor is None else factor)
    from research.datasets.colmap import load_colmap

    return load_colmap(path, factor=factor)


def protocol_srgb(split: Split, protocol: Protocol | None) -> np.ndarray:
    """(N, H, W, 4): the sRGB colour premultiplied by alpha (colour x alpha, in sRGB) and alpha.

    Composited on a background b as `rgb + (1 - alpha) b`, this is the NeRF/3DGS target
    `srgb * alpha + (1 - alpha) b`. drlab's own datasets (no srgb): the sRGB of the linear image on
    black, and alpha (research.metrics.srgb_targets).
    """
    if split.srgb is None:
        from research.metrics import srgb_targets

        return srgb_targets(split.rgba)
    s = split.srgb.astype(np.float64)
    return np.concatenate([s[..., :3] * s[..., 3:], s[..., 3:]], axis=-1).astype(np.float32)


def protocol_target_srgb(split: Split, protocol: Protocol | None) -> np.ndarray:
    """(N, H, W, 3) the evaluation target in sRGB, clipped to [0, 1].

    drlab (no srgb in the split, or no protocol): the sRGB of the linear image on black
    (research.metrics.srgb_on_black). External data: the files' sRGB composited on the protocol's
    background in sRGB, `srgb * alpha + (1 - alpha) b` (opaque images: as they are).
    """
    if split.srgb is None or protocol is None:
        from research.metrics import srgb_on_black

        return srgb_on_black(split.rgba.astype(np.float64)).astype(np.float32)
    p = protocol_srgb(split, protocol).astype(np.float64)
    bg = np.asarray(protocol.background if protocol.background is not None else (0.0, 0.0, 0.0), np.float64)
    return np.clip(p[..., :3] + (1.0 - p[..., 3:]) * bg, 0.0, 1.0).astype(np.float32)


def protocol_target_linear(split: Split, protocol: Protocol | None) -> np.ndarray:
    """(N, H, W, 3) linear RGB whose sRGB encoding is `protocol_target_srgb` (drlab: the linear image on
    black as it is), so research.metrics' `srgb_on_black` of it gives that target back (to rounding)."""
    if split.srgb is None or protocol is None:
        return split.rgba[..., :3]
    return io.srgb_to_linear(protocol_target_srgb(split, protocol).astype(np.float64)).astype(np.float32)
