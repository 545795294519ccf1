"""Bundle adjustment: pinhole reprojection residuals and their Jacobians, one thread per observation.

Camera (OpenCV axes, research/cameras.py): world-to-camera T_cw = [[R, t], [0, 1]] per camera,
intrinsics (fx, fy, cx, cy) shared by every camera. Observation k sees point p_j (world) in camera
c with measured pixel (u_k, v_k) (pixel centres at half-integers, as the renderers use):

    X = R p_j + t = (X, Y, Z)                                    (camera frame)
    pi(X) = (fx X / Z + cx,  fy Y / Z + cy)
    r_k = pi(X) - (u_k, v_k)                                     (2 residuals per observation)

Pose convention (shared with kernels/splat, kernels/volume/rays.py and research/poses/se3.py): a
LEFT-multiplied se(3) perturbation of world-to-camera, T_cw <- exp(xi^) T_cw, xi = (rho, phi),
translation first. To first order at xi = 0, exp(xi^) X = X + rho + phi x X, so with

    d pi / d X = [[fx / Z, 0, -fx X / Z^2],
                  [0, fy / Z, -fy Y / Z^2]]                      (2 x 3)

the Jacobians written per observation are

    d r / d xi  = d pi/dX [ I | -X^ ]      (2 x 6, at xi = 0; X^ the skew matrix of X)
    d r / d p_j = d pi/dX R                 (2 x 3),

and, for RGB-D residuals on the point's depth Z in its camera,

    d Z / d xi = (0, 0, 1, Y, -X, 0),       d Z / d p_j = (row 3 of R).

A solver that keeps xi as a free parameter with T = exp(xi^) T_0 chains the first with the SE(3)
left Jacobian of xi (research/vo/ba.py does). Non-smooth points: none for Z > 0; the projection is
undefined at Z = 0, and for Z < 0 (a point behind the camera) the formulas still hold but the
residual is meaningless, so `reproject` also returns Z for the caller's cheirality test.

One thread per observation writes its own rows (split launches are race-free); float32 and float64
run the same generic kernel. Inputs follow the array contract (kernels._arrays).
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _reproject_kernel(
    poses: wp.array3d(dtype=typing.Any), points: wp.array2d(dtype=typing.Any), obs: wp.array2d(dtype=typing.Any),
    cam_idx: wp.array(dtype=wp.int32), pt_idx: wp.array(dtype=wp.int32), intr: wp.array(dtype=typing.Any),
    out_r: wp.array2d(dtype=typing.Any), out_jpose: wp.array3d(dtype=typing.Any),
    out_jpoint: wp.array3d(dtype=typing.Any), out_z: wp.array(dtype=typing.Any), out_jz: wp.array2d(dtype=typing.Any),
    want_jac: int, offset: int,
):
    k = wp.tid() + offset
    c = cam_idx[k]
    j = pt_idx[k]
    zero = points.dtype(0.0)
    X = poses[c, 0, 0] * points[j, 0] + poses[c, 0, 1] * points[j, 1] + poses[c, 0, 2] * points[j, 2] + poses[c, 0, 3]
    Y = poses[c, 1, 0] * points[j, 0] + poses[c, 1, 1] * points[j, 1] + poses[c, 1, 2] * points[j, 2] + poses[c, 1, 3]
    Z = poses[c, 2, 0] * points[j, 0] + poses[c, 2, 1] * points[j, 1] + poses[c, 2, 2] * points[j, 2] + poses[c, 2, 3]
    fx = intr[0]
    fy = intr[1]
    iz = points.dtype(1.0) / Z
    out_r[k, 0] = fx * X * iz + intr[2] - obs[k, 0]
    out_r[k, 1] = fy * Y * iz + intr[3] - obs[k, 1]
    out_z[k] = Z
    if want_jac != 0:
        # d pi / dX rows: a = (fx/Z, 0, -fx X/Z^2), b = (0, fy/Z, -fy Y/Z^2)
        a0 = fx * iz
        a2 = -fx * X * iz * iz
        b1 = fy * iz
        b2 = -fy * Y * iz * iz
        # rho block: d pi/dX
        out_jpose[k, 0, 0] = a0
        out_jpose[k, 0, 1] = zero
        out_jpose[k, 0, 2] = a2
        out_jpose[k, 1, 0] = zero
        out_jpose[k, 1, 1] = b1
        out_jpose[k, 1, 2] = b2
        # phi block: d pi/dX (-X^), -X^ = [[0, Z, -Y], [-Z, 0, X], [Y, -X, 0]]
        out_jpose[k, 0, 3] = a2 * Y
        out_jpose[k, 0, 4] = a0 * Z - a2 * X
        out_jpose[k, 0, 5] = -a0 * Y
        out_jpose[k, 1, 3] = -b1 * Z + b2 * Y
        out_jpose[k, 1, 4] = -b2 * X
        out_jpose[k, 1, 5] = b1 * X
        # point block: d pi/dX R
        for m in range(3):
            out_jpoint[k, 0, m] = a0 * poses[c, 0, m] + a2 * poses[c, 2, m]
            out_jpoint[k, 1, m] = b1 * poses[c, 1, m] + b2 * poses[c, 2, m]
        # depth Z: d Z/d xi = (0, 0, 1, Y, -X, 0), d Z/d p = R row 2
        out_jz[k, 0] = zero
        out_jz[k, 1] = zero
        out_jz[k, 2] = points.dtype(1.0)
        out_jz[k, 3] = Y
        out_jz[k, 4] = -X
        out_jz[k, 5] = zero
        for m in range(3):
            out_jz[k, 6 + m] = poses[c, 2, m]


A.declare_float_overloads(_reproject_kernel)


@dataclass
class Reprojection:
    """What `reproject` returns, in the kind of `poses` (NumPy in, NumPy out; wp.array in, wp.array out).

    residuals (M, 2): pi(R p + t) - observed pixel; depth (M,): Z of each observation's point in its
    camera; jac_pose (M, 2, 6): d r / d xi at xi = 0 (left perturbation, rho first), jac_point
    (M, 2, 3): d r / d p, and jac_depth (M, 9): (d Z / d xi, d Z / d p); all None when
    `jacobians=False`.
    """

    residuals: Any
    depth: Any
    jac_pose: Any = None
    jac_point: Any = None
    jac_depth: Any = None


def reproject(poses: Any, points: Any, observations: Any, cam_idx: Any, pt_idx: Any, intrinsics: Any, *,
              jacobians: bool = True, device: Any = None) -> Reprojection:
    """Reprojection residuals (and Jacobians) of M observations (module docstring).

    poses: (C, 3, 4) or (C, 4, 4) world-to-camera matrices (only the top 3 rows are read);
    points: (N, 3) world points; observations: (M, 2) measured pixels; cam_idx, pt_idx: (M,) integer
    indices into poses and points; intrinsics: (fx, fy, cx, cy), fx and fy positive.
    """
    a = A.Inputs(device, poses, points, observations)
    if not hasattr(poses, "shape") or len(poses.shape) != 3 or tuple(poses.shape[1:]) not in ((3, 4), (4, 4)):
        raise ValueError(f"poses: expected world-to-camera matrices of shape (C, 3, 4) or (C, 4, 4), "
                         f"got {A.shape_text(getattr(poses, 'shape', ()))}")
    pw = a.floats("poses", poses, (None, poses.shape[1], 4), nonempty=True)
    xw = a.floats("points", points, (None, 3), nonempty=True)
    ow = a.floats("observations", observations, (None, 2), nonempty=True)
    m = observations.shape[0]
    cw = a.ints("cam_idx", cam_idx, (m,), minimum=0)
    jw = a.ints("pt_idx", pt_idx, (m,), minimum=0)
    if A.values_checked():
        for name, idx, n in (("cam_idx", cam_idx, poses.shape[0]), ("pt_idx", pt_idx, points.shape[0])):
            h = A.host_view(idx)
            if h is None:
                h = idx.numpy()
            if h.size and int(np.max(h)) >= n:
                raise ValueError(f"{name}: expected values < {n} (the number of {name[:-4]}s), "
                                 f"got a maximum of {int(np.max(h))}")
    intr = np.asarray(intrinsics, dtype=np.float64)
    if intr.shape != (4,) or not np.all(np.isfinite(intr)) or intr[0] <= 0 or intr[1] <= 0:
        raise ValueError(f"intrinsics: expected 4 finite numbers (fx, fy, cx, cy) with fx, fy > 0, got {intr.tolist()}")
    iw = wp.array(intr.astype(a.np_dtype), dtype=a.scalar, device=a.device)
    r = a.empty((m, 2))
    z = a.empty((m,))
    if jacobians:
        jp, jx, jz = a.empty((m, 2, 6)), a.empty((m, 2, 3)), a.empty((m, 9))
    else:
        jp, jx, jz = a.empty((1, 2, 6)), a.empty((1, 2, 3)), a.empty((1, 9))
    a.launch(_reproject_kernel, m, [pw, xw, ow, cw, jw, iw, r, jp, jx, z, jz, int(bool(jacobians))])
    if not jacobians:
        return Reprojection(a.out(r), a.out(z))
    return Reprojection(a.out(r), a.out(z), a.out(jp), a.out(jx), a.out(jz))


__all__ = ["Reprojection", "reproject"]
