"""Pinhole cameras in the OpenCV convention, and conversions to Mitsuba and NeRF.

Conventions (the Mitsuba facts behind them are in docs/mitsuba.md):

* Camera frame (OpenCV): +x right, +y down, +z forward. A camera is its
  intrinsics K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]], its camera-to-world
  matrix c2w = [[R, t], [0, 1]] (R in SO(3); t is the camera centre in world
  coordinates), and its image size (width, height).
* Pixel (i, j) -- column i, row j -- has its centre at continuous image
  coordinates (u, v) = (i + 0.5, j + 0.5). The image spans [0, W] x [0, H].
* Projection of a world point X:  x_c = R^T (X - t),  [u, v, 1]^T ~ K x_c,
  z-depth = x_c[2].  Back-projection of pixel (u, v) at z-depth z:
  X = t + z * R K^{-1} [u, v, 1]^T.  Ray distance = z * |K^{-1}[u, v, 1]|.
* Mitsuba's camera frame is +x image-left, +y up, +z forward, so
  c2w_opencv = to_world @ diag(-1, -1, 1, 1).
* NeRF / Blender / OpenGL `transform_matrix` frame is +x right, +y up, +z
  backward, so c2w_nerf = to_world @ diag(-1, 1, -1, 1)
  = c2w_opencv @ diag(1, -1, -1, 1).
* Mitsuba intrinsics (fov_axis 'x'): fx = fy = (W/2) / tan(fov_x/2),
  cx = W/2 - principal_point_offset_x * W,  cy = H/2 - principal_point_offset_y * H.

* Every pose taken in (`Camera`, `check_pose`, so every dataset reader) passes the one rotation
  check of kernels/rotation.py: max |R^T R - I| <= 1e-5 (what float32 JSON and 6-8 digit text
  can hold; the derivation is there) and det R > 0, else ValueError naming the argument; an accepted
  rotation is replaced by its nearest rotation (the orthogonal polar factor).

* A camera may carry a lens model (`lens`: a kernels.lens.Lens, opencv radial-tangential, fisheye
  or orthographic; None is the pinhole). Then pixel (u, v) = (fx m_x + cx, fy m_y + cy) for the
  normalised image point m of the lens (kernels/lens.py states the models), and the ray methods
  (`camera_directions`, `rays`, `project`, `backproject`) go through it (kernels.lens.project_points,
  kernels.volume.lens_rays); pixels outside the lens's domain give NaN. `scaled` keeps the lens
  (its coefficients act on normalised coordinates).

This module is the only place where these conversions live.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from kernels.lens import Lens, check_lens
from kernels.rotation import checked_rigid, checked_rotation

_CV_TO_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])  # self-inverse
_CV_TO_NERF = np.diag([1.0, -1.0, -1.0, 1.0])  # self-inverse


def _as_matrix(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains non-finite values")
    return arr


def check_rotation(name: str, R: Any, tol: float | None = None) -> np.ndarray:
    """R as the nearest rotation, after `kernels.rotation.checked_rotation`'s check (ValueError naming
    `name` unless max |R^T R - I| <= tol, default 1e-5, and det R > 0; that module derives the tolerance
    from how the formats store matrices and re-orthonormalises with the polar factor)."""
    return checked_rotation(name, R, tol)


def check_pose(name: str, pose: Any) -> np.ndarray:
    """A 4x4 rigid transform as float64, its rotation re-orthonormalised and its last row exact
    (`kernels.rotation.checked_rigid`: the one rotation check; ValueError naming `name`)."""
    return checked_rigid(name, _as_matrix(name, pose, (4, 4)))


def intrinsics_from_fov(fov_x_deg: float, width: int, height: int) -> np.ndarray:
    """K for a horizontal field of view (degrees), square pixels, centred principal point."""
    if not (0.0 < fov_x_deg < 180.0):
        raise ValueError(f"fov_x_deg: expected a value in (0, 180), got {fov_x_deg}")
    f = (width / 2.0) / math.tan(math.radians(fov_x_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class Camera:
    """A camera: intrinsics K, OpenCV camera-to-world c2w, image size, and an optional lens model
    (None: the pinhole; module docstring)."""

    K: np.ndarray
    c2w: np.ndarray
    width: int
    height: int
    lens: Lens | None = None

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise ValueError(f"{name}: expected a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        K = _as_matrix("K", self.K, (3, 3))
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"K: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
        if not np.allclose(K[1:, :], [[0.0, K[1, 1], K[1, 2]], [0.0, 0.0, 1.0]], atol=0.0):
            raise ValueError("K: expected the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
        c2w = check_pose("c2w", self.c2w)
        K.setflags(write=False)
        c2w.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "c2w", c2w)
        object.__setattr__(self, "lens", check_lens("lens", self.lens))
        if self.lens is not None and K[0, 1] != 0.0:
            raise ValueError("K: a camera with a lens model takes no skew")

    # ------------------------------------------------------------------ basics
    @classmethod
    def from_fov(cls, fov_x_deg: float, width: int, height: int, c2w: Any) -> "Camera":
        return cls(intrinsics_from_fov(fov_x_deg, width, height), np.asarray(c2w, float), width, height)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def R(self) -> np.ndarray:
        """Camera-to-world rotation (columns: camera x, y, z axes in world)."""
        return self.c2w[:3, :3]

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return self.c2w[:3, 3]

    @property
    def w2c(self) -> np.ndarray:
        R, t = self.R, self.center
        out = np.eye(4)
        out[:3, :3] = R.T
        out[:3, 3] = -R.T @ t
        return out

    @property
    def fov_x_deg(self) -> float:
        """Horizontal field of view, for a centred principal point (NeRF's camera_angle_x)."""
        return math.degrees(2.0 * math.atan((self.width / 2.0) / self.fx))

    def scaled(self, factor: float) -> "Camera":
        """The same camera at `factor` times the resolution (K scales with the pixel grid)."""
        w, h = round(self.width * factor), round(self.height * factor)
        if w <= 0 or h <= 0 or not math.isclose(w / self.width, h / self.height, rel_tol=1e-9):
            raise ValueError(f"factor: {factor} does not give an integer image size from {self.width}x{self.height}")
        S = np.diag([w / self.width, h / self.height, 1.0])
        return Camera(S @ self.K, self.c2w, w, h, self.lens)

    # ------------------------------------------------------------------ rays
    def pixel_centers(self) -> tuple[np.ndarray, np.ndarray]:
        """(u, v), each (H, W): continuous coordinates of every pixel centre."""
        u, v = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
        return u, v

    def camera_directions(self, u: np.ndarray | None = None, v: np.ndarray | None = None) -> np.ndarray:
        """K^{-1}[u, v, 1] in the camera frame, shape (..., 3), with z = 1 (so t = z-depth); through the
        lens when there is one (NaN outside its domain; an orthographic camera has no such rays)."""
        if u is None or v is None:
            u, v = self.pixel_centers()
        if self.lens is not None:
            if not self.lens.central:
                raise ValueError("lens: an orthographic camera has parallel rays: use Camera.rays")
            _, d, z, valid = self._lens_rays(np.eye(4), u, v)
            return np.where(valid[..., None], d / z[..., None], np.nan)
        uv1 = np.stack([u, v, np.ones_like(u, dtype=np.float64)], axis=-1)
        return uv1 @ np.linalg.inv(self.K).T

    def rays(self, normalize: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """World-space rays through every pixel centre: origins (H, W, 3), directions (H, W, 3).

        With normalize=False the directions have camera z-component 1, so a point at
        parameter t along the ray has z-depth t. With a lens, pixels outside its domain get NaN.
        """
        if self.lens is not None:
            u, v = self.pixel_centers()
            o, d, z, valid = self._lens_rays(self.w2c, u, v)
            if not normalize:
                d = d / z[..., None]
            return np.where(valid[..., None], o, np.nan), np.where(valid[..., None], d, np.nan)
        d = self.camera_directions() @ self.R.T
        if normalize:
            d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        o = np.broadcast_to(self.center, d.shape).copy()
        return o, d

    def _lens_rays(self, w2c: np.ndarray, u: np.ndarray, v: np.ndarray):
        from kernels.volume.lens_rays import lens_rays

        u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
        px = np.stack([u.ravel(), v.ravel()], axis=1)
        o, d, z, valid = lens_rays(w2c, [self.fx, self.fy, self.cx, self.cy], self.lens, px, device="cpu")
        shape = u.shape
        return o.reshape(*shape, 3), d.reshape(*shape, 3), z.reshape(shape), valid.reshape(shape)

    def ray_cosines(self) -> np.ndarray:
        """cos(theta) between each pixel's ray and the optical axis, (H, W)."""
        return 1.0 / np.linalg.norm(self.camera_directions(), axis=-1)

    # ------------------------------------------------------------------ projection
    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=np.float64)
        if points.shape[-1] != 3:
            raise ValueError(f"points: expected shape (..., 3), got {points.shape}")
        return (points - self.center) @ self.R

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) -> pixel coordinates (..., 2) and z-depth (...).

        Points with z <= 0 (behind the camera) get NaN pixel coordinates.
        """
        xc = self.world_to_camera(points)
        z = xc[..., 2]
        if self.lens is not None:
            from kernels.lens import project_points

            flat = xc.reshape(-1, 3)
            uv, valid = project_points(self.lens, [self.fx, self.fy, self.cx, self.cy], flat, device="cpu")
            uv = np.where(valid[:, None], uv, np.nan)
            return uv.reshape(*xc.shape[:-1], 2), z
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = xc @ self.K.T
            uv = uvw[..., :2] / uvw[..., 2:3]
        uv = np.where((z > 0)[..., None], uv, np.nan)
        return uv, z

    def backproject(self, depth: np.ndarray) -> np.ndarray:
        """A z-depth map (H, W) -> world points (H, W, 3) through every pixel centre."""
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != (self.height, self.width):
            raise ValueError(f"depth: expected shape {(self.height, self.width)}, got {depth.shape}")
        if self.lens is not None:
            o, d = self.rays(normalize=False)
            return o + depth[..., None] * d
        return self.center + (depth[..., None] * self.camera_directions()) @ self.R.T

    # ------------------------------------------------------------------ conversions
    def to_mitsuba(self) -> np.ndarray:
        """Mitsuba sensor `to_world` (4x4)."""
        return self.c2w @ _CV_TO_MITSUBA

    def mitsuba_intrinsics(self) -> dict[str, float]:
        """Mitsuba `perspective` parameters: fov (degrees, axis 'x') and principal point offsets."""
        if self.lens is not None:
            raise ValueError(f"lens: Mitsuba's perspective sensor is a pinhole, this camera has a {self.lens.model} "
                             "lens")
        if not math.isclose(self.fx, self.fy, rel_tol=1e-12) or self.K[0, 1] != 0.0:
            raise ValueError("K: Mitsuba's perspective sensor needs square pixels (fx == fy) and zero skew")
        return {
            "fov": self.fov_x_deg,
            "fov_axis": "x",
            "principal_point_offset_x": (self.width / 2.0 - self.cx) / self.width,
            "principal_point_offset_y": (self.height / 2.0 - self.cy) / self.height,
        }

    @classmethod
    def from_mitsuba(
        cls,
        to_world: Any,
        width: int,
        height: int,
        fov_deg: float,
        fov_axis: str = "x",
        principal_point_offset_x: float = 0.0,
        principal_point_offset_y: float = 0.0,
    ) -> "Camera":
        """Build a Camera from a Mitsuba perspective sensor's parameters."""
        axis_len = {"x": width, "y": height, "smaller": min(width, height), "larger": max(width, height)}
        if fov_axis not in axis_len:
            raise ValueError(f"fov_axis: expected one of {sorted(axis_len)}, got {fov_axis!r}")
        if not (0.0 < fov_deg < 180.0):
            raise ValueError(f"fov_deg: expected a value in (0, 180), got {fov_deg}")
        f = (axis_len[fov_axis] / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
        cx = width / 2.0 - principal_point_offset_x * width
        cy = height / 2.0 - principal_point_offset_y * height
        K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        to_world = check_pose("to_world", to_world)
        return cls(K, to_world @ _CV_TO_MITSUBA, width, height)

    def to_nerf(self) -> np.ndarray:
        """NeRF/Blender/OpenGL `transform_matrix` (camera-to-world, +y up, +z backward)."""
        return self.c2w @ _CV_TO_NERF

    @classmethod
    def from_nerf(
        cls,
        transform_matrix: Any,
        width: int,
        height: int,
        camera_angle_x: float | None = None,
        fl_x: float | None = None,
        fl_y: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
    ) -> "Camera":
        """Build a Camera from a NeRF-synthetic frame (camera_angle_x in radians, or fl_x/fl_y)."""
        if fl_x is None:
            if camera_angle_x is None:
                raise ValueError("camera_angle_x: needed when fl_x is not given")
            fl_x = (width / 2.0) / math.tan(camera_angle_x / 2.0)
        fl_y = fl_x if fl_y is None else fl_y
        cx = width / 2.0 if cx is None else cx
        cy = height / 2.0 if cy is None else cy
        K = np.array([[fl_x, 0.0, cx], [0.0, fl_y, cy], [0.0, 0.0, 1.0]])
        M = check_pose("transform_matrix", transform_matrix)
        return cls(K, M @ _CV_TO_NERF, width, height)

    def to_dict(self) -> dict[str, Any]:
        out = {"width": self.width, "height": self.height, "K": self.K.tolist(), "c2w": self.c2w.tolist()}
        if self.lens is not None:
            out["lens"] = self.lens.to_dict()
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Camera":
        missing = {"width", "height", "K", "c2w"} - set(d)
        if missing:
            raise ValueError(f"camera: missing keys {sorted(missing)}")
        return cls(np.asarray(d["K"], float), np.asarray(d["c2w"], float), d["width"], d["height"], d.get("lens"))


# ---------------------------------------------------------------------- poses
def _unit(name: str, v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"{name}: expected a non-zero finite vector, got {np.asarray(v).tolist()}")
    return v / n


def look_at(eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera-to-world for a camera at `eye` looking at `target`, with world `up` upward in the image."""
    eye = _as_matrix("eye", eye, (3,))
    target = _as_matrix("target", target, (3,))
    up = _as_matrix("up", up, (3,))
    z = _unit("target - eye", target - eye)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9 * np.linalg.norm(up):
        raise ValueError("up: parallel to the viewing direction; choose another up vector")
    x = _unit("right", x)
    y = np.cross(z, x)  # image down
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = x, y, z, eye
    return M


def _orthonormal_up_frame(up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An orthonormal basis (a, b, up) with `up` as third axis."""
    up = _unit("up", np.asarray(up, dtype=np.float64))
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = _unit("a", np.cross(helper, up))
    b = np.cross(up, a)
    return a, b, up


def orbit_poses(
    n: int,
    radius: float,
    center: Sequence[float] = (0.0, 0.0, 0.0),
    up: Sequence[float] = (0.0, 0.0, 1.0),
    hemisphere: bool = True,
    min_elevation_deg: float = 5.0,
    seed: int | None = None,
    max_elevation_deg: float = 90.0,
) -> list[np.ndarray]:
    """`n` cameras on a sphere (or the upper hemisphere) of `radius` around `center`, looking at it.

    Directions follow a Fibonacci spiral, which covers the sphere almost uniformly;
    with a `seed` the spiral is rotated about `up` by a random angle. In
    hemisphere mode elevations lie in [min_elevation_deg, max_elevation_deg) degrees.
    """
    if n <= 0:
        raise ValueError(f"n: expected a positive number of views, got {n}")
    if not radius > 0:
        raise ValueError(f"radius: expected a positive value, got {radius}")
    a, b, upv = _orthonormal_up_frame(np.asarray(up, float))
    center = _as_matrix("center", center, (3,))
    golden = math.pi * (3.0 - math.sqrt(5.0))
    phase = 0.0 if seed is None else float(np.random.default_rng(seed).uniform(0, 2 * math.pi))
    zmin = math.sin(math.radians(min_elevation_deg)) if hemisphere else -1.0
    zmax = math.sin(math.radians(max_elevation_deg)) if hemisphere else 1.0
    if not zmax > zmin:
        raise ValueError(f"max_elevation_deg: expected more than min_elevation_deg ({min_elevation_deg}), "
                         f"got {max_elevation_deg}")
    poses = []
    for k in range(n):
        # Heights equally spaced in [zmin, zmax) give equal areas on the sphere.
        h = zmin + (zmax - zmin) * (k + 0.5) / n
        r = math.sqrt(max(0.0, 1.0 - h * h))
        phi = phase + golden * k
        d = r * math.cos(phi) * a + r * math.sin(phi) * b + h * upv
        eye = center + radius * d
        # Near the pole the image "up" is ill-defined; use a tilted up vector there.
        up_k = upv if abs(h) < 0.999 else a
        poses.append(look_at(eye, center, up_k))
    return poses


def smooth_path(
    n_frames: int,
    radius: float,
    center: Sequence[float] = (0.0, 0.0, 0.0),
    up: Sequence[float] = (0.0, 0.0, 1.0),
    start_azimuth_deg: float = 0.0,
    sweep_deg: float = 30.0,
    elevation_deg: float = 25.0,
    elevation_wobble_deg: float = 3.0,
    radius_wobble: float = 0.03,
) -> list[np.ndarray]:
    """A smooth video camera path: an arc of `sweep_deg` around `center` with gentle wobbles.

    Azimuth moves linearly; elevation and radius vary sinusoidally over the path,
    so consecutive frames differ by a small, smooth motion (a few pixels of flow).
    """
    if n_frames < 2:
        raise ValueError(f"n_frames: expected at least 2, got {n_frames}")
    if not radius > 0:
        raise ValueError(f"radius: expected a positive value, got {radius}")
    a, b, upv = _orthonormal_up_frame(np.asarray(up, float))
    center = _as_matrix("center", center, (3,))
    poses = []
    for k in range(n_frames):
        s = k / (n_frames - 1)
        az = math.radians(start_azimuth_deg + sweep_deg * s)
        el = math.radians(elevation_deg + elevation_wobble_deg * math.sin(2 * math.pi * s))
        r = radius * (1.0 + radius_wobble * math.sin(math.pi * s))
        d = math.cos(el) * (math.cos(az) * a + math.sin(az) * b) + math.sin(el) * upv
        poses.append(look_at(center + r * d, center, upv))
    return poses
