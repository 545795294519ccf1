"""Scan-to-scan and scan-to-local-map LiDAR odometry with drlab's ICP, in KISS-ICP's structure.

Per scan (points in the sensor frame; Vizzo et al., "KISS-ICP: In defense of point-to-point ICP -- simple,
accurate, and robust registration if done the right way", RA-L 2023, whose steps these follow):

* Downsampling (`voxel_downsample`: the first point of each occupied voxel, in input order, as KISS-ICP
  keeps it): the frame at 0.5 v, and the registration source from that at 1.5 v, v = `voxel_size`.
* Prediction: constant velocity, T_pred = T_{k-1} Delta_{k-1} with Delta_{k-1} = T_{k-2}^-1 T_{k-1}.
* Threshold (`AdaptiveThreshold`, KISS-ICP's): the model deviation D = T_pred^-1 T_k of each scan gives
  the error delta = |t(D)| + 2 r_max sin(theta(D) / 2) (r_max the scanner's maximum range, theta the
  rotation angle); scans with delta > min_motion enter sigma = sqrt(mean delta^2), sigma = initial
  before any has. Pairs are kept within 3 sigma, and the robust kernel's scale is sigma (KISS-ICP 1.3's
  Python pipeline passes sigma as its Geman-McClure scale). `fixed_threshold` replaces sigma by a constant.
* Registration (research.lidar.registration): point-to-point or point-to-plane ICP.
  - scan-to-scan: the source onto the previous scan's downsampled frame, in that scan's sensor frame,
    from the prediction Delta_{k-1}; T_k = T_{k-1} Delta_k.
  - scan-to-map: onto the local map (`VoxelMap`, world frame) from T_pred. The map holds at most
    `max_points_per_voxel` points per voxel of size v (the first ones added), gets each registered
    frame (0.5 v downsampled) in world coordinates, and drops points farther than r_max from the sensor.
    For point-to-plane each point keeps the normal it had in its own scan (PCA over its frame's
    `normal_k` nearest, rotated into the world; points whose neighbourhood was degenerate have none
    and are left out of the target), so the normals are not re-estimated on the whole map every scan.

The first scan defines the world frame (T_0 = I unless a start pose is given). A scan with no returns, or
with non-finite points, is refused with a ValueError naming it.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from research.lidar.registration import IcpConfig, Target, check_cloud, make_target, point_normals, register
from research.poses.se3 import so3_log

MODES = ("scan2scan", "scan2map")


def voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """One int64 per point naming its voxel floor(p / voxel) (21 bits per axis, offset by 2^20: voxel
    indices within +-10^6 per axis, e.g. +-500 km at 0.5 m voxels)."""
    cells = np.floor(points / voxel).astype(np.int64) + (1 << 20)
    if len(cells) and (cells.min() < 0 or cells.max() >= (1 << 21)):
        raise ValueError(f"points: expected coordinates within {(1 << 20) * voxel:g} of the origin at voxel {voxel:g}")
    return (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """The first point (in input order) of each occupied voxel floor(p / voxel), in input order."""
    if not (math.isfinite(voxel) and voxel > 0):
        raise ValueError(f"voxel: expected a positive size, got {voxel}")
    if len(points) == 0:
        return points.copy()
    _, first = np.unique(voxel_keys(points, voxel), return_index=True)
    return points[np.sort(first)]


class VoxelMap:
    """A local map: at most `max_per_voxel` points per voxel of size `voxel` (the first added), world frame."""

    def __init__(self, voxel: float, max_per_voxel: int, max_range: float):
        self.voxel, self.max_per_voxel, self.max_range = float(voxel), int(max_per_voxel), float(max_range)
        self.points = np.zeros((0, 3))
        self.normals = np.zeros((0, 3))  # beside each point (NaN: none), when updates bring normals

    def update(self, world_points: np.ndarray, origin: np.ndarray, normals: np.ndarray | None = None) -> None:
        pts = np.concatenate([self.points, world_points])
        nrm = np.concatenate([self.normals, np.full_like(world_points, np.nan) if normals is None else normals])
        keys = voxel_keys(pts, self.voxel)
        order = np.argsort(keys, kind="stable")  # by voxel, insertion order inside each
        sorted_v = keys[order]
        starts = np.flatnonzero(np.r_[True, sorted_v[1:] != sorted_v[:-1]])
        rank = np.arange(len(order)) - np.repeat(starts, np.diff(np.r_[starts, len(order)]))
        keep = np.zeros(len(pts), bool)
        keep[order[rank < self.max_per_voxel]] = True
        near = np.linalg.norm(pts - origin, axis=1) <= self.max_range
        self.points = pts[keep & near]
        self.normals = nrm[keep & near]


class AdaptiveThreshold:
    """KISS-ICP's adaptive correspondence threshold (module docstring)."""

    def __init__(self, initial: float, min_motion: float, max_range: float):
        self.initial, self.min_motion, self.max_range = initial, min_motion, max_range
        self.sse, self.count = 0.0, 0

    def sigma(self) -> float:
        return self.initial if self.count == 0 else math.sqrt(self.sse / self.count)

    def update(self, deviation: np.ndarray) -> None:
        theta = float(np.linalg.norm(so3_log(deviation[:3, :3])))
        err = float(np.linalg.norm(deviation[:3, 3])) + 2.0 * self.max_range * math.sin(theta / 2.0)
        if err > self.min_motion:
            self.sse += err * err
            self.count += 1


@dataclass(frozen=True)
class OdometryConfig:
    mode: str = "scan2map"
    icp: IcpConfig = field(default_factory=IcpConfig)
    voxel_size: float = 0.5
    max_points_per_voxel: int = 20
    max_range: float = 50.0
    initial_threshold: float = 2.0
    min_motion: float = 0.1
    fixed_threshold: float | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode: expected one of {', '.join(MODES)}, got {self.mode!r}")
        for name in ("voxel_size", "max_range", "initial_threshold", "min_motion"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a positive value, got {v}")
        if self.fixed_threshold is not None and not (math.isfinite(self.fixed_threshold) and self.fixed_threshold > 0):
            raise ValueError(f"fixed_threshold: expected a positive value or None, got {self.fixed_threshold}")

    def config(self) -> dict[str, Any]:
        return {**asdict(self), "icp": self.icp.config()}


class Odometry:
    """Feed scans in order with `register_frame`; `poses` holds the sensor-to-world estimates."""

    def __init__(self, config: OdometryConfig, start_pose: Any = None):
        self.config = config
        self.poses: list[np.ndarray] = []
        self.start = np.eye(4) if start_pose is None else np.array(start_pose, dtype=np.float64)
        self.delta = np.eye(4)
        self.threshold = AdaptiveThreshold(config.initial_threshold, config.min_motion, config.max_range)
        self.map = VoxelMap(config.voxel_size, config.max_points_per_voxel, config.max_range)
        self.previous: Target | None = None  # scan-to-scan: the last frame, in its sensor frame
        self.iterations: list[int] = []
        self.seconds: list[float] = []

    def _sigma(self) -> float:
        c = self.config
        return c.fixed_threshold if c.fixed_threshold is not None else self.threshold.sigma()

    def register_frame(self, points: Any, name: str = "scan") -> np.ndarray:
        """Register one scan (M, 3, sensor frame) and return its sensor-to-world pose estimate."""
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim == 2 and pts.shape[0] == 0:
            raise ValueError(f"{name}: no returns (every ray missed or fell outside the scanner's range); "
                             "odometry needs points in every scan")
        pts = check_cloud(name, pts)
        t0 = time.perf_counter()
        c = self.config
        frame = voxel_downsample(pts, 0.5 * c.voxel_size)
        source = voxel_downsample(frame, 1.5 * c.voxel_size)
        icp = c.icp
        if not self.poses:
            pose = self.start.copy()
            its = 0
        else:
            last = self.poses[-1]
            sigma = self._sigma()
            if c.mode == "scan2scan":
                res = register(source, self.previous, self.delta, max_distance=3.0 * sigma, kernel_scale=sigma,
                               config=icp)
                pose = last @ res.T
            else:
                res = register(source, self._map_target, last @ self.delta, max_distance=3.0 * sigma,
                               kernel_scale=sigma, config=icp)
                pose = res.T
            its = res.iterations
            predicted = last @ self.delta
            self.threshold.update(np.linalg.inv(predicted) @ pose)
            self.delta = np.linalg.inv(last) @ pose
        normals = point_normals(frame, icp.normal_k) if icp.metric == "plane" else None
        if c.mode == "scan2scan":
            self.previous = make_target(frame, icp.metric, icp.normal_k, normals)
        else:
            R = pose[:3, :3]
            self.map.update(frame @ R.T + pose[:3, 3], pose[:3, 3], None if normals is None else normals @ R.T)
            self._map_target = make_target(self.map.points, icp.metric, icp.normal_k,
                                           self.map.normals if normals is not None else None)
        self.poses.append(pose)
        self.iterations.append(its)
        self.seconds.append(time.perf_counter() - t0)
        return pose


def run_odometry(scans: list[np.ndarray], config: OdometryConfig, start_pose: Any = None, progress=None
                 ) -> Odometry:
    """Odometry over a list of scans (each (M, 3), sensor frame); `progress` wraps the frame range."""
    odo = Odometry(config, start_pose)
    frames = range(len(scans)) if progress is None else progress(range(len(scans)))
    for k in frames:
        odo.register_frame(scans[k], name=f"scans[{k}]")
    return odo
