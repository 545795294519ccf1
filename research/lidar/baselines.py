"""The baselines on the same scans: KISS-ICP's odometry (the `kiss-icp` wheel) and Open3D's
registration_icp for single scan pairs. Both libraries are optional (the `[bench]` extra):
`missing_kiss_icp()` / `missing_open3d()` say in one line why one cannot run, or return None.

KISS-ICP (Vizzo et al., RA-L 2023) runs through its Python pipeline class `kiss_icp.kiss_icp.KissICP`
with a `KISSConfig`: every scan with its per-point timestamps (`register_frame(points, timestamps)`),
the scanner's min/max range, deskewing off (the simulated sweeps have no motion inside them: see
research/lidar/scanner.py), the given voxel size and its defaults otherwise (20 points per voxel,
adaptive threshold from 2 m with 0.1 m minimum motion, point-to-point ICP with a Geman-McClure kernel).
Its poses start at the identity; they are moved to the given start pose.

Open3D's `registration_icp` (point-to-point or point-to-plane; the target's normals by Open3D's own
estimate_normals over the same k nearest) aligns one source onto one target from an initial guess, with
a fixed correspondence distance, no robust kernel, and stops on relative fitness and RMSE changes below
`relative_change` (1e-6, Open3D's default) or at max_iteration.
"""

from __future__ import annotations

import time

import numpy as np


def missing_kiss_icp() -> str | None:
    try:
        from kiss_icp.kiss_icp import KissICP  # noqa: F401
    except ImportError as e:
        return f"kiss-icp is not installed (pip install kiss-icp, or drlab's [bench] extra): {e}"
    return None


def missing_open3d() -> str | None:
    try:
        import open3d  # noqa: F401
    except (ImportError, OSError) as e:
        return f"open3d is not installed or does not load (pip install open3d-cpu, drlab's [bench] extra): {e}"
    return None


def kiss_icp_version() -> str:
    from importlib.metadata import version

    return version("kiss-icp")


def run_kiss_icp(scans: list[np.ndarray], times: list[np.ndarray], *, voxel_size: float, min_range: float,
                 max_range: float, start_pose: np.ndarray | None = None, progress=None
                 ) -> tuple[np.ndarray, list[float]]:
    """(sensor-to-world poses (n, 4, 4), seconds per scan) of KISS-ICP over the scans (module docstring)."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    cfg = KISSConfig()
    cfg.data.max_range, cfg.data.min_range, cfg.data.deskew = float(max_range), float(min_range), False
    cfg.mapping.voxel_size = float(voxel_size)
    odo = KissICP(cfg)
    start = np.eye(4) if start_pose is None else np.asarray(start_pose, dtype=np.float64)
    poses, seconds = [], []
    frames = range(len(scans)) if progress is None else progress(range(len(scans)))
    for k in frames:
        t0 = time.perf_counter()
        odo.register_frame(np.ascontiguousarray(scans[k], dtype=np.float64),
                           np.ascontiguousarray(times[k], dtype=np.float64))
        seconds.append(time.perf_counter() - t0)
        poses.append(start @ odo.last_pose)
    return np.array(poses), seconds


def open3d_icp(source: np.ndarray, target: np.ndarray, init: np.ndarray, *, max_distance: float, metric: str,
               normal_k: int = 10, max_iterations: int = 50, relative_change: float = 1e-6
               ) -> tuple[np.ndarray, float]:
    """(source-to-target 4x4, seconds) of Open3D's ICP; the seconds include the target's normals for
    point-to-plane (module docstring)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    src, tgt = o3d.geometry.PointCloud(), o3d.geometry.PointCloud()
    src.points = o3d.utility.Vector3dVector(np.asarray(source, dtype=np.float64))
    tgt.points = o3d.utility.Vector3dVector(np.asarray(target, dtype=np.float64))
    t0 = time.perf_counter()
    if metric == "plane":
        tgt.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(int(normal_k)))
        est = reg.TransformationEstimationPointToPlane()
    elif metric == "point":
        est = reg.TransformationEstimationPointToPoint()
    else:
        raise ValueError(f"metric: expected point or plane, got {metric!r}")
    crit = reg.ICPConvergenceCriteria(relative_fitness=relative_change, relative_rmse=relative_change,
                                      max_iteration=int(max_iterations))
    res = reg.registration_icp(src, tgt, float(max_distance), np.asarray(init, dtype=np.float64), est, crit)
    return np.array(res.transformation), time.perf_counter() - t0
