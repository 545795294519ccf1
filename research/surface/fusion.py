"""Depth maps -> TSDF -> mesh, with drlab's Warp kernels (kernels.tsdf) and with Open3D (the baseline).

Grid. `fusion_grid(bbox, voxel_size, truncation)` covers the scene box grown by the truncation distance
plus one voxel on every side (so the band behind each surface fits), with its origin on a multiple of
the voxel size: voxel centres then sit at (k + 1/2) h in world units.

drlab (`fuse`): a kernels.tsdf.TSDFVolume over that grid, one `integrate` per view that can see the
volume (kernels.tsdf.sees_volume; views that see nothing, or whose depth map has no measurement, are
skipped and counted), then `marching_cubes` at level 0 over the observed voxels.

Open3D (`fuse_open3d`, when the `open3d-cpu` wheel of the `[bench]` extra is installed):
`o3d.pipelines.integration.UniformTSDFVolume(length=n h, resolution=n, sdf_trunc=tau, NoColor,
origin=the grid's origin)`, n the grid's largest side (Open3D's uniform volume is a cube, so it covers our
grid and more, with the same voxel centres); `integrate` per view with depth_scale 1 and no depth
cut-off, `extract_triangle_mesh`. (Its ScalableTSDFVolume returned empty meshes on these depth maps with
open3d-cpu 0.20, for either colour type and depth sampling stride 1 or 4, so the dense volume it is.)
Open3D puts
pixel centres at integer coordinates, so its principal point is (c_x - 1/2, c_y - 1/2) of ours (the same
pixel for every projection). Its legacy integration computes the same update as kernels/tsdf/integrate.py
(distance along the pixel ray, +1 weight per view), on its own sparse blocks.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class FusedMesh:
    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64
    seconds: float  # integration + mesh extraction, wall time
    integrate_seconds: float
    extract_seconds: float
    views: int  # views integrated
    skipped: list[str] = field(default_factory=list)  # why each skipped view was skipped


def fusion_grid(bbox: np.ndarray, voxel_size: float, truncation: float) -> tuple[np.ndarray, tuple[int, int, int]]:
    """(origin, shape) of the grid over `bbox` (2, 3) grown by truncation + voxel_size (module docstring)."""
    bbox = np.asarray(bbox, dtype=np.float64)
    pad = truncation + voxel_size
    lo = np.floor((bbox[0] - pad) / voxel_size) * voxel_size
    hi = bbox[1] + pad
    shape = tuple(int(max(2, math.ceil((hi[a] - lo[a]) / voxel_size))) for a in range(3))
    return lo, shape


def fuse(depths: np.ndarray, cameras: list, bbox: np.ndarray, voxel_size: float, truncation: float,
         device: Any = "cpu", dtype: Any = np.float32, max_bytes: int | None = None) -> FusedMesh:
    """Fuse (V, H, W) z-depth maps seen by `cameras` (research.cameras.Camera) with kernels.tsdf."""
    from kernels.tsdf import TSDFVolume, integrate, marching_cubes, sees_volume

    if len(depths) != len(cameras):
        raise ValueError(f"depths: expected one depth map per camera ({len(cameras)}), got {len(depths)}")
    origin, shape = fusion_grid(bbox, voxel_size, truncation)
    t0 = time.perf_counter()
    vol = TSDFVolume(origin, voxel_size, shape, truncation, dtype=dtype, device=device, max_bytes=max_bytes)
    skipped, used = [], 0
    for k, (cam, depth) in enumerate(zip(cameras, depths)):
        if not sees_volume(vol, cam.K, cam.w2c, cam.width, cam.height):
            skipped.append(f"view {k}: sees nothing of the volume")
            continue
        if not np.any(depth > 0):
            skipped.append(f"view {k}: no pixel has a depth")
            continue
        integrate(vol, np.asarray(depth, dtype=dtype), cam.K, cam.w2c)
        used += 1
    import warp as wp

    wp.synchronize_device(vol.device)
    t1 = time.perf_counter()
    grids = vol.numpy() if vol.device.is_cpu else None
    if grids is not None:
        mesh = marching_cubes(grids["tsdf"], grids["weight"], vol.origin, voxel_size)
    else:
        mesh = marching_cubes(vol.tsdf.reshape(vol.shape), vol.weight.reshape(vol.shape), vol.origin, voxel_size)
    verts = np.asarray(mesh.vertices.numpy() if hasattr(mesh.vertices, "numpy") else mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces.numpy() if hasattr(mesh.faces, "numpy") else mesh.faces, dtype=np.int64)
    t2 = time.perf_counter()
    return FusedMesh(verts, faces, t2 - t0, t1 - t0, t2 - t1, used, skipped)


def open3d_module() -> Any:
    """Open3D, or None when it is not installed (it is the optional `[bench]` extra)."""
    try:
        import open3d as o3d
    except Exception:  # not installed, or a missing system library
        return None
    return o3d


def fuse_open3d(depths: np.ndarray, cameras: list, bbox: np.ndarray, voxel_size: float,
                truncation: float) -> FusedMesh:
    """The same depth maps fused by Open3D's UniformTSDFVolume on fusion_grid's voxels (module docstring)."""
    o3d = open3d_module()
    if o3d is None:
        raise RuntimeError("open3d is not installed (pip install open3d-cpu: the [bench] extra)")
    integ = o3d.pipelines.integration
    t0 = time.perf_counter()
    origin, shape = fusion_grid(bbox, voxel_size, truncation)
    n = max(shape)
    vol = integ.UniformTSDFVolume(length=n * voxel_size, resolution=n, sdf_trunc=truncation,
                                  color_type=integ.TSDFVolumeColorType.NoColor, origin=origin)
    skipped, used = [], 0
    for k, (cam, depth) in enumerate(zip(cameras, depths)):
        if not np.any(depth > 0):
            skipped.append(f"view {k}: no pixel has a depth")
            continue
        h, w = depth.shape
        intr = o3d.camera.PinholeCameraIntrinsic(w, h, cam.fx, cam.fy, cam.cx - 0.5, cam.cy - 0.5)
        color = o3d.geometry.Image(np.zeros((h, w, 3), dtype=np.uint8))
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, o3d.geometry.Image(np.ascontiguousarray(depth, dtype=np.float32)), depth_scale=1.0,
            depth_trunc=1e9, convert_rgb_to_intensity=False)
        vol.integrate(rgbd, intr, np.array(cam.w2c, dtype=np.float64))
        used += 1
    t1 = time.perf_counter()
    mesh = vol.extract_triangle_mesh()
    t2 = time.perf_counter()
    return FusedMesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64),
                     t2 - t0, t1 - t0, t2 - t1, used, skipped)
