"""Benchmark family "tsdf": TSDF integration and marching cubes (kernels/tsdf), beside Open3D.

Input (seed 0): an analytic sphere of radius 1 seen by V cameras on a ring of radius 3 around it (z-depth
of the ray-sphere hits at W x W pixels, focal W), fused into a cubic grid of n^3 voxels over [-1.5, 1.5]^3,
truncation 4 voxels, float32. Sizes (n voxels per side, V views, W pixels; full / quick / tiny):
128, 16, 256 / 64, 8, 128 / 24, 2, 32.

Phases, each the median of REPEATS runs after a warm-up (research.bench.time_medians, interleaved):

  integrate_s           V kernels.tsdf.integrate calls into a fresh volume (CPU: kernels.launch threads);
  mc_s                  kernels.tsdf.marching_cubes of the fused grid;
  ref_open3d_<phase>_s  Open3D's UniformTSDFVolume on the same voxels and depth maps (integrate; extract_
                        triangle_mesh) when importable (the `open3d-cpu` wheel of the `[bench]` extra), else
                        `open3d_missing`; Open3D picks its own thread count;
  speedup_open3d_<phase>: Open3D time / drlab time (> 1: drlab faster).
"""

from __future__ import annotations

from typing import Any, Iterator

import numpy as np
import warp as wp

from kernels import tsdf as kt
from kernels.launch import default_threads
from research.bench import SETTLE_S, time_medians

SIZES = {"full": (128, 16, 256), "quick": (64, 8, 128), "tiny": (24, 2, 32)}
REPEATS = 3


def sphere_views(n_views: int, width: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """(K, world-to-camera poses, (V, W, W) z-depths) of the unit sphere seen from a ring of radius 3."""
    K = np.array([[width, 0.0, width / 2], [0.0, width, width / 2], [0.0, 0.0, 1.0]])
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(width) + 0.5)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    poses, depths = [], []
    for k in range(n_views):
        a = 2 * np.pi * k / n_views
        c = np.array([3 * np.cos(a), 3 * np.sin(a), 0.3])
        f = -c / np.linalg.norm(c)
        r = np.cross(f, [0.0, 0.0, 1.0])
        r /= np.linalg.norm(r)
        d = np.cross(f, r)
        R = np.stack([r, d, f])  # rows: camera x, y, z in world
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R, -R @ c
        dw = rays @ R  # ray directions in world
        b = dw @ c
        disc = b * b - (c @ c - 1.0)
        t = -b - np.sqrt(np.maximum(disc, 0.0))
        depths.append(np.where(disc > 0, t * rays[..., 2], 0.0).astype(np.float32))
        poses.append(w2c)
    return K, poses, np.stack(depths)


def _open3d() -> Any:
    try:
        import open3d as o3d
    except Exception:  # not installed, or a missing system library
        return None
    return o3d


def cases(device: str, quick: bool, tiny: bool = False) -> Iterator[dict]:
    n, n_views, width = SIZES["tiny" if tiny else ("quick" if quick else "full")]
    K, poses, depths = sphere_views(n_views, width)
    h = 3.0 / n
    origin = np.full(3, -1.5)
    o3d = _open3d()

    def fused() -> kt.TSDFVolume:
        vol = kt.TSDFVolume(origin, h, (n, n, n), 4 * h, device=device)
        for w2c, d in zip(poses, depths):
            kt.integrate(vol, d, K, w2c)
        return vol

    grids = fused().numpy()
    sync = (lambda: wp.synchronize_device(device))
    fns = {"integrate": fused, "mc": lambda: kt.marching_cubes(grids["tsdf"], grids["weight"], origin, h,
                                                               device=device)}
    if o3d is not None:
        integ = o3d.pipelines.integration
        intr = o3d.camera.PinholeCameraIntrinsic(width, width, K[0, 0], K[1, 1], K[0, 2] - 0.5, K[1, 2] - 0.5)
        blank = o3d.geometry.Image(np.zeros((width, width, 3), dtype=np.uint8))
        images = [o3d.geometry.RGBDImage.create_from_color_and_depth(blank, o3d.geometry.Image(d), depth_scale=1.0,
                                                                      depth_trunc=1e9, convert_rgb_to_intensity=False)
                  for d in depths]

        def o3d_fused():
            vol = integ.UniformTSDFVolume(length=3.0, resolution=n, sdf_trunc=4 * h,
                                          color_type=integ.TSDFVolumeColorType.NoColor, origin=origin)
            for w2c, im in zip(poses, images):
                vol.integrate(im, intr, w2c)
            return vol

        o3d_vol = o3d_fused()
        fns["open3d_integrate"] = o3d_fused
        fns["open3d_mc"] = o3d_vol.extract_triangle_mesh
    t = time_medians(fns, repeats=REPEATS, sync=sync, settle_s=SETTLE_S)
    for phase in ("integrate", "mc"):
        row: dict[str, Any] = {"bench": f"tsdf.{phase}", "device": device, "threads": default_threads(),
                               "voxels_per_side": n, "views": n_views, "pixels": width, "dtype": "float32",
                               f"{phase}_s": t[phase]}
        if o3d is not None:
            row[f"ref_open3d_{phase}_s"] = t[f"open3d_{phase}"]
            row[f"speedup_open3d_{phase}"] = t[f"open3d_{phase}"] / t[phase]
        else:
            row["open3d_missing"] = "open3d (pip install open3d-cpu: the [bench] extra)"
        yield row
