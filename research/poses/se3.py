"""Camera poses: SO(3)/SE(3) exponential and logarithm, pose perturbations, TUM trajectories, ATE and RPE.

Conventions (shared with the camera gradients of kernels/volume/rays.py and kernels/splat):

* drlab cameras are OpenCV camera-to-world matrices c2w = [[R, t], [0, 1]] (research/cameras.py);
  the world-to-camera matrix is T_cw = c2w^-1.
* A pose update is a LEFT-multiplied se(3) perturbation of world-to-camera,

      T_cw <- exp(xi^) T_cw,      xi = (rho, phi) in R^6, translation rho first, rotation phi second,

  so c2w <- c2w exp(-xi^). Gradients "with respect to the pose" are d/dxi at xi = 0.
* exp: R = exp(phi^) (Rodrigues), t = V(phi) rho with V = I + (1 - cos a)/a^2 Phi + (a - sin a)/a^3 Phi^2,
  a = |phi|, Phi = phi^ (the skew matrix). log inverts both (phi in the ball |phi| <= pi).
* TUM trajectories (Sturm et al. 2012, "A benchmark for the evaluation of RGB-D SLAM systems"): one
  line per pose, `timestamp tx ty tz qx qy qz qw`, the camera's pose in the world (camera-to-world,
  translation = camera centre), '#' starts a comment.
* ATE (absolute trajectory error, Sturm et al. 2012): estimated positions p_i are aligned onto the
  reference positions q_i by the least-squares similarity (Umeyama 1991, "Least-squares estimation
  of transformation parameters between two point patterns"): SE(3) (s = 1) or Sim(3); then
  e_i = |q_i - (s R p_i + t)| and ATE RMSE = sqrt(mean e_i^2).
* RPE (relative pose error, the same paper): for every frame pair (i, i + delta), i = 0 .. N-1-delta
  (all overlapping pairs, as the TUM benchmark's script and evo's `all_pairs=True` do),
  E_i = (Q_i^-1 Q_{i+delta})^-1 (P_i^-1 P_{i+delta}) with P the estimate and Q the reference
  (camera-to-world); the translational error is |trans(E_i)|, the rotational error the angle of
  rot(E_i), arccos((tr - 1)/2). RPE is invariant to a rigid alignment; with `align="sim3"` the
  estimate's translations are first scaled by the Sim(3) scale (monocular estimates).

The `evo` package (Grupp 2017) computes the same ATE and RPE; the tests check both against it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from research.cameras import check_pose, check_rotation

_SMALL = 1e-8


# =========================================================================== SO(3) and SE(3)


def hat(v: Any) -> np.ndarray:
    """The skew matrix v^ with v^ w = v x w."""
    x, y, z = np.asarray(v, dtype=np.float64)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _vec(name: str, v: Any, n: int) -> np.ndarray:
    arr = np.asarray(v, dtype=np.float64)
    if arr.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains non-finite values")
    return arr


def so3_exp(phi: Any) -> np.ndarray:
    """Rotation matrix exp(phi^) (Rodrigues' formula; Taylor series below |phi| = 1e-8)."""
    phi = _vec("phi", phi, 3)
    a = float(np.linalg.norm(phi))
    P = hat(phi)
    if a < _SMALL:
        return np.eye(3) + P + 0.5 * P @ P
    return np.eye(3) + math.sin(a) / a * P + (1.0 - math.cos(a)) / (a * a) * P @ P


def so3_log(R: Any) -> np.ndarray:
    """phi with exp(phi^) = R and |phi| <= pi (R a rotation; checked)."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3):
        raise ValueError(f"R: expected shape (3, 3), got {R.shape}")
    R = check_rotation("R", R)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    c = min(1.0, max(-1.0, 0.5 * (np.trace(R) - 1.0)))
    a = math.acos(c)
    if a < 1e-6:
        return 0.5 * w * (1.0 + a * a / 6.0)
    if a > math.pi - 1e-3:
        # Near pi, sin a is small: read the axis from the symmetric part, R + R^T = 2 I + 2 (1 - cos a)(n n^T - I).
        B = (0.5 * (R + R.T) - np.eye(3)) / (1.0 - c) + np.eye(3)
        k = int(np.argmax(np.diag(B)))
        n = B[:, k] / math.sqrt(max(B[k, k], 1e-300))
        n /= np.linalg.norm(n)
        if n @ w < 0:
            n = -n
        return a * n
    return 0.5 * a / math.sin(a) * w


def _V(phi: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(phi))
    P = hat(phi)
    if a < 1e-5:
        return np.eye(3) + 0.5 * P + P @ P / 6.0
    return np.eye(3) + (1.0 - math.cos(a)) / (a * a) * P + (a - math.sin(a)) / a ** 3 * P @ P


def se3_exp(xi: Any) -> np.ndarray:
    """The 4x4 rigid transform exp(xi^), xi = (rho, phi): R = exp(phi^), t = V(phi) rho."""
    xi = _vec("xi", xi, 6)
    T = np.eye(4)
    T[:3, :3] = so3_exp(xi[3:])
    T[:3, 3] = _V(xi[3:]) @ xi[:3]
    return T


def se3_log(T: Any) -> np.ndarray:
    """xi = (rho, phi) with exp(xi^) = T (T a rigid transform; checked)."""
    T = check_pose("T", T)
    phi = so3_log(T[:3, :3])
    return np.concatenate([np.linalg.solve(_V(phi), T[:3, 3]), phi])


def perturb_w2c(w2c: Any, xi: Any) -> np.ndarray:
    """exp(xi^) T_cw: the module's left perturbation of a world-to-camera matrix."""
    return se3_exp(xi) @ check_pose("w2c", w2c)


def perturb_c2w(c2w: Any, xi: Any) -> np.ndarray:
    """The camera-to-world matrix of exp(xi^) T_cw, i.e. c2w exp(-xi^)."""
    return check_pose("c2w", c2w) @ se3_exp(-_vec("xi", xi, 6))


def rotation_angle_deg(R: Any) -> float:
    """The angle of a rotation matrix in degrees (arccos((tr R - 1)/2), clipped)."""
    R = np.asarray(R, dtype=np.float64)
    return math.degrees(math.acos(min(1.0, max(-1.0, 0.5 * (np.trace(R) - 1.0)))))


def pose_errors(c2w_est: Any, c2w_ref: Any) -> tuple[np.ndarray, np.ndarray]:
    """Per-camera (rotation error in degrees, camera-centre distance) between two pose lists."""
    est, ref = check_trajectory("c2w_est", c2w_est), check_trajectory("c2w_ref", c2w_ref)
    _same_length(est, ref)
    rot = np.array([rotation_angle_deg(e[:3, :3].T @ r[:3, :3]) for e, r in zip(est, ref)])
    return rot, np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=1)


def random_perturbations(n: int, rot_deg: float, trans: float, seed: int) -> np.ndarray:
    """(n, 6) perturbations xi = (rho, phi) with |phi| = rot_deg degrees and |rho| = trans exactly,
    about uniformly random axes drawn from `seed`."""
    if int(n) != n or n < 1:
        raise ValueError(f"n: expected a positive integer, got {n}")
    for name, v in (("rot_deg", rot_deg), ("trans", trans)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name}: expected a finite value >= 0, got {v}")
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(2, int(n), 3))
    axes /= np.linalg.norm(axes, axis=2, keepdims=True)
    return np.concatenate([trans * axes[0], math.radians(rot_deg) * axes[1]], axis=1)


# =========================================================================== trajectories


def check_trajectory(name: str, poses: Any) -> np.ndarray:
    """A list or array of 4x4 rigid transforms as an (N, 4, 4) float64 array, each re-orthonormalised by
    `check_pose`; ValueError naming `name` and the pose index for any that is not a rotation plus translation."""
    arr = np.asarray(poses, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (4, 4) or arr.shape[0] < 1:
        raise ValueError(f"{name}: expected a non-empty array of 4x4 poses (N, 4, 4), got shape {arr.shape}")
    return np.array([check_pose(f"{name}[{i}]", T) for i, T in enumerate(arr)])


def _same_length(est: np.ndarray, ref: np.ndarray) -> None:
    if est.shape[0] != ref.shape[0]:
        raise ValueError(f"est, ref: expected trajectories of the same length (associated poses), "
                         f"got {est.shape[0]} and {ref.shape[0]}")


def quat_to_matrix(q: Any) -> np.ndarray:
    """Rotation matrix of a unit quaternion (qx, qy, qz, qw) (Hamilton convention, as TUM files use)."""
    x, y, z, w = np.asarray(q, dtype=np.float64)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def matrix_to_quat(R: Any) -> np.ndarray:
    """The unit quaternion (qx, qy, qz, qw), qw >= 0, of a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s])
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 - R[0, 0] + R[1, 1] - R[2, 2])
        q = np.array([(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s])
    else:
        s = 2.0 * math.sqrt(1.0 - R[0, 0] - R[1, 1] + R[2, 2])
        q = np.array([(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def read_tum(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps (N,), camera-to-world poses (N, 4, 4)) of a TUM trajectory file.

    Reads what evo's `read_tum_trajectory_file` reads: the poses stay in the file's order, so
    timestamps that repeat or go back are kept as they stand; a quaternion of any non-zero norm is
    normalised (evo and the TUM benchmark's evaluate_rpe do the same); a UTF-8 byte-order mark is
    skipped. Also takes the tabs, commas and CRLF that the benchmark's own read_file_list accepts.

    Raises ValueError naming the file and line for a line without 8 numbers, a non-finite value or
    a zero quaternion (evo would read it as the identity; it holds no rotation), and for a file
    without poses.
    """
    path = os.fspath(path)
    stamps, poses = [], []
    with open(path, encoding="utf-8-sig") as f:
        for lineno, line in enumerate(f, 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            fields = text.replace(",", " ").split()
            try:
                vals = [float(v) for v in fields]
            except ValueError:
                vals = []
            where = f"{path}:{lineno}"
            if len(vals) != 8:
                raise ValueError(f"{where}: expected 8 numbers 'timestamp tx ty tz qx qy qz qw', got {text[:60]!r}")
            if not all(math.isfinite(v) for v in vals):
                raise ValueError(f"{where}: expected finite numbers, got {text[:60]!r}")
            q = np.array(vals[4:])
            norm = float(np.linalg.norm(q))
            if not norm > 1e-12:
                raise ValueError(f"{where}: quaternion (qx qy qz qw) has norm {norm:.6g}, expected a non-zero "
                                 "quaternion (a rotation)")
            T = np.eye(4)
            T[:3, :3] = quat_to_matrix(q / norm)
            T[:3, 3] = vals[1:4]
            stamps.append(vals[0])
            poses.append(T)
    if not poses:
        raise ValueError(f"{path}: no poses (expected lines 'timestamp tx ty tz qx qy qz qw')")
    return np.array(stamps), np.array(poses)


def write_tum(path: str | os.PathLike, timestamps: Any, c2w: Any) -> None:
    """Write camera-to-world poses as a TUM trajectory file (full float64 precision)."""
    poses = check_trajectory("c2w", c2w)
    ts = np.asarray(timestamps, dtype=np.float64)
    if ts.shape != (poses.shape[0],):
        raise ValueError(f"timestamps: expected shape ({poses.shape[0]},) (one per pose), got {ts.shape}")
    if not np.all(np.isfinite(ts)) or np.any(np.diff(ts) <= 0):
        raise ValueError("timestamps: expected finite, strictly increasing values")
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for t, T in zip(ts, poses):
        vals = [t, *T[:3, 3], *matrix_to_quat(T[:3, :3])]
        lines.append(" ".join(repr(float(v)) for v in vals))
    with open(os.fspath(path), "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")


# =========================================================================== alignment, ATE, RPE


def umeyama(src: Any, dst: Any, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, s) minimising sum_i |dst_i - (s R src_i + t)|^2 over points (N, 3) (Umeyama 1991);
    s = 1 unless `with_scale`."""
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape != y.shape:
        raise ValueError(f"src, dst: expected two point sets of the same shape (N, 3), got {x.shape} and {y.shape}")
    if x.shape[0] < 3:
        raise ValueError(f"src: expected at least 3 points to align, got {x.shape[0]}")
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    var_x = float((xc ** 2).sum()) / x.shape[0]
    if var_x <= 0.0:
        raise ValueError("src: all points coincide; the alignment is undefined")
    U, D, Vt = np.linalg.svd(yc.T @ xc / x.shape[0])
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_x) if with_scale else 1.0
    return R, my - s * R @ mx, s


_ALIGN = ("none", "se3", "sim3")


def _check_align(align: str) -> str:
    if align not in _ALIGN:
        raise ValueError(f"align: expected one of {list(_ALIGN)}, got {align!r}")
    return align


def align_trajectory(c2w_est: Any, c2w_ref: Any, align: str = "se3") -> np.ndarray:
    """The estimate mapped by the SE(3)/Sim(3) alignment of its positions onto the reference's:
    P_i <- [[R R_i, s R t_i + t], [0, 1]] (s = 1 for "se3"; unchanged for "none")."""
    est, ref = check_trajectory("c2w_est", c2w_est), check_trajectory("c2w_ref", c2w_ref)
    _same_length(est, ref)
    if _check_align(align) == "none":
        return est.copy()
    R, t, s = umeyama(est[:, :3, 3], ref[:, :3, 3], with_scale=align == "sim3")
    out = est.copy()
    out[:, :3, :3] = R @ est[:, :3, :3]
    out[:, :3, 3] = s * est[:, :3, 3] @ R.T + t
    return out


@dataclass
class ErrorStats:
    rmse: float
    mean: float
    median: float
    max: float
    errors: np.ndarray

    @classmethod
    def of(cls, e: np.ndarray) -> "ErrorStats":
        return cls(float(np.sqrt(np.mean(e ** 2))), float(np.mean(e)), float(np.median(e)), float(np.max(e)), e)


def ate(c2w_est: Any, c2w_ref: Any, align: str = "se3") -> ErrorStats:
    """Absolute trajectory error of the positions after alignment (module docstring)."""
    est = align_trajectory(c2w_est, c2w_ref, align)
    ref = np.asarray(c2w_ref, dtype=np.float64)
    return ErrorStats.of(np.linalg.norm(ref[:, :3, 3] - est[:, :3, 3], axis=1))


@dataclass
class RPE:
    translation: ErrorStats  # |trans(E_i)|, in the trajectory's units
    rotation_deg: ErrorStats  # angle of rot(E_i), degrees


def rpe(c2w_est: Any, c2w_ref: Any, delta: int = 1, align: str = "none") -> RPE:
    """Relative pose error over frame pairs (i, i + delta) (module docstring)."""
    est, ref = check_trajectory("c2w_est", c2w_est), check_trajectory("c2w_ref", c2w_ref)
    _same_length(est, ref)
    if int(delta) != delta or delta < 1 or delta >= est.shape[0]:
        raise ValueError(f"delta: expected an integer in [1, {est.shape[0] - 1}] (frames in the trajectory - 1), "
                         f"got {delta}")
    delta = int(delta)
    if _check_align(align) == "sim3":
        est = align_trajectory(est, ref, "sim3")
    inv = np.linalg.inv
    E = [inv(inv(ref[i]) @ ref[i + delta]) @ (inv(est[i]) @ est[i + delta]) for i in range(est.shape[0] - delta)]
    return RPE(ErrorStats.of(np.array([np.linalg.norm(e[:3, 3]) for e in E])),
               ErrorStats.of(np.array([rotation_angle_deg(e[:3, :3]) for e in E])))


def loop_path(n_frames: int, radius: float, center: Any = (0.0, 0.0, 0.0), up: Any = (0.0, 0.0, 1.0),
              start_azimuth_deg: float = 0.0, elevation_deg: float = 25.0, elevation_wobble_deg: float = 5.0,
              radius_wobble: float = 0.05) -> list[np.ndarray]:
    """A closed camera path (c2w list) that returns to its start: one full orbit around `center`, looking at it.

    Frame k sits at s = k / n_frames of the loop (frame n_frames would be frame 0 again, so the last
    frame is one step before the first): azimuth start + 360 s degrees, elevation
    elevation_deg + elevation_wobble_deg sin(4 pi s), distance radius (1 + radius_wobble sin(2 pi s)).
    Every term is periodic in s, so the motion from the last frame back to the first is as small and
    smooth as every other step (a loop closure for SLAM).
    """
    from research.cameras import look_at

    if int(n_frames) != n_frames or n_frames < 3:
        raise ValueError(f"n_frames: expected an integer >= 3 for a loop, got {n_frames}")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"radius: expected a positive value, got {radius}")
    upv = _vec("up", up, 3)
    upv = upv / np.linalg.norm(upv)
    a = np.cross(upv, [1.0, 0.0, 0.0] if abs(upv[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(upv, a)
    centre = _vec("center", center, 3)
    poses = []
    for k in range(int(n_frames)):
        s = k / n_frames
        az = math.radians(start_azimuth_deg + 360.0 * s)
        el = math.radians(elevation_deg + elevation_wobble_deg * math.sin(4.0 * math.pi * s))
        r = radius * (1.0 + radius_wobble * math.sin(2.0 * math.pi * s))
        d = math.cos(el) * (math.cos(az) * a + math.sin(az) * b) + math.sin(el) * upv
        poses.append(look_at(centre + r * d, centre, upv))
    return poses


def path_length(c2w: Any) -> float:
    """Sum of the distances between consecutive camera centres."""
    p = check_trajectory("c2w", c2w)[:, :3, 3]
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


__all__ = ["hat", "so3_exp", "so3_log", "se3_exp", "se3_log", "perturb_w2c", "perturb_c2w", "rotation_angle_deg",
           "pose_errors", "random_perturbations", "check_trajectory", "quat_to_matrix", "matrix_to_quat", "read_tum",
           "write_tum", "umeyama", "align_trajectory", "ErrorStats", "ate", "RPE", "rpe", "loop_path", "path_length"]
