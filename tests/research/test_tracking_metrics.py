"""research.tracking.metrics against hand-computed cases and against py-motmetrics.

py-motmetrics (a test-only dependency) is imported lazily; its
`distances.iou_matrix` calls np.asfarray, removed in NumPy 2, so the reference
distances are built from `motmetrics.distances.boxiou` with iou_matrix's rule
(NaN where 1 - IoU > 0.5).
"""

from __future__ import annotations

import numpy as np
import pytest

from research.tracking.boxes import xyxy_to_xywh
from research.tracking.metrics import MOTAccumulator, MOTCounts, evaluate_sequence


def box(x: float, y: float, w: float = 10.0, h: float = 20.0) -> list[float]:
    return [x, y, x + w, y + h]


def test_hand_computed_case():
    """Frame 0: both objects matched. Frame 1: the hypotheses swap objects (2 switches).
    Frame 2: object 1 missed, one false positive.
    MOTA = 1 - (1 miss + 1 FP + 2 switches) / 5 = 0.2; IDTP = 2 of 5 + 5, IDF1 = 0.4."""
    A, B, far = box(0, 0), box(50, 0), box(200, 200)
    gt = [([1, 2], [A, B]), ([1, 2], [A, B]), ([1], [A])]
    hyp = [([10, 20], [A, B]), ([10, 20], [B, A]), ([30], [far])]
    c = evaluate_sequence(gt, hyp)
    assert (c.num_objects, c.num_predictions) == (5, 5)
    assert (c.num_matches, c.num_switches, c.num_misses, c.num_false_positives) == (2, 2, 1, 1)
    assert c.mota == pytest.approx(0.2)
    assert c.motp == pytest.approx(0.0)
    assert c.idtp == 2 and c.idf1 == pytest.approx(0.4)


def test_established_match_is_kept_over_a_better_one():
    """CLEAR step 1: a still-valid correspondence wins over a closer new hypothesis."""
    A = box(0, 0)
    near = box(1, 0)  # IoU with A: 9/11
    exact = box(0, 0)
    acc = MOTAccumulator()
    acc.update([1], [A], [7], [near])
    fm = acc.update([1], [A], [7, 8], [near, exact])
    assert fm.pairs == [(1, 7)] and fm.false_positives == [8] and not fm.switches
    c = acc.result()
    assert c.num_switches == 0 and c.motp == pytest.approx(1 - 9 / 11)


def test_iou_threshold_boundary_and_empty_frames():
    acc = MOTAccumulator(iou_threshold=0.5)
    # IoU exactly 0.5 pairs (motmetrics: NaN only where 1 - IoU > 0.5).
    fm = acc.update([1], [[0, 0, 10, 10]], [5], [[0, 0, 10, 5]])
    assert fm.pairs == [(1, 5)]
    acc.update([], np.zeros((0, 4)), [], np.zeros((0, 4)))
    acc.update([1], [[0, 0, 10, 10]], [], np.zeros((0, 4)))
    c = acc.result()
    assert (c.num_frames, c.num_matches, c.num_misses) == (3, 1, 1)
    assert np.isnan(MOTCounts().mota) and np.isnan(MOTCounts().idf1)
    with pytest.raises(ValueError):
        acc.update([1, 1], [box(0, 0), box(5, 5)], [], np.zeros((0, 4)))


def random_case(rng: np.random.Generator, n_frames: int = 40, n_obj: int = 6):
    """GT trajectories with births and deaths, and a noisy tracker with ID swaps,
    fragmentation, id reuse, misses and false positives."""
    start = rng.uniform(0, 200, (n_obj, 2))
    vel = rng.normal(0, 3, (n_obj, 2))
    size = rng.uniform(10, 40, (n_obj, 2))
    life = np.sort(rng.integers(0, n_frames, (n_obj, 2)), axis=1)
    hyp_id = np.arange(n_obj) + 100
    noise = rng.uniform(0.03, 0.2)  # box jitter, in object sizes: some pairs fall below IoU 0.5
    gt, hyp = [], []
    for t in range(n_frames):
        alive = [o for o in range(n_obj) if life[o, 0] <= t <= life[o, 1] + 5]
        g_boxes = [np.concatenate([start[o] + vel[o] * t, start[o] + vel[o] * t + size[o]]) for o in alive]
        gt.append((alive, np.array(g_boxes).reshape(-1, 4)))
        if rng.uniform() < 0.1 and n_obj > 1:  # swap two hypothesis ids
            i, j = rng.choice(n_obj, 2, replace=False)
            hyp_id[[i, j]] = hyp_id[[j, i]]
        if rng.uniform() < 0.05:  # fragmentation: a fresh id
            hyp_id[rng.integers(n_obj)] = 1000 + t
        h_ids, h_boxes = [], []
        for o, b in zip(alive, g_boxes):
            if rng.uniform() < 0.15:
                continue
            jitter = rng.normal(0, noise, 4) * np.r_[size[o], size[o]]
            h_ids.append(int(hyp_id[o]))
            h_boxes.append(b + jitter)
        for k in range(rng.poisson(0.7)):
            p = rng.uniform(0, 250, 2)
            h_ids.append(5000 + k)
            h_boxes.append(np.r_[p, p + rng.uniform(10, 40, 2)])
        order = rng.permutation(len(h_ids))
        hyp.append(([h_ids[i] for i in order], np.array(h_boxes).reshape(-1, 4)[order]))
    return gt, hyp


def motmetrics_accumulator(mm, gt, hyp):
    acc = mm.MOTAccumulator(auto_id=True)
    for (oids, ob), (hids, hb) in zip(gt, hyp):
        if len(oids) and len(hids):
            iou = mm.distances.boxiou(xyxy_to_xywh(ob)[:, None], xyxy_to_xywh(hb)[None, :])
            dist = 1.0 - iou
            dist = np.where(dist > 0.5, np.nan, dist)
        else:
            dist = np.empty((len(oids), len(hids)))
        acc.update(list(oids), list(hids), dist)
    return acc


FIELDS = {
    "num_frames": "num_frames",
    "num_objects": "num_objects",
    "num_predictions": "num_predictions",
    "num_matches": "num_matches",
    "num_switches": "num_switches",
    "num_false_positives": "num_false_positives",
    "num_misses": "num_misses",
    "mota": "mota",
    "motp": "motp",
    "idtp": "idtp",
    "idfp": "idfp",
    "idfn": "idfn",
    "idf1": "idf1",
    "idp": "idp",
    "idr": "idr",
}


@pytest.mark.parametrize("seed", range(10))
def test_matches_motmetrics_on_random_sequences(seed):
    mm = pytest.importorskip("motmetrics")
    gt, hyp = random_case(np.random.default_rng(seed))
    ref = mm.metrics.create().compute(
        motmetrics_accumulator(mm, gt, hyp), metrics=list(FIELDS.values()), name="seq"
    ).iloc[0]
    ours = evaluate_sequence(gt, hyp).summary()
    for mine, theirs in FIELDS.items():
        assert ours[mine] == pytest.approx(float(ref[theirs]), rel=1e-9, abs=1e-12), mine
    assert ours["num_switches"] > 0 and ours["num_false_positives"] > 0 and ours["num_misses"] > 0


def test_overall_over_sequences_matches_motmetrics():
    mm = pytest.importorskip("motmetrics")
    rng = np.random.default_rng(42)
    cases = [random_case(rng, n_frames=25) for _ in range(3)]
    accs = [motmetrics_accumulator(mm, g, h) for g, h in cases]
    ref = mm.metrics.create().compute_many(
        accs, metrics=list(FIELDS.values()), names=["a", "b", "c"], generate_overall=True
    ).loc["OVERALL"]
    total = MOTCounts()
    for g, h in cases:
        total = total + evaluate_sequence(g, h)
    ours = total.summary()
    for mine, theirs in FIELDS.items():
        if mine == "num_frames":
            continue
        assert ours[mine] == pytest.approx(float(ref[theirs]), rel=1e-9, abs=1e-12), mine


def test_iou_matches_motmetrics_boxiou():
    mm = pytest.importorskip("motmetrics")
    from research.tracking.boxes import iou_matrix

    rng = np.random.default_rng(0)
    a = rng.uniform(0, 50, (7, 4))
    a[:, 2:] = a[:, :2] + rng.uniform(0, 30, (7, 2))
    b = a + rng.normal(0, 8, (7, 4))
    b[:, 2:] = np.maximum(b[:, 2:], b[:, :2])
    ref = mm.distances.boxiou(xyxy_to_xywh(a)[:, None], xyxy_to_xywh(b)[None, :])
    np.testing.assert_allclose(iou_matrix(a, b), ref, atol=1e-12)
