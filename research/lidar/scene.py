"""A closed hall with a street of boxes and pillars, as a Mitsuba scene, and a sensor path along the street.

The hall is an axis-aligned box, x in [-L/2, L/2], y in [-W/2, W/2], z in [0, H] (z up), seen from inside
(Mitsuba's ray_intersect hits a surface from either side), so every ray of a scanner inside it returns.
Along both sides of the street (|y| >= street_half_width + 1) stand boxes of random size, height and
yaw; a few pillars (vertical cylinders, floor to ceiling) stand between them; a few low boxes lie in the
street's margins. The layout is drawn from `seed`; every object stays clear of the path's band
|y| <= street_half_width, so the sensor never enters one.

The path: x runs from -0.36 L at a constant `speed` along x (at most to +0.36 L); y = A sin(2 pi x / lambda
+ phase) wanders inside the street (A = 0.4 street_half_width, lambda and the phase drawn from `seed`); the
height z = z0 + 0.05 sin(...) bobs; the heading follows the path's tangent, and pitch and roll wobbles of
1 degree excite every degree of freedom. Frame k is at time k / rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class HallSpec:
    length: float = 60.0
    width: float = 24.0
    height: float = 6.0
    street_half_width: float = 3.0
    n_boxes: int = 28
    n_pillars: int = 8
    n_kerbs: int = 4


def _T(matrix: np.ndarray):
    import mitsuba as mi

    return mi.ScalarTransform4f(np.asarray(matrix, dtype=np.float64).tolist())


def _box_matrix(center, half, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    M = np.eye(4)
    M[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.diag(half)
    M[:3, 3] = center
    return M


def hall_objects(spec: HallSpec, seed: int) -> list[dict[str, Any]]:
    """The objects as plain dicts: {"kind": "box", "center", "half", "yaw"} or {"kind": "pillar", "xy", "radius"}."""
    rng = np.random.default_rng(seed)
    L, W = spec.length, spec.width
    objs: list[dict[str, Any]] = []
    for _ in range(spec.n_boxes):
        side = rng.choice([-1.0, 1.0])
        half = np.array([rng.uniform(0.4, 2.0), rng.uniform(0.4, 1.5), rng.uniform(0.4, 2.5)])
        yaw = rng.uniform(-0.6, 0.6)
        reach = float(np.hypot(half[0], half[1]))  # the box's radius in plan
        y = side * rng.uniform(spec.street_half_width + 1.0 + reach, W / 2 - 0.2)
        x = rng.uniform(-L / 2 + 1.0 + reach, L / 2 - 1.0 - reach)
        objs.append({"kind": "box", "center": [x, y, half[2]], "half": half.tolist(), "yaw": yaw})
    for _ in range(spec.n_pillars):
        side = rng.choice([-1.0, 1.0])
        r = rng.uniform(0.2, 0.5)
        objs.append({"kind": "pillar", "xy": [rng.uniform(-L / 2 + 2, L / 2 - 2),
                                             side * rng.uniform(spec.street_half_width + 0.6 + r, W / 2 - 1.0)],
                     "radius": r})
    for _ in range(spec.n_kerbs):  # low kerb blocks at the street's edges
        side = rng.choice([-1.0, 1.0])
        half = [rng.uniform(0.5, 1.5), 0.25, rng.uniform(0.15, 0.4)]
        objs.append({"kind": "box", "center": [rng.uniform(-L / 2 + 3, L / 2 - 3),
                                               side * (spec.street_half_width + 0.45), half[2]],
                     "half": half, "yaw": 0.0})
    return objs


def hall_scene_dict(spec: HallSpec, seed: int) -> dict[str, Any]:
    """A `mi.load_dict` dictionary of the hall (no sensor, no emitter: the scanner only ray-casts)."""
    grey = {"type": "diffuse"}
    d: dict[str, Any] = {"type": "scene", "hall": {
        "type": "cube", "bsdf": grey,
        "to_world": _T(_box_matrix([0.0, 0.0, spec.height / 2], [spec.length / 2, spec.width / 2, spec.height / 2],
                                   0.0))}}
    for i, o in enumerate(hall_objects(spec, seed)):
        if o["kind"] == "box":
            d[f"box{i}"] = {"type": "cube", "bsdf": grey, "to_world": _T(_box_matrix(o["center"], o["half"], o["yaw"]))}
        else:
            x, y = o["xy"]
            d[f"pillar{i}"] = {"type": "cylinder", "bsdf": grey, "p0": [x, y, 0.0], "p1": [x, y, spec.height],
                               "radius": o["radius"]}
    return d


def street_path(spec: HallSpec, n_frames: int, seed: int, rate_hz: float = 10.0, speed: float = 4.0,
                height: float = 1.8) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps (n,), sensor-to-world poses (n, 4, 4)) along the street at `speed` m/s (module docstring)."""
    if int(n_frames) != n_frames or n_frames < 2:
        raise ValueError(f"n_frames: expected an integer >= 2, got {n_frames}")
    length = (n_frames - 1) * speed / rate_hz
    if length > 0.72 * spec.length:
        raise ValueError(f"n_frames: {n_frames} frames at {speed} m/s and {rate_hz} Hz run {length:.1f} m, longer "
                         f"than the street ({0.72 * spec.length:.1f} m)")
    rng = np.random.default_rng(seed + 7919)
    phase, lam = rng.uniform(0, 2 * math.pi), rng.uniform(18.0, 26.0)
    amp = 0.4 * spec.street_half_width
    x = -0.36 * spec.length + speed / rate_hz * np.arange(int(n_frames))
    y = amp * np.sin(2 * math.pi * x / lam + phase)
    z = height + 0.05 * np.sin(2 * math.pi * x / 7.0 + phase)
    yaw = np.arctan2(amp * 2 * math.pi / lam * np.cos(2 * math.pi * x / lam + phase), 1.0)
    pitch = np.radians(1.0) * np.sin(2 * math.pi * x / 9.0 + 2 * phase)
    roll = np.radians(1.0) * np.sin(2 * math.pi * x / 11.0 + 3 * phase)
    poses = np.tile(np.eye(4), (int(n_frames), 1, 1))
    for k in range(int(n_frames)):
        cy, sy, cp, sp, cr, sr = (math.cos(yaw[k]), math.sin(yaw[k]), math.cos(pitch[k]), math.sin(pitch[k]),
                                  math.cos(roll[k]), math.sin(roll[k]))
        Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
        Ry = np.array([[cp, 0, sp], [0, 1.0, 0], [-sp, 0, cp]])
        Rx = np.array([[1.0, 0, 0], [0, cr, -sr], [0, sr, cr]])
        poses[k, :3, :3] = Rz @ Ry @ Rx
        poses[k, :3, 3] = [x[k], y[k], z[k]]
    return np.arange(int(n_frames)) / float(rate_hz), poses
