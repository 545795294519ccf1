"""SORT: Simple Online and Realtime Tracking (Bewley, Ge, Ott, Ramos & Upcroft, ICIP 2016).

Per frame:
1. every track predicts its box with its Kalman filter (box_track.KalmanBoxTrack);
   tracks whose prediction is not finite are deleted;
2. detections with score >= det_thresh are matched to predictions by the
   Hungarian algorithm on IoU (maximise total IoU, then reject pairs with
   IoU < iou_threshold);
3. matched tracks update; each unmatched detection starts a new track;
4. tracks unmatched for more than max_age frames are deleted;
5. output: the tracks updated in this frame whose hit streak is at least
   min_hits (or all of them during the first min_hits frames).

Defaults are the paper's (max_age 1, min_hits 3, IoU threshold 0.3).

Bad input (documented behaviour): rows with NaN/inf, or with zero or negative
width or height, are dropped with an `InvalidDetectionWarning` and counted in
`stats` ("dropped_nonfinite", "dropped_degenerate"); an empty frame (None or
an empty array) only predicts. In both cases existing tracks keep predicting
and age as for a frame with no detection of them; none is lost because of
the bad rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from research.tracking import checks
from research.tracking.assignment import max_iou_assignment
from research.tracking.box_track import KalmanBoxTrack
from research.tracking.boxes import frame_detections, pairwise_iou


@dataclass(frozen=True)
class SortConfig:
    max_age: int = 1
    min_hits: int = 3
    iou_threshold: float = 0.3
    det_thresh: float = 0.0  # detections below this score are ignored

    def __post_init__(self) -> None:
        checks.integer("max_age", self.max_age, 0)
        checks.integer("min_hits", self.min_hits, 0)
        checks.probability("iou_threshold", self.iou_threshold)
        checks.probability("det_thresh", self.det_thresh)


def empty_output() -> np.ndarray:
    return np.zeros((0, 5))


class Sort:
    """SORT tracker. `update(dets)` takes (N, 5) rows [x1, y1, x2, y2, score] and
    returns (M, 5) rows [x1, y1, x2, y2, track_id] (ids start at 1)."""

    def __init__(self, config: SortConfig = SortConfig()) -> None:
        if not isinstance(config, SortConfig):
            raise ValueError(f"config: expected a SortConfig, got {type(config).__name__}")
        self.config = config
        self.tracks: list[KalmanBoxTrack] = []
        self.frame_count = 0
        self._next_id = 1
        self.stats = {"frames": 0, "dropped_nonfinite": 0, "dropped_degenerate": 0}

    def _new_id(self) -> int:
        self._next_id += 1
        return self._next_id - 1

    def update(self, dets: np.ndarray | None, embeddings: np.ndarray | None = None) -> np.ndarray:
        """Advance one frame. `embeddings` is accepted for a common interface and ignored."""
        cfg = self.config
        self.frame_count += 1
        clean = frame_detections(self.stats, dets)
        d = clean.dets[clean.dets[:, 4] >= cfg.det_thresh]

        predicted = [t.predict() for t in self.tracks]
        finite = [bool(np.all(np.isfinite(b))) for b in predicted]
        self.tracks = [t for t, ok in zip(self.tracks, finite) if ok]
        pred_boxes = np.array([b for b, ok in zip(predicted, finite) if ok]).reshape(-1, 4)

        matches, unmatched_dets, _ = max_iou_assignment(
            pairwise_iou(d[:, :4], pred_boxes), cfg.iou_threshold
        )
        for det_i, trk_i in matches:
            self.tracks[trk_i].update(d[det_i, :4], d[det_i, 4])
        for det_i in unmatched_dets:
            self.tracks.append(KalmanBoxTrack(d[det_i, :4], self._new_id(), d[det_i, 4]))

        out = []
        for t in self.tracks:
            if t.time_since_update < 1 and (t.hit_streak >= cfg.min_hits or self.frame_count <= cfg.min_hits):
                out.append(np.concatenate([t.box, [t.id]]))
        self.tracks = [t for t in self.tracks if t.time_since_update <= cfg.max_age]
        return np.array(out).reshape(-1, 5) if out else empty_output()
