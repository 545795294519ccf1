"""Stereo disparity and optical flow ground truth from exact depth and known poses.

Both are pure geometry on the 1-sample-per-pixel geometry pass (render.py):

* Rectified stereo. The right camera is the left one moved by +b along the
  OpenCV x axis (same K, same rotation). A left pixel at (x, y) with z-depth Z
  appears in the right view at (x - d, y) with disparity d = f_x b / Z.
* Forward flow from frame 1 to frame 2 of a static scene. Back-project pixel
  centre x with frame 1's depth to a world point X, project X into frame 2:
  flow = pi_2(X) - x.
* Visibility (the occlusion test). The point is visible in the other view when
  it projects inside the image and its z-depth there agrees, to a relative
  tolerance (1% by default), with the other view's depth sampled at that spot.
  The sample is bilinear when the four neighbouring pixel centres all hit a
  surface, else the nearest pixel's depth.
"""

from __future__ import annotations

import numpy as np

from research.cameras import Camera

DEFAULT_Z_TOL = 0.01


def sample_depth(depth: np.ndarray, hit: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample a depth map at continuous coordinates (u, v) (pixel centres at +0.5).

    Returns (depth, inside): bilinear where all four neighbours are hits, the
    nearest pixel's depth otherwise, 0 outside the image or on a miss.
    """
    H, W = depth.shape
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H) & np.isfinite(u) & np.isfinite(v)
    uu = np.where(inside, u, 0.5)
    vv = np.where(inside, v, 0.5)
    # Nearest pixel.
    i_n = np.clip(np.floor(uu).astype(int), 0, W - 1)
    j_n = np.clip(np.floor(vv).astype(int), 0, H - 1)
    nearest = np.where(hit[j_n, i_n], depth[j_n, i_n], 0.0)
    # Bilinear between the four surrounding pixel centres.
    x, y = uu - 0.5, vv - 0.5
    i0 = np.clip(np.floor(x).astype(int), 0, W - 1)
    j0 = np.clip(np.floor(y).astype(int), 0, H - 1)
    i1 = np.clip(i0 + 1, 0, W - 1)
    j1 = np.clip(j0 + 1, 0, H - 1)
    fx = np.clip(x - i0, 0.0, 1.0)
    fy = np.clip(y - j0, 0.0, 1.0)
    all_hit = hit[j0, i0] & hit[j0, i1] & hit[j1, i0] & hit[j1, i1]
    bil = ((1 - fx) * (1 - fy) * depth[j0, i0] + fx * (1 - fy) * depth[j0, i1]
           + (1 - fx) * fy * depth[j1, i0] + fx * fy * depth[j1, i1])
    out = np.where(all_hit, bil, nearest)
    return np.where(inside, out, 0.0), inside


def stereo_right_camera(left: Camera, baseline: float) -> Camera:
    """The rectified right camera: `left` moved by +baseline along its own x axis."""
    if not baseline > 0:
        raise ValueError(f"baseline: expected a positive distance, got {baseline}")
    c2w = left.c2w.copy()
    c2w[:3, 3] += baseline * left.R[:, 0]
    return Camera(left.K, c2w, left.width, left.height)


def stereo_disparity(left: Camera, baseline: float, depth_left: np.ndarray, hit_left: np.ndarray,
                     depth_right: np.ndarray, hit_right: np.ndarray,
                     z_tol: float = DEFAULT_Z_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Left disparity (H, W) and its non-occluded mask.

    disparity = f_x * b / Z on hits and 0 elsewhere; `noc` is True where the point is
    a hit, lands inside the right image and passes the z-test there.
    """
    disp = np.where(hit_left, left.fx * baseline / np.where(hit_left, depth_left, 1.0), 0.0)
    u, v = left.pixel_centers()
    zr, inside = sample_depth(depth_right, hit_right, u - disp, v)
    noc = hit_left & inside & (zr > 0) & (np.abs(zr - depth_left) <= z_tol * depth_left)
    return disp, noc


def forward_flow(cam1: Camera, depth1: np.ndarray, hit1: np.ndarray, cam2: Camera, depth2: np.ndarray,
                 hit2: np.ndarray, z_tol: float = DEFAULT_Z_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Flow (H, W, 2) from frame 1 to frame 2 ([..., 0] = x right, [..., 1] = y down) and its validity.

    Flow is 0 where frame 1 has no surface; `valid` is True where the surface point
    is visible in frame 2 (in the image, in front of the camera, passes the z-test).
    """
    X = cam1.backproject(np.where(hit1, depth1, 1.0))
    uv2, z2 = cam2.project(X)
    u, v = cam1.pixel_centers()
    flow = np.stack([uv2[..., 0] - u, uv2[..., 1] - v], axis=-1)
    flow = np.where(hit1[..., None] & np.isfinite(flow), flow, 0.0)
    zs, inside = sample_depth(depth2, hit2, uv2[..., 0], uv2[..., 1])
    valid = hit1 & inside & (z2 > 0) & (zs > 0) & (np.abs(zs - z2) <= z_tol * np.abs(z2))
    return flow, valid
