"""The tracking experiments in --quick mode (their findings hold at that size), into tmp_path.

Quick mode takes a few seconds each on 2 CPU cores (kalman_tracking ~4 s,
mot_tracking ~8 s), under the 20 s limit for smoke tests.
"""

from __future__ import annotations

import json

import pytest

from experiments import kalman_tracking, mot_tracking


@pytest.mark.timeout(120)
def test_kalman_tracking_quick(tmp_path):
    out = tmp_path / "out"
    assert kalman_tracking.main(["--quick", "--out", str(out), "--seed", "1", "--no-progress"]) == 0
    for f in ("metrics.json", "table.md", "trajectory.png"):
        assert (out / f).is_file()
    saved = json.loads((out / "metrics.json").read_text())
    assert saved["seed"] == 1 and saved["device"] == "cpu" and saved["config"]["quick"]
    metrics = saved["metrics"]
    m = metrics["methods"]
    # The textbook filter barely helps; the tuned one clearly does; the smoother more.
    assert m["textbook"]["filter_reduction"]["mean"] < 0.1
    assert m["cv_white_accel"]["filter_reduction"]["mean"] > 0.2
    assert m["cv_white_accel"]["smoother_rmse"]["mean"] < m["cv_white_accel"]["filter_rmse"]["mean"]
    assert "Why the textbook" in (out / "table.md").read_text()


@pytest.mark.timeout(120)
def test_mot_tracking_quick(tmp_path):
    out = tmp_path / "out"
    assert mot_tracking.main(["--quick", "--out", str(out), "--no-progress"]) == 0
    for f in ("metrics.json", "table.md", "tracks.png", "recall_vs_visibility.png"):
        assert (out / f).is_file()
    metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    tr = metrics["trackers"]
    assert set(tr) >= {"sort", "bytetrack", "bytetrack_app"}
    for m in tr.values():
        assert -1.0 <= m["mota"] <= 1.0 and 0.0 <= m["idf1"] <= 1.0 and m["fps"] > 0
    for r in metrics["robustness"]["trackers"].values():
        assert r["invalid_rows"]["identical_to_clean"]
