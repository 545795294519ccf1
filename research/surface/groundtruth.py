"""The true geometry of a built-in Mitsuba scene (research/datasets/scenes.py) as surface samples.

`sample_scene_surface(scene, n, seed)` loads the scene's shapes with Mitsuba and draws n points with
their normals, uniform over the total area: each shape gets a share of the points in proportion to its
`surface_area()` (largest remainder), drawn by the shape's own `sample_position` (uniform in area on
every shape type Mitsuba ships: spheres, cylinders, disks, rectangles, meshes); the normals are the
shapes' geometric normals. Open shapes (the ground rectangle, disks) are sampled on their one side.

`observed(points, cameras, depths, tolerance)` keeps the samples that some view saw: a point whose
z-depth in a camera is within `tolerance` of that view's ground-truth depth at the pixel it projects to
(and lies in front of the camera, inside the image). Parts no camera can see (the box's base on the
ground, the ground under the objects, the bottom of the can) then do not count against completeness,
as observation masks do in multi-view benchmarks (DTU's, Tanks and Temples' crops).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def sample_scene_surface(scene: str, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """(points (n, 3), normals (n, 3), {shape id: (area, samples)}) on the scene's shapes, float64."""
    import mitsuba as mi

    from research.datasets.scenes import get_scene
    from research.mitsuba_env import select_variant

    if n < 1:
        raise ValueError(f"n: expected an integer >= 1, got {n}")
    select_variant()
    shapes = list(mi.load_dict(get_scene(scene).build()).shapes())
    areas = np.array([float(np.asarray(s.surface_area()).ravel()[0]) for s in shapes])
    share = areas / areas.sum() * n
    counts = np.floor(share).astype(int)
    counts[np.argsort(-(share - counts))[: n - counts.sum()]] += 1
    rng = np.random.default_rng(seed)
    pts, nrm, info = [], [], {}
    for s, a, c in zip(shapes, areas, counts):
        info[s.id()] = {"area": float(a), "samples": int(c)}
        if c == 0:
            continue
        u = rng.random((2, c)).astype(np.float32)
        ps = s.sample_position(0.0, mi.Point2f(u[0], u[1]))
        pts.append(np.broadcast_to(np.asarray(ps.p, dtype=np.float64).T.reshape(-1, 3), (c, 3)))
        nn = np.broadcast_to(np.asarray(ps.n, dtype=np.float64).T.reshape(-1, 3), (c, 3))
        nrm.append(nn / np.linalg.norm(nn, axis=1, keepdims=True))
    return np.concatenate(pts), np.concatenate(nrm), info


def observed(points: np.ndarray, cameras: list, depths: np.ndarray, tolerance: float) -> np.ndarray:
    """(n,) bool: seen by at least one of the views (module docstring); depths (V, H, W) z-depth, 0 = none."""
    seen = np.zeros(len(points), dtype=bool)
    for cam, depth in zip(cameras, depths):
        p = points @ cam.w2c[:3, :3].T + cam.w2c[:3, 3]
        z = p[:, 2]
        front = z > 1e-9
        u = np.where(front, cam.fx * p[:, 0] / np.where(front, z, 1) + cam.cx, -1)
        v = np.where(front, cam.fy * p[:, 1] / np.where(front, z, 1) + cam.cy, -1)
        inside = front & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        c = np.where(inside, u, 0).astype(int)
        r = np.where(inside, v, 0).astype(int)
        d = depth[r, c]
        seen |= inside & (d > 0) & (np.abs(d - z) < tolerance)
    return seen
