"""A small, feature-rich Mitsuba render for the SfM tests: noise-textured boxes on a noise-textured
ground under a constant sky, seen from a ring of cameras. Returns the ground-truth cameras."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from research import io
from research.cameras import Camera, look_at
from research.datasets.render import SceneRenderer
from research.datasets.scenes import SceneSpec


def _noise_texture(seed: int, cells: int = 24) -> np.ndarray:
    """Random colours on a `cells` x `cells` grid: squares of a few pixels in the views (blobs for SIFT)."""
    rng = np.random.default_rng(seed)
    grey = rng.uniform(0.02, 1.0, (cells, cells, 1)) ** 2  # SIFT sees the luminance: contrast in grey
    tint = rng.uniform(0.6, 1.0, (cells, cells, 3))
    return np.ascontiguousarray((grey * tint).astype(np.float32))


def _build() -> dict:
    import mitsuba as mi

    def textured(seed, cells=24):
        return {"type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": mi.Bitmap(_noise_texture(seed, cells)),
                                                   "filter_type": "nearest"}}

    def T(M):
        return mi.ScalarTransform4f(np.asarray(M, dtype=np.float64).tolist())

    def box(center, half):
        M = np.diag([half, half, half, 1.0])
        M[:3, 3] = center
        return T(M)

    return {"type": "scene", "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
            "ground": {"type": "rectangle", "to_world": T(np.diag([2.0, 2.0, 1.0, 1.0])), "bsdf": textured(1)},
            "a": {"type": "cube", "to_world": box([-0.5, -0.3, 0.4], 0.4), "bsdf": textured(2, 6)},
            "b": {"type": "cube", "to_world": box([0.6, 0.4, 0.3], 0.3), "bsdf": textured(3, 6)}}


TEXTURED = SceneSpec(name="textured-test", description="noise-textured boxes (SfM test)", build=_build,
                     bbox_min=(-2.0, -2.0, 0.0), bbox_max=(2.0, 2.0, 0.8), up=(0.0, 0.0, 1.0),
                     target=(0.0, 0.0, 0.2), radius=3.5, fov_x_deg=50.0)


def ring(n: int, res: int) -> list[Camera]:
    cams = []
    for k in range(n):
        a = 2 * math.pi * k / n
        el = math.radians(40.0 + 10.0 * math.sin(2 * a))
        r = TEXTURED.radius * (1.0 + 0.1 * math.cos(3 * a))
        eye = np.array(TEXTURED.target) + r * np.array([math.cos(el) * math.cos(a), math.cos(el) * math.sin(a),
                                                         math.sin(el)])
        cams.append(Camera.from_fov(TEXTURED.fov_x_deg, res, res, look_at(eye, TEXTURED.target, TEXTURED.up)))
    return cams


def render_textured(folder: Path, n: int = 24, res: int = 128, spp: int = 16) -> list[Camera]:
    """PNGs folder/v_<k>.png of `n` ring views; their cameras."""
    folder.mkdir(parents=True, exist_ok=True)
    renderer = SceneRenderer(TEXTURED, spp=spp)
    cams = ring(n, res)
    for k, cam in enumerate(cams):
        io.write_png(folder / f"v_{k:02d}.png", renderer.render_rgba(cam, k))
    return cams
