"""Reliability of research.tracking: tracker configurations, Kalman models and boxes.

Each case names the bad value and the one-line ValueError it must raise when the configuration
or model is made (max_age=-1, iou_threshold=nan and a negative q used to be accepted). Bad
detections are a fault, not a usage error: trackers drop them with a warning and keep tracking.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from research.tracking import kalman
from research.tracking.appearance import HistogramConfig
from research.tracking.boxes import InvalidDetectionWarning, iou_matrix, xywh_to_xyxy, xyxy_to_xywh, xyxy_to_z
from research.tracking.bytetrack import ByteTrack, ByteTrackConfig
from research.tracking.sort import Sort, SortConfig

NAN = float("nan")
INF = float("inf")
CV = kalman.constant_velocity(ndim=2, q=1.0, r=1.0)
ASYM = np.array([[1.0, 0.5], [0.0, 1.0]])
NOT_PSD = np.array([[1.0, 2.0], [2.0, 1.0]])

# (id, constructor, expected message (regex))
CASES = [
    ("sort-max-age-negative", lambda: SortConfig(max_age=-1), r"max_age: expected an integer >= 0, got -1"),
    ("sort-max-age-float", lambda: SortConfig(max_age=1.5), r"max_age: expected an integer >= 0, got 1.5"),
    ("sort-max-age-bool", lambda: SortConfig(max_age=True), r"max_age: expected an integer >= 0, got True"),
    ("sort-min-hits-negative", lambda: SortConfig(min_hits=-2), r"min_hits: expected an integer >= 0, got -2"),
    ("sort-iou-nan", lambda: SortConfig(iou_threshold=NAN), r"iou_threshold: expected a finite number in \[0, 1\], got nan"),
    ("sort-iou-above-1", lambda: SortConfig(iou_threshold=1.5), r"iou_threshold: expected a finite number in \[0, 1\]"),
    ("sort-iou-negative", lambda: SortConfig(iou_threshold=-0.1), r"iou_threshold: expected a finite number in \[0, 1\]"),
    ("sort-iou-text", lambda: SortConfig(iou_threshold="0.3"), r"iou_threshold: expected a finite number in \[0, 1\]"),
    ("sort-det-thresh-inf", lambda: SortConfig(det_thresh=INF), r"det_thresh: expected a finite number in \[0, 1\]"),
    ("sort-config-not-a-config", lambda: Sort({"max_age": 1}), r"config: expected a SortConfig, got dict"),
    ("byte-track-thresh-nan", lambda: ByteTrackConfig(track_thresh=NAN), r"track_thresh: expected a finite number in \[0, 1\]"),
    ("byte-low-thresh-negative", lambda: ByteTrackConfig(low_thresh=-0.1), r"low_thresh: expected a finite number in \[0, 1\]"),
    ("byte-low-above-track", lambda: ByteTrackConfig(track_thresh=0.3, low_thresh=0.5),
     r"low_thresh: expected low_thresh <= track_thresh = 0.3, got 0.5"),
    ("byte-new-track-thresh-2", lambda: ByteTrackConfig(new_track_thresh=2.0), r"new_track_thresh: expected a finite"),
    ("byte-match-thresh-nan", lambda: ByteTrackConfig(match_thresh=NAN), r"match_thresh: expected a finite number in \[0, 1\]"),
    ("byte-second-match-negative", lambda: ByteTrackConfig(second_match_thresh=-1.0), r"second_match_thresh: expected"),
    ("byte-unconfirmed-match-inf", lambda: ByteTrackConfig(unconfirmed_match_thresh=INF), r"unconfirmed_match_thresh:"),
    ("byte-track-buffer-negative", lambda: ByteTrackConfig(track_buffer=-1), r"track_buffer: expected an integer >= 0, got -1"),
    ("byte-track-buffer-float", lambda: ByteTrackConfig(track_buffer=30.0), r"track_buffer: expected an integer >= 0, got 30.0"),
    ("byte-duplicate-iou-above-1", lambda: ByteTrackConfig(duplicate_iou=1.2), r"duplicate_iou: expected a finite number in \[0, 1\]"),
    ("byte-ema-alpha-nan", lambda: ByteTrackConfig(ema_alpha=NAN), r"ema_alpha: expected a finite number in \[0, 1\]"),
    ("byte-app-thresh-3", lambda: ByteTrackConfig(app_thresh=3.0), r"app_thresh: expected a finite number in \[0, 2\]"),
    ("byte-gate-chi2-0", lambda: ByteTrackConfig(gate_chi2=0.0), r"gate_chi2: expected a finite number > 0, got 0.0"),
    ("byte-gate-sigma-negative", lambda: ByteTrackConfig(gate_sigma=-0.05), r"gate_sigma: expected a finite number >= 0"),
    ("byte-use-appearance-string", lambda: ByteTrackConfig(use_appearance="yes"), r"use_appearance: expected True or False"),
    ("byte-config-not-a-config", lambda: ByteTrack(SortConfig()), r"config: expected a ByteTrackConfig, got SortConfig"),
    ("histogram-bins-0", lambda: HistogramConfig(hue_bins=0), r"hue_bins: expected an integer >= 1, got 0"),
    ("histogram-shrink-half", lambda: HistogramConfig(shrink=0.5), r"shrink: expected a finite number in \[0, 0.49\]"),
    ("histogram-sat-min-nan", lambda: HistogramConfig(sat_min=NAN), r"sat_min: expected a finite number in \[0, 1\]"),
    ("kalman-q-negative", lambda: kalman.constant_velocity(q=-1.0), r"q: expected a finite number >= 0, got -1.0"),
    ("kalman-q-nan", lambda: kalman.constant_acceleration(q=NAN), r"q: expected a finite number >= 0, got nan"),
    ("kalman-q-inf", lambda: kalman.kinematic_model(1, 2, INF, 1.0), r"q: expected a finite number >= 0, got inf"),
    ("kalman-r-negative", lambda: kalman.constant_velocity(r=-0.1), r"r: expected a finite number >= 0, got -0.1"),
    ("kalman-dt-0", lambda: kalman.constant_velocity(dt=0.0), r"dt: expected a finite number > 0, got 0.0"),
    ("kalman-ndim-0", lambda: kalman.constant_velocity(ndim=0), r"ndim: expected an integer >= 1, got 0"),
    ("kalman-order-3", lambda: kalman.kinematic_model(3, 2, 1.0, 1.0), r"order must be 1 \(CV\) or 2 \(CA\); got 3"),
    ("model-Q-asymmetric", lambda: kalman.LinearGaussianModel(np.eye(2), np.eye(2), ASYM, np.eye(2)),
     r"Q: expected a symmetric covariance matrix"),
    ("model-Q-not-psd", lambda: kalman.LinearGaussianModel(np.eye(2), np.eye(2), NOT_PSD, np.eye(2)),
     r"Q: expected a positive semi-definite covariance matrix, smallest eigenvalue is -1"),
    ("model-R-nan", lambda: kalman.LinearGaussianModel(np.eye(2), np.eye(2), np.eye(2), np.full((2, 2), NAN)),
     r"R: contains NaN or infinite values"),
    ("model-R-negative-variance", lambda: kalman.LinearGaussianModel(np.eye(2), np.eye(2), np.eye(2), -np.eye(2)),
     r"R: expected a positive semi-definite covariance matrix"),
    ("model-F-inf", lambda: kalman.LinearGaussianModel(np.full((2, 2), INF), np.eye(2), np.eye(2), np.eye(2)),
     r"F: contains NaN or infinite values"),
    ("model-shapes", lambda: kalman.LinearGaussianModel(np.eye(2), np.eye(3), np.eye(2), np.eye(3)),
     r"H must be \(3, 2\) and R \(3, 3\)"),
    ("filter-P0-asymmetric", lambda: kalman.kalman_filter(np.zeros((3, 2)), CV, np.zeros(4), np.triu(np.ones((4, 4)))),
     r"P0: expected a symmetric covariance matrix"),
    ("filter-P0-shape", lambda: kalman.kalman_filter(np.zeros((3, 2)), CV, np.zeros(4), np.eye(3)),
     r"P0: expected \(4, 4\), got shape \(3, 3\)"),
    ("filter-x0-nan", lambda: kalman.kalman_filter(np.zeros((3, 2)), CV, np.full(4, NAN), np.eye(4)),
     r"x0: expected finite values of shape \(4,\)"),
    ("prior-var-0", lambda: kalman.diffuse_prior(CV, np.zeros(2), var=0.0), r"var: expected a finite number > 0, got 0.0"),
    ("iou-nan-box", lambda: iou_matrix([[0, 0, NAN, 1]], [[0, 0, 1, 1]]),
     r"a: boxes must be finite, found NaN or infinite coordinates"),
    ("iou-negative-width", lambda: iou_matrix([[0, 0, 1, 1]], [[5, 0, 1, 1]]),
     r"b: expected boxes \[x1, y1, x2, y2\] with w, h >= 0, got row 0 \[5.0, 0.0, 1.0, 1.0\]"),
    ("iou-three-columns", lambda: iou_matrix(np.zeros((2, 3)), np.zeros((1, 4))), r"a: expected xyxy boxes \(\.\.\., 4\)"),
    ("box-to-z-zero-height", lambda: xyxy_to_z(np.array([0.0, 2.0, 4.0, 2.0])),
     r"box: expected boxes \[x1, y1, x2, y2\] with w, h > 0"),
    ("box-to-z-inf", lambda: xyxy_to_z(np.array([0.0, 0.0, INF, 2.0])), r"box: boxes must be finite"),
    ("box-to-z-two-boxes", lambda: xyxy_to_z(np.zeros((2, 4))), r"box: expected one xyxy box of 4 values"),
    ("xyxy-to-xywh-negative-height", lambda: xyxy_to_xywh([[0, 5, 1, 1]]), r"boxes: expected boxes .* with w, h >= 0"),
    ("xywh-to-xyxy-negative-width", lambda: xywh_to_xyxy([[0, 0, -1, 1]]), r"boxes: expected finite xywh boxes with w, h >= 0"),
    ("xywh-to-xyxy-nan", lambda: xywh_to_xyxy([[NAN, 0, 1, 1]]), r"boxes: expected finite xywh boxes"),
]


@pytest.mark.parametrize("make, message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_tracking_bad_value_is_one_line_value_error(make, message):
    with pytest.raises(ValueError, match=message) as info:
        make()
    assert "\n" not in str(info.value)


def test_the_paper_defaults_and_the_experiment_settings_are_accepted():
    SortConfig(), ByteTrackConfig(), HistogramConfig()
    SortConfig(max_age=30, det_thresh=0.5), ByteTrackConfig(track_thresh=0.5, low_thresh=0.5, use_appearance=True)
    kalman.constant_velocity(q=0.0), kalman.constant_acceleration(ndim=3, q=0.4, r=1.5, dt=0.5)
    assert iou_matrix([[1, 1, 1, 1]], [[0, 0, 2, 2]])[0, 0] == 0.0  # an empty box is valid, IoU 0


# Faults: bad detector output is dropped with a warning, and tracking goes on.
FAULTS = [
    ("nan-row", np.array([[NAN, 0, 10, 10, 0.9]])),
    ("inf-score", np.array([[0, 0, 10, 10, INF]])),
    ("zero-size", np.array([[5, 5, 5, 9, 0.9]])),
]


@pytest.mark.parametrize("tracker", ["sort", "bytetrack"])
@pytest.mark.parametrize("bad", [c[1] for c in FAULTS], ids=[c[0] for c in FAULTS])
def test_bad_detections_are_dropped_with_a_warning_and_tracks_survive(tracker, bad):
    make = {"sort": lambda: Sort(SortConfig(max_age=3, min_hits=1)),
            "bytetrack": lambda: ByteTrack(ByteTrackConfig())}[tracker]
    t = make()
    good = np.array([[10.0, 10.0, 30.0, 40.0, 0.9]])
    for k in range(3):
        t.update(good + [k, 0, k, 0, 0])
    with pytest.warns(InvalidDetectionWarning):
        t.update(np.concatenate([good + [3, 0, 3, 0, 0], bad]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = t.update(good + [4, 0, 4, 0, 0])
    assert len(out) == 1 and out[0, 4] == 1  # the same track, id 1, kept through the bad frame
