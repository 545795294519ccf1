"""A rotating 360-degree scanner, ray-cast with Mitsuba.

The model (a spinning multi-beam LiDAR such as a Velodyne or Ouster unit, simplified):

* `beams` lasers at elevations evenly spaced from `elevation_deg[0]` (lowest) to `elevation_deg[1]`
  (highest), all fired at each of `azimuth_steps` azimuths a_j = 2 pi j / azimuth_steps, j = 0 .. A-1;
  a ray's direction in the sensor frame (x forward, y left, z up) is
  (cos e cos a, cos e sin a, sin e), from the sensor's origin.
* Range noise: the measured range is the true first-hit distance plus N(0, range_noise^2), drawn per
  ray from the scan's own generator (`seed`, `frame`), so each scan's noise is reproducible.
* A return is kept when the noisy range lies in [min_range, max_range]; a miss or a range outside gives
  no point (a scan with no returns at all is possible outside a closed scene: the odometry refuses it).
* Motion during a sweep is ignored: every ray of scan k leaves from the pose at the scan's time t_k.
  Each point still carries its firing time inside the sweep, t_k + (j / A) / rate_hz (what real drivers
  give and KISS-ICP's deskewing reads); since the scan is not skewed, the odometry does not deskew.

Points come back in the sensor frame, float64, with the beam index, the azimuth index and the time.
Mitsuba's ray_intersect runs vectorised on the LLVM variant (research.mitsuba_env picks it) and in a
Python loop on scalar_rgb (slow; fine for tiny tests).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Callable

import numpy as np

from research.mitsuba_env import select_variant


@dataclass(frozen=True)
class Scanner:
    beams: int = 32
    elevation_deg: tuple[float, float] = (-25.0, 15.0)
    azimuth_steps: int = 720
    range_noise: float = 0.01  # metres, standard deviation
    min_range: float = 0.5
    max_range: float = 50.0
    rate_hz: float = 10.0

    def __post_init__(self) -> None:
        if int(self.beams) != self.beams or self.beams < 1:
            raise ValueError(f"beams: expected an integer >= 1, got {self.beams}")
        if int(self.azimuth_steps) != self.azimuth_steps or self.azimuth_steps < 1:
            raise ValueError(f"azimuth_steps: expected an integer >= 1, got {self.azimuth_steps}")
        lo, hi = (float(e) for e in self.elevation_deg)
        if not (-90.0 < lo <= hi < 90.0) or (self.beams > 1 and lo == hi):
            raise ValueError(f"elevation_deg: expected -90 < lowest < highest < 90 degrees, got {self.elevation_deg}")
        if not (math.isfinite(self.range_noise) and self.range_noise >= 0):
            raise ValueError(f"range_noise: expected a finite value >= 0, got {self.range_noise}")
        if not (0 <= self.min_range < self.max_range < math.inf):
            raise ValueError(f"max_range: expected 0 <= min_range < max_range < inf, got min_range "
                             f"{self.min_range}, max_range {self.max_range}")
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"rate_hz: expected a positive value, got {self.rate_hz}")

    def config(self) -> dict[str, Any]:
        return {**asdict(self), "elevation_deg": list(self.elevation_deg),
                "motion_during_sweep": "ignored (every ray from the scan's pose)"}

    def directions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(unit directions (beams * A, 3) in the sensor frame, beam index, azimuth index), beam-major."""
        lo, hi = self.elevation_deg
        el = np.radians(np.linspace(lo, hi, self.beams)) if self.beams > 1 else np.radians([lo])
        az = 2.0 * math.pi * np.arange(self.azimuth_steps) / self.azimuth_steps
        E, Az = np.meshgrid(el, az, indexing="ij")
        d = np.stack([np.cos(E) * np.cos(Az), np.cos(E) * np.sin(Az), np.sin(E)], axis=-1).reshape(-1, 3)
        b, a = np.meshgrid(np.arange(self.beams), np.arange(self.azimuth_steps), indexing="ij")
        return d, b.ravel(), a.ravel()


@dataclass
class Scan:
    """One sweep: points (M, 3) in the sensor frame, beam (M,), azimuth (M,) indices, times (M,) seconds,
    the scan's time t and its ground-truth sensor-to-world pose."""

    points: np.ndarray
    beam: np.ndarray
    azimuth: np.ndarray
    times: np.ndarray
    t: float
    pose: np.ndarray


class RayCaster:
    """First hits of rays in a Mitsuba scene; `build()` returns its `mi.load_dict` dictionary (called once
    Mitsuba's variant is set, since the dictionary holds Mitsuba transforms)."""

    def __init__(self, build: Callable[[], dict[str, Any]]):
        import mitsuba as mi

        self.variant = select_variant()
        self.mi = mi
        self.scene = mi.load_dict(build())

    def distances(self, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Distance to the first hit along each unit direction from `origin`; inf on a miss."""
        mi = self.mi
        o = np.asarray(origin, dtype=np.float64)
        d = np.ascontiguousarray(directions, dtype=np.float64)
        if self.variant.startswith("scalar"):
            t = np.full(len(d), np.inf)
            for k in range(len(d)):
                si = self.scene.ray_intersect(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d[k])))
                if si.is_valid():
                    t[k] = float(si.t)
            return t
        n = len(d)
        ray = mi.Ray3f(mi.Point3f(*[mi.Float(np.full(n, o[i])) for i in range(3)]),
                       mi.Vector3f(*[mi.Float(d[:, i]) for i in range(3)]))
        si = self.scene.ray_intersect(ray)
        valid = np.array(si.is_valid(), dtype=bool)
        return np.where(valid, np.array(si.t, dtype=np.float64), np.inf)


def scan(caster: RayCaster, scanner: Scanner, pose: np.ndarray, t: float, seed: int, frame: int) -> Scan:
    """One sweep of `scanner` at sensor-to-world `pose` (module docstring)."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"pose: expected a finite 4x4 sensor-to-world matrix, got shape {pose.shape}")
    d, beam, az = scanner.directions()
    true_range = caster.distances(pose[:3, 3], d @ pose[:3, :3].T)
    rng = np.random.default_rng([int(seed), int(frame)])
    noisy = true_range + rng.normal(0.0, scanner.range_noise, size=true_range.shape)
    keep = np.isfinite(true_range) & (noisy >= scanner.min_range) & (noisy <= scanner.max_range)
    times = t + (az / scanner.azimuth_steps) / scanner.rate_hz
    return Scan(d[keep] * noisy[keep, None], beam[keep], az[keep], times[keep], float(t), pose)


def scan_sequence(caster: RayCaster, scanner: Scanner, timestamps: np.ndarray, poses: np.ndarray, seed: int,
                  progress=None) -> list[Scan]:
    """One scan per pose; `progress` wraps the frame range (e.g. a tqdm)."""
    frames = range(len(poses)) if progress is None else progress(range(len(poses)))
    return [scan(caster, scanner, poses[k], float(timestamps[k]), seed, k) for k in frames]
