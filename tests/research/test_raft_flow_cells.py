"""raft_flow --levels/--radius: one cell of the RAFT-style ablation per run (what a sweep spreads over tasks)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from research.registry import REPO_ROOT


def _run(args: list[str]) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    return subprocess.run([sys.executable, "-m", "experiments.raft_flow", *args], cwd=REPO_ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.timeout(300)
def test_one_cell(tmp_path):
    out = tmp_path / "out"
    r = _run(["--smoke", "--no-progress", "--levels", "2", "--radius", "3", "--out", str(out),
              "--data", str(tmp_path / "data")])
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    m = json.loads((out / "metrics.json").read_text())["metrics"]
    assert list(m["ablation"]) == ["L2_r3"]
    assert m["cell"]["levels"] == 2 and m["cell"]["radius"] == 3 and m["cell"]["epe"] == m["ablation"]["L2_r3"]["epe"]
    assert "CorrFlow (L=2, r=3)" in m["per_scene"]["objects"] and "radiometric" not in m
