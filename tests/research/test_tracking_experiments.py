"""Smoke runs of the tracking experiments in --quick mode, into tmp_path.

Quick mode takes a few seconds each on 2 CPU cores (kalman_tracking ~4 s,
mot_tracking ~8 s), under the 20 s limit for smoke tests.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"


def load(name: str):
    spec = importlib.util.spec_from_file_location(f"_exp_{name}", EXPERIMENTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.timeout(120)
def test_kalman_tracking_quick(tmp_path):
    metrics = load("kalman_tracking").main(["--quick", "--out", str(tmp_path), "--seed", "1"])
    for f in ("metrics.json", "table.md", "trajectory.png"):
        assert (tmp_path / f).is_file()
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["seed"] == 1 and saved["device"] == "cpu" and saved["config"]["quick"]
    m = metrics["methods"]
    # The textbook filter barely helps; the tuned one clearly does; the smoother more.
    assert m["textbook"]["filter_reduction"]["mean"] < 0.1
    assert m["cv_white_accel"]["filter_reduction"]["mean"] > 0.2
    assert m["cv_white_accel"]["smoother_rmse"]["mean"] < m["cv_white_accel"]["filter_rmse"]["mean"]
    assert "Why the textbook" in (tmp_path / "table.md").read_text()


@pytest.mark.timeout(120)
def test_mot_tracking_quick(tmp_path):
    metrics = load("mot_tracking").main(["--quick", "--out", str(tmp_path)])
    for f in ("metrics.json", "table.md", "tracks.png", "recall_vs_visibility.png"):
        assert (tmp_path / f).is_file()
    tr = metrics["trackers"]
    assert set(tr) >= {"sort", "bytetrack", "bytetrack_app"}
    for m in tr.values():
        assert -1.0 <= m["mota"] <= 1.0 and 0.0 <= m["idf1"] <= 1.0 and m["fps"] > 0
    for r in metrics["robustness"]["trackers"].values():
        assert r["invalid_rows"]["identical_to_clean"]
