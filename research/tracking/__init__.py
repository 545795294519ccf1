"""Tracking: Kalman filtering, RTS smoothing, SORT, ByteTrack and MOT metrics.

Modules (pure NumPy/SciPy; no Warp kernels needed):
    kalman      linear Kalman filter (Joseph form), RTS smoother, CV/CA models
    boxes       box conversions, IoU, validation of detections
    assignment  Hungarian assignment with SORT's and ByteTrack's gating rules
    box_track   SORT's 7-state Kalman box track
    sort        SORT (Bewley et al. 2016)
    bytetrack   ByteTrack (Zhang et al. 2022), optionally with an appearance cost
    appearance  colour-histogram embeddings and cosine distance (DeepSORT style)
    synthetic   synthetic trajectories and multi-object sequences with ground truth
    metrics     MOTA, MOTP, ID switches and IDF1 with py-motmetrics' definitions; HOTA, DetA,
                AssA and LocA with TrackEval's
    motchallenge  MOTChallenge (MOT17/MOT20) sequence folders: reader, the evaluation's
                distractor preprocessing, result files

Trackers share one interface: `update(dets, embeddings=None)` with dets (N, 5)
rows [x1, y1, x2, y2, score] returns (M, 5) rows [x1, y1, x2, y2, track_id].
"""

from research.tracking.bytetrack import ByteTrack, ByteTrackConfig
from research.tracking.metrics import HOTACounts, MOTCounts, hota_sequence
from research.tracking.motchallenge import MOTSequence, SeqInfo, find_sequences, load_sequence
from research.tracking.sort import Sort, SortConfig

__all__ = ["ByteTrack", "ByteTrackConfig", "HOTACounts", "MOTCounts", "MOTSequence", "SeqInfo", "Sort",
           "SortConfig", "find_sequences", "hota_sequence", "load_sequence"]
