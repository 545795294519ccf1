"""Axis-aligned boxes: conversions, IoU and detection validation.

Boxes are [x1, y1, x2, y2] in pixels ("xyxy"), x right and y down, with
x2 > x1 and y2 > y1 for a valid box. Detections are rows [x1, y1, x2, y2, score].

SORT's measurement (Bewley et al. 2016) is z = [u, v, s, r]: the box centre
(u, v), its area s = w h and its aspect ratio r = w / h, so that
w = sqrt(s r) and h = s / w.

IoU(a, b) = |a ∩ b| / |a ∪ b|, and 0 when the union is empty.

Domain: `iou_matrix` and the xyxy/xywh conversions take finite boxes with w, h >= 0 (an empty box
has IoU 0 with everything); `xyxy_to_z` needs w, h > 0 (r = w / h). Anything else raises
ValueError naming the argument. Detections are different: trackers drop bad rows with a warning
(`sanitize_detections`), so one bad detector output does not stop a sequence.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from research.tracking import checks


class InvalidDetectionWarning(RuntimeWarning):
    """Raised (as a warning) when a tracker drops NaN or degenerate detections."""


def xyxy_to_xywh(boxes: np.ndarray) -> np.ndarray:
    """[x1, y1, x2, y2] -> [x1, y1, w, h] (py-motmetrics' and MOTChallenge's layout)."""
    b = checks.boxes("boxes", boxes)
    return np.concatenate([b[:, :2], b[:, 2:] - b[:, :2]], axis=1)


def xywh_to_xyxy(boxes: np.ndarray) -> np.ndarray:
    b = np.asarray(boxes, dtype=float)
    if b.size and b.shape[-1] != 4:
        raise ValueError(f"boxes: expected xywh boxes (..., 4), got shape {b.shape}")
    b = b.reshape(-1, 4)
    if not np.all(np.isfinite(b)) or np.any(b[:, 2:] < 0):
        raise ValueError("boxes: expected finite xywh boxes with w, h >= 0")
    return np.concatenate([b[:, :2], b[:, :2] + b[:, 2:]], axis=1)


def xyxy_to_z(box: np.ndarray) -> np.ndarray:
    """One box [x1, y1, x2, y2] (finite, w, h > 0) -> SORT measurement [u, v, s, r]."""
    if np.shape(box) != (4,):
        raise ValueError(f"box: expected one xyxy box of 4 values, got shape {np.shape(box)}")
    return box_to_z(checks.boxes("box", box, allow_empty_box=False)[0])


def box_to_z(box: np.ndarray) -> np.ndarray:
    """`xyxy_to_z` without its checks, for boxes the caller has validated (the trackers' detections,
    which `sanitize_detections` cleaned on entry)."""
    w = box[2] - box[0]
    h = box[3] - box[1]
    return np.array([box[0] + 0.5 * w, box[1] + 0.5 * h, w * h, w / h])


def z_to_xyxy(z: np.ndarray, min_area: float = 1e-6, min_ratio: float = 1e-3) -> np.ndarray:
    """SORT state or measurement [u, v, s, r, ...] -> [x1, y1, x2, y2].

    Area and ratio are clamped to small positive values, so a state that has
    drifted to s <= 0 or r <= 0 still gives a finite (tiny) box instead of NaN.
    """
    s = max(float(z[2]), min_area)
    r = max(float(z[3]), min_ratio)
    w = np.sqrt(s * r)
    h = s / w
    return np.array([z[0] - 0.5 * w, z[1] - 0.5 * h, z[0] + 0.5 * w, z[1] + 0.5 * h])


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU of xyxy boxes a (N, 4) and b (M, 4) -> (N, M); 0 where a union is empty."""
    return pairwise_iou(checks.boxes("a", a), checks.boxes("b", b))


def pairwise_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`iou_matrix` without its checks, for (N, 4) and (M, 4) float boxes the caller has validated
    (the trackers call it once per association; the checks cost a fifth of ByteTrack's update)."""
    a = np.asarray(a, dtype=float).reshape(-1, 4)
    b = np.asarray(b, dtype=float).reshape(-1, 4)
    ix1 = np.maximum(a[:, None, 0], b[None, :, 0])
    iy1 = np.maximum(a[:, None, 1], b[None, :, 1])
    ix2 = np.minimum(a[:, None, 2], b[None, :, 2])
    iy2 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(ix2 - ix1, 0.0, None) * np.clip(iy2 - iy1, 0.0, None)
    area_a = np.clip(a[:, 2] - a[:, 0], 0.0, None) * np.clip(a[:, 3] - a[:, 1], 0.0, None)
    area_b = np.clip(b[:, 2] - b[:, 0], 0.0, None) * np.clip(b[:, 3] - b[:, 1], 0.0, None)
    union = area_a[:, None] + area_b[None, :] - inter
    out = np.zeros_like(inter)
    np.divide(inter, union, out=out, where=(union > 0) & (inter > 0))
    return out


@dataclass(frozen=True)
class CleanDetections:
    dets: np.ndarray  # (K, 5) valid detections
    keep: np.ndarray  # (N,) bool mask into the input rows
    n_nonfinite: int  # rows dropped for NaN/inf
    n_degenerate: int  # rows dropped for zero or negative width/height


def sanitize_detections(dets: np.ndarray | None, *, warn: bool = True) -> CleanDetections:
    """Drop invalid detection rows instead of letting them poison the filters.

    Accepts None or an empty array as an empty frame. Rows with a non-finite
    value (box or score) and boxes with x2 <= x1 or y2 <= y1 are dropped, and
    an `InvalidDetectionWarning` says how many. Rows must have 5 columns
    [x1, y1, x2, y2, score]; another column count is a programming error and
    raises ValueError.
    """
    if dets is None:
        return CleanDetections(np.zeros((0, 5)), np.zeros(0, bool), 0, 0)
    arr = np.asarray(dets, dtype=float)
    if arr.size == 0:
        return CleanDetections(np.zeros((0, 5)), np.zeros(arr.shape[0] if arr.ndim == 2 else 0, bool), 0, 0)
    if arr.ndim != 2 or arr.shape[1] != 5:
        raise ValueError(f"detections must be (N, 5) rows [x1, y1, x2, y2, score]; got shape {arr.shape}")
    finite = np.all(np.isfinite(arr), axis=1)
    with np.errstate(invalid="ignore"):
        positive = (arr[:, 2] > arr[:, 0]) & (arr[:, 3] > arr[:, 1])
    keep = finite & positive
    n_nonfinite = int(np.sum(~finite))
    n_degenerate = int(np.sum(finite & ~positive))
    if warn and (n_nonfinite or n_degenerate):
        warnings.warn(
            f"dropped {n_nonfinite} non-finite and {n_degenerate} zero/negative-size detection(s)",
            InvalidDetectionWarning,
            stacklevel=3,
        )
    return CleanDetections(arr[keep], keep, n_nonfinite, n_degenerate)


def frame_detections(stats: dict[str, int], dets: np.ndarray | None) -> CleanDetections:
    """A tracker's frame: sanitize_detections(dets), counted into its `stats` (frames, dropped_nonfinite,
    dropped_degenerate)."""
    stats["frames"] += 1
    clean = sanitize_detections(dets)
    stats["dropped_nonfinite"] += clean.n_nonfinite
    stats["dropped_degenerate"] += clean.n_degenerate
    return clean
