"""The pinhole camera of the splatting kernels (OpenCV axes: x right, y down, z forward).

A world point X maps to p = W X + t in the camera frame (viewmat = [[W, t], [0, 0, 0, 1]], W a
rotation), and to the pixel (fx p_x / p_z + cx, fy p_y / p_z + cy); pixel (i, j) has its centre
at (i + 0.5, j + 0.5). Splats with z-depth outside [near, far] are culled. Host code only.
viewmat passes the one rotation check (kernels/rotation.py: max |W^T W - I| <= 1e-5, det W > 0, last
row 0 0 0 1) and is kept with W re-orthonormalised (the polar factor).

Pose perturbations (the convention of the camera gradients, render_backward(want_camera=True)):
a twist xi = (rho, phi), translation first, acts on the LEFT of world-to-camera,

    viewmat <- exp(xi^) viewmat,  exp(xi^) = [[R, V rho], [0, 1]],  R = exp([phi]x) (Rodrigues),
    V = I + (1 - cos a)/a^2 [phi]x + (a - sin a)/a^3 [phi]x^2,  a = |phi|,

so rho is a translation and phi a rotation in the camera frame (`se3_exp`, `SplatCamera.perturbed`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kernels import _arrays as A
from kernels.lens import Lens, check_lens
from kernels.rotation import checked_rigid
from kernels.splat.tiles import MAX_SIDE, TILE

DEFAULT_NEAR = 0.01
DEFAULT_FAR = 1e10


@dataclass(frozen=True)
class SplatCamera:
    """A pinhole camera for the splatting kernels (module docstring).

    viewmat: 4x4 world-to-camera; K: 3x3 intrinsics [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    (no skew); splats with z-depth outside [near, far] are culled. `lens`: None (the pinhole) or a
    kernels.lens.Lens (opencv, fisheye, orthographic; kernels/splat/lens_projection.py); a Lens
    "pinhole" is stored as None.
    """

    viewmat: np.ndarray
    K: np.ndarray
    width: int
    height: int
    near: float = DEFAULT_NEAR
    far: float = DEFAULT_FAR
    lens: Lens | None = None

    def __post_init__(self) -> None:
        view = np.asarray(self.viewmat, dtype=np.float64)
        K = np.asarray(self.K, dtype=np.float64)
        if view.shape != (4, 4) or not np.all(np.isfinite(view)):
            raise ValueError(f"viewmat: expected a finite 4x4 matrix, got shape {view.shape}")
        try:
            view = checked_rigid("viewmat", view)
        except ValueError as exc:
            raise ValueError(f"viewmat: expected a rigid world-to-camera transform [[R, t], [0, 0, 0, 1]]; "
                             f"{str(exc).removeprefix('viewmat: ')}") from None
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError(f"K: expected a finite 3x3 matrix, got shape {K.shape}")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or K[0, 1] != 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise ValueError("K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0 and no skew")
        width = A.check_int("width", self.width, minimum=1, maximum=MAX_SIDE)
        height = A.check_int("height", self.height, minimum=1, maximum=MAX_SIDE)
        if not (0 < self.near < self.far):
            raise ValueError(f"near, far: expected 0 < near < far, got {self.near}, {self.far}")
        object.__setattr__(self, "viewmat", view)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "width", width)
        object.__setattr__(self, "height", height)
        object.__setattr__(self, "lens", check_lens("lens", self.lens))

    def perturbed(self, xi: np.ndarray) -> "SplatCamera":
        """This camera with viewmat <- se3_exp(xi) viewmat (module docstring)."""
        return SplatCamera(se3_exp(xi) @ self.viewmat, self.K, self.width, self.height, self.near, self.far,
                           self.lens)

    def with_intrinsics(self, fx: float, fy: float, cx: float, cy: float) -> "SplatCamera":
        """This camera with other intrinsics."""
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return SplatCamera(self.viewmat, K, self.width, self.height, self.near, self.far, self.lens)

    def params(self) -> np.ndarray:
        """(fx, fy, cx, cy, near, far)."""
        K = self.K
        return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], self.near, self.far])

    @property
    def tiles(self) -> tuple[int, int]:
        return (self.width + TILE - 1) // TILE, (self.height + TILE - 1) // TILE


def _hat(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """The 4x4 rigid transform exp(xi^) of a twist xi = (rho, phi), translation first (module docstring)."""
    xi = np.asarray(xi, dtype=np.float64)
    if xi.shape != (6,) or not np.all(np.isfinite(xi)):
        raise ValueError(f"xi: expected a finite 6-vector (rho, phi), got shape {xi.shape}")
    rho, phi = xi[:3], xi[3:]
    a = float(np.linalg.norm(phi))
    P = _hat(phi)
    if a < 1e-8:  # series to second order: the terms dropped are below 1e-16
        R = np.eye(3) + P + 0.5 * P @ P
        V = np.eye(3) + 0.5 * P + P @ P / 6.0
    else:
        R = np.eye(3) + np.sin(a) / a * P + (1.0 - np.cos(a)) / a**2 * P @ P
        V = np.eye(3) + (1.0 - np.cos(a)) / a**2 * P + (a - np.sin(a)) / a**3 * P @ P
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = V @ rho
    return T
