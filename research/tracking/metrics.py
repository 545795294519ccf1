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

HOTA (Luiten et al., IJCV 2021), with TrackEval's definitions (HOTA class of the
`trackeval` package, v1.3), for IoU similarity S(o, h) between boxes:
1. over the whole sequence, for every object o and hypothesis h, the soft
   co-occurrence P(o, h) = sum over frames of S(o, h) / (sum_h' S(o, h') +
   sum_o' S(o', h) - S(o, h)), and the global alignment
   A(o, h) = P(o, h) / (n_o + n_h - P(o, h)) (n_o, n_h: frames with o, with h);
2. per frame, ONE Hungarian matching maximising sum A(o, h) S(o, h); then for each
   alpha in 0.05, 0.10, ..., 0.95 the matched pairs with S >= alpha are true
   positives (TP_a), the other objects FN_a and hypotheses FP_a, and LocA sums S
   over them;
3. with c_a(o, h) the number of frames o and h are a TP_a pair,
   AssA_a = sum over TP_a pairs of c_a / (n_o + n_h - c_a), divided by TP_a
   (max 1), DetA_a = TP_a / (TP_a + FN_a + FP_a) (denominator max 1),
   HOTA_a = sqrt(DetA_a AssA_a), LocA_a = sum S / TP_a;
4. HOTA, DetA, AssA and LocA are the means over the 19 alphas (so HOTA is not
   sqrt(DetA AssA) of the means).
Over several sequences TP, FN and FP are summed and AssA and LocA are averaged
with weights TP_a (TrackEval's COMBINED_SEQ); `HOTACounts` holds the additive
sums. Pass the frames after the benchmark's preprocessing
(research.tracking.motchallenge.evaluation_frames for MOTChallenge).

Boxes are xyxy (boxes.py); py-motmetrics takes xywh.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import asdict, dataclass, field, fields
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


# --------------------------------------------------------------------------- HOTA

HOTA_ALPHAS = np.arange(0.05, 0.99, 0.05)  # TrackEval's array_labels: 0.05, 0.10, ..., 0.95
_EPS = np.finfo(float).eps


def _zeros() -> np.ndarray:
    return np.zeros(len(HOTA_ALPHAS))


@dataclass
class HOTACounts:
    """Additive HOTA sums, one value per alpha (HOTA_ALPHAS); the metrics are properties."""

    tp: np.ndarray = field(default_factory=_zeros)
    fn: np.ndarray = field(default_factory=_zeros)
    fp: np.ndarray = field(default_factory=_zeros)
    ass_sum: np.ndarray = field(default_factory=_zeros)  # AssA_a * TP_a
    ass_re_sum: np.ndarray = field(default_factory=_zeros)  # AssRe_a * TP_a
    ass_pr_sum: np.ndarray = field(default_factory=_zeros)  # AssPr_a * TP_a
    loc_sum: np.ndarray = field(default_factory=_zeros)  # sum of IoU over TP_a pairs

    def __add__(self, other: "HOTACounts") -> "HOTACounts":
        return HOTACounts(**{f.name: getattr(self, f.name) + getattr(other, f.name) for f in fields(self)})

    # per-alpha arrays, as TrackEval's _compute_final_fields
    @property
    def det_a_alpha(self) -> np.ndarray:
        return self.tp / np.maximum(1, self.tp + self.fn + self.fp)

    @property
    def ass_a_alpha(self) -> np.ndarray:
        return self.ass_sum / np.maximum(1.0, self.tp)

    @property
    def hota_alpha(self) -> np.ndarray:
        return np.sqrt(self.det_a_alpha * self.ass_a_alpha)

    @property
    def loc_a_alpha(self) -> np.ndarray:
        return np.maximum(1e-10, self.loc_sum) / np.maximum(1e-10, self.tp)

    @property
    def hota(self) -> float:
        return float(np.mean(self.hota_alpha))

    @property
    def det_a(self) -> float:
        return float(np.mean(self.det_a_alpha))

    @property
    def ass_a(self) -> float:
        return float(np.mean(self.ass_a_alpha))

    @property
    def loc_a(self) -> float:
        return float(np.mean(self.loc_a_alpha))

    @property
    def det_re(self) -> float:
        return float(np.mean(self.tp / np.maximum(1, self.tp + self.fn)))

    @property
    def det_pr(self) -> float:
        return float(np.mean(self.tp / np.maximum(1, self.tp + self.fp)))

    @property
    def ass_re(self) -> float:
        return float(np.mean(self.ass_re_sum / np.maximum(1.0, self.tp)))

    @property
    def ass_pr(self) -> float:
        return float(np.mean(self.ass_pr_sum / np.maximum(1.0, self.tp)))

    @property
    def hota0(self) -> float:
        """HOTA at alpha = 0.05 (TrackEval's HOTA(0))."""
        return float(self.hota_alpha[0])

    def summary(self) -> dict[str, float]:
        return {name: getattr(self, name) for name in
                ("hota", "det_a", "ass_a", "loc_a", "det_re", "det_pr", "ass_re", "ass_pr", "hota0")}


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of xyxy boxes (N, 4) x (M, 4), with TrackEval's rules for empty boxes and unions (0)."""
    a = np.asarray(a, dtype=float).reshape(-1, 4)
    b = np.asarray(b, dtype=float).reshape(-1, 4)
    lo = np.minimum(a[:, None, :], b[None, :, :])
    hi = np.maximum(a[:, None, :], b[None, :, :])
    inter = np.maximum(lo[..., 2] - hi[..., 0], 0) * np.maximum(lo[..., 3] - hi[..., 1], 0)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    inter[area_a <= _EPS, :] = 0
    inter[:, area_b <= _EPS] = 0
    inter[union <= _EPS] = 0
    union[union <= _EPS] = 1
    return inter / union


def _relabel(frames: list[tuple[np.ndarray, np.ndarray]]) -> tuple[list[np.ndarray], int]:
    ids = [np.asarray(i, dtype=np.int64).reshape(-1) for i, _ in frames]
    for t, i in enumerate(ids):
        if len(np.unique(i)) != len(i):
            raise ValueError(f"ids must be unique within a frame (frame index {t})")
    uniq = np.unique(np.concatenate(ids)) if ids else np.zeros(0, np.int64)
    return [np.searchsorted(uniq, i) for i in ids], len(uniq)


def hota_sequence(gt: Iterable[tuple[np.ndarray, np.ndarray]],
                  hyp: Iterable[tuple[np.ndarray, np.ndarray]]) -> HOTACounts:
    """HOTA sums of one sequence (module docstring); gt and hyp yield (ids (N,), xyxy boxes (N, 4))
    per frame, the same number of frames."""
    gt, hyp = list(gt), list(hyp)
    if len(gt) != len(hyp):
        raise ValueError(f"hyp: expected {len(gt)} frames like gt, got {len(hyp)}")
    gt_ids, n_gt = _relabel(gt)
    hyp_ids, n_hyp = _relabel(hyp)
    gt_boxes = [np.asarray(b, dtype=float).reshape(len(i), 4) for i, (_, b) in zip(gt_ids, gt)]
    hyp_boxes = [np.asarray(b, dtype=float).reshape(len(i), 4) for i, (_, b) in zip(hyp_ids, hyp)]
    res = HOTACounts()
    n_gt_dets = sum(len(i) for i in gt_ids)
    n_hyp_dets = sum(len(i) for i in hyp_ids)
    if n_hyp_dets == 0 or n_gt_dets == 0:  # TrackEval's early returns
        res.fn += n_gt_dets
        res.fp += n_hyp_dets
        return res
    sims = [box_iou(g, h) for g, h in zip(gt_boxes, hyp_boxes)]

    # 1. global alignment between ids
    potential = np.zeros((n_gt, n_hyp))
    gt_count = np.zeros((n_gt, 1))
    hyp_count = np.zeros((1, n_hyp))
    for g, h, s in zip(gt_ids, hyp_ids, sims):
        denom = s.sum(0)[np.newaxis, :] + s.sum(1)[:, np.newaxis] - s
        s_iou = np.zeros_like(s)
        mask = denom > 0 + _EPS
        s_iou[mask] = s[mask] / denom[mask]
        potential[g[:, np.newaxis], h[np.newaxis, :]] += s_iou
        gt_count[g] += 1
        hyp_count[0, h] += 1
    alignment = potential / (gt_count + hyp_count - potential)

    # 2. per-frame matching, thresholded at every alpha
    matches = [np.zeros_like(potential) for _ in HOTA_ALPHAS]
    for g, h, s in zip(gt_ids, hyp_ids, sims):
        if len(g) == 0:
            res.fp += len(h)
            continue
        if len(h) == 0:
            res.fn += len(g)
            continue
        score = alignment[g[:, np.newaxis], h[np.newaxis, :]] * s
        rows, cols = linear_sum_assignment(-score)
        for a, alpha in enumerate(HOTA_ALPHAS):
            ok = s[rows, cols] >= alpha - _EPS
            r, c = rows[ok], cols[ok]
            res.tp[a] += len(r)
            res.fn[a] += len(g) - len(r)
            res.fp[a] += len(h) - len(r)
            if len(r):
                res.loc_sum[a] += sum(s[r, c])
                matches[a][g[r], h[c]] += 1

    # 3. association
    for a in range(len(HOTA_ALPHAS)):
        m = matches[a]
        res.ass_sum[a] = np.sum(m * (m / np.maximum(1, gt_count + hyp_count - m)))
        res.ass_re_sum[a] = np.sum(m * (m / np.maximum(1, gt_count)))
        res.ass_pr_sum[a] = np.sum(m * (m / np.maximum(1, hyp_count)))
    return res
