"""Render a full image (RGB, z-depth, opacity) of a radiance field from a Camera.

Rays go through every pixel centre (research.cameras, OpenCV convention) with unit directions;
z_scale = cos(theta) to the optical axis turns the ray parameter t into z-depth, so `depth` is the
expected z-depth sum_k w_k t_k cos(theta) (depth means z-depth throughout the project). Rays are
rendered in chunks by kernels.volume.render_rays. With an `ndc` (research.nerf.ndc.NDC, forward-facing
data) the rays are mapped to NDC first and `bbox` is a box in NDC; `depth` is then the expected NDC
ray parameter (research.nerf.ndc).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from kernels import _arrays as A
from kernels.volume import DEFAULT_T_THRESHOLD, Field, OccupancyGrid, Workspace, render_rays
from research.cameras import Camera


@dataclass
class Image:
    rgb: np.ndarray  # (H, W, 3)
    depth: np.ndarray  # (H, W) expected z-depth
    opacity: np.ndarray  # (H, W)
    n_samples: int  # samples evaluated


def camera_rays(camera: Camera, dtype: Any = np.float64, ndc: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit-direction rays through every pixel centre: origins, dirs (H*W, 3) and z_scale (H*W,);
    with `ndc` (research.nerf.ndc.NDC) those rays in NDC (`NDC.rays`)."""
    o, d = camera.rays(normalize=True)
    if ndc is not None:
        return tuple(x.astype(dtype) for x in ndc.rays(o.reshape(-1, 3), d.reshape(-1, 3)))
    return (o.reshape(-1, 3).astype(dtype), d.reshape(-1, 3).astype(dtype),
            camera.ray_cosines().reshape(-1).astype(dtype))


def render_image(
    camera: Camera,
    field: Field,
    bbox: Any,
    *,
    near: float = 0.0,
    far: float = 1e10,
    n_samples: int | None = None,
    step: float | None = None,
    occupancy: OccupancyGrid | None = None,
    background: Any = (0.0, 0.0, 0.0),
    t_threshold: float = DEFAULT_T_THRESHOLD,
    chunk: int = 16384,
    progress: bool = False,
    ndc: Any = None,
) -> Image:
    """Render `field` as seen by `camera` (see kernels.volume.sample_rays for the sampling options)."""
    if not isinstance(camera, Camera):
        raise ValueError(f"camera: expected a research.cameras.Camera, got {type(camera).__name__}")
    A.check_int("chunk", chunk, minimum=1)
    o, d, zs = camera_rays(camera, A.NP_OF_WP[field.dtype], ndc)
    n = o.shape[0]
    rgb, depth, opacity = np.empty((n, 3)), np.empty(n), np.empty(n)
    n_samples_total = 0
    starts = range(0, n, chunk)
    workspace = Workspace(field.device)  # every chunk's outputs are copied out before the next
    for s in tqdm(starts, desc="render", disable=not progress, leave=False):
        e = min(s + chunk, n)
        res = render_rays(field, o[s:e], d[s:e], bbox, near=near, far=far, n_samples=n_samples, step=step,
                          z_scale=zs[s:e], occupancy=occupancy, background=background, t_threshold=t_threshold,
                          workspace=workspace, keep_factor=False)  # never backpropagated: no per-sample state
        rgb[s:e], depth[s:e], opacity[s:e] = res.rgb.numpy(), res.depth.numpy(), res.opacity.numpy()  # workspace views
        n_samples_total += res.samples.n_samples
    h, w = camera.height, camera.width
    return Image(rgb.reshape(h, w, 3), depth.reshape(h, w), opacity.reshape(h, w), n_samples_total)
