"""Feature visual odometry (RGB-D): essential-matrix initialisation, PnP tracking, keyframes, local BA.

Poses are world-to-camera T_cw (research/poses/se3.py conventions); frame 0's pose is given (it fixes the
world frame, as in splat SLAM). Pipeline, per frame k (research/vo/features.py for the features):

1. Initialisation (frame 1): ORB matches with keyframe 0, the essential matrix with RANSAC
   (cv2.findEssentialMat) and cv2.recoverPose give R and a unit translation; the inlier matches are
   triangulated (cv2.triangulatePoints). Scale from depth: s = median(measured z / triangulated z)
   over keyframe 0's inlier keypoints with a valid depth; t and the points are multiplied by s.
2. Tracking: the frame's descriptors are matched with the landmarks of the last `window` keyframes
   that project within `search_px` of a keypoint under the constant-velocity prediction (guided
   matching); cv2.solvePnPRansac (reprojection threshold `pnp_px`) gives the pose. When that fails,
   the match is repeated without the prediction (relocalisation against the local map). Fewer than `min_inliers`
   inliers is a tracking failure: it is recorded, the frame keeps the constant-velocity prediction,
   and `max_failures` failures in a row raise TrackingError (never a silent trajectory of guesses).
3. Keyframes: every `keyframe_every` frames, or when the inliers drop below `keyframe_inlier_frac` of
   the last keyframe's. A new keyframe's unassigned keypoints are matched with the previous
   keyframe's and triangulated; points behind either camera, with a reprojection error above
   `pnp_px` or a parallax below `min_parallax_deg` are dropped. Scale from depth: the new points are
   rescaled about the camera centre by the median of measured / triangulated depth (keeps the map
   metric), and points whose depth still disagrees by more than 10% are dropped.
4. Local bundle adjustment (research/vo/ba.py, Warp Jacobians) over the last `window` keyframes and
   their landmarks, the oldest two keyframes held fixed (gauge), robust loss `ba_loss`; observations
   with a valid depth add a relative depth residual weighted `ba_depth_weight` (RGB-D).

Non-keyframes keep their pose relative to their reference keyframe, so a later correction of the
keyframes (bundle adjustment, loop closure) moves them too.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import cv2
import numpy as np

from research.cameras import check_pose
from research.vo.ba import LOSSES, bundle_adjust
from research.vo.features import ORB, Features, backproject, match


class TrackingError(RuntimeError):
    """Tracking lost for `max_failures` frames in a row (the message names the frames and the reason)."""


@dataclass
class VOConfig:
    n_features: int = 1000
    ratio: float = 0.8  # Lowe's ratio test
    pnp_px: float = 2.0  # RANSAC reprojection threshold (pixels) for E, PnP and triangulation
    min_inliers: int = 15  # fewer PnP inliers = tracking failure
    max_failures: int = 3  # consecutive failures that stop the run
    keyframe_every: int = 2
    keyframe_inlier_frac: float = 0.6
    window: int = 5  # keyframes in the tracking map and in the local BA
    search_px: float = 15.0  # guided matching radius around a landmark's predicted projection
    min_parallax_deg: float = 0.5
    ba: bool = True
    ba_loss: str = "huber"
    ba_f_scale: float = 2.0  # robust loss inlier scale, pixels
    ba_max_nfev: int = 20
    # pixels per unit relative depth error of an observation (0: pixels only); chosen among 0, 30, 100, 300
    # on the smoke sequence (seed 0, 4 spp), not on the data feature_vo reports
    ba_depth_weight: float = 30.0

    def validate(self) -> "VOConfig":
        for name in ("n_features", "min_inliers", "max_failures", "keyframe_every", "ba_max_nfev"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name}: expected an integer >= 1, got {v}")
        if int(self.window) != self.window or self.window < 2:
            raise ValueError(f"window: expected an integer >= 2 (keyframes in the local map), got {self.window}")
        for name in ("ratio", "keyframe_inlier_frac"):
            v = getattr(self, name)
            if not 0.0 < v <= 1.0:
                raise ValueError(f"{name}: expected a value in (0, 1], got {v}")
        for name in ("pnp_px", "ba_f_scale", "search_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected a positive number of pixels, got {getattr(self, name)}")
        if not self.ba_depth_weight >= 0:
            raise ValueError(f"ba_depth_weight: expected a value >= 0, got {self.ba_depth_weight}")
        if self.ba_loss not in LOSSES:
            raise ValueError(f"ba_loss: expected one of {list(LOSSES)}, got {self.ba_loss!r}")
        return self


@dataclass
class Keyframe:
    frame: int
    T: np.ndarray  # (4, 4) world-to-camera
    feats: Features
    lm: np.ndarray  # (n,) landmark id per keypoint, -1 if none


@dataclass
class VOResult:
    c2w: np.ndarray  # (N, 4, 4) camera-to-world per frame (the odometry, before loop closure)
    keyframes: list[Keyframe]
    ref_kf: np.ndarray  # (N,) index into keyframes of each frame's reference keyframe
    rel: np.ndarray  # (N, 4, 4) T_cw(frame) T_cw(reference keyframe)^-1
    points: np.ndarray  # (L, 3) landmarks
    lm_desc: np.ndarray  # (L, 32) a descriptor per landmark
    failures: list[dict] = field(default_factory=list)
    frames: list[dict] = field(default_factory=list)  # per-frame records (matches, inliers, keyframe, ...)
    ba: list[dict] = field(default_factory=list)  # per-BA records (rms before / after, nfev)
    seconds: float = 0.0
    init_scale: float = float("nan")

    def trajectory(self, kf_T: np.ndarray | None = None) -> np.ndarray:
        """c2w per frame from keyframe poses (default: the current ones) and the relative poses."""
        Ts = np.stack([k.T for k in self.keyframes]) if kf_T is None else kf_T
        return np.stack([np.linalg.inv(self.rel[i] @ Ts[self.ref_kf[i]]) for i in range(len(self.ref_kf))])


def check_sequence(rgba: Any, depth: Any, K: Any, c2w0: Any, window: int) -> None:
    """ValueError naming the argument (and frame) for input the odometry cannot run on."""
    if depth is None:
        raise ValueError("depth: RGB-D odometry needs a depth map per frame, got None")
    rgba = np.asarray(rgba)
    if rgba.ndim != 4 or rgba.shape[-1] not in (3, 4):
        raise ValueError(f"rgba: expected frames of shape (N, H, W, 3|4), got {rgba.shape}")
    depth = np.asarray(depth)
    if depth.shape != rgba.shape[:3]:
        raise ValueError(f"depth: expected one (H, W) map per frame, shape {rgba.shape[:3]}, got {depth.shape}")
    if rgba.shape[0] < max(2, window):
        raise ValueError(f"rgba: the sequence has {rgba.shape[0]} frames, fewer than the keyframe window "
                         f"({window}) or 2")
    for k in range(depth.shape[0]):
        d = depth[k]
        if not np.all(np.isfinite(d)) or np.any(d < 0):
            raise ValueError(f"depth[{k}]: expected finite z-depths >= 0")
        if not np.any(d > 0):
            raise ValueError(f"depth[{k}]: frame {k} has no depth (every pixel 0); RGB-D mode needs depth")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K: expected a 3x3 intrinsic matrix with fx, fy > 0, got {K.tolist()}")
    check_pose("c2w0", c2w0)


def _project(T: np.ndarray, X: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Xc = X @ T[:3, :3].T + T[:3, 3]
    z = Xc[:, 2]
    uv = np.stack([K[0, 0] * Xc[:, 0] / z + K[0, 2], K[1, 1] * Xc[:, 1] / z + K[1, 2]], axis=1)
    return uv, z


def _pose_from_rt(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    return T


class _Map:
    def __init__(self):
        self.xyz: list[np.ndarray] = []
        self.desc: list[np.ndarray] = []

    def add(self, xyz: np.ndarray, desc: np.ndarray) -> np.ndarray:
        start = len(self.xyz)
        self.xyz.extend(list(xyz))
        self.desc.extend(list(desc))
        return np.arange(start, start + len(xyz))


def _triangulate(Ta: np.ndarray, Tb: np.ndarray, uva: np.ndarray, uvb: np.ndarray, K: np.ndarray,
                 max_px: float, min_parallax_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """World points of matches (n, 2) x 2 between cameras Ta, Tb, and the mask of good ones."""
    X = cv2.triangulatePoints(K @ Ta[:3], K @ Tb[:3], uva.T, uvb.T)
    X = (X[:3] / X[3]).T
    ua, za = _project(Ta, X, K)
    ub, zb = _project(Tb, X, K)
    ca, cb = -Ta[:3, :3].T @ Ta[:3, 3], -Tb[:3, :3].T @ Tb[:3, 3]
    ra, rb = X - ca, X - cb
    cosang = np.sum(ra * rb, 1) / np.maximum(np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-12)
    good = ((za > 0) & (zb > 0) & (np.linalg.norm(ua - uva, axis=1) < max_px)
            & (np.linalg.norm(ub - uvb, axis=1) < max_px)
            & (cosang < np.cos(np.radians(min_parallax_deg))))
    return X, good


def run_vo(rgba: Any, depth: Any, K: Any, c2w0: Any, cfg: VOConfig | None = None, *, device: Any = "cpu",
           progress: Callable[[int, dict], None] | None = None) -> VOResult:
    """Run the odometry over a sequence (N, H, W, 3|4) with z-depth (N, H, W) (module docstring)."""
    cfg = (cfg or VOConfig()).validate()
    check_sequence(rgba, depth, K, c2w0, cfg.window)
    K = np.asarray(K, dtype=np.float64)
    n = len(rgba)
    orb = ORB(cfg.n_features)
    t0 = time.perf_counter()
    world = _Map()
    feats0 = orb(rgba[0], depth[0])
    kfs = [Keyframe(0, np.linalg.inv(check_pose("c2w0", c2w0)), feats0, -np.ones(len(feats0.uv), dtype=int))]
    ref_kf = np.zeros(n, dtype=int)
    rel = np.tile(np.eye(4), (n, 1, 1))
    failures, records, ba_records = [], [{"frame": 0, "keyframe": True}], []
    T_frames = [kfs[0].T]
    init_scale = float("nan")
    last_kf_inliers = None
    consecutive = 0

    for k in range(1, n):
        f = orb(rgba[k], depth[k])
        rec: dict = {"frame": k, "keypoints": len(f.uv), "keyframe": False}
        T = None
        if len(kfs) == 1:  # ------------------------------------------------- initialisation
            m = match(kfs[0].feats.desc, f.desc, cfg.ratio)
            rec["matches"] = len(m)
            if len(m) >= max(8, cfg.min_inliers):
                a, b = kfs[0].feats.uv[m[:, 0]], f.uv[m[:, 1]]
                E, mask = cv2.findEssentialMat(a, b, K, method=cv2.RANSAC, prob=0.999, threshold=cfg.pnp_px)
                if E is not None and E.shape == (3, 3):
                    _, R, t, mask = cv2.recoverPose(E, a, b, K, mask=mask)
                    inl = mask.ravel() > 0
                    rec["inliers"] = int(inl.sum())
                    if inl.sum() >= cfg.min_inliers:
                        T_rel = np.eye(4)
                        T_rel[:3, :3], T_rel[:3, 3] = R, t.ravel()
                        Xc, good = _triangulate(np.eye(4), T_rel, a[inl], b[inl], K, cfg.pnp_px, 0.0)
                        zmeas = kfs[0].feats.depth[m[inl, 0]]
                        use = good & (zmeas > 0)
                        if use.sum() >= cfg.min_inliers:
                            # scale from depth: the unit-baseline triangulation against measured z
                            s = float(np.median(zmeas[use] / Xc[use, 2]))
                            init_scale = s
                            T_rel[:3, 3] *= s
                            ia, ib = m[inl][use, 0], m[inl][use, 1]
                            # landmarks: keyframe 0's inlier keypoints at their measured depth (metric)
                            Xw = (backproject(a[inl][use], zmeas[use], K) - kfs[0].T[:3, 3]) @ kfs[0].T[:3, :3]
                            guess = T_rel @ kfs[0].T
                            ok, rvec, tvec, pin = cv2.solvePnPRansac(
                                Xw, b[inl][use], K, None, cv2.Rodrigues(guess[:3, :3])[0],
                                guess[:3, 3].reshape(3, 1).copy(), useExtrinsicGuess=True, iterationsCount=200,
                                reprojectionError=cfg.pnp_px, confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE)
                            if ok and pin is not None and len(pin) >= cfg.min_inliers:
                                T = _pose_from_rt(rvec, tvec)
                                keep = pin.ravel()
                                ids = world.add(Xw[keep], kfs[0].feats.desc[ia[keep]])
                                kfs[0].lm[ia[keep]] = ids
                                lm_new = -np.ones(len(f.uv), dtype=int)
                                lm_new[ib[keep]] = ids
                                kfs.append(Keyframe(k, T, f, lm_new))
                                _add_depth_landmarks(kfs[0], world, K)
                                _add_depth_landmarks(kfs[1], world, K)
                                rec.update(keyframe=True, landmarks=len(world.xyz), scale=s)
                                last_kf_inliers = len(keep)
            if T is None:
                raise TrackingError(f"frame {k}: initialisation failed ({rec.get('matches', 0)} matches, "
                                    f"{rec.get('inliers', 0)} essential-matrix inliers; need {cfg.min_inliers})")
        else:  # ------------------------------------------------------------ tracking
            local = {int(i) for kf in kfs[-cfg.window:] for i in kf.lm if i >= 0}
            ids = np.array(sorted(local))
            v = T_frames[-1] @ np.linalg.inv(T_frames[-2]) if len(T_frames) >= 2 else np.eye(4)
            T_pred = v @ T_frames[-1]
            m = np.zeros((0, 2), int)
            if len(ids):
                # guided matching: keypoints within search_px of the landmark's constant-velocity projection
                uvp, zp = _project(T_pred, np.stack([world.xyz[i] for i in ids]), K)
                d2 = ((uvp[:, None, :] - f.uv[None, :, :]) ** 2).sum(-1)
                allowed = (d2 < cfg.search_px ** 2) & (zp > 0)[:, None]
                m = match(np.stack([world.desc[i] for i in ids]), f.desc, cfg.ratio, allowed)
            rec["matches"] = len(m)
            inliers, rvec, tvec = _pnp(world, ids, m, f, K, T_pred, cfg)
            if len(inliers) < cfg.min_inliers and len(ids):
                # relocalisation: the prediction may be off (after a failure); match without it
                m2 = match(np.stack([world.desc[i] for i in ids]), f.desc, cfg.ratio)
                inl2, rv2, tv2 = _pnp(world, ids, m2, f, K, T_pred, cfg)
                if len(inl2) > len(inliers):
                    m, inliers, rvec, tvec = m2, inl2, rv2, tv2
                    rec.update(matches=len(m), relocalised=True)
            rec["inliers"] = len(inliers)
            if len(inliers) >= cfg.min_inliers:
                T = _pose_from_rt(rvec, tvec)
                consecutive = 0
            else:
                consecutive += 1
                reason = f"{len(inliers)} PnP inliers of {len(m)} matches (need {cfg.min_inliers})"
                failures.append({"frame": k, "reason": reason})
                rec["failure"] = reason
                if consecutive >= cfg.max_failures:
                    raise TrackingError(f"tracking lost for {consecutive} frames in a row, frames "
                                        f"{k - consecutive + 1}..{k}: {reason}")
                T = T_pred
            need_kf = (not rec.get("failure") and
                       (k - kfs[-1].frame >= cfg.keyframe_every
                        or len(inliers) < cfg.keyframe_inlier_frac * (last_kf_inliers or 0)))
            if need_kf:
                lm_new = -np.ones(len(f.uv), dtype=int)
                lm_new[m[inliers, 1]] = ids[m[inliers, 0]]
                prev = kfs[-1]
                free_prev = np.nonzero(prev.lm < 0)[0]
                free_new = np.nonzero(lm_new < 0)[0]
                mm = match(prev.feats.desc[free_prev], f.desc[free_new], cfg.ratio)
                added = 0
                if len(mm):
                    ia, ib = free_prev[mm[:, 0]], free_new[mm[:, 1]]
                    X, good = _triangulate(prev.T, T, prev.feats.uv[ia], f.uv[ib], K, cfg.pnp_px,
                                           cfg.min_parallax_deg)
                    zt = X @ T[2, :3] + T[2, 3]
                    zm = f.depth[ib]
                    use = good & (zm > 0)
                    if use.sum() >= 3:
                        rec["depth_scale"] = float(np.median(zm[use] / zt[use]))  # triangulation vs depth
                    # verified matches (triangulation: both reprojections within pnp_px, in front of both
                    # cameras); metric depth where the keypoint has one, else the triangulated point
                    # rescaled by the depth scale (about this camera's centre)
                    Xd = (backproject(f.uv[ib], zm, K) - T[:3, 3]) @ T[:3, :3]
                    c = -T[:3, :3].T @ T[:3, 3]
                    Xt = c + rec.get("depth_scale", 1.0) * (X - c)
                    X = np.where((zm > 0)[:, None], Xd, Xt)
                    keep = good
                    new_ids = world.add(X[keep], f.desc[ib[keep]])
                    prev.lm[ia[keep]] = new_ids
                    lm_new[ib[keep]] = new_ids
                    added = int(keep.sum())
                kfs.append(Keyframe(k, T, f, lm_new))
                added += _add_depth_landmarks(kfs[-1], world, K)
                rec.update(keyframe=True, new_landmarks=added)
                last_kf_inliers = len(inliers)
        if rec.get("keyframe") and cfg.ba and len(kfs) >= 3:
            ba_records.append(_local_ba(kfs, world, K, cfg, device))
            T = kfs[-1].T
        T_frames.append(T)
        ref_kf[k] = len(kfs) - 1  # the newest keyframe (this frame itself when it is one)
        rel[k] = T @ np.linalg.inv(kfs[ref_kf[k]].T)
        records.append(rec)
        if progress is not None:
            progress(k, rec)

    res = VOResult(np.zeros((n, 4, 4)), kfs, ref_kf, rel, np.array(world.xyz), np.array(world.desc), failures,
                   records, ba_records, time.perf_counter() - t0, init_scale)
    res.c2w = res.trajectory()
    return res


def _pnp(world: _Map, ids: np.ndarray, m: np.ndarray, f: Features, K: np.ndarray, T_pred: np.ndarray,
         cfg: VOConfig) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(inlier indices into m, rvec, tvec) of PnP RANSAC from the prediction; no inliers when it fails."""
    if len(m) < max(6, cfg.min_inliers):
        return np.zeros(0, dtype=int), None, None
    obj = np.stack([world.xyz[i] for i in ids[m[:, 0]]])
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, f.uv[m[:, 1]], K, None, cv2.Rodrigues(T_pred[:3, :3])[0],
                                             T_pred[:3, 3].reshape(3, 1).copy(), useExtrinsicGuess=True,
                                             iterationsCount=200, reprojectionError=cfg.pnp_px, confidence=0.999,
                                             flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok or inl is None:
        return np.zeros(0, dtype=int), None, None
    return inl.ravel(), rvec, tvec


def _add_depth_landmarks(kf: Keyframe, world: _Map, K: np.ndarray) -> int:
    """Every keypoint of `kf` without a landmark but with a valid depth becomes one (RGB-D: metric)."""
    sel = np.nonzero((kf.lm < 0) & (kf.feats.depth > 0))[0]
    if len(sel):
        Xw = (backproject(kf.feats.uv[sel], kf.feats.depth[sel], K) - kf.T[:3, 3]) @ kf.T[:3, :3]
        kf.lm[sel] = world.add(Xw, kf.feats.desc[sel])
    return len(sel)


def _local_ba(kfs: list[Keyframe], world: _Map, K: np.ndarray, cfg: VOConfig, device: Any) -> dict:
    """Bundle-adjust the last `window` keyframes and their landmarks in place; the oldest two are fixed."""
    win = kfs[-cfg.window:]
    cam, pts, obs, zs = [], [], [], []
    for c, kf in enumerate(win):
        sel = np.nonzero(kf.lm >= 0)[0]
        cam.append(np.full(len(sel), c))
        pts.append(kf.lm[sel])
        obs.append(kf.feats.uv[sel])
        zs.append(kf.feats.depth[sel])
    cam, pts, obs, zs = np.concatenate(cam), np.concatenate(pts), np.concatenate(obs), np.concatenate(zs)
    ids, counts = np.unique(pts, return_counts=True)
    multi = set(ids[counts >= 2].tolist())
    sel = np.array([p in multi for p in pts])
    cam, pts, obs, zs = cam[sel], pts[sel], obs[sel], zs[sel]
    ids, local = np.unique(pts, return_inverse=True)
    P0 = np.stack([world.xyz[i] for i in ids])
    # cheirality before the adjustment: drop observations of points behind their camera
    Ts = np.stack([kf.T for kf in win])
    zc = np.einsum("kab,kb->ka", Ts[cam, :3, :3], P0[local])[:, 2] + Ts[cam, 2, 3]
    front = zc > 1e-6
    cam, local, obs, zs = cam[front], local[front], obs[front], zs[front]
    K4 = (K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    r = bundle_adjust(Ts, P0, obs, cam, local, K4, depths=zs, depth_weight=cfg.ba_depth_weight, fixed=(0, 1),
                      loss=cfg.ba_loss, f_scale=cfg.ba_f_scale, max_nfev=cfg.ba_max_nfev, device=device)
    for kf, T in zip(win, r.poses):
        kf.T = T
    for i, p in zip(ids, r.points):
        world.xyz[i] = p
    return {"keyframe": win[-1].frame, "cameras": len(win), "points": len(ids), "observations": len(obs),
            "rms_before_px": r.rms_before, "rms_after_px": r.rms_after, "nfev": r.nfev}
