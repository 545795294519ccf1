"""Tests for research.tracking: Kalman filter, RTS smoother, boxes, assignment, SORT,
ByteTrack, appearance and bad input. Metrics against py-motmetrics live in
test_tracking_metrics.py, experiment smoke runs in test_tracking_experiments.py."""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from research.tracking import ByteTrack, ByteTrackConfig, Sort, SortConfig, kalman
from research.tracking.appearance import HistogramConfig, color_histogram, cosine_distance, rgb_to_hsv
from research.tracking.assignment import gated_assignment, max_iou_assignment
from research.tracking.box_track import KalmanBoxTrack
from research.tracking.boxes import (
    InvalidDetectionWarning,
    iou_matrix,
    sanitize_detections,
    xyxy_to_z,
    z_to_xyxy,
)
from research.tracking.synthetic import SceneConfig, circular_trajectory, make_sequence


def random_spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T + n * np.eye(n))


# --------------------------------------------------------------------------- Kalman
@pytest.mark.parametrize("seed", range(5))
def test_predict_update_match_numpy_reference(seed):
    rng = np.random.default_rng(seed)
    n, m = 4, 2
    x, P = rng.normal(size=n), random_spd(rng, n)
    F, Q = rng.normal(size=(n, n)), random_spd(rng, n, 0.1)
    H, R = rng.normal(size=(m, n)), random_spd(rng, m, 0.5)
    z = rng.normal(size=m)

    xp, Pp = kalman.predict(x, P, F, Q)
    np.testing.assert_allclose(xp, F @ x, rtol=1e-12)
    np.testing.assert_allclose(Pp, F @ P @ F.T + Q, rtol=1e-12)

    res = kalman.update(xp, Pp, z, H, R)
    S = H @ Pp @ H.T + R
    K = Pp @ H.T @ np.linalg.inv(S)
    np.testing.assert_allclose(res.x, xp + K @ (z - H @ xp), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(res.P, (np.eye(n) - K @ H) @ Pp, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(res.S, S, rtol=1e-12)
    assert res.loglik == pytest.approx(multivariate_normal(H @ xp, S).logpdf(z), rel=1e-10)
    assert np.isnan(kalman.update(xp, Pp, z, H, R, with_loglik=False).loglik)


@pytest.mark.parametrize("q, r, p0", [(0.0, 1e-10, 1e10), (1e-9, 1e-12, 1e10), (0.5, 2.0, 1.0)])
def test_joseph_form_keeps_covariance_symmetric_psd(q, r, p0):
    """A nearly noise-free measurement of a poorly known constant-acceleration state
    (condition numbers ~1e20): the Joseph-form covariance stays exactly symmetric
    and positive semi-definite. (The textbook form (I - K H) P goes indefinite
    on the first two cases on a typical float64 BLAS; not asserted, as rounding
    differs between machines.)"""
    model = kalman.constant_acceleration(ndim=1, q=q, r=r)
    x, P = np.zeros(3), p0 * np.eye(3)
    for k in range(100):
        if k:
            x, P = kalman.predict(x, P, model.F, model.Q)
        res = kalman.update(x, P, np.array([0.3 * k]), model.H, model.R)
        x, P = res.x, res.P
        assert np.array_equal(P, P.T)  # exact on any BLAS: kalman._symmetrise returns (P + P^T) / 2, and a + b == b + a
        eig = np.linalg.eigvalsh(P)
        assert eig.min() >= -1e-9 * eig.max()


def test_kalman_filter_matches_stepwise_and_batch():
    rng = np.random.default_rng(1)
    model = kalman.constant_velocity(ndim=2, q=0.3, r=2.0)
    zs = rng.normal(size=(3, 20, 2)).cumsum(axis=1)
    zs[:, 7] = np.nan  # a step missing in every sequence
    x0 = rng.normal(size=(3, 4))
    P0 = 5.0 * np.eye(4)
    batch = kalman.kalman_filter(zs, model, x0, P0)
    for b in range(3):
        single = kalman.kalman_filter(zs[b], model, x0[b], P0)
        np.testing.assert_allclose(batch.x_filt[b], single.x_filt, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(batch.loglik[b], single.loglik, rtol=1e-10)
        x, P = x0[b], P0
        for k in range(20):
            if k:
                x, P = kalman.predict(x, P, model.F, model.Q)
            if k != 7:
                res = kalman.update(x, P, zs[b, k], model.H, model.R)
                x, P = res.x, res.P
                assert single.loglik[k] == pytest.approx(res.loglik, rel=1e-10)
            np.testing.assert_allclose(single.x_filt[k], x, rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(single.P_filt[k], P, rtol=1e-10, atol=1e-10)
    assert np.all(batch.loglik[:, 7] == 0)
    with pytest.raises(ValueError):
        bad = zs.copy()
        bad[0, 3] = np.nan
        kalman.kalman_filter(bad, model, x0, P0)


def joint_gaussian(model: kalman.LinearGaussianModel, m0: np.ndarray, P0: np.ndarray, T: int):
    """Mean and covariance of the stacked states X and measurements Z of the model."""
    n = model.state_dim
    F, H, Q, R = model.F, model.H, model.Q, model.R
    mu = [m0]
    for _ in range(T - 1):
        mu.append(F @ mu[-1])
    # Cov(x_i, x_j) for i <= j: Cov(x_i, x_i) F^(j - i)^T.
    marg = [P0]
    for _ in range(T - 1):
        marg.append(F @ marg[-1] @ F.T + Q)
    Sx = np.zeros((T * n, T * n))
    for i in range(T):
        for j in range(i, T):
            c = marg[i] @ np.linalg.matrix_power(F, j - i).T
            Sx[i * n:(i + 1) * n, j * n:(j + 1) * n] = c
            Sx[j * n:(j + 1) * n, i * n:(i + 1) * n] = c.T
    Hb = np.kron(np.eye(T), H)
    Sz = Hb @ Sx @ Hb.T + np.kron(np.eye(T), R)
    return np.concatenate(mu), Sx, Hb, Sz


@pytest.mark.parametrize("order", [1, 2])
def test_rts_smoother_equals_batch_gaussian_posterior(order):
    rng = np.random.default_rng(order)
    T = 7
    model = kalman.kinematic_model(order, ndim=2, q=0.4, r=1.5)
    n = model.state_dim
    m0, P0 = rng.normal(size=n), random_spd(rng, n, 0.5)
    zs = rng.normal(size=(T, 2)) * 3
    mu, Sx, Hb, Sz = joint_gaussian(model, m0, P0, T)
    z = zs.ravel()
    gain = Sx @ Hb.T @ np.linalg.inv(Sz)
    post_mean = (mu + gain @ (z - Hb @ mu)).reshape(T, n)
    post_cov = Sx - gain @ Hb @ Sx

    res = kalman.kalman_filter(zs, model, m0, P0)
    xs, Ps = kalman.rts_smoother(res, model.F)
    np.testing.assert_allclose(xs, post_mean, rtol=1e-8, atol=1e-9)
    for k in range(T):
        np.testing.assert_allclose(Ps[k], post_cov[k * n:(k + 1) * n, k * n:(k + 1) * n], rtol=1e-8, atol=1e-9)
    # The last filtered estimate is already the full posterior; the log-likelihoods
    # of the innovations add up to the marginal likelihood of all measurements.
    np.testing.assert_allclose(res.x_filt[-1], post_mean[-1], rtol=1e-8, atol=1e-9)
    assert res.loglik.sum() == pytest.approx(multivariate_normal(Hb @ mu, Sz).logpdf(z), rel=1e-9)


def test_rts_smoother_with_missing_measurement_equals_posterior():
    rng = np.random.default_rng(3)
    T = 6
    model = kalman.constant_velocity(ndim=1, q=0.2, r=0.7)
    m0, P0 = np.zeros(2), np.diag([4.0, 1.0])
    zs = rng.normal(size=(T, 1))
    zs[2] = np.nan
    mu, Sx, Hb, Sz = joint_gaussian(model, m0, P0, T)
    keep = np.isfinite(zs.ravel())
    Hk, Szk = Hb[keep], Sz[np.ix_(keep, keep)]
    gain = Sx @ Hk.T @ np.linalg.inv(Szk)
    post_mean = (mu + gain @ (zs.ravel()[keep] - Hk @ mu)).reshape(T, 2)
    xs, _ = kalman.rts_smoother(kalman.kalman_filter(zs, model, m0, P0), model.F)
    np.testing.assert_allclose(xs, post_mean, rtol=1e-8, atol=1e-10)


def test_kinematic_models():
    cv = kalman.constant_velocity(ndim=2, q=2.0, r=3.0, dt=0.5)
    np.testing.assert_allclose(cv.F, [[1, 0, 0.5, 0], [0, 1, 0, 0.5], [0, 0, 1, 0], [0, 0, 0, 1]])
    np.testing.assert_allclose(cv.H, np.eye(2, 4))
    np.testing.assert_allclose(cv.Q[[0, 0, 2], [0, 2, 2]], 2.0 * np.array([0.5**3 / 3, 0.5**2 / 2, 0.5]))
    np.testing.assert_allclose(cv.R, 3.0 * np.eye(2))
    ca = kalman.constant_acceleration(ndim=1, q=1.0, dt=2.0)
    np.testing.assert_allclose(ca.F, [[1, 2, 2], [0, 1, 2], [0, 0, 1]])
    assert np.all(np.linalg.eigvalsh(ca.Q) > 0)
    # A CV filter with q = 0 tracks a straight line exactly.
    line = np.stack([np.arange(10.0), 2.0 * np.arange(10.0)], axis=1)
    m = kalman.constant_velocity(ndim=2, q=0.0, r=1.0)
    res = kalman.kalman_filter(line, m, *kalman.diffuse_prior(m, line[0]))
    np.testing.assert_allclose(res.x_filt[-1], [9, 18, 1, 2], atol=1e-4)


def test_circular_trajectory_is_the_textbook_circle():
    c = circular_trajectory(50, 10.0, (20.0, 20.0))
    assert c.shape == (50, 2)
    np.testing.assert_allclose(np.linalg.norm(c - 20.0, axis=1), 10.0)
    np.testing.assert_allclose(c[0], [30.0, 20.0])


# --------------------------------------------------------------------------- boxes, assignment
def test_iou_matrix_against_brute_force_and_degenerate_boxes():
    rng = np.random.default_rng(0)
    a = np.concatenate([rng.uniform(0, 50, (6, 2)), rng.uniform(0, 50, (6, 2))], axis=1)
    a[:, 2:] = a[:, :2] + rng.uniform(1, 30, (6, 2))
    b = a[::-1] + rng.normal(0, 5, (6, 4))
    b[:, 2:] = np.maximum(b[:, 2:], b[:, :2] + 1)
    iou = iou_matrix(a, b)
    for i, j in itertools.product(range(6), range(6)):
        w = max(0.0, min(a[i, 2], b[j, 2]) - max(a[i, 0], b[j, 0]))
        h = max(0.0, min(a[i, 3], b[j, 3]) - max(a[i, 1], b[j, 1]))
        inter = w * h
        area = lambda r: (r[2] - r[0]) * (r[3] - r[1])  # noqa: E731
        assert iou[i, j] == pytest.approx(inter / (area(a[i]) + area(b[j]) - inter), abs=1e-12)
    degenerate = np.array([[5, 5, 5, 5], [0, 0, 0, 10.0], [3, 4, 9, 4]])  # empty boxes: IoU 0
    out = iou_matrix(degenerate, np.concatenate([degenerate, a[:2]]))
    assert np.all(np.isfinite(out)) and np.all(out == 0)
    with pytest.raises(ValueError, match=r"a: expected boxes \[x1, y1, x2, y2\] with w, h >= 0"):
        iou_matrix(np.array([[10, 10, 0, 0.0]]), a)  # negative size: refused (test_reliability_tracking)
    assert iou_matrix(np.zeros((0, 4)), a).shape == (0, 6)


def test_sort_box_parametrisation_round_trip():
    box = np.array([10.0, 20.0, 40.0, 80.0])
    z = xyxy_to_z(box)
    np.testing.assert_allclose(z, [25, 50, 30 * 60, 0.5])
    np.testing.assert_allclose(z_to_xyxy(z), box)
    assert np.all(np.isfinite(z_to_xyxy(np.array([0.0, 0.0, -5.0, -1.0]))))


def brute_force_gated(cost: np.ndarray, limit: float) -> float:
    """Minimum of sum(matched costs) + limit/2 per unmatched row and column."""
    n, m = cost.shape
    best = limit / 2 * (n + m)
    for k in range(1, min(n, m) + 1):
        for rows in itertools.combinations(range(n), k):
            for cols in itertools.permutations(range(m), k):
                c = [cost[r, q] for r, q in zip(rows, cols)]
                if max(c) > limit:
                    continue
                best = min(best, sum(c) + limit / 2 * (n + m - 2 * k))
    return best


@pytest.mark.parametrize("seed", range(8))
def test_gated_assignment_is_optimal(seed):
    rng = np.random.default_rng(seed)
    n, m = rng.integers(1, 5, 2)
    cost = rng.uniform(0, 1, (n, m))
    limit = 0.6
    matches, ur, uc = gated_assignment(cost, limit)
    value = cost[matches[:, 0], matches[:, 1]].sum() + limit / 2 * (len(ur) + len(uc))
    assert value == pytest.approx(brute_force_gated(cost, limit), abs=1e-12)
    assert np.all(cost[matches[:, 0], matches[:, 1]] <= limit)
    assert sorted([*matches[:, 0], *ur]) == list(range(n))
    assert sorted([*matches[:, 1], *uc]) == list(range(m))


def test_max_iou_assignment_and_empty_inputs():
    iou = np.array([[0.9, 0.2], [0.8, 0.25]])
    matches, ur, uc = max_iou_assignment(iou, 0.3)
    assert matches.tolist() == [[0, 0]] and ur.tolist() == [1] and uc.tolist() == [1]
    for fn, arg in ((max_iou_assignment, 0.3), (gated_assignment, 0.8)):
        matches, ur, uc = fn(np.zeros((0, 3)), arg)
        assert matches.shape == (0, 2) and ur.size == 0 and uc.tolist() == [0, 1, 2]


# --------------------------------------------------------------------------- trackers
def moving_box(x0: float, y0: float, vx: float, vy: float, t: int, w: float = 30, h: float = 60) -> np.ndarray:
    x, y = x0 + vx * t, y0 + vy * t
    return np.array([x, y, x + w, y + h])


def det_rows(*boxes_scores) -> np.ndarray:
    return np.array([[*b, s] for b, s in boxes_scores]).reshape(-1, 5)


def ids_by_object(out: np.ndarray, centres: dict[str, float]) -> dict[str, int]:
    """Map each named object to the id of the output box whose centre x is nearest."""
    res = {}
    for name, cx in centres.items():
        if len(out):
            i = int(np.argmin(np.abs(0.5 * (out[:, 0] + out[:, 2]) - cx)))
            res[name] = int(out[i, 4])
    return res


TRACKER_FACTORIES = {
    "sort": lambda: Sort(SortConfig(max_age=3, min_hits=1)),
    "bytetrack": lambda: ByteTrack(),
}


@pytest.mark.parametrize("name", list(TRACKER_FACTORIES))
def test_two_crossing_objects_keep_identity(name):
    tracker = TRACKER_FACTORIES[name]()
    seen: dict[str, set[int]] = {"a": set(), "b": set()}
    for t in range(40):
        a = moving_box(0, 100, 5, 0, t)
        b = moving_box(200, 110, -5, 0, t)  # they overlap from t = 15 to 25, fully aligned in x at t = 20
        out = tracker.update(det_rows((b, 0.9), (a, 0.9)))
        if t >= 2:
            assert len(out) == 2
        if t >= 2 and abs(t - 20) > 5:  # outside the overlap, tell them apart by x
            for key, v in ids_by_object(out, {"a": a[0] + 15, "b": b[0] + 15}).items():
                seen[key].add(v)
    assert len(seen["a"]) == 1 and len(seen["b"]) == 1 and seen["a"] != seen["b"]


def run_occlusion(tracker, low_frames: range, low_score: float = 0.3) -> list[np.ndarray]:
    outs = []
    for t in range(30):
        box = moving_box(20, 50, 4, 1, t)
        score = low_score if t in low_frames else 0.9
        outs.append(tracker.update(det_rows((box, score))))
    return outs


def test_low_score_detection_keeps_track_only_in_bytetrack():
    low = range(12, 18)
    byte = run_occlusion(ByteTrack(ByteTrackConfig(track_thresh=0.5, low_thresh=0.1)), low)
    sort = run_occlusion(Sort(SortConfig(det_thresh=0.5)), low)
    byte_no_low = run_occlusion(ByteTrack(ByteTrackConfig(track_thresh=0.5, low_thresh=0.5)), low)
    # ByteTrack reports the object in every frame after confirmation, always with one id.
    assert all(len(o) == 1 for o in byte[1:])
    assert len({int(o[0, 4]) for o in byte[1:]}) == 1
    # SORT (score threshold 0.5) loses it during the low-score frames and starts a new id after.
    assert all(len(sort[t]) == 0 for t in low)
    assert int(sort[-1][0, 4]) != int(sort[5][0, 4])
    # ByteTrack without its second association misses the low-score frames too.
    assert all(len(byte_no_low[t]) == 0 for t in low)


def test_low_score_detections_never_start_bytetrack_tracks():
    tracker = ByteTrack()
    for t in range(10):
        out = tracker.update(det_rows((moving_box(0, 0, 2, 0, t), 0.4)))
        assert len(out) == 0
    assert not tracker.tracked and not tracker.lost


def test_sort_min_hits_and_max_age():
    tracker = Sort(SortConfig(max_age=2, min_hits=3))
    outs = [tracker.update(det_rows((moving_box(0, 0, 3, 0, t), 0.9))) for t in range(6)]
    # Reported in the first min_hits frames (warm-up), and from then on every frame.
    assert [len(o) for o in outs] == [1, 1, 1, 1, 1, 1]
    tracker2 = Sort(SortConfig(max_age=2, min_hits=3))
    for t in range(8):
        tracker2.update(det_rows((moving_box(0, 0, 3, 0, t), 0.9)))
    for _ in range(3):
        tracker2.update(np.zeros((0, 5)))
    assert tracker2.tracks == []  # deleted after max_age frames without a match


def two_tone_frame(boxes: list[np.ndarray], colours: list[tuple], size=(200, 400)) -> np.ndarray:
    img = np.full((*size, 3), 110, dtype=np.uint8)
    for b, (top, bottom) in zip(boxes, colours):
        x1, y1, x2, y2 = (int(round(v)) for v in b)
        mid = (y1 + y2) // 2
        img[y1:mid, x1:x2] = top
        img[mid:y2, x1:x2] = bottom
    return img


def test_appearance_reidentifies_track_after_occlusion():
    """An object hides for 12 frames and comes back displaced from its predicted
    path (it stopped while hidden): IoU cannot match it, appearance can."""
    from research.tracking.appearance import embed_boxes

    colours = [((220, 30, 30), (30, 30, 220))]

    def run(use_app: bool) -> list[set[int]]:
        tracker = ByteTrack(ByteTrackConfig(use_appearance=use_app))
        ids = []
        for t in range(40):
            if t < 15:
                box = moving_box(20, 60, 3, 0, t)
            elif t < 27:
                box = None  # hidden
            else:
                box = moving_box(20 + 3 * 14 + 15, 60, 0, 0, 0)  # reappears stopped, short of the prediction
            dets = det_rows((box, 0.9)) if box is not None else np.zeros((0, 5))
            frame = two_tone_frame([box] if box is not None else [], colours)
            out = tracker.update(dets, embed_boxes(frame, dets[:, :4]))
            ids.append({int(i) for i in out[:, 4]})
        return ids

    plain, app = run(False), run(True)
    assert len(plain[10]) == 1 and len(app[10]) == 1
    assert plain[-1] and plain[-1] != plain[10]  # IoU-only ByteTrack starts a new id
    assert app[-1] == app[10]  # appearance re-identifies the lost track


@pytest.mark.parametrize("same_colour", [True, False])
def test_appearance_match_needs_similar_colours(same_colour):
    """After 12 hidden frames an object appears 32 px short of the lost track's
    prediction (IoU 0, inside the gate): the same colours re-identify the track,
    different colours start a new one."""
    from research.tracking.appearance import embed_boxes

    red_blue = ((220, 30, 30), (30, 30, 220))
    after = red_blue if same_colour else ((30, 200, 30), (200, 200, 30))
    tracker = ByteTrack(ByteTrackConfig(use_appearance=True))
    ids = []
    for t in range(26):
        if t < 10:
            box, col = moving_box(20, 60, 3, 0, t), red_blue
        elif t < 22:
            box, col = None, None
        else:
            box, col = moving_box(20 + 3 * 22 - 32, 60, 0, 0, 0), after
        dets = det_rows((box, 0.9)) if box is not None else np.zeros((0, 5))
        frame = two_tone_frame([box] if box is not None else [], [col] if col else [])
        out = tracker.update(dets, embed_boxes(frame, dets[:, :4]))
        ids.append({int(i) for i in out[:, 4]})
    assert ids[-1]
    if same_colour:
        assert ids[-1] == ids[5] and tracker.stats["reidentified"] == 1
    else:
        assert ids[-1] != ids[5] and tracker.stats["reidentified"] == 0


def test_color_histogram_embedding():
    img = two_tone_frame([np.array([10, 10, 50, 90]), np.array([100, 10, 140, 90])],
                         [((220, 30, 30), (30, 30, 220)), ((30, 200, 30), (200, 200, 30))])
    cfg = HistogramConfig()
    a = color_histogram(img, np.array([10, 10, 50, 90]), cfg)
    a_shift = color_histogram(img, np.array([12, 12, 51, 88]), cfg)
    b = color_histogram(img, np.array([100, 10, 140, 90]), cfg)
    assert a.shape == (cfg.dim,) and np.linalg.norm(a) == pytest.approx(1.0)
    d = cosine_distance(np.stack([a, a_shift]), np.stack([a, b]))
    assert d[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert d[1, 0] < 0.05 and d[0, 1] > 0.9
    assert not np.any(color_histogram(img, np.array([500, 500, 520, 530]), cfg))  # outside: zero vector
    h, s, v = rgb_to_hsv(np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0.5, 0.5, 0.5]]))
    np.testing.assert_allclose(h[:3], [0, 1 / 3, 2 / 3])
    np.testing.assert_allclose(s, [1, 1, 1, 0])


# --------------------------------------------------------------------------- bad input
def test_sanitize_detections():
    dets = np.array(
        [
            [0, 0, 10, 10, 0.9],
            [np.nan, 0, 10, 10, 0.9],
            [0, 0, 10, 10, np.nan],
            [5, 5, 5, 10, 0.9],  # zero width
            [10, 10, 0, 0, 0.9],  # negative size
            [0, 0, np.inf, 10, 0.9],
        ]
    )
    with pytest.warns(InvalidDetectionWarning, match="3 non-finite and 2 zero/negative"):
        clean = sanitize_detections(dets)
    assert clean.dets.tolist() == [[0, 0, 10, 10, 0.9]]
    assert clean.keep.tolist() == [True, False, False, False, False, False]
    for empty in (None, [], np.zeros((0, 5)), np.zeros((0,))):
        assert sanitize_detections(empty).dets.shape == (0, 5)
    with pytest.raises(ValueError):
        sanitize_detections(np.zeros((2, 4)))


BAD_FRAMES = {
    "nan": np.array([[np.nan, np.nan, np.nan, np.nan, np.nan]]),
    "zero_size": np.array([[50, 50, 50, 50, 0.9]]),
    "negative_size": np.array([[80, 90, 40, 10, 0.95]]),
    "empty_array": np.zeros((0, 5)),
    "none": None,
}


@pytest.mark.parametrize("kind", list(BAD_FRAMES))
@pytest.mark.parametrize("name", ["sort", "bytetrack", "bytetrack_app"])
def test_bad_frames_do_not_crash_or_lose_tracks(name, kind):
    """Two frames of invalid (or no) detections in the middle of a track: no crash,
    the track keeps predicting, and it resumes with the same id."""
    factories = {
        "sort": lambda: Sort(SortConfig(max_age=5, min_hits=1)),
        "bytetrack": lambda: ByteTrack(),
        "bytetrack_app": lambda: ByteTrack(ByteTrackConfig(use_appearance=True)),
    }
    tracker = factories[name]()
    bad = BAD_FRAMES[kind]
    ids = []
    for t in range(16):
        if t in (8, 9):
            dets = bad
        else:
            dets = det_rows((moving_box(10, 20, 4, 2, t), 0.9))
        n = 0 if dets is None else len(dets)
        emb = np.ones((n, HistogramConfig().dim)) if name == "bytetrack_app" and dets is not None else None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InvalidDetectionWarning)
            out = tracker.update(dets, emb)
        assert np.all(np.isfinite(out))
        if t in (8, 9):
            assert len(out) == 0
        elif t >= 1:
            ids.append(int(out[0, 4]))
    assert len(set(ids)) == 1 and len(ids) == 13
    dropped = tracker.stats["dropped_nonfinite"] + tracker.stats["dropped_degenerate"]
    assert dropped == (2 if kind in ("nan", "zero_size", "negative_size") else 0)


def test_invalid_rows_mixed_with_valid_ones_are_dropped_with_warning():
    tracker = ByteTrack()
    good = det_rows((moving_box(0, 0, 1, 0, 0), 0.9))
    mixed = np.concatenate([good, [[np.nan, 0, 1, 1, 0.9], [3, 3, 1, 1, 0.9]]])
    tracker.update(good)
    with pytest.warns(InvalidDetectionWarning):
        out = tracker.update(mixed)
    assert len(out) == 1 and tracker.stats == {
        "frames": 2, "dropped_nonfinite": 1, "dropped_degenerate": 1, "reidentified": 0
    }


def test_box_track_negative_area_rate_stays_finite():
    trk = KalmanBoxTrack(np.array([0.0, 0.0, 10.0, 10.0]), 1)
    trk.x[6] = -500.0  # area would go negative
    for _ in range(5):
        assert np.all(np.isfinite(trk.predict()))
    assert trk.x[2] > 0


def test_bytetrack_with_appearance_requires_embeddings():
    with pytest.raises(ValueError):
        ByteTrack(ByteTrackConfig(use_appearance=True)).update(det_rows((np.array([0, 0, 5, 5]), 0.9)))


# --------------------------------------------------------------------------- synthetic data
def test_synthetic_sequence_is_deterministic_and_consistent():
    cfg = SceneConfig(n_objects=5, n_frames=25, width=320, height=180)
    a, b = make_sequence(3, cfg), make_sequence(3, cfg)
    assert all(np.array_equal(x, y) for x, y in zip(a.dets, b.dets))
    assert np.array_equal(a.render(7), b.render(7))
    img = a.render(0)
    assert img.shape == (180, 320, 3) and img.dtype == np.uint8
    for t in range(cfg.n_frames):
        assert sorted(a.gt_ids[t].tolist()) == list(range(5))
        assert np.all((a.gt_visibility[t] >= 0) & (a.gt_visibility[t] <= 1))
        boxes = a.gt_boxes[t]
        assert np.all(boxes[:, 2] > boxes[:, 0]) and np.all(boxes[:, :2] >= 0)
        assert np.all(boxes[:, 2] <= 320) and np.all(boxes[:, 3] <= 180)
        d = a.dets[t]
        assert d.shape[1] == 5 and np.all((d[:, 4] >= 0) & (d[:, 4] <= 1))
        assert len(a.det_gt[t]) == len(d)
    assert make_sequence(4, cfg).dets[0].tolist() != a.dets[0].tolist()


def test_synthetic_detector_scores_fall_with_visibility():
    seq = make_sequence(0, SceneConfig(n_objects=8, n_frames=120))
    vis, score = [], []
    for t in range(seq.n_frames):
        v = dict(zip(seq.gt_ids[t].tolist(), seq.gt_visibility[t].tolist()))
        for row, g in zip(seq.dets[t], seq.det_gt[t]):
            if g >= 0:
                vis.append(v[int(g)])
                score.append(row[4])
    vis, score = np.array(vis), np.array(score)
    assert vis.min() >= 0.15  # invisible objects are never detected
    assert np.median(score[vis > 0.9]) > 0.9
    assert np.median(score[vis < 0.5]) < 0.5


def test_invalid_rows_leave_tracker_output_unchanged_on_a_synthetic_sequence():
    from research.tracking.harness import corrupt_detections, evaluate_tracking, run_tracker

    seq = make_sequence(5, SceneConfig(n_objects=6, n_frames=60, width=400, height=240))
    embs = [np.ones((len(d), HistogramConfig().dim)) for d in seq.dets]
    bad_d, bad_e = corrupt_detections(seq.dets, embs, np.random.default_rng(0))
    assert all(len(b) == len(d) + 5 for b, d in zip(bad_d, seq.dets))
    for make in (lambda: Sort(SortConfig(max_age=30)), lambda: ByteTrack(ByteTrackConfig(use_appearance=True))):
        clean, _, _ = run_tracker(make, seq.dets, embs)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InvalidDetectionWarning)
            dirty, _, stats = run_tracker(make, bad_d, bad_e)
        assert all(np.array_equal(a, b) for a, b in zip(clean, dirty))
        assert stats["dropped_nonfinite"] == 3 * 60 and stats["dropped_degenerate"] == 2 * 60
        counts, vis, hit = evaluate_tracking(seq, clean)
        assert counts.num_objects == 6 * 60 == len(vis) == len(hit)
        assert 0.0 < counts.mota <= 1.0
