"""ByteTrack (Zhang et al., "ByteTrack: Multi-Object Tracking by Associating Every
Detection Box", ECCV 2022), optionally with a DeepSORT-style appearance cost.

BYTE association, per frame (following the reference implementation's
byte_tracker.py; defaults are its MOT17 settings):
1. split detections into high (score >= track_thresh) and low
   (low_thresh < score < track_thresh);
2. predict every confirmed track and every lost track (lost tracks with a
   frozen scale rate);
3. first association: confirmed + lost tracks against high detections, cost
   1 - IoU * score ("fuse_score"), minimum-cost matching gated at
   match_thresh; a matched lost track is re-activated with its old id;
4. second association: the still-unmatched *tracked* tracks against the low
   detections, cost 1 - IoU, gated at second_match_thresh (IoU >= 0.5);
   tracks left unmatched become lost. Low detections never start tracks;
5. unconfirmed (one-frame-old) tracks against the remaining high detections
   (gate unconfirmed_match_thresh); an unmatched unconfirmed track is removed;
6. remaining high detections with score >= new_track_thresh start
   unconfirmed tracks (confirmed at once in the first frame);
7. lost tracks older than track_buffer frames are removed; a tracked/lost
   pair with IoU > 0.85 is a duplicate and the younger one is dropped.
Output: confirmed tracks updated in this frame, boxes from the Kalman state.

Motion model: the reference uses DeepSORT's 8-state [x, y, a, h] filter; here
every tracker shares SORT's 7-state box filter (box_track.py), so that a
comparison with SORT isolates the association.

Appearance (use_appearance=True; after DeepSORT and BoT-SORT, Aharon et al.
2022): each track keeps an EMA of the embeddings of its high-score detections
(appearance.py). In the first association the cost becomes
    min(fused IoU cost, d_app)
where d_app is the cosine distance, set to 1 unless d_app <= app_thresh and
the detection centre c passes the Mahalanobis gate of the track's predicted
centre c^ (DeepSORT's gating):
    (c - c^)^T G^{-1} (c - c^) <= gate_chi2     (chi-square, 2 dof),
    G = S + n_lost (gate_sigma h)^2 I,
with S the Kalman innovation covariance of the centre, n_lost the frames
since the track's last update and h its box height. The second term is
DeepSORT's position noise (1/20 of the box height per frame), accumulated
while the track is unobserved: an occluded object may stop or turn, and
SORT's own process noise (1 px per frame) is tuned for frame-to-frame
association, not for gaps. This lets a lost track be re-identified after an
occlusion even when its predicted box no longer overlaps the reappearing object.

Bad input: as for SORT (sort.py): invalid rows are dropped with a warning and
counted in `stats`; an empty frame only predicts and tracks are kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from research.tracking import checks
from research.tracking.appearance import cosine_distance, ema_feature
from research.tracking.assignment import gated_assignment
from research.tracking.box_track import KalmanBoxTrack
from research.tracking.boxes import frame_detections, pairwise_iou
from research.tracking.sort import empty_output


class TrackState(Enum):
    TRACKED = 1
    LOST = 2
    REMOVED = 3


@dataclass(frozen=True)
class ByteTrackConfig:
    track_thresh: float = 0.5
    low_thresh: float = 0.1
    new_track_thresh: float = 0.6
    match_thresh: float = 0.8
    second_match_thresh: float = 0.5
    unconfirmed_match_thresh: float = 0.7
    track_buffer: int = 30
    fuse_score: bool = True
    duplicate_iou: float = 0.85
    use_appearance: bool = False
    app_thresh: float = 0.25
    gate_chi2: float = 9.21  # 99% quantile of chi-square with 2 dof
    gate_sigma: float = 0.05  # extra position std per unobserved frame, in box heights
    ema_alpha: float = 0.9

    def __post_init__(self) -> None:
        for name in ("track_thresh", "low_thresh", "new_track_thresh", "match_thresh", "second_match_thresh",
                     "unconfirmed_match_thresh", "duplicate_iou", "ema_alpha"):
            checks.probability(name, getattr(self, name))
        if self.low_thresh > self.track_thresh:
            raise ValueError(f"low_thresh: expected low_thresh <= track_thresh = {self.track_thresh}, "
                             f"got {self.low_thresh}")
        checks.integer("track_buffer", self.track_buffer, 0)
        checks.flag("fuse_score", self.fuse_score)
        checks.flag("use_appearance", self.use_appearance)
        checks.number("app_thresh", self.app_thresh, 0.0, 2.0)  # a cosine distance
        checks.number("gate_chi2", self.gate_chi2, 0.0, low_open=True)
        checks.number("gate_sigma", self.gate_sigma, 0.0)


class _Track(KalmanBoxTrack):
    def __init__(self, box: np.ndarray, track_id: int, score: float, frame: int, feature: np.ndarray | None):
        super().__init__(box, track_id, score)
        self.state = TrackState.TRACKED
        self.is_activated = False
        self.start_frame = frame
        self.end_frame = frame
        if feature is not None and np.any(feature):
            self.feature = feature.copy()


class ByteTrack:
    """ByteTrack tracker. `update(dets, embeddings=None)` takes (N, 5) rows
    [x1, y1, x2, y2, score] (and (N, D) embeddings when use_appearance) and
    returns (M, 5) rows [x1, y1, x2, y2, track_id] (ids start at 1)."""

    def __init__(self, config: ByteTrackConfig = ByteTrackConfig()) -> None:
        if not isinstance(config, ByteTrackConfig):
            raise ValueError(f"config: expected a ByteTrackConfig, got {type(config).__name__}")
        self.config = config
        self.tracked: list[_Track] = []  # state TRACKED, confirmed or not
        self.lost: list[_Track] = []
        self.frame_id = 0
        self._next_id = 1
        self.stats = {"frames": 0, "dropped_nonfinite": 0, "dropped_degenerate": 0, "reidentified": 0}

    def _new_id(self) -> int:
        self._next_id += 1
        return self._next_id - 1

    # -- costs ---------------------------------------------------------------
    def _iou_cost(self, tracks: list[_Track], dets: np.ndarray, fuse: bool) -> np.ndarray:
        boxes = np.array([t.box for t in tracks]).reshape(-1, 4)
        iou = pairwise_iou(boxes, dets[:, :4])
        if fuse:
            iou = iou * dets[None, :, 4]
        return 1.0 - iou

    def _appearance_cost(self, tracks: list[_Track], dets: np.ndarray, feats: np.ndarray) -> np.ndarray:
        cfg = self.config
        cost = np.ones((len(tracks), len(dets)))
        if not tracks or not len(dets):
            return cost
        track_feats = np.array([t.feature if t.feature is not None else np.zeros(feats.shape[1]) for t in tracks])
        d_app = cosine_distance(track_feats, feats)
        centres = 0.5 * (dets[:, :2] + dets[:, 2:4])
        for i, t in enumerate(tracks):
            diff = centres - t.x[:2]
            box = t.box
            n_lost = self.frame_id - t.end_frame - 1  # 0 for a track updated in the previous frame
            G = t.position_innovation_cov() + n_lost * (cfg.gate_sigma * (box[3] - box[1])) ** 2 * np.eye(2)
            maha = np.einsum("nj,jk,nk->n", diff, np.linalg.inv(G), diff)
            ok = (maha <= cfg.gate_chi2) & (d_app[i] <= cfg.app_thresh)
            cost[i, ok] = d_app[i, ok]
        return cost

    # -- one frame -----------------------------------------------------------
    def update(self, dets: np.ndarray | None, embeddings: np.ndarray | None = None) -> np.ndarray:
        cfg = self.config
        self.frame_id += 1
        clean = frame_detections(self.stats, dets)
        d = clean.dets
        feats = None
        if cfg.use_appearance:
            if embeddings is None and len(clean.keep):
                raise ValueError("use_appearance=True needs embeddings for the detections")
            emb = np.asarray(embeddings if embeddings is not None else np.zeros((0, 1)), dtype=float)
            if emb.size == 0:
                emb = np.zeros((len(clean.keep), emb.shape[-1] if emb.ndim == 2 else 1))
            if emb.ndim != 2 or emb.shape[0] != len(clean.keep):
                raise ValueError(f"embeddings must be (N, D) for N = {len(clean.keep)} detections; got {emb.shape}")
            # A non-finite embedding becomes the zero vector: cosine distance 1 to every track.
            feats = np.nan_to_num(emb[clean.keep], nan=0.0, posinf=0.0, neginf=0.0)

        high_mask = d[:, 4] >= cfg.track_thresh
        low_mask = (d[:, 4] > cfg.low_thresh) & ~high_mask
        d_high, d_low = d[high_mask], d[low_mask]
        f_high = feats[high_mask] if feats is not None else None

        unconfirmed = [t for t in self.tracked if not t.is_activated]
        confirmed = [t for t in self.tracked if t.is_activated]
        pool = confirmed + self.lost
        for t in pool:
            t.predict(freeze_scale_rate=t.state != TrackState.TRACKED)

        refound: list[_Track] = []
        lost_now: list[_Track] = []

        # 1. high-score detections against confirmed + lost tracks
        iou_cost = self._iou_cost(pool, d_high, cfg.fuse_score)
        cost = iou_cost
        if feats is not None:
            cost = np.minimum(iou_cost, self._appearance_cost(pool, d_high, f_high))
        matches, u_track, u_high = gated_assignment(cost, cfg.match_thresh)
        for ti, di in matches:
            t = pool[ti]
            self._apply(t, d_high[di], f_high[di] if f_high is not None else None)
            if t.state != TrackState.TRACKED:
                t.state = TrackState.TRACKED
                refound.append(t)
                if iou_cost[ti, di] > cfg.match_thresh:  # only appearance could make this match
                    self.stats["reidentified"] += 1

        # 2. low-score detections against the remaining tracked (not lost) tracks
        r_tracked = [pool[i] for i in u_track if pool[i].state == TrackState.TRACKED]
        matches, u_rest, _ = gated_assignment(self._iou_cost(r_tracked, d_low, False), cfg.second_match_thresh)
        for ti, di in matches:
            self._apply(r_tracked[ti], d_low[di], None)  # occluded crops: do not update appearance
        for i in u_rest:
            t = r_tracked[i]
            t.state = TrackState.LOST
            lost_now.append(t)

        # 3. unconfirmed tracks against the remaining high-score detections
        d_rest = d_high[u_high]
        f_rest = f_high[u_high] if f_high is not None else None
        matches, u_unconf, u_new = gated_assignment(
            self._iou_cost(unconfirmed, d_rest, cfg.fuse_score), cfg.unconfirmed_match_thresh
        )
        for ti, di in matches:
            t = unconfirmed[ti]
            self._apply(t, d_rest[di], f_rest[di] if f_rest is not None else None)
            t.is_activated = True
        for i in u_unconf:
            unconfirmed[i].state = TrackState.REMOVED

        # 4. new tracks from the remaining confident detections
        new_tracks = []
        for di in u_new:
            if d_rest[di, 4] < cfg.new_track_thresh:
                continue
            t = _Track(d_rest[di, :4], self._new_id(), d_rest[di, 4], self.frame_id,
                       f_rest[di] if f_rest is not None else None)
            t.is_activated = self.frame_id == 1
            new_tracks.append(t)

        # 5. expire lost tracks
        for t in self.lost:
            if t.state == TrackState.LOST and self.frame_id - t.end_frame > cfg.track_buffer:
                t.state = TrackState.REMOVED

        self.tracked = [t for t in self.tracked if t.state == TrackState.TRACKED] + refound + new_tracks
        self.tracked = list({id(t): t for t in self.tracked}.values())
        self.lost = [t for t in self.lost + lost_now if t.state == TrackState.LOST]
        self._remove_duplicates()

        out = [np.concatenate([t.box, [t.id]]) for t in self.tracked if t.is_activated and t.end_frame == self.frame_id]
        return np.array(out).reshape(-1, 5) if out else empty_output()

    def _apply(self, t: _Track, det: np.ndarray, feature: np.ndarray | None) -> None:
        t.update(det[:4], det[4])
        t.end_frame = self.frame_id
        if feature is not None and np.any(feature):
            t.feature = ema_feature(t.feature, feature, self.config.ema_alpha)

    def _remove_duplicates(self) -> None:
        """ByteTrack's remove_duplicate_stracks: of a tracked/lost pair overlapping
        with IoU > duplicate_iou, keep the one that has been tracked longer."""
        if not self.tracked or not self.lost:
            return
        iou = pairwise_iou(np.array([t.box for t in self.tracked]), np.array([t.box for t in self.lost]))
        drop_tracked, drop_lost = set(), set()
        for i, j in zip(*np.nonzero(iou > self.config.duplicate_iou)):
            a, b = self.tracked[i], self.lost[j]
            if a.end_frame - a.start_frame > b.end_frame - b.start_frame:
                drop_lost.add(j)
            else:
                drop_tracked.add(i)
        self.tracked = [t for i, t in enumerate(self.tracked) if i not in drop_tracked]
        self.lost = [t for j, t in enumerate(self.lost) if j not in drop_lost]
