"""drlab sweep: a 4-run sweep of kalman_tracking --smoke (2 seeds x 2 trial counts) through the local
executor and a local Ray instance with 2 worker processes (identical gathered tables), a Ray worker
killed by PID mid-run (retried, the sweep completes), a sweep interrupted by Ctrl-C and started again
(complete runs are not redone), a failing run (reported, counted in the exit status); `drlab
reproduce --ray` and a tiny dataset rendered as Ray tasks against their local counterparts.

The Ray tests share one local instance (module fixture: 2 CPUs, no dashboard, loopback only, its
own session folder under /tmp), stopped at the end of the module; its teardown fails if any process
naming that session folder (raylet, GCS server, workers) is still running, and removes the folder.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

from research import cli, sweep
from research.registry import REPO_ROOT

SPEC = """
[sweep]
name = "{name}"
experiment = "kalman_tracking"
seeds = [0, 1]
options = ["--smoke", "--tune-trials", "4"]

[grid]
"--trials" = [5, 8]

[resources]
cpus = 1
max_retries = 2
timeout_s = 300

[table]
rows = "methods"
metrics = ["filter_rmse.mean", "smoother_rmse.mean"]
"""


def _spec(tmp: Path, name: str = "kq", text: str = SPEC) -> Path:
    path = tmp / f"{name}.toml"
    path.write_text(text.format(name=name))
    return path


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


def _mtimes(sweep_dir: Path) -> dict[str, int]:
    return {p.parent.name: p.stat().st_mtime_ns for p in sweep_dir.glob("*/metrics.json")}


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory) -> Path:
    """The 4-run sweep through the local executor (2 at a time), via the command line."""
    tmp = tmp_path_factory.mktemp("local")
    rc = cli.main(["sweep", str(_spec(tmp)), "--results", str(tmp / "results"), "--jobs", "2", "--no-progress"])
    assert rc == 0
    return tmp / "results" / "kq"


@pytest.fixture(scope="module")
def ray_instance():
    """One local Ray instance for the module: 2 worker CPUs, no dashboard, loopback only, own session folder."""
    pytest.importorskip("ray")
    session = Path(tempfile.mkdtemp(prefix="drlab-ray-", dir="/tmp"))
    info = {"session": session, "worker_pids": set()}
    with sweep.ray_session(sweep.RayOptions(num_cpus=2, temp_dir=str(session))) as ray:
        info["ray"] = ray
        yield info
    # shut down: none of the instance's processes (raylet, GCS, workers) may be left running
    left = _processes_of(session) + [(pid, "a Ray worker that ran a test's task") for pid in info["worker_pids"]
                                     if Path(f"/proc/{pid}").exists()]
    deadline = time.monotonic() + 20
    while left and time.monotonic() < deadline:
        time.sleep(0.2)
        left = _processes_of(session) + [(pid, "a Ray worker") for pid in info["worker_pids"]
                                         if Path(f"/proc/{pid}").exists()]
    for pid, _ in left:  # don't leave them for the next test run either
        os.kill(pid, signal.SIGKILL)
    shutil.rmtree(session, ignore_errors=True)
    assert not left, f"Ray processes left running after shutdown: {left}"


def _processes_of(session: Path) -> list[tuple[int, str]]:
    """Processes whose command line names `session` (the Ray instance's session folder)."""
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if str(session) in cmd:
            found.append((int(pid), cmd[:160]))
    return found


def test_local_sweep_gathers_mean_and_std_over_seeds(local_sweep):
    spec = sweep.load_spec(local_sweep.parent.parent / "kq.toml")
    runs = spec.runs()
    assert len(runs) == 4 and len({r.key for r in runs}) == 4
    for run in runs:
        assert sweep.is_complete(run, local_sweep / run.key)
        assert (local_sweep / "logs" / f"{run.key}.log").read_text().startswith("== drlab sweep: run")
    table = json.loads((local_sweep / "table.json").read_text())
    assert table["failed"] == [] and len(table["table"]) == 2 * 5  # 2 trial counts x 5 filter models
    # mean and sample std over the two seeds, recomputed from the runs' own metrics.json
    row = next(r for r in table["table"] if r["group"] == {"--trials": "5"} and r["row"] == "textbook")
    vals = []
    for run in runs:
        if dict(run.options)["--trials"] == 5:
            doc = json.loads((local_sweep / run.key / "metrics.json").read_text())
            vals.append(doc["metrics"]["methods"]["textbook"]["filter_rmse"]["mean"])
    mean = sum(vals) / 2
    assert row["metrics"]["filter_rmse.mean"]["mean"] == pytest.approx(mean, rel=1e-12)
    assert row["metrics"]["filter_rmse.mean"]["std"] == pytest.approx(abs(vals[0] - vals[1]) / 2**0.5, rel=1e-12)
    assert "| 5 | textbook |" in (local_sweep / "table.md").read_text()
    assert (local_sweep / "figure.png").stat().st_size > 0
    assert {r["status"] for r in json.loads((local_sweep / "runs.json").read_text())["runs"]} == {"ok"}


@pytest.mark.timeout(120)
def test_ray_executor_table_equals_local(local_sweep, ray_instance, tmp_path):
    spec = sweep.load_spec(_spec(tmp_path))
    ex = sweep.ray_executor(sweep.RayOptions(), spec.cpus, spec.gpus, spec.max_retries)
    result = sweep.run_sweep(spec, tmp_path / "results", ex, progress=False, executor_name="ray")
    assert result.failed == [] and len(result.executed) == 4
    for name in ("table.md", "table.json"):
        assert (result.sweep_dir / name).read_text() == (local_sweep / name).read_text()
    # the runs ran in Ray's worker processes, not in this one
    pids = {o["pid"] for o in result.outcomes.values()}
    assert os.getpid() not in pids
    ray_instance["worker_pids"] |= pids


@pytest.mark.timeout(120)
def test_ray_worker_killed_mid_run_is_retried(local_sweep, ray_instance, tmp_path):
    spec_path = _spec(tmp_path, text=SPEC.replace('"--trials" = [5, 8]', '"--trials" = [5]'))
    spec = sweep.load_spec(spec_path)
    ex = sweep.ray_executor(sweep.RayOptions(), spec.cpus, spec.gpus, spec.max_retries)
    sweep_dir = tmp_path / "results" / "kq"
    box = {}
    t = threading.Thread(target=lambda: box.update(r=sweep.run_sweep(spec, tmp_path / "results", ex, progress=False)))
    t.start()
    victim = spec.runs()[0]
    log = sweep_dir / "logs" / f"{victim.key}.log"
    deadline = time.monotonic() + 60
    pid = None
    while pid is None and time.monotonic() < deadline:
        if log.exists() and "worker pid " in log.read_text():
            pid = int(log.read_text().split("worker pid ")[1].split(",")[0])
        time.sleep(0.02)
    assert pid is not None and pid != os.getpid()
    os.kill(pid, signal.SIGKILL)  # the Ray worker process running the task, mid-run
    t.join(timeout=100)
    assert not t.is_alive()
    result = box["r"]
    assert result.failed == [] and len(result.executed) == 2
    attempts = [line for line in log.read_text().splitlines() if line.startswith("== drlab sweep: run")]
    assert len(attempts) == 2  # the killed attempt and Ray's retry
    assert result.outcomes[victim.key]["pid"] != pid
    ray_instance["worker_pids"] |= {o["pid"] for o in result.outcomes.values()}
    # the killed attempt's experiment process died with its worker and left no temporary folder behind
    assert not [p for p in sweep_dir.iterdir() if ".partial-" in p.name or ".old-" in p.name]
    assert all(sweep.is_complete(r, sweep_dir / r.key) for r in spec.runs())
    # the numbers equal the local executor's for the same runs
    for run in spec.runs():
        assert (json.loads((sweep_dir / run.key / "metrics.json").read_text())["metrics"]
                == json.loads((local_sweep / run.key / "metrics.json").read_text())["metrics"])


def _strip_timings(obj):
    """metrics without wall-clock fields (keys naming seconds), for comparing a Ray run with a local one."""
    if isinstance(obj, dict):
        return {k: _strip_timings(v) for k, v in obj.items() if "second" not in k and not k.endswith("_s")}
    if isinstance(obj, list):
        return [_strip_timings(v) for v in obj]
    return obj


@pytest.mark.timeout(120)
def test_reproduce_on_ray_equals_local_reproduce(ray_instance, tmp_path, monkeypatch, capsys):
    """`drlab reproduce --quick --ray` over two registered experiments: the same folders and README as a local
    reproduce, timings aside."""
    from research import registry

    names = ["kalman_tracking", "lucas_kanade"]
    monkeypatch.setattr(cli, "EXPERIMENTS", {n: cli.EXPERIMENTS[n] for n in names})
    monkeypatch.setattr(registry, "EXPERIMENTS", cli.EXPERIMENTS)
    out = {}
    for mode, extra in (("local", []), ("ray", ["--ray"])):
        base = tmp_path / mode
        monkeypatch.setattr(registry, "base_dir", lambda base=base: base)
        monkeypatch.setattr(registry, "results_dir", lambda quick=False, smoke=False, base=base: base / "results")
        assert cli.main(["reproduce", "--quick", *extra]) == 0
        out[mode] = base / "results"
    assert "as Ray tasks on a local Ray instance" in capsys.readouterr().out
    for name in names:
        docs = [json.loads((out[m] / name / "metrics.json").read_text()) for m in ("local", "ray")]
        assert _strip_timings(docs[0]["metrics"]) == _strip_timings(docs[1]["metrics"])
        assert docs[0]["config"] == docs[1]["config"]
        assert not (out["ray"] / name / sweep.RUN_FILE).exists()
        assert (tmp_path / "ray" / "build" / "logs" / "reproduce-quick" / f"{name}.log").stat().st_size > 0

    def sections(readme: Path) -> list[str]:  # the README without the provenance lines (wall time, host)
        return [line for line in readme.read_text().splitlines() if not line.startswith("Run --quick at")]

    local, ray = sections(out["local"] / "README.md"), sections(out["ray"] / "README.md")
    assert len(local) == len(ray) and "## kalman_tracking" in local and "## lucas_kanade" in local
    for a, b in zip(local, ray):
        if a != b:  # only table rows may differ, and only in their last cell: lucas_kanade's seconds
            assert a.startswith("| ") and a.rsplit("|", 2)[0] == b.rsplit("|", 2)[0], (a, b)


@pytest.mark.timeout(120)
def test_dataset_rendered_as_ray_tasks_has_the_local_content_hash(ray_instance, tmp_path):
    from research.datasets import DatasetConfig, generate

    cfg = DatasetConfig(scene="spheres", views=4, res=24, spp=4, seed=3, stereo=True, stereo_pairs=2, flow=True,
                        flow_frames=3)
    local = generate(cfg, tmp_path / "local", show_progress=False)
    on_ray = generate(cfg, tmp_path / "ray", show_progress=False, ray=sweep.RayOptions())
    m_local, m_ray = (json.loads((p / "manifest.json").read_text()) for p in (local, on_ray))
    assert m_ray["files"] == m_local["files"] and len(m_ray["files"]) > 40
    assert m_ray["content_hash"] == m_local["content_hash"]
    assert m_ray["mitsuba_variant"] == m_local["mitsuba_variant"]
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]  # both committed


def test_interrupted_sweep_resumes_without_redoing_complete_runs(tmp_path):
    spec_path = _spec(tmp_path)
    results = tmp_path / "results"
    sweep_dir = results / "kq"
    proc = subprocess.Popen([sys.executable, "-m", "research.cli", "sweep", str(spec_path), "--results", str(results),
                             "--no-progress"], env=_env(), cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(list(sweep_dir.glob("*/" + sweep.RUN_FILE))) < 1:
        time.sleep(0.05)
    time.sleep(0.5)  # the second run is under way
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in the terminal: the sweep and its experiment process
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == cli.EXIT_INTERRUPTED, err
    done_before = _mtimes(sweep_dir)
    assert 1 <= len(done_before) < 4
    assert not [p for p in sweep_dir.iterdir() if ".partial-" in p.name]  # the interrupted run cleaned up
    runs_doc = json.loads((sweep_dir / "runs.json").read_text())
    assert "not run" in {r["status"] for r in runs_doc["runs"]}

    # a complete run whose record was lost counts as not done
    spec = sweep.load_spec(spec_path)
    lost = next(r for r in spec.runs() if r.key in done_before)
    (sweep_dir / lost.key / sweep.RUN_FILE).unlink()

    rc = cli.main(["sweep", str(spec_path), "--results", str(results), "--no-progress"])
    assert rc == 0
    after = _mtimes(sweep_dir)
    assert len(after) == 4
    for key, mtime in done_before.items():
        if key == lost.key:
            assert after[key] != mtime  # redone
        else:
            assert after[key] == mtime  # skipped
    statuses = {r["key"]: r["status"] for r in json.loads((sweep_dir / "runs.json").read_text())["runs"]}
    assert sum(s == "skipped" for s in statuses.values()) == len(done_before) - 1


@pytest.mark.timeout(120)
def test_ray_task_whose_worker_keeps_dying_is_failed_after_its_retries(ray_instance, tmp_path):
    text = SPEC.replace('"--trials" = [5, 8]', '"--trials" = [5]').replace("seeds = [0, 1]", "seeds = [0]")
    spec = sweep.load_spec(_spec(tmp_path, text=text.replace("max_retries = 2", "max_retries = 0")))
    ex = sweep.ray_executor(sweep.RayOptions(), spec.cpus, spec.gpus, spec.max_retries)
    box = {}
    t = threading.Thread(target=lambda: box.update(r=sweep.run_sweep(spec, tmp_path / "results", ex, progress=False)))
    t.start()
    log = tmp_path / "results" / "kq" / "logs" / f"{spec.runs()[0].key}.log"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (log.exists() and "worker pid " in log.read_text()):
        time.sleep(0.02)
    os.kill(int(log.read_text().split("worker pid ")[1].split(",")[0]), signal.SIGKILL)
    t.join(timeout=100)
    result = box["r"]
    assert result.failed == [spec.runs()[0].key]
    assert result.outcomes[spec.runs()[0].key]["error"].startswith("Ray task failed after 0 retries: ")
    assert "## Failed runs" in (result.sweep_dir / "table.md").read_text()


def test_run_past_its_timeout_is_stopped_and_failed(tmp_path):
    text = SPEC.replace('"--trials" = [5, 8]', '"--trials" = [5]').replace("seeds = [0, 1]", "seeds = [0]")
    spec = sweep.load_spec(_spec(tmp_path, text=text.replace("timeout_s = 300", "timeout_s = 1")))
    result = sweep.run_sweep(spec, tmp_path / "results", sweep.local_executor(1), progress=False)
    key = spec.runs()[0].key
    assert result.failed == [key] and result.outcomes[key]["error"] == "timed out after 1 s (stopped)"
    # stopped with SIGTERM: the experiment deleted its temporary folder
    assert not [p for p in result.sweep_dir.iterdir() if ".partial-" in p.name]
    assert not (result.sweep_dir / key).exists()


def test_failing_run_is_reported_and_counted(tmp_path, capsys):
    text = SPEC.replace('[grid]\n"--trials" = [5, 8]', '[[list]]\n"--trials" = 5\n\n[[list]]\n"--trials" = -3')
    text = text.replace("seeds = [0, 1]", "seeds = [0]")
    spec_path = _spec(tmp_path, text=text)
    rc = cli.main(["sweep", str(spec_path), "--results", str(tmp_path / "results"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 1  # one failed run
    assert err.strip().splitlines()[-1].startswith("drlab sweep: 1 of 2 runs failed")
    sweep_dir = tmp_path / "results" / "kq"
    table = (sweep_dir / "table.md").read_text()
    assert "## Failed runs" in table and "negative dimensions are not allowed" in table
    doc = json.loads((sweep_dir / "table.json").read_text())
    assert [f["seed"] for f in doc["failed"]] == [0] and "exit 2" in doc["failed"][0]["error"]
    ok_row = next(r for r in doc["table"] if r["group"] == {"--trials": "5"})
    assert ok_row["failed_seeds"] == [] and ok_row["metrics"]["filter_rmse.mean"]["n"] == 1
    bad_row = next(r for r in doc["table"] if r["group"] == {"--trials": "-3"})
    assert bad_row["failed_seeds"] == [0] and bad_row["metrics"]["filter_rmse.mean"] is None
    # started again, the failed run is tried again (and fails again); the good one is skipped
    rc = cli.main(["sweep", str(spec_path), "--results", str(tmp_path / "results"), "--no-progress"])
    assert rc == 1
    statuses = sorted(r["status"] for r in json.loads((sweep_dir / "runs.json").read_text())["runs"])
    assert statuses == ["failed", "skipped"]


def test_every_committed_sweep_file_loads():
    files = sorted((REPO_ROOT / "experiments" / "sweeps").glob("*.toml"))
    assert len(files) >= 3
    for path in files:
        assert sweep.load_spec(path).runs()


def test_raft_ablation_spreads_the_grid_over_runs():
    """One (levels, radius) cell per run (raft_flow --levels --radius), 16 cells x 3 seeds; a seed's runs
    share that seed's data folder (research.datasets renders it once, under a lock)."""
    spec = sweep.load_spec(REPO_ROOT / "experiments" / "sweeps" / "raft_ablation.toml")
    assert (spec.name, spec.experiment, spec.rows) == ("raft_ablation", "raft_flow", None)
    runs = spec.runs()
    assert len(runs) == 48 and len({r.key for r in runs}) == 48
    cells = {(dict(r.options)["--levels"], dict(r.options)["--radius"]) for r in runs}
    assert cells == {(lv, rad) for lv in (1, 2, 3, 4) for rad in (1, 2, 3, 4)}
    for r in runs:
        argv = r.argv()
        assert argv[argv.index("--data") + 1] == f"data/sweeps/raft_ablation/seed{r.seed}"
    assert spec.group_by == ["--levels", "--radius"] and spec.metrics == ["cell.epe", "cell.f1_all"]
    smoke = spec.smoke_variant()
    assert smoke.name == "raft_ablation-smoke" and "--quick" not in smoke.fixed and smoke.fixed[0] == "--smoke"
    assert {r.key for r in smoke.runs()}.isdisjoint(r.key for r in runs)


# stereo_tuning spreads its grid over one run per configuration: tests/research/test_stereo_sweep.py


def test_run_key_is_the_hash_of_the_full_configuration():
    base = sweep.Run("kalman_tracking", "cpu", 0, (("--smoke", True), ("--trials", 5)))
    assert base.key == sweep.Run("kalman_tracking", "cpu", 0, (("--smoke", True), ("--trials", 5))).key
    assert len(base.key) == sweep.KEY_DIGITS and int(base.key, 16) >= 0
    others = [sweep.Run("kalman_tracking", "cpu", 1, base.options),
              sweep.Run("kalman_tracking", "cuda", 0, base.options),
              sweep.Run("lucas_kanade", "cpu", 0, base.options),
              sweep.Run("kalman_tracking", "cpu", 0, (("--smoke", True), ("--trials", 6))),
              sweep.Run("kalman_tracking", "cpu", 0, (("--smoke", True), ("--trials", "5"))),
              sweep.Run("kalman_tracking", "cpu", 0, (("--trials", 5),))]
    assert len({base.key, *(o.key for o in others)}) == 1 + len(others)
    assert base.argv() == ["--smoke", "--trials", "5"]
    assert sweep.Run("x", "cpu", 7, (("--flag", False), ("--d", "s{seed}"), ("--l", [1, 2.5]))).argv() == \
        ["--d", "s7", "--l", "1", "2.5"]


def test_figure_of_a_large_grid_sorts_groups_into_horizontal_bars(tmp_path):
    """Beyond _VERTICAL_MAX groups the figure is a tall chart of horizontal bars sorted by the metric."""
    from PIL import Image

    spec = sweep.load_spec(REPO_ROOT / "experiments" / "sweeps" / "stereo_tuning.toml")
    rng = __import__("numpy").random.default_rng(0)
    rows = [{"group": {"--cost": cost, "--radius": r}, "row": "m",
             "metrics": {spec.figure: {"mean": float(rng.random()), "std": 0.01}}}
            for cost in ("sad", "bt", "census") for r in range(30)]
    assert len(rows) > sweep._VERTICAL_MAX
    path = sweep._figure(spec, tmp_path, rows)
    width, height = Image.open(path).size
    assert height > width
    few = sweep._figure(spec, tmp_path, rows[:4])
    width, height = Image.open(few).size
    assert width > height


def _listening_addresses(pids: list[int]) -> list[tuple[int, str]]:
    """(pid, local address) of every TCP socket in LISTEN state that one of `pids` holds, from /proc:
    the socket inodes among each process's open files, matched against /proc/net/tcp and tcp6."""
    listening = {}
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A":  # TCP_LISTEN
                listening[fields[9]] = fields[1].split(":")[0]
    found = []
    for pid in pids:
        try:
            links = [os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd")]
        except OSError:
            continue
        for link in links:
            if link.startswith("socket:[") and link[8:-1] in listening:
                found.append((pid, listening[link[8:-1]]))
    return found


# /proc/net/tcp writes an IPv4 address as 8 hex digits in host byte order (127.0.0.1 -> 0100007F);
# tcp6 as 32, with an IPv4-mapped loopback ending in ...0000FFFF0100007F
_LOOPBACK_HEX = {"0100007F", "00000000000000000000000001000000", "0000000000000000FFFF00000100007F"}


def test_local_ray_instance_listens_on_the_loopback_address_only(ray_instance):
    pids = [pid for pid, _ in _processes_of(ray_instance["session"])]
    sockets = _listening_addresses(pids)
    assert sockets, "found no listening socket of the Ray instance (GCS server, raylet)"
    assert all(addr in _LOOPBACK_HEX for _, addr in sockets), \
        f"Ray listens beyond the loopback interface: {sorted(set(a for _, a in sockets) - _LOOPBACK_HEX)}"


def test_command_line_ray_sweep_leaves_no_session_folder_or_process(tmp_path):
    """`drlab sweep --ray` starts its instance in a session folder of its own and removes it once the
    instance's processes have exited (Ray's default, /tmp/ray, would keep every session)."""
    pytest.importorskip("ray")
    before = set(Path("/tmp").glob("drlab-ray-*"))
    ray_default = set(Path("/tmp/ray").glob("session_2*")) if Path("/tmp/ray").is_dir() else set()
    proc = subprocess.run([sys.executable, "-m", "research.cli", "sweep", str(_spec(tmp_path, "kr")), "--ray",
                           "--jobs", "2", "--results", str(tmp_path / "results"), "--no-progress"],
                          env=_env(), cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    new = set(Path("/tmp").glob("drlab-ray-*")) - before
    assert not new, f"session folders left: {sorted(new)}"
    assert (set(Path("/tmp/ray").glob("session_2*")) if Path("/tmp/ray").is_dir() else set()) <= ray_default
