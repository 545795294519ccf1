"""The drlab command line: subcommands, exit statuses and output formats."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from research import cli
from research.registry import EXPERIMENTS, REPO_ROOT


def run_cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "research.cli", *args], cwd=REPO_ROOT, capture_output=True,
                          text=True, timeout=timeout)


def test_help_lists_every_subcommand():
    out = run_cli("--help").stdout
    for cmd in ("dataset", "run", "reproduce", "gradcheck", "bench", "list"):
        assert cmd in out


def test_every_registered_experiment_is_a_module_of_the_experiments_package():
    # Their --help and smoke runs: tests/research/test_experiments.py.
    import importlib.util

    assert EXPERIMENTS, "no experiment registered"
    for spec in EXPERIMENTS.values():
        assert spec.module == f"experiments.{spec.name}"
        found = importlib.util.find_spec(spec.module)
        assert found is not None and Path(found.origin) == REPO_ROOT / "experiments" / f"{spec.name}.py"


def test_run_command_is_python_m_with_options_passed_through(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cmd = cli._experiment_command("kalman_tracking", True, "cpu", Path("rel"), 5, ["--trials", "3"])
    if cmd[1] == "-P":  # Python 3.11+: the current directory stays off sys.path
        del cmd[1]
    assert cmd[:3] == [sys.executable, "-m", "experiments.kalman_tracking"]
    assert cmd[3:] == ["--device", "cpu", "--out", str(tmp_path / "rel"), "--quick", "--seed", "5", "--trials", "3"]
    calls = []
    monkeypatch.setattr(cli, "_run_one", lambda *a: calls.append(a) or 0)
    assert cli.main(["run", "kalman_tracking", "--quick", "--", "--data", "d", "--no-progress"]) == 0
    assert calls == [("kalman_tracking", True, "cpu", None, None, ["--data", "d", "--no-progress"])]


def test_options_after_double_dash_are_only_for_run():
    r = run_cli("list", "--", "--smoke")
    assert r.returncode == 2 and "only for `drlab run`" in r.stderr


def test_run_unknown_experiment_fails_clearly():
    r = run_cli("run", "no_such_experiment")
    assert r.returncode == 2 and "unknown experiment" in r.stderr


def test_gradcheck_selftest_table_and_exit_status():
    r = run_cli("gradcheck", "selftest", "--device", "cpu")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "selftest.known_gradient" in r.stdout and "0 failed" in r.stdout


def test_gradcheck_exit_status_is_1_on_failure(monkeypatch, capsys):
    from research import gradcheck

    bad = gradcheck.GradcheckResult(name="x", input="a", max_abs_err=1.0, max_rel_err=1.0, n_checks=1,
                                    passed=False, eps=1e-6, rtol=1e-6, atol=0.0)
    monkeypatch.setattr(gradcheck, "run_checks", lambda names=None: [bad])
    assert cli.main(["gradcheck"]) == 1
    assert "1 failed" in capsys.readouterr().out


def test_bench_json_lines_are_clean_json():
    r = run_cli("bench", "launch", "--json", "--quick")
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stdout.splitlines() if ln.strip()]
    assert lines, "no output"
    for ln in lines:
        row = json.loads(ln)  # any banner on stdout would break this
        assert row["bench"] == "launch.split" and row["device"] == "cpu"
        assert row["threads"] >= 1 and row["speedup"] > 0 and row["cpu"]


def test_bench_unknown_family():
    r = run_cli("bench", "nope")
    assert r.returncode == 2 and "unknown" in r.stderr


def test_dataset_command_writes_a_loadable_dataset(tmp_path):
    out = tmp_path / "ds"
    r = run_cli("dataset", "--scene", "spheres", "--views", "3", "--res", "16", "--spp", "2", "--out", str(out))
    assert r.returncode == 0, r.stderr
    from research.datasets import load

    assert len(load(out).views) == 3
    r = run_cli("dataset", "--scene", "spheres", "--views", "3", "--res", "16", "--spp", "2", "--out", str(out))
    assert r.returncode != 0 and "--force" in r.stderr


def test_results_index_gathers_tables(tmp_path, monkeypatch):
    name = next(iter(EXPERIMENTS))
    (tmp_path / name).mkdir()
    (tmp_path / name / "table.md").write_text("| a |\n|---|\n| 1 |\n")
    (tmp_path / name / "fig.png").write_bytes(b"png")
    path = cli.write_results_index(tmp_path, [name], quick=False)
    text = path.read_text()
    assert f"## {name}" in text and "| 1 |" in text and f"({name}/fig.png)" in text
    assert "metrics.json missing" in text and "## comparison" not in text

    from research.results import write_results

    write_results(tmp_path / name, experiment=name, config={"quick": True}, seed=0, device="cpu", wall_time_s=90.0,
                  metrics={}, table_md="| a |\n|---|\n| 2 |\n")
    (tmp_path / "comparison").mkdir()
    (tmp_path / "comparison" / "table.md").write_text("| method |\n|---|\n| 3DGS |\n")
    text = cli.write_results_index(tmp_path, [name], quick=False).read_text()
    commit = json.loads((tmp_path / name / "metrics.json").read_text())["source"]["commit"]
    assert commit is None or f"at commit `{commit[:10]}`" in text
    assert "Run --quick at" in text and "1.5 min" in text and "| 2 |" in text
    cpu = json.loads((tmp_path / name / "metrics.json").read_text())["host"]["cpu"]
    assert f"on `cpu` ({cpu}, " in text
    assert "## comparison" in text and "| 3DGS |" in text


@pytest.mark.parametrize("argv", [["dataset", "--scene", "objects"], ["run"]])
def test_missing_required_arguments_exit_2(argv):
    r = run_cli(*argv)
    assert r.returncode == 2


def test_reproduce_subset_reruns_only_those_and_indexes_all(tmp_path, monkeypatch):
    """`drlab reproduce NAME`: only NAME runs; results/README.md still gathers every registered experiment."""
    from research import cli, registry

    names = ["kalman_tracking", "lucas_kanade"]
    monkeypatch.setattr(cli, "EXPERIMENTS", {n: cli.EXPERIMENTS[n] for n in names})
    monkeypatch.setattr(registry, "EXPERIMENTS", cli.EXPERIMENTS)
    results = tmp_path / "results"
    monkeypatch.setattr(registry, "results_dir", lambda quick=False, smoke=False: results)
    ran = []

    def fake_run(name, quick, device, out, seed, extra):
        ran.append(name)
        out.mkdir(parents=True)
        (out / "table.md").write_text(f"table of {name}\n")
        return 0

    monkeypatch.setattr(cli, "_run_one", fake_run)
    assert cli.main(["reproduce", "--quick", "lucas_kanade"]) == 0
    assert ran == ["lucas_kanade"]
    readme = (results / "README.md").read_text()
    assert "## kalman_tracking" in readme and "did not finish" in readme and "table of lucas_kanade" in readme


def test_reproduce_runs_an_experiments_reported_seed_in_full_mode_only(tmp_path, monkeypatch):
    """splat_slam's reported run is --seed 1 (its settings were picked on the seed-0 sequence): `drlab
    reproduce` passes it in full mode, locally and as Ray jobs; quick mode keeps the default seed."""
    from research import cli, registry
    from research.sweep.runs import reproduce_jobs

    assert registry.EXPERIMENTS["splat_slam"].reproduce_seed == 1
    names = ["lucas_kanade", "splat_slam"]
    monkeypatch.setattr(cli, "EXPERIMENTS", {n: cli.EXPERIMENTS[n] for n in names})
    monkeypatch.setattr(registry, "EXPERIMENTS", cli.EXPERIMENTS)
    monkeypatch.setattr(registry, "results_dir", lambda quick=False, smoke=False: tmp_path / "results")
    seeds = {}

    def fake_run(name, quick, device, out, seed, extra):
        seeds[(name, quick)] = seed
        out.mkdir(parents=True, exist_ok=True)
        (out / "table.md").write_text(f"table of {name}\n")
        return 0

    monkeypatch.setattr(cli, "_run_one", fake_run)
    assert cli.main(["reproduce"]) == 0
    assert cli.main(["reproduce", "--quick"]) == 0
    assert seeds == {("lucas_kanade", False): None, ("splat_slam", False): 1,
                     ("lucas_kanade", True): None, ("splat_slam", True): None}
    jobs = {j["key"]: j["seed"] for j in reproduce_jobs(names, tmp_path / "r", False, "cpu", tmp_path / "logs", [])}
    assert jobs == {"lucas_kanade": None, "splat_slam": 1}
    assert all(j["seed"] is None for j in reproduce_jobs(names, tmp_path / "r", True, "cpu", tmp_path / "logs", []))
