"""SORT's Kalman box track (Bewley et al. 2016, and github.com/abewley/sort).

State x = [u, v, s, r, u', v', s']: box centre, area, aspect ratio (w/h) and
the rates of the first three; r is taken as constant. Constant-velocity
transition with dt = 1 frame; the measurement is z = [u, v, s, r] (boxes.xyxy_to_z).

Noise settings are SORT's published ones:
    R  = diag(1, 1, 10, 10)
    P0 = diag(10, 10, 10, 10, 1e4, 1e4, 1e4)   (unobserved rates very uncertain)
    Q  = diag(1, 1, 1, 1, 0.01, 0.01, 1e-4)
Before each prediction, a negative predicted area (s + s' <= 0) sets s' = 0.
The filter steps are research.tracking.kalman.predict / update (Joseph form).
"""

from __future__ import annotations

import numpy as np

from research.tracking import kalman
from research.tracking.boxes import box_to_z, z_to_xyxy

F = np.eye(7)
F[0, 4] = F[1, 5] = F[2, 6] = 1.0
H = np.eye(4, 7)
R = np.diag([1.0, 1.0, 10.0, 10.0])
P0 = np.diag([10.0, 10.0, 10.0, 10.0, 1e4, 1e4, 1e4])
Q = np.diag([1.0, 1.0, 1.0, 1.0, 0.01, 0.01, 1e-4])


class KalmanBoxTrack:
    """One tracked box: its Kalman state and SORT's bookkeeping counters."""

    def __init__(self, box: np.ndarray, track_id: int, score: float = 1.0) -> None:
        # `box` and the boxes given to `update` are detections the tracker has cleaned
        # (boxes.sanitize_detections: finite, w, h > 0), so they are not checked again here.
        self.x = np.zeros(7)
        self.x[:4] = box_to_z(np.asarray(box, dtype=float))
        self.P = P0.copy()
        self.id = track_id
        self.score = float(score)
        self.age = 0  # frames since creation
        # SORT counts the creating detection in neither counter (as its reference code does).
        self.hits = 0  # updates since creation
        self.hit_streak = 0  # consecutive frames with an update
        self.time_since_update = 0
        self.feature: np.ndarray | None = None  # appearance embedding (unit norm), if used

    def predict(self, freeze_scale_rate: bool = False) -> np.ndarray:
        """Advance one frame and return the predicted box.

        freeze_scale_rate sets s' = 0 first (ByteTrack does this for lost tracks,
        whose size should not keep growing or shrinking while unobserved).
        """
        if freeze_scale_rate or self.x[2] + self.x[6] <= 0:
            self.x[6] = 0.0
        self.x, self.P = kalman.predict(self.x, self.P, F, Q)
        self.age += 1
        if self.time_since_update > 0:
            self.hit_streak = 0
        self.time_since_update += 1
        return self.box

    def update(self, box: np.ndarray, score: float = 1.0) -> None:
        z = box_to_z(np.asarray(box, dtype=float))
        res = kalman.update(self.x, self.P, z, H, R, with_loglik=False)
        self.x, self.P = res.x, res.P
        self.score = float(score)
        self.time_since_update = 0
        self.hits += 1
        self.hit_streak += 1

    @property
    def box(self) -> np.ndarray:
        """Current state as an xyxy box."""
        return z_to_xyxy(self.x)

    def position_innovation_cov(self) -> np.ndarray:
        """2x2 covariance of the centre measurement (H P H^T + R)[:2, :2], for gating."""
        return self.P[:2, :2] + R[:2, :2]
