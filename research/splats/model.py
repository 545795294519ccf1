"""The splat model: parameter arrays, initialisation from points, and rendering a Camera.

Parameters follow the 3DGS code and its PLY layout: means (N, 3), log-scales (N, 3),
quaternions (w, x, y, z) (N, 4, unnormalised), opacity logits (N,), and SH
coefficients split into the DC term (N, 1, 3) and the rest (N, 15, 3) (degree 3),
which have different learning rates. Arrays are float32 NumPy; `inputs(device)` hands them to the
kernels as wp.arrays on the device, so renders and gradients come back as wp.arrays there.

Initialisation (3DGS): a point with colour c gets SH DC (c - 1/2) / C0, zero higher
SH, opacity 0.1, identity rotation, and an isotropic scale equal to the RMS
distance to its 3 nearest neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import warp as wp
from scipy.spatial import cKDTree

from kernels import _arrays as A
from kernels import splat as ks
from kernels.sh import SH_C0
from research.cameras import Camera
from research.io import srgb_to_linear

SH_COEFFS = 16


@dataclass
class GaussianModel:
    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray

    def __post_init__(self) -> None:
        n = len(np.asarray(self.means))
        shapes = {"means": (n, 3), "log_scales": (n, 3), "quats": (n, 4), "opacity_logits": (n,),
                  "sh_dc": (n, 1, 3), "sh_rest": (n, SH_COEFFS - 1, 3)}
        for name, shape in shapes.items():
            arr = np.ascontiguousarray(getattr(self, name), dtype=np.float32)
            if arr.shape != shape:
                raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{name}: contains NaN or infinite values")
            setattr(self, name, arr)

    @staticmethod
    def names() -> tuple[str, ...]:
        return tuple(f.name for f in fields(GaussianModel))

    @property
    def n(self) -> int:
        return len(self.means)

    @property
    def sh(self) -> np.ndarray:
        return np.concatenate([self.sh_dc, self.sh_rest], axis=1)

    @property
    def opacities(self) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-self.opacity_logits))

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in self.names()}

    def select(self, index: np.ndarray) -> "GaussianModel":
        return GaussianModel(**{k: v[index] for k, v in self.arrays().items()})

    def append(self, other: "GaussianModel") -> "GaussianModel":
        return GaussianModel(**{k: np.concatenate([v, getattr(other, k)]) for k, v in self.arrays().items()})

    def copy(self) -> "GaussianModel":
        return GaussianModel(**{k: v.copy() for k, v in self.arrays().items()})

    def inputs(self, device: Any = None) -> ks.GaussianInputs:
        """The parameters, checked, as wp.arrays on `device` (None: the CPU)."""
        dev = A.get_device(device)
        arrays = [wp.array(x, dtype=wp.float32, device=dev)
                  for x in (self.means, self.log_scales, self.quats, self.opacity_logits, self.sh)]
        return ks.gaussian_inputs(*arrays, device=dev)


def logit(p: float) -> float:
    return float(np.log(p / (1.0 - p)))


def from_points(points: np.ndarray, colors: np.ndarray, init_opacity: float = 0.1) -> GaussianModel:
    """3DGS initialisation from a coloured point cloud (module docstring)."""
    points = np.asarray(points, dtype=np.float64)
    colors = np.asarray(colors, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 4:
        raise ValueError(f"points: expected shape (N >= 4, 3), got {points.shape}")
    if colors.shape != points.shape:
        raise ValueError(f"colors: expected shape {points.shape}, got {colors.shape}")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(colors))):
        raise ValueError("points, colors: contain NaN or infinite values")
    dist, _ = cKDTree(points).query(points, k=4)
    mean_sq = np.maximum((dist[:, 1:] ** 2).mean(axis=1), 1e-7)
    n = len(points)
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    return GaussianModel(
        means=points,
        log_scales=np.repeat(0.5 * np.log(mean_sq)[:, None], 3, axis=1),
        quats=quats,
        opacity_logits=np.full(n, logit(init_opacity)),
        sh_dc=((colors - 0.5) / SH_C0)[:, None, :],
        sh_rest=np.zeros((n, SH_COEFFS - 1, 3)),
    )


def points_from_depth(cameras: list[Camera], rgba: np.ndarray, depth: np.ndarray, max_points: int,
                      seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Back-project every surface pixel (depth > 0) of the views; a random subset of `max_points`.

    Colours are the premultiplied linear RGB divided by alpha (the surface colour).
    """
    pts, cols = [], []
    for cam, img, z in zip(cameras, rgba, depth):
        valid = z > 0
        world = cam.backproject(np.where(valid, z, 0.0))
        alpha = np.maximum(img[..., 3:4], 1e-6)
        pts.append(world[valid])
        cols.append(np.clip(img[..., :3] / alpha, 0.0, 1.0)[valid])
    points, colors = np.concatenate(pts), np.concatenate(cols)
    if len(points) == 0:
        raise ValueError("depth: no pixel with depth > 0 in any view")
    if len(points) > max_points:
        keep = np.random.default_rng(seed).choice(len(points), max_points, replace=False)
        points, colors = points[keep], colors[keep]
    return points, colors


def points_from_sfm(points: np.ndarray, colors_srgb: np.ndarray, max_points: int,
                    seed: int) -> tuple[np.ndarray, np.ndarray]:
    """SfM points with their colours, sRGB-encoded, decoded to linear RGB; a random subset of `max_points`,
    kept in the points' order."""
    colors = srgb_to_linear(colors_srgb)
    if len(points) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(len(points), max_points, replace=False))
        points, colors = points[keep], colors[keep]
    return points, colors


def random_points(bbox: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """`n` points uniform in the box (2, 3) with uniform random colours (3DGS's synthetic-scene init)."""
    bbox = np.asarray(bbox, dtype=np.float64)
    if bbox.shape != (2, 3) or np.any(bbox[1] <= bbox[0]):
        raise ValueError(f"bbox: expected [min, max] corners of shape (2, 3) with min < max, got {bbox.tolist()}")
    rng = np.random.default_rng(seed)
    return rng.uniform(bbox[0], bbox[1], (n, 3)), rng.uniform(0.0, 1.0, (n, 3))


def points_in_frusta(cameras: list[Camera], rgba: np.ndarray, near_far: np.ndarray, n: int,
                     seed: int) -> tuple[np.ndarray, np.ndarray]:
    """`n` points in the views' frusta between their z-depth bounds, for data without SfM points (LLFF).

    Each point picks a view uniformly, a pixel uniformly, and a z-depth uniform in disparity 1/z
    between the view's near and far bounds (what NeRF's NDC samples are uniform in for forward-facing
    scenes; uniform in volume would put almost every point near the far bound), and takes that
    pixel's colour (premultiplied linear RGB over alpha). `rgba` (V, H, W, 4), `near_far` (V, 2).
    """
    near_far = np.asarray(near_far, dtype=np.float64)
    if near_far.shape != (len(cameras), 2) or np.any(near_far[:, 0] <= 0) or np.any(near_far[:, 1] <= near_far[:, 0]):
        raise ValueError(f"near_far: expected ({len(cameras)}, 2) bounds with 0 < near < far, got shape "
                         f"{near_far.shape}")
    rng = np.random.default_rng(seed)
    view = rng.integers(0, len(cameras), n)
    u, v = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 1.0, n)
    disparity = rng.uniform(1.0 / near_far[view, 1], 1.0 / near_far[view, 0])
    points, colors = np.empty((n, 3)), np.empty((n, 3))
    for k, cam in enumerate(cameras):
        sel = np.nonzero(view == k)[0]
        if not len(sel):
            continue
        uu, vv = u[sel] * cam.width, v[sel] * cam.height
        rays = cam.camera_directions(uu, vv) @ cam.R.T  # z-depth 1 along each
        points[sel] = cam.center + rays / disparity[sel, None]
        px = rgba[k, np.minimum(vv.astype(int), cam.height - 1), np.minimum(uu.astype(int), cam.width - 1)]
        colors[sel] = np.clip(px[:, :3] / np.maximum(px[:, 3:4], 1e-6), 0.0, 1.0)
    return points, colors


def splat_camera(camera: Camera, near: float = ks.DEFAULT_NEAR) -> ks.SplatCamera:
    return ks.SplatCamera(camera.w2c, camera.K, camera.width, camera.height, near=near, lens=camera.lens)


def render(model: GaussianModel, camera: Camera, *, sh_degree: int = 3, background=(0.0, 0.0, 0.0),
           antialiased: bool = False, mode: str = ks.DEFAULT_MODE, device: Any = None,
           dilation: float | None = None) -> ks.Render:
    """Render `model` from a research Camera (float32) on `device` (None: the CPU); wp.array results.
    `mode` picks the reference conventions ("3dgs", the default, or "gsplat"; kernels/splat/modes.py),
    `dilation` the low-pass dilation (None: the mode's)."""
    return ks.render(model.inputs(device), splat_camera(camera), np.asarray(background, dtype=np.float32),
                     sh_degree=sh_degree, antialiased=antialiased, mode=mode, dilation=dilation)


def scene_extent(cameras: list[Camera]) -> float:
    """3DGS's spatial scale: 1.1 x the largest distance of a camera centre from their mean."""
    centres = np.array([c.center for c in cameras])
    return float(1.1 * np.linalg.norm(centres - centres.mean(axis=0), axis=1).max())
