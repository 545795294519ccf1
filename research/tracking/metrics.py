"""Multi-object tracking metrics: CLEAR MOT (MOTA, MOTP, ID switches) and IDF1,
with py-motmetrics' definitions (github.com/cheind/py-motmetrics, v1.4).

Per frame, a ground-truth object o and a hypothesis h may pair only if their
distance d = 1 - IoU(o, h) is at most 1 - iou_threshold (IoU >= 0.5 by default).

CLEAR MOT (Bernardin & Stiefelhagen 2008), frame by frame, as motmetrics'
MOTAccumulator.update does it:
1. keep established correspondences: if o was last matched to h and both are
   present and may pair, they match again (objects in input order);
2. the remaining objects and hypotheses are matched by minimum total distance
   (Hungarian; forbidden pairs get motmetrics' large finite cost, so the
   number of matches is maximised first);
   a match of o to h is an ID switch if o was last matched to another h' != h
   (at any earlier frame);
3. unmatched objects are misses (FN), unmatched hypotheses false positives (FP).
Then, summed over frames,
    MOTA = 1 - (FN + FP + IDSW) / GT,      GT = number of object instances,
    MOTP = sum of d over matches / number of matches   (motmetrics: a distance,
           lower is better; MOTChallenge's MOTP is 1 - this, the mean IoU).

IDF1 (Ristani et al. 2016): count, over all frames, n_o (frames with object
o), n_h (frames with hypothesis h) and n_oh (frames where o and h may pair,
whatever CLEAR matched). A global one-to-one matching of object trajectories
to hypothesis trajectories maximises IDTP = sum n_oh over matched pairs
(motmetrics minimises IDFN + IDFP, which differs from -2 IDTP by a constant).
    IDFN = GT - IDTP,  IDFP = PRED - IDTP,  IDF1 = 2 IDTP / (GT + PRED).
Over several sequences the counts are summed (each sequence has its own
global matching), as motmetrics' "OVERALL" row does.

Boxes are xyxy (boxes.py); py-motmetrics takes xywh.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import asdict, dataclass, fields
from typing import Iterable

import numpy as np
from scipy.optimize import linear_sum_assignment

from research.tracking.boxes import iou_matrix


@dataclass
class MOTCounts:
    """Additive counts; the metrics are properties."""

    num_frames: int = 0
    num_objects: int = 0  # GT instances
    num_predictions: int = 0  # hypothesis instances
    num_matches: int = 0  # CLEAR matches that are not switches
    num_switches: int = 0
    num_false_positives: int = 0
    num_misses: int = 0
    sum_distance: float = 0.0  # sum of 1 - IoU over matches and switches
    idtp: int = 0

    def __add__(self, other: "MOTCounts") -> "MOTCounts":
        return MOTCounts(**{f.name: getattr(self, f.name) + getattr(other, f.name) for f in fields(self)})

    @staticmethod
    def _div(a: float, b: float) -> float:
        return float(a) / float(b) if b else float("nan")

    @property
    def num_detections(self) -> int:
        return self.num_matches + self.num_switches

    @property
    def mota(self) -> float:
        return 1.0 - self._div(self.num_misses + self.num_switches + self.num_false_positives, self.num_objects)

    @property
    def motp(self) -> float:
        """motmetrics' MOTP: mean 1 - IoU of matched pairs (lower is better)."""
        return self._div(self.sum_distance, self.num_detections)

    @property
    def motp_iou(self) -> float:
        """MOTChallenge's MOTP: mean IoU of matched pairs."""
        return 1.0 - self.motp

    @property
    def idfn(self) -> int:
        return self.num_objects - self.idtp

    @property
    def idfp(self) -> int:
        return self.num_predictions - self.idtp

    @property
    def idf1(self) -> float:
        return self._div(2 * self.idtp, self.num_objects + self.num_predictions)

    @property
    def idp(self) -> float:
        return self._div(self.idtp, self.num_predictions)

    @property
    def idr(self) -> float:
        return self._div(self.idtp, self.num_objects)

    @property
    def recall(self) -> float:
        return self._div(self.num_detections, self.num_objects)

    @property
    def precision(self) -> float:
        return self._div(self.num_detections, self.num_predictions)

    def summary(self) -> dict[str, float]:
        out: dict[str, float] = dict(asdict(self))
        for name in ("mota", "motp", "motp_iou", "idf1", "idp", "idr", "idfn", "idfp", "recall", "precision"):
            out[name] = getattr(self, name)
        return out


def _expensive_edges(costs: np.ndarray) -> np.ndarray:
    """motmetrics.lap.add_expensive_edges: NaN -> a cost no optimal matching would pick
    unless the problem has no other choice."""
    valid = np.isfinite(costs)
    if valid.all():
        return costs.copy()
    if not valid.any():
        return np.zeros_like(costs)
    r = min(costs.shape)
    c = np.abs(costs[valid]).max() + 1
    return np.where(valid, costs, 2 * r * c + 1)


@dataclass(frozen=True)
class FrameMatches:
    """CLEAR MOT outcome of one frame: matched (object, hypothesis) ids, and switches."""

    pairs: list[tuple[int, int]]
    switches: list[tuple[int, int]]
    misses: list[int]
    false_positives: list[int]


class MOTAccumulator:
    """Frame-by-frame CLEAR MOT and ID-measure bookkeeping (see module docstring)."""

    def __init__(self, iou_threshold: float = 0.5) -> None:
        self.max_distance = 1.0 - iou_threshold
        self.counts = MOTCounts()
        self._last_match: dict[int, int] = {}  # object id -> hypothesis id of its latest match
        self._obj_frames: dict[int, int] = defaultdict(int)
        self._hyp_frames: dict[int, int] = defaultdict(int)
        self._pair_frames: dict[tuple[int, int], int] = defaultdict(int)

    def distances(self, gt_boxes: np.ndarray, hyp_boxes: np.ndarray) -> np.ndarray:
        """1 - IoU, NaN where a pair is not allowed (as motmetrics.distances.iou_matrix)."""
        dist = 1.0 - iou_matrix(gt_boxes, hyp_boxes)
        dist[dist > self.max_distance] = np.nan
        return dist

    def update(
        self, gt_ids: Iterable[int], gt_boxes: np.ndarray, hyp_ids: Iterable[int], hyp_boxes: np.ndarray
    ) -> FrameMatches:
        oids = np.asarray(list(gt_ids), dtype=np.int64)
        hids = np.asarray(list(hyp_ids), dtype=np.int64)
        if len(np.unique(oids)) != len(oids) or len(np.unique(hids)) != len(hids):
            raise ValueError("ids must be unique within a frame")
        gt_boxes = np.asarray(gt_boxes, dtype=float).reshape(len(oids), 4)
        hyp_boxes = np.asarray(hyp_boxes, dtype=float).reshape(len(hids), 4)
        dist = self.distances(gt_boxes, hyp_boxes)
        c = self.counts
        c.num_frames += 1
        c.num_objects += len(oids)
        c.num_predictions += len(hids)
        for o in oids:
            self._obj_frames[int(o)] += 1
        for h in hids:
            self._hyp_frames[int(h)] += 1
        for i, j in zip(*np.nonzero(np.isfinite(dist))):
            self._pair_frames[(int(oids[i]), int(hids[j]))] += 1

        o_done = np.zeros(len(oids), bool)
        h_done = np.zeros(len(hids), bool)
        pairs: list[tuple[int, int]] = []
        switches: list[tuple[int, int]] = []
        if len(oids) and len(hids):
            # 1. keep established correspondences
            for i, o in enumerate(oids):
                h_prev = self._last_match.get(int(o))
                if h_prev is None:
                    continue
                (js,) = np.nonzero(~h_done & (hids == h_prev))
                if len(js) and np.isfinite(dist[i, js[0]]):
                    j = js[0]
                    o_done[i] = h_done[j] = True
                    pairs.append((int(o), int(hids[j])))
                    c.num_matches += 1
                    c.sum_distance += float(dist[i, j])
            # 2. minimum-distance matching of the rest
            rest = dist.copy()
            rest[o_done, :] = np.nan
            rest[:, h_done] = np.nan
            rows, cols = linear_sum_assignment(_expensive_edges(rest))
            for i, j in zip(rows, cols):
                if not np.isfinite(rest[i, j]):
                    continue
                o, h = int(oids[i]), int(hids[j])
                if o in self._last_match and self._last_match[o] != h:
                    switches.append((o, h))
                    c.num_switches += 1
                else:
                    c.num_matches += 1
                c.sum_distance += float(rest[i, j])
                o_done[i] = h_done[j] = True
                pairs.append((o, h))
                self._last_match[o] = h
        misses = [int(o) for o in oids[~o_done]]
        fps = [int(h) for h in hids[~h_done]]
        c.num_misses += len(misses)
        c.num_false_positives += len(fps)
        return FrameMatches(pairs, switches, misses, fps)

    def idtp(self) -> int:
        """IDTP of the global trajectory matching (maximum total co-occurrence)."""
        if not self._pair_frames:
            return 0
        o_index = {o: i for i, o in enumerate(sorted(self._obj_frames))}
        h_index = {h: j for j, h in enumerate(sorted(self._hyp_frames))}
        weight = np.zeros((len(o_index), len(h_index)))
        for (o, h), n in self._pair_frames.items():
            weight[o_index[o], h_index[h]] = n
        rows, cols = linear_sum_assignment(weight, maximize=True)
        return int(round(weight[rows, cols].sum()))

    def result(self) -> MOTCounts:
        """All counts so far, IDTP included."""
        out = MOTCounts(**asdict(self.counts))
        out.idtp = self.idtp()
        return out


def evaluate_sequence(
    gt: Iterable[tuple[np.ndarray, np.ndarray]],
    hyp: Iterable[tuple[np.ndarray, np.ndarray]],
    iou_threshold: float = 0.5,
) -> MOTCounts:
    """Counts for one sequence; gt and hyp yield (ids (N,), xyxy boxes (N, 4)) per frame."""
    acc = MOTAccumulator(iou_threshold)
    for (gi, gb), (hi, hb) in zip(gt, hyp, strict=True):
        acc.update(gi, gb, hi, hb)
    return acc.result()


def tracker_output_frames(outputs: Iterable[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Tracker rows [x1, y1, x2, y2, id] per frame -> (ids, boxes) per frame."""
    frames = []
    for rows in outputs:
        rows = np.asarray(rows, dtype=float).reshape(-1, 5)
        frames.append((rows[:, 4].astype(np.int64), rows[:, :4]))
    return frames
