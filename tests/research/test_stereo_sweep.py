"""stereo_depth's one-configuration mode (--cost ...) and the committed sweep that spreads its grid over tasks."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from research import sweep

REPO_ROOT = Path(__file__).resolve().parents[2]
SPEC = REPO_ROOT / "experiments" / "sweeps" / "stereo_tuning.toml"


def _experiment():
    from experiments import stereo_depth

    return stereo_depth, stereo_depth.main.__self__


def test_stereo_tuning_spec_spreads_the_grid_over_runs():
    spec = sweep.load_spec(SPEC)
    assert (spec.name, spec.experiment, spec.rows) == ("stereo_tuning", "stereo_depth", "methods")
    runs = spec.runs()
    configs = {tuple(o for o in r.options if o[0] != "--data") for r in runs}
    assert len(runs) == 540 and len(configs) == 180 and len({r.key for r in runs}) == 540
    assert sorted({r.seed for r in runs}) == [0, 1, 2]
    # each seed renders into its own data folder, so concurrent runs never share a seed-dependent cache
    assert {r.argv()[r.argv().index("--data") + 1] for r in runs if r.seed == 1} == {
        "data/sweeps/stereo_tuning/seed1"}
    smoke = spec.smoke_variant()
    assert smoke.name == "stereo_tuning-smoke" and smoke.fixed[0] == "--smoke" and "--quick" not in smoke.fixed


def test_every_smoke_run_of_the_spec_parses_into_one_configuration():
    """A dry run: each run's argv goes through stereo_depth's parser and becomes a valid StereoConfig."""
    module, experiment = _experiment()
    parser = experiment.parser()
    costs = set()
    for run in sweep.load_spec(SPEC).smoke_variant().runs():
        args = parser.parse_args(run.argv())
        cfg = module.single_config(args)
        assert args.smoke and cfg.cost == args.cost and cfg.aggregation == args.aggregation
        assert (cfg.p1, cfg.p2) == (args.p1, args.p2)
        costs.add(cfg.cost)
    assert costs == {"sad", "zncc", "census", "bt", "corr"}


@pytest.mark.timeout(240)
def test_one_smoke_run_of_the_spec(tmp_path):
    run = next(r for r in sweep.load_spec(SPEC).smoke_variant().runs() if ("--cost", "census") in r.options)
    argv = [a if not a.startswith("data/") else str(tmp_path / "data") for a in run.argv()]
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "experiments.stereo_depth", *argv, "--out", str(out), "--no-progress",
                        "--seed", str(run.seed)], cwd=REPO_ROOT, capture_output=True, text=True, timeout=230)
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads((out / "metrics.json").read_text())
    (label, row), = doc["metrics"]["methods"].items()
    assert label == doc["metrics"]["best_drlab"] and label.startswith("census")
    assert 0.0 <= row["tuning_d1"] <= 1.0 and 0.0 <= row["pooled"]["d1"] <= 1.0
    assert doc["config"]["single"]["cost"] == "census"
