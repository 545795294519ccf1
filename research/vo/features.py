"""Features for the visual odometry: ORB keypoints and binary descriptors through OpenCV, matching, depth.

Pixel coordinates. OpenCV puts the centre of pixel (col i, row j) at (i, j); drlab (research/cameras.py,
the renderers) at (i + 1/2, j + 1/2). Keypoints are returned in drlab's convention (OpenCV's plus 1/2),
so drlab's intrinsics K are used unchanged everywhere, OpenCV's geometry functions included (they only
read the numbers).

Matching: brute-force Hamming distance (ORB's binary descriptors), Lowe's ratio test (best distance
below `ratio` times the second best) and a mutual check (each match is the other side's best).

Depth at a keypoint: the z-depth of its pixel, accepted only where the 3x3 neighbourhood is all
surface (> 0) and spans less than `edge_tol` relative depth (corners sit on depth edges, where one
pixel's depth belongs to the background).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class Features:
    uv: np.ndarray  # (n, 2) keypoints, drlab pixel coordinates
    desc: np.ndarray  # (n, 32) uint8 ORB descriptors
    depth: np.ndarray  # (n,) z-depth at the keypoint, 0 where not valid (edge or no surface)


def to_grey_u8(rgba: np.ndarray) -> np.ndarray:
    """Linear premultiplied RGB(A) in [0, 1] -> 8-bit sRGB grey on black (what a camera would record)."""
    from research.metrics import srgb_on_black

    rgb = np.clip(srgb_on_black(np.asarray(rgba, dtype=np.float32)[..., :3]), 0.0, 1.0)
    return cv2.cvtColor((rgb * 255.0 + 0.5).astype(np.uint8), cv2.COLOR_RGB2GRAY)


def depth_at(depth: np.ndarray, uv: np.ndarray, edge_tol: float = 0.05) -> np.ndarray:
    """z-depth at drlab pixel coordinates uv (n, 2), 0 where invalid (module docstring)."""
    h, w = depth.shape
    cols = np.clip(np.floor(uv[:, 0]).astype(int), 1, w - 2)
    rows = np.clip(np.floor(uv[:, 1]).astype(int), 1, h - 2)
    patch = np.stack([depth[rows + dy, cols + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=1)
    lo, hi = patch.min(1), patch.max(1)
    ok = (lo > 0) & (hi - lo < edge_tol * np.maximum(lo, 1e-12))
    return np.where(ok, depth[rows, cols], 0.0)


class ORB:
    """ORB detector + descriptor (OpenCV) sized for small renders."""

    def __init__(self, n_features: int = 1000, fast_threshold: int = 5):
        self.orb = cv2.ORB_create(nfeatures=n_features, scaleFactor=1.2, nlevels=4, edgeThreshold=8,
                                  patchSize=15, fastThreshold=fast_threshold)

    def __call__(self, rgba: np.ndarray, depth: np.ndarray) -> Features:
        kps, desc = self.orb.detectAndCompute(to_grey_u8(rgba), None)
        if desc is None or not kps:
            return Features(np.zeros((0, 2)), np.zeros((0, 32), np.uint8), np.zeros(0))
        uv = np.array([k.pt for k in kps], dtype=np.float64) + 0.5
        return Features(uv, desc, depth_at(depth, uv))


def match(desc_a: np.ndarray, desc_b: np.ndarray, ratio: float = 0.8, allowed: np.ndarray | None = None,
          max_hamming: int = 64) -> np.ndarray:
    """(m, 2) index pairs (i in a, j in b): ratio test and mutual best match (module docstring).

    `allowed` (len a, len b) bool restricts the candidate pairs (guided matching: b's keypoints near
    where a's landmarks are predicted to project); a single candidate passes the ratio test.
    Matches farther than `max_hamming` bits are dropped.
    """
    if len(desc_a) < 1 or len(desc_b) < 1:
        return np.zeros((0, 2), dtype=int)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    if allowed is None:
        ab = bf.knnMatch(desc_a, desc_b, k=2)
        ba = bf.match(desc_b, desc_a)
    else:
        mask = np.ascontiguousarray(allowed, dtype=np.uint8)
        ab = bf.knnMatch(desc_a, desc_b, k=2, mask=mask)
        ba = bf.match(desc_b, desc_a, mask=np.ascontiguousarray(mask.T))
    best_ba = {m.queryIdx: m.trainIdx for m in ba}
    pairs = [(m[0].queryIdx, m[0].trainIdx) for m in ab
             if len(m) >= 1 and (len(m) == 1 or m[0].distance < ratio * m[1].distance)
             and m[0].distance <= max_hamming and best_ba.get(m[0].trainIdx) == m[0].queryIdx]
    return np.array(pairs, dtype=int).reshape(-1, 2)


def backproject(uv: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera-frame points of pixels uv (n, 2) at z-depth z (n,)."""
    return np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0] * z, (uv[:, 1] - K[1, 2]) / K[1, 1] * z, z], axis=1)
