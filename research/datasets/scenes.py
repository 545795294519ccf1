"""Built-in Mitsuba scenes for ground-truth datasets.

Each scene is a `SceneSpec`: a builder returning a `mi.load_dict` dictionary
(without sensor or integrator: those belong to the render passes), the scene's
axis-aligned bounding box (for NeRF and splat initialisation), its world up
vector, and how cameras are placed around it.

* `spheres`: the volume-rendering scene of the Video and 3D Vision textbook chapter,
  three diffuse spheres seen from the origin looking down +z (OpenCV world, so "up" is -y).
* `objects`: a checker-textured sphere, a cube, a cylinder and a disk on a square
  ground plane, lit by a procedural sky environment map and a directional sun; z up.
* `cornell`: Mitsuba's Cornell box (`mi.cornell_box()`), y up, open towards +z;
  cameras sit on a cap in front of the opening.
* `backdrop`: an unbounded scene for mip-NeRF 360-style fields: a small group of objects (checker
  sphere, cube, cylinder) on a table in the middle of a ground disk of radius 14, surrounded by a
  distant panorama wall (an emitting open cylinder of radius 15 with a procedural mountain and
  forest texture) under the sky environment map and a sun; z up. Cameras orbit at 2.6 looking in,
  so most pixels are background beyond the objects' box (`bbox`, radius ~1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from research.cameras import look_at, orbit_poses


@dataclass(frozen=True)
class SceneSpec:
    name: str
    description: str
    build: Callable[[], dict[str, Any]]
    bbox_min: tuple[float, float, float]
    bbox_max: tuple[float, float, float]
    up: tuple[float, float, float]
    # Where cameras look, and how far away they sit.
    target: tuple[float, float, float]
    radius: float
    fov_x_deg: float
    hemisphere: bool = True
    min_elevation_deg: float = 10.0
    max_elevation_deg: float = 90.0
    # Cameras on a cap of this half-angle around `cap_axis` (used instead of an orbit when set).
    cap_axis: tuple[float, float, float] | None = None
    cap_half_angle_deg: float = 0.0
    near_clip: float = 0.05
    far_clip: float = 100.0
    # Hide directly seen emitters so alpha = coverage. Only scenes without an environment may show them.
    hide_emitters: bool = True
    # Unbounded scenes: the box bounds the foreground only (what a bounded field models); geometry and
    # emitters extend beyond it (the background that mip-NeRF 360-style fields are measured on).
    unbounded: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def bbox(self) -> np.ndarray:
        return np.array([self.bbox_min, self.bbox_max], dtype=np.float64)

    def view_poses(self, n: int, seed: int) -> list[np.ndarray]:
        """Camera-to-world (OpenCV) poses for `n` multi-view cameras."""
        if self.cap_axis is None:
            return orbit_poses(n, self.radius, self.target, self.up, self.hemisphere, self.min_elevation_deg, seed,
                               self.max_elevation_deg)
        return _cap_poses(n, self.radius, np.array(self.target), np.array(self.cap_axis),
                          np.array(self.up), self.cap_half_angle_deg, seed)


def _cap_poses(n: int, radius: float, target: np.ndarray, axis: np.ndarray, up: np.ndarray,
               half_angle_deg: float, seed: int) -> list[np.ndarray]:
    """Cameras on a spherical cap (Fibonacci spiral, equal areas) around `axis`, looking at `target`."""
    axis = axis / np.linalg.norm(axis)
    a = np.cross(up, axis)
    a /= np.linalg.norm(a)
    b = np.cross(axis, a)
    golden = math.pi * (3.0 - math.sqrt(5.0))
    phase = float(np.random.default_rng(seed).uniform(0, 2 * math.pi))
    cmin = math.cos(math.radians(half_angle_deg))
    poses = []
    for k in range(n):
        c = 1.0 - (1.0 - cmin) * (k + 0.5) / n
        s = math.sqrt(max(0.0, 1.0 - c * c))
        phi = phase + golden * k
        d = c * axis + s * (math.cos(phi) * a + math.sin(phi) * b)
        poses.append(look_at(target + radius * d, target, up))
    return poses


def _T(matrix: np.ndarray):
    import mitsuba as mi

    return mi.ScalarTransform4f(np.asarray(matrix, dtype=np.float64).tolist())


def _translate_scale(t, s) -> np.ndarray:
    M = np.diag([*np.broadcast_to(np.asarray(s, float), (3,)), 1.0])
    M[:3, 3] = t
    return M


def _diffuse(rgb) -> dict[str, Any]:
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(rgb)}}


def _checker_diffuse(rgb0, rgb1, uv_scale: tuple[float, float]) -> dict[str, Any]:
    """A diffuse BSDF whose reflectance is a checkerboard of rgb0 and rgb1; (u, v) scaled by `uv_scale`."""
    return {"type": "diffuse", "reflectance": {
        "type": "checkerboard", "color0": {"type": "rgb", "value": list(rgb0)},
        "color1": {"type": "rgb", "value": list(rgb1)},
        "to_uv": _T(np.diag([*uv_scale, 1.0, 1.0]))}}


def _build_spheres() -> dict[str, Any]:
    # World = the textbook camera's OpenCV frame: x right, y down, z forward.
    spheres = {
        "red": ((0.0, 0.0, 4.0), 0.8, (0.8, 0.1, 0.1)),
        "green": ((1.5, 0.5, 5.0), 0.6, (0.1, 0.8, 0.1)),
        "blue": ((-1.0, -0.5, 3.5), 0.5, (0.1, 0.1, 0.8)),
    }
    scene: dict[str, Any] = {"type": "scene", "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.6}},
                             "key": {"type": "directional", "direction": [0.3, 0.8, 0.6],
                                     "irradiance": {"type": "rgb", "value": 2.0}}}
    for name, (c, r, rgb) in spheres.items():
        scene[name] = {"type": "sphere", "center": list(c), "radius": r, "bsdf": _diffuse(rgb)}
    return scene


def _sky_bitmap(height: int = 64) -> np.ndarray:
    """A latitude-longitude sky: bright blue-white zenith fading to a darker warm horizon and ground."""
    width = 2 * height
    theta = (np.arange(height) + 0.5) / height * math.pi  # 0 at the envmap's +y pole
    elev = 0.5 * math.pi - theta
    zen = np.clip(np.sin(elev), 0.0, 1.0)[:, None]
    sky = (1 - zen) * np.array([0.9, 0.8, 0.7]) + zen * np.array([0.35, 0.55, 1.0])
    ground = np.array([0.25, 0.22, 0.2])
    img = np.where((elev > 0)[:, None], sky, ground)
    # A gentle azimuthal variation makes the lighting non-symmetric.
    az = (np.arange(width) + 0.5) / width * 2 * math.pi
    img = img[:, None, :] * (0.85 + 0.15 * np.cos(az))[None, :, None]
    return np.ascontiguousarray(img.astype(np.float32))


def _sky_and_sun() -> dict[str, Any]:
    """The z-up scenes' light: the procedural sky environment map and a directional sun."""
    import mitsuba as mi

    # Mitsuba's envmap has +y as its pole; rotate it so the pole is world +z.
    env_to_world = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
    return {
        "sky": {"type": "envmap", "bitmap": mi.Bitmap(_sky_bitmap()), "scale": 0.8, "to_world": _T(env_to_world)},
        "sun": {"type": "directional", "direction": [-0.4, -0.3, -0.85],
                "irradiance": {"type": "rgb", "value": [2.6, 2.4, 2.1]}},
    }


def _checker_ball() -> dict[str, Any]:
    """The red and yellow checker BSDF of the ball (objects and backdrop)."""
    return _checker_diffuse((0.85, 0.15, 0.1), (0.95, 0.85, 0.2), (8.0, 4.0))


def _can_with_lid(x: float, y: float, radius: float, height: float) -> dict[str, Any]:
    """The green can standing on z = 0 at (x, y) (an open cylinder) and the white disk that closes its top."""
    return {
        "can": {"type": "cylinder", "p0": [x, y, 0.0], "p1": [x, y, height], "radius": radius,
                "bsdf": _diffuse((0.2, 0.7, 0.3))},
        "can_lid": {"type": "disk", "to_world": _T(_translate_scale([x, y, height], radius)),
                    "bsdf": _diffuse((0.9, 0.9, 0.85))},
    }


def _build_objects() -> dict[str, Any]:
    return {
        "type": "scene",
        **_sky_and_sun(),
        "ground": {"type": "rectangle", "to_world": _T(_translate_scale([0, 0, 0], [2.0, 2.0, 1.0])),
                   "bsdf": _checker_diffuse((0.55, 0.55, 0.5), (0.35, 0.35, 0.32), (6.0, 6.0))},
        "ball": {"type": "sphere", "center": [-0.6, -0.5, 0.5], "radius": 0.5, "bsdf": _checker_ball()},
        "box": {"type": "cube", "to_world": _T(_rotz_translate_scale(25.0, [0.7, -0.3, 0.35], 0.35)),
                "bsdf": _diffuse((0.15, 0.35, 0.8))},
        **_can_with_lid(0.2, 0.8, 0.28, 0.9),
        "coaster": {"type": "disk", "to_world": _T(_translate_scale([-0.7, 0.7, 0.01], 0.4)),
                    "bsdf": _diffuse((0.8, 0.5, 0.2))},
    }


def _rotz_translate_scale(deg: float, t, s: float) -> np.ndarray:
    c, s_ = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    M = np.eye(4)
    M[:3, :3] = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]]) * s
    M[:3, 3] = t
    return M


def _panorama_bitmap(height: int = 64) -> np.ndarray:
    """The backdrop's texture (u around the wall, v up): hills and tree stripes under a hazy band."""
    width = 4 * height
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    ridge = 0.45 + 0.12 * np.sin(2 * math.pi * 3 * u) + 0.07 * np.sin(2 * math.pi * 11 * u + 1.0)
    img = np.empty((height, width, 3))
    sky = (1 - v)[:, None, None] * np.array([0.85, 0.8, 0.7]) + v[:, None, None] * np.array([0.45, 0.6, 0.95])
    img[:] = sky
    hill = v[:, None] < ridge[None, :]
    shade = 0.6 + 0.4 * (v[:, None] / ridge[None, :])
    trees = 0.75 + 0.25 * np.sign(np.sin(2 * math.pi * 40 * u))[None, :]
    hill_rgb = np.array([0.25, 0.45, 0.2])[None, None, :] * (shade * trees)[..., None]
    img = np.where(hill[..., None], hill_rgb, img)
    img[: height // 8] = np.array([0.35, 0.3, 0.25])  # the wall's foot: dark earth
    return np.ascontiguousarray(img.astype(np.float32))  # row 0 is v = 0, the wall's foot (checked in a render)


def _build_backdrop() -> dict[str, Any]:
    import mitsuba as mi

    scene = _build_objects_group()
    scene.update({
        **_sky_and_sun(),
        "ground": {"type": "disk", "to_world": _T(_translate_scale([0, 0, 0], [14.0, 14.0, 1.0])),
                   "bsdf": _checker_diffuse((0.5, 0.45, 0.35), (0.35, 0.4, 0.3), (8.0, 8.0))},
        "wall": {"type": "cylinder", "p0": [0.0, 0.0, -0.5], "p1": [0.0, 0.0, 7.0], "radius": 15.0,
                 "flip_normals": True,
                 "emitter": {"type": "area", "radiance": {"type": "bitmap", "bitmap": mi.Bitmap(_panorama_bitmap())}},
                 "bsdf": _diffuse((0.0, 0.0, 0.0))},
    })
    return scene


def _build_objects_group() -> dict[str, Any]:
    """The backdrop scene's foreground: a checker ball, a box and a can on a round table top."""
    return {
        "type": "scene",
        "table": {"type": "disk", "to_world": _T(_translate_scale([0, 0, 0.01], 0.9)), "bsdf": _diffuse((0.8, 0.75, 0.7))},
        "ball": {"type": "sphere", "center": [-0.3, -0.25, 0.3], "radius": 0.3, "bsdf": _checker_ball()},
        "box": {"type": "cube", "to_world": _T(_rotz_translate_scale(25.0, [0.35, -0.15, 0.22], 0.22)),
                "bsdf": _diffuse((0.15, 0.35, 0.8))},
        **_can_with_lid(0.05, 0.4, 0.18, 0.6),
    }


def _build_cornell() -> dict[str, Any]:
    import mitsuba as mi

    scene = dict(mi.cornell_box())
    scene.pop("sensor", None)
    scene.pop("integrator", None)
    return scene


SCENES: dict[str, SceneSpec] = {
    "spheres": SceneSpec(
        name="spheres", description="three diffuse spheres of the textbook volume-rendering task",
        build=_build_spheres, bbox_min=(-1.5, -1.0, 3.0), bbox_max=(2.1, 1.1, 5.6), up=(0.0, -1.0, 0.0),
        target=(0.25, 0.0, 4.3), radius=5.0, fov_x_deg=45.0, hemisphere=False, near_clip=0.05),
    "objects": SceneSpec(
        name="objects", description="textured sphere, cube, cylinder and disk on a ground plane; sky + sun",
        build=_build_objects, bbox_min=(-2.0, -2.0, -0.01), bbox_max=(2.0, 2.0, 1.0), up=(0.0, 0.0, 1.0),
        target=(0.0, 0.0, 0.3), radius=4.2, fov_x_deg=45.0, hemisphere=True, min_elevation_deg=15.0,
        near_clip=0.05),
    "cornell": SceneSpec(
        name="cornell", description="Mitsuba's Cornell box (mi.cornell_box)",
        build=_build_cornell, bbox_min=(-1.0, -1.0, -1.0), bbox_max=(1.0, 1.0, 1.0), up=(0.0, 1.0, 0.0),
        target=(0.0, 0.0, 0.0), radius=3.9, fov_x_deg=39.3077, cap_axis=(0.0, 0.0, 1.0),
        cap_half_angle_deg=12.0, near_clip=0.05, hide_emitters=False),
    "backdrop": SceneSpec(
        name="backdrop", description="objects on a table inside a distant panorama wall; ground disk, sky + sun",
        build=_build_backdrop, bbox_min=(-1.0, -1.0, -0.01), bbox_max=(1.0, 1.0, 1.0), up=(0.0, 0.0, 1.0),
        target=(0.0, 0.0, 0.3), radius=2.6, fov_x_deg=60.0, hemisphere=True, min_elevation_deg=3.0,
        max_elevation_deg=30.0, near_clip=0.05, far_clip=100.0, hide_emitters=False, unbounded=True),
}


def get_scene(name: str) -> SceneSpec:
    if name not in SCENES:
        raise ValueError(f"scene: unknown scene {name!r}; expected one of {sorted(SCENES)}")
    return SCENES[name]
