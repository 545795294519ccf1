"""Tiny datasets in the exact formats of NeRF-synthetic and COLMAP / Mip-NeRF 360, written by the tests.

Images are random textures (seeded), 16x16 by default; the cameras look at the origin from a ring.
COLMAP models are written through pycolmap's own writer (binary or text).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from research import io
from research.cameras import Camera, look_at


REPO = Path(__file__).resolve().parents[2]


def smoke_run(experiment: str, data: Path, tmp_path: Path, fields: tuple[str, ...] = ("grid",)) -> tuple[dict, Path]:
    """`python -m experiments.<experiment> --smoke` on the dataset folder `data` (fit_splats writes its PLY into
    tmp_path, fit_nerf fits `fields`); asserts it exits 0 and returns its metrics and its output folder."""
    out = tmp_path / "out"
    extra = ["--ply", str(tmp_path / "m.ply")] if experiment == "fit_splats" else ["--fields", *fields]
    r = subprocess.run([sys.executable, "-m", f"experiments.{experiment}", "--smoke", "--no-progress", "--data",
                        str(data), "--out", str(out), *extra], cwd=REPO, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return json.loads((out / "metrics.json").read_text())["metrics"], out


def ring_cameras(n: int, width: int = 16, height: int = 16, fov_x_deg: float = 50.0, radius: float = 4.0):
    cams = []
    for k in range(n):
        a = 2 * math.pi * k / n
        eye = (radius * math.cos(a), radius * math.sin(a), 1.0 + 0.3 * math.sin(3 * a))
        cams.append(Camera.from_fov(fov_x_deg, width, height, look_at(eye, (0.0, 0.0, 0.0))))
    return cams


def write_rgba(path: Path, rng, width: int, height: int, alpha: bool = True) -> np.ndarray:
    img = rng.integers(0, 256, (height, width, 4 if alpha else 3), dtype=np.uint8)
    if alpha:
        img[:3, :, 3] = 0  # a transparent band, as around NeRF-synthetic objects
        img[3:, :, 3] = np.maximum(img[3:, :, 3], 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    io.write_png_u8(path, img)
    return img


OFFICIAL_DRIFT = 6.25e-7  # R (I + eps S), S symmetric with unit off-diagonal entries: max |R^T R - I| = 2 eps


def official_precision(M: np.ndarray, drift: float = 0.0) -> list[list[float]]:
    """A 4x4 `transform_matrix` as the official NeRF-synthetic files hold it: float32 values written as JSON
    numbers (Blender's matrices are float32), the rotation part first moved off orthonormal by `drift`
    (R (I + drift S): max |R^T R - I| ~ 2 drift, as the float32 products before storage leave it; the
    official lego transforms_train.json reaches 1.25e-6)."""
    M = np.array(M, dtype=np.float64)
    S = np.array([[0.0, 1.0, -1.0], [1.0, 0.0, 1.0], [-1.0, 1.0, 0.0]])
    M[:3, :3] = M[:3, :3] @ (np.eye(3) + drift * S)
    return [[float(np.float32(x)) for x in row] for row in M]


def write_blender(root: Path, views: dict[str, int] | None = None, size: int = 16, nerfstudio: str | None = None,
                  seed: int = 0, float32: bool = False) -> dict[str, list[Camera]]:
    """A NeRF-synthetic folder: transforms_<split>.json with camera_angle_x (or nerfstudio intrinsics:
    nerfstudio="global" or "frame") and RGBA PNGs train/r_<k>.png; returns the (exact) cameras per split.
    float32: the matrices at the official files' precision (`official_precision`), the first train
    frame's with OFFICIAL_DRIFT (max |R^T R - I| about 1.25e-6, as lego's frame 88)."""
    views = views or {"train": 4, "val": 1, "test": 2}
    rng = np.random.default_rng(seed)
    total = sum(views.values())
    cams = ring_cameras(total, size, size)
    out, k = {}, 0
    for split, n in views.items():
        frames, out[split] = [], []
        for i in range(n):
            cam = cams[k]
            k += 1
            write_rgba(root / split / f"r_{i}.png", rng, size, size)
            matrix = cam.to_nerf().tolist()
            if float32:
                matrix = official_precision(cam.to_nerf(), OFFICIAL_DRIFT if (split, i) == ("train", 0) else 0.0)
            frame = {"file_path": f"./{split}/r_{i}", "rotation": 0.0, "transform_matrix": matrix}
            if nerfstudio == "frame":
                frame.update(fl_x=cam.fx, fl_y=cam.fy, cx=cam.cx, cy=cam.cy, w=size, h=size)
            frames.append(frame)
            out[split].append(cam)
        doc: dict = {"frames": frames}
        if nerfstudio == "global":
            doc.update(fl_x=cams[0].fx, fl_y=cams[0].fy, cx=cams[0].cx, cy=cams[0].cy, w=size, h=size)
        elif nerfstudio is None:
            doc["camera_angle_x"] = math.radians(cams[0].fov_x_deg)
        (root / f"transforms_{split}.json").write_text(json.dumps(doc, indent=1))
    return out


COLMAP_PARAMS = {  # intrinsics of a 16x12 camera per model; distortion 0 unless `distorted`
    "SIMPLE_PINHOLE": [18.0, 8.0, 6.0],
    "PINHOLE": [18.0, 19.0, 8.5, 5.5],
    "SIMPLE_RADIAL": [18.0, 8.0, 6.0, 0.0],
    "RADIAL": [18.0, 8.0, 6.0, 0.0, 0.0],
    "OPENCV": [18.0, 19.0, 8.5, 5.5, 0.0, 0.0, 0.0, 0.0],
}


def write_colmap(root: Path, n: int = 9, model: str = "PINHOLE", text: bool = False, factors=(1, 2),
                 distorted: bool = False, width: int = 16, height: int = 12, points: int = 50,
                 seed: int = 0, layout: str = "sparse/0") -> list[Camera]:
    """A Mip-NeRF 360-style folder: images/ (+ images_N), `layout` with a model written by pycolmap.

    Returns the OpenCV cameras at full size (image k is named img_<k>.png; sorted order = k)."""
    import pycolmap

    from research.datasets.colmap import colmap_from_c2w

    rng = np.random.default_rng(seed)
    params = list(COLMAP_PARAMS[model])
    if distorted:
        params[-1 if model != "OPENCV" else 4] = 0.05
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=width, height=height, params=params,
                                                    camera_id=1))
    cams = ring_cameras(n, width, height)
    for k, cam in enumerate(cams):
        R, t = colmap_from_c2w(cam.c2w)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(R), t)
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"img_{k:02d}.png", camera_id=1, image_id=k + 1), pose)
        for f in factors:
            folder = root / ("images" if f == 1 else f"images_{f}")
            write_rgba(folder / f"img_{k:02d}.png", rng, math.ceil(width / f), math.ceil(height / f), alpha=False)
    xyz = rng.uniform(-1.0, 1.0, (points, 3))
    for p in xyz:
        rec.add_point3D(p, pycolmap.Track(), rng.integers(0, 256, 3).astype(np.uint8))
    d = root / layout
    d.mkdir(parents=True, exist_ok=True)
    (rec.write_text if text else rec.write_binary)(str(d))
    return cams
