"""Projective TSDF integration of one depth map (Curless and Levoy, "A volumetric method for building
complex models from range images", SIGGRAPH 1996; Newcombe et al., "KinectFusion", ISMAR 2011), as
Open3D's UniformTSDFVolume integrates it.

For every voxel centre x (kernels/tsdf/volume.py) and a camera with world-to-camera [R | t] and
intrinsics K (OpenCV axes: x right, y down, z forward; pixel (c, r) has its centre at (c + 1/2, r + 1/2)):

    p = R x + t,  z = p_z;                     skipped when z <= 0
    u = f_x p_x / z + c_x,  v = f_y p_y / z + c_y;  skipped unless 0 <= u < W and 0 <= v < H
    (c, r) = (floor u, floor v)                the pixel that contains the projection
    d = D[r, c];                               skipped unless d > 0 (0 marks a pixel without a measurement)
    sdf = (d - z) m[r, c],  m = |K^-1 (c + 1/2, r + 1/2, 1)|
                                               the distance along the pixel's ray from the voxel to the
                                               measured surface (positive in front of it)
    skipped when sdf <= -tau;                  else, with the observation's value f = min(1, sdf / tau),
    D <- (W D + f) / (W + 1),  C <- (W C + rgb[r, c]) / (W + 1),  W <- W + 1.

Each voxel is one thread and writes only its own entries, so the launch splits over CPU threads
(kernels/launch.py). The depth is a z-depth (the project's convention). Integration has no gradient
here: nothing differentiates through it (the weights and the pixel choice are piecewise constant, and
the min and the skips are kinks), so there is no backward pass.
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.rotation import checked_rigid
from kernels.tsdf.volume import TSDFVolume, sees_volume

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _integrate_kernel(tsdf: wp.array(dtype=typing.Any), weight: wp.array(dtype=typing.Any),
                      color: wp.array2d(dtype=typing.Any), has_color: int,
                      depth: wp.array2d(dtype=typing.Any), rgb: wp.array3d(dtype=typing.Any),
                      pose: wp.array2d(dtype=typing.Any), intr: wp.array(dtype=typing.Any),
                      origin: wp.array(dtype=typing.Any), h: typing.Any, trunc: typing.Any,
                      ny: int, nz: int, offset: int):
    v = wp.tid() + offset
    i = v // (ny * nz)
    j = (v // nz) % ny
    k = v % nz
    half = h.dtype(0.5)
    x = origin[0] + (h.dtype(float(i)) + half) * h
    y = origin[1] + (h.dtype(float(j)) + half) * h
    zw = origin[2] + (h.dtype(float(k)) + half) * h
    px = pose[0, 0] * x + pose[0, 1] * y + pose[0, 2] * zw + pose[0, 3]
    py = pose[1, 0] * x + pose[1, 1] * y + pose[1, 2] * zw + pose[1, 3]
    pz = pose[2, 0] * x + pose[2, 1] * y + pose[2, 2] * zw + pose[2, 3]
    if pz <= h.dtype(0.0):
        return
    fx = intr[0]
    fy = intr[1]
    cx = intr[2]
    cy = intr[3]
    u = fx * px / pz + cx
    w_img = depth.shape[1]
    h_img = depth.shape[0]
    vv = fy * py / pz + cy
    if not (u >= h.dtype(0.0) and u < h.dtype(float(w_img)) and vv >= h.dtype(0.0) and vv < h.dtype(float(h_img))):
        return
    c = int(u)
    r = int(vv)
    d = depth[r, c]
    if not (d > h.dtype(0.0)):
        return
    dx = (h.dtype(float(c)) + half - cx) / fx
    dy = (h.dtype(float(r)) + half - cy) / fy
    sdf = (d - pz) * wp.sqrt(h.dtype(1.0) + dx * dx + dy * dy)
    if sdf <= -trunc:
        return
    f = wp.min(h.dtype(1.0), sdf / trunc)
    w0 = weight[v]
    w1 = w0 + h.dtype(1.0)
    tsdf[v] = (tsdf[v] * w0 + f) / w1
    if has_color != 0:
        for ch in range(3):
            color[v, ch] = (color[v, ch] * w0 + rgb[r, c, ch]) / w1
    weight[v] = w1


A.declare_float_overloads(_integrate_kernel)


def integrate(volume: TSDFVolume, depth: Any, K: Any, w2c: Any, rgb: Any = None) -> None:
    """Fuse one z-depth map into `volume` in place (module docstring).

    depth (H, W): z-depth, 0 (or negative) where there is no measurement; finite. K (3, 3): intrinsics
    with f_x, f_y > 0; w2c (4, 4): world-to-camera rigid transform (OpenCV axes). rgb (H, W, 3): the
    colours, required exactly when the volume keeps colour. The arrays take the volume's dtype and
    device; ValueError (naming the argument) on bad input before any kernel runs, including a depth map
    with no measurement at all and a camera that sees nothing of the volume (`sees_volume`).
    """
    if not isinstance(volume, TSDFVolume):
        raise ValueError(f"volume: expected a kernels.tsdf.TSDFVolume, got {type(volume).__name__}")
    a = A.Inputs(volume.device, depth)
    a.scalar = volume.scalar
    if not A.is_array(depth) or len(depth.shape) != 2 or min(depth.shape) == 0:
        shape = tuple(depth.shape) if A.is_array(depth) else type(depth).__name__
        raise ValueError(f"depth: expected a non-empty (H, W) array, got {shape}")
    d = a.floats("depth", np.asarray(depth, dtype=volume.np_dtype) if isinstance(depth, np.ndarray) else depth,
                 (None, None))
    h_img, w_img = (int(s) for s in depth.shape)
    host = A.host_view(d)
    if host is None:  # on a CUDA device: one image's copy
        host = d.numpy()
    if not np.any(host > 0):
        raise ValueError("depth: no pixel has a measurement (every value <= 0)")
    K = np.asarray(K, dtype=np.float64)
    A.check_shape("K", K, (3, 3))
    A.check_finite("K", K)
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"K: expected focal lengths > 0, got f_x = {K[0, 0]}, f_y = {K[1, 1]}")
    w2c = checked_rigid("w2c", w2c)
    if volume.has_color:
        if rgb is None:
            raise ValueError("rgb: the volume keeps colour, so every depth map needs its (H, W, 3) colours")
        col = a.floats("rgb", np.asarray(rgb, dtype=volume.np_dtype) if isinstance(rgb, np.ndarray) else rgb,
                       (h_img, w_img, 3))
    elif rgb is not None:
        raise ValueError("rgb: the volume keeps no colour (TSDFVolume(..., color=True) keeps it)")
    else:
        col = a.zeros((1, 1, 3))
    if not sees_volume(volume, K, w2c, w_img, h_img):
        raise ValueError("w2c: this camera sees nothing of the volume (the volume's box lies outside its view "
                         "frustum); kernels.tsdf.sees_volume tells before the call")
    color = volume.color if volume.has_color else a.zeros((1, 3))
    pose = wp.array(w2c, dtype=volume.scalar, device=volume.device)
    intr = wp.array(np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]), dtype=volume.scalar, device=volume.device)
    origin = wp.array(volume.origin, dtype=volume.scalar, device=volume.device)
    nx, ny, nz = volume.shape
    a.launch(_integrate_kernel, volume.n_voxels,
             [volume.tsdf, volume.weight, color, int(volume.has_color), d, col, pose, intr, origin,
              a.s(volume.voxel_size), a.s(volume.truncation), ny, nz])
