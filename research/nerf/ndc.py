"""Normalised device coordinates for forward-facing captures (NeRF's LLFF parametrisation).

NeRF (Mildenhall et al. 2020, appendix C) fits forward-facing scenes in NDC: the world frame is one
whose cameras look down -z (NeRF's recentred LLFF poses, research.datasets.llff), a near plane
z = -near (near = 1 after NeRF's bd_factor rescaling, which puts the nearest scene depth at
1/0.75), and the projective map of a reference pinhole of focal lengths (fx, fy) and size (W, H)
(the capture's one camera) takes the frustum beyond the near plane to a box: x and y in [-1, 1]
for the reference camera's own rays, z from -1 (the near plane) to 1 (infinite depth). Each ray is
mapped by kernels.volume.ndc_rays (NeRF's `ndc_rays`, with its NumPy reference and backward).

`NDC.rays(origins, dirs)` gives the renderer's rays: NDC origins, unit NDC directions (so a sample
interval is an NDC length, as NeRF's `dists * |rays_d|`) and z_scale = 1 / |d'| = u'_z / 2, which
makes the renderer's "depth" the expected NDC ray parameter t in [0, 1] (t = 1 - near / z-depth:
linear in disparity), not a z-depth. Samples spaced evenly along the NDC ray are evenly spaced in
t, NeRF's `lindisp=False` sampling for LLFF. `NDC.bbox_for(cameras)` is the smallest box holding
every camera's frustum in NDC: the frustum between the near plane and infinity maps to a convex
polytope whose vertices are the four image-corner rays at t = 0 and t = 1, so their NDC positions
bound it (x, y a little beyond [-1, 1] for cameras offset from the reference).

The fields of research.nerf see positions only (their colour has no view dependence), so the NDC
directions never reach them as view directions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from research.cameras import Camera


@dataclass(frozen=True)
class NDC:
    near: float  # the near plane z = -near of the world frame
    focal: tuple[float, float]  # (fx, fy) of the reference pinhole, pixels
    size: tuple[int, int]  # its (width, height), pixels

    def __post_init__(self) -> None:
        if not (np.isfinite(self.near) and self.near > 0):
            raise ValueError(f"near: expected a finite distance > 0, got {self.near!r}")
        if len(self.focal) != 2 or not all(np.isfinite(f) and f > 0 for f in self.focal):
            raise ValueError(f"focal: expected (fx, fy) > 0, got {self.focal!r}")
        if len(self.size) != 2 or not all(int(s) == s and s > 0 for s in self.size):
            raise ValueError(f"size: expected (width, height) positive integers, got {self.size!r}")

    @classmethod
    def of_camera(cls, camera: Camera, near: float = 1.0) -> "NDC":
        return cls(float(near), (camera.fx, camera.fy), (camera.width, camera.height))

    def rays(self, origins: Any, dirs: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(NDC origins (R, 3), unit NDC dirs (R, 3), z_scale (R,)) of world rays (module docstring), in
        the dtype of `origins`."""
        from kernels.volume.rays import ndc_rays

        o, u = ndc_rays(origins, dirs, self.near, self.focal, self.size, normalize=True)
        return o, u, (u[:, 2] * 0.5).astype(u.dtype)

    def points(self, points: Any) -> np.ndarray:
        """World points (..., 3) with z < 0 in NDC (the same map as `rays`, for positions)."""
        p = np.asarray(points, dtype=np.float64)
        ax, ay = 2.0 * self.focal[0] / self.size[0], 2.0 * self.focal[1] / self.size[1]
        z = p[..., 2]
        return np.stack([-ax * p[..., 0] / z, -ay * p[..., 1] / z, 1.0 + 2.0 * self.near / z], axis=-1)

    def bbox_for(self, cameras: list[Camera]) -> np.ndarray:
        """(2, 3): the box of every camera's frustum in NDC (module docstring), z in [-1, 1]."""
        corners = []
        for c in cameras:
            uv = np.array([[0.0, 0.0], [c.width, 0.0], [0.0, c.height], [c.width, c.height]])
            d = c.camera_directions(uv[:, 0], uv[:, 1]) @ c.R.T
            o = np.broadcast_to(c.center, d.shape)
            on, dn = self._ndc_np(o, d)
            corners += [on, on + dn]  # t = 0 and t = 1 (d'_z = 2 takes z from -1 to 1)
        pts = np.concatenate(corners)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        lo[2], hi[2] = -1.0, 1.0
        return np.array([lo, hi])

    def _ndc_np(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from kernels.volume.rays import ndc_rays

        if np.any(d[:, 2] >= 0):
            raise ValueError("cameras: a frustum corner ray does not point down -z (the data is not "
                             "forward-facing in this world frame)")
        return ndc_rays(np.ascontiguousarray(o, np.float64), np.ascontiguousarray(d, np.float64), self.near,
                        self.focal, self.size)
