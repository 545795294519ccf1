"""Running trackers over sequences and scoring them: timing, CLEAR/ID metrics,
recall by visibility, and corrupted inputs for robustness checks."""

from __future__ import annotations

import time
from typing import Callable, Protocol, Sequence as Seq

import numpy as np

from research.tracking.metrics import MOTAccumulator, MOTCounts
from research.tracking.synthetic import Sequence


class Tracker(Protocol):
    stats: dict[str, int]

    def update(self, dets: np.ndarray | None, embeddings: np.ndarray | None = None) -> np.ndarray: ...


def run_tracker(
    make: Callable[[], Tracker], dets: Seq[np.ndarray | None], embs: Seq[np.ndarray] | None = None
) -> tuple[list[np.ndarray], float, dict[str, int]]:
    """Feed a fresh tracker every frame; returns (outputs per frame, seconds inside update, stats)."""
    tracker = make()
    outputs, elapsed = [], 0.0
    for t in range(len(dets)):
        t0 = time.perf_counter()
        out = tracker.update(dets[t], embs[t] if embs is not None else None)
        elapsed += time.perf_counter() - t0
        outputs.append(out)
    return outputs, elapsed, dict(tracker.stats)


def evaluate_tracking(
    seq: Sequence, outputs: Seq[np.ndarray], iou_threshold: float = 0.5
) -> tuple[MOTCounts, np.ndarray, np.ndarray]:
    """CLEAR/ID counts of tracker rows [x1, y1, x2, y2, id] against the sequence's
    ground truth (the first len(outputs) frames), and per GT instance its visibility
    and whether CLEAR matched it."""
    acc = MOTAccumulator(iou_threshold)
    vis, hit = [], []
    for t, out in enumerate(outputs):
        out = np.asarray(out, dtype=float).reshape(-1, 5)
        fm = acc.update(seq.gt_ids[t], seq.gt_boxes[t], out[:, 4].astype(np.int64), out[:, :4])
        matched = {o for o, _ in fm.pairs}
        vis.append(seq.gt_visibility[t])
        hit.append(np.array([int(o) in matched for o in seq.gt_ids[t]], dtype=bool))
    return acc.result(), np.concatenate(vis), np.concatenate(hit)


def recall_by_visibility(vis: np.ndarray, hit: np.ndarray, edges: Seq[float]) -> list[float]:
    """Share of GT instances matched, per visibility bin [edges[i], edges[i + 1]); NaN if empty."""
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (vis >= lo) & (vis < hi)
        out.append(float(hit[m].mean()) if m.any() else float("nan"))
    return out


def invalid_rows(rng: np.random.Generator, width: float = 600.0, height: float = 300.0) -> np.ndarray:
    """Five invalid detection rows: NaN coordinate, NaN score, zero width, negative size, inf."""
    x, y = rng.uniform(0, width), rng.uniform(0, height)
    return np.array(
        [
            [np.nan, y, x + 30, y + 60, 0.9],
            [x, y, x + 30, y + 60, np.nan],
            [x, y, x, y + 60, 0.9],
            [x + 30, y + 60, x, y, 0.95],
            [x, y, np.inf, y + 40, 0.8],
        ]
    )


def corrupt_detections(
    dets: Seq[np.ndarray], embs: Seq[np.ndarray], rng: np.random.Generator, empty_every: int | None = None
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Insert `invalid_rows` at random places in every frame, keeping the order of the
    valid rows (so a tracker that drops them must give identical output); their
    embeddings are random. With empty_every = k, every k-th frame is emptied instead."""
    out_d, out_e = [], []
    for t, (d, e) in enumerate(zip(dets, embs)):
        if empty_every and t % empty_every == empty_every - 1:
            out_d.append(np.zeros((0, 5)))
            out_e.append(np.zeros((0, e.shape[1])))
            continue
        bad = invalid_rows(rng)
        total = len(d) + len(bad)
        is_bad = np.zeros(total, bool)
        is_bad[rng.choice(total, len(bad), replace=False)] = True
        rows = np.empty((total, 5))
        rows[~is_bad], rows[is_bad] = d, bad
        feats = rng.random((total, e.shape[1]))
        feats[~is_bad] = e
        out_d.append(rows)
        out_e.append(feats)
    return out_d, out_e
