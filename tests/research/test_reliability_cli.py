"""Reliability of the command line and the experiment contract: bad input and faults.

Bad input: each case is a command line (or an experiment's options) and the one line it must
print to stderr, with exit status 2, before any work and before any file is created. Faults: Ctrl-C
(SIGINT) and SIGKILL of real runs, --debug, --device cuda without a GPU, stale temporary folders.
Most cases run in-process (cli.main, Experiment.main); the few subprocess ones use smoke sizes.
"""

from __future__ import annotations

import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from research import cli, experiment
from research.registry import EXPERIMENTS, REPO_ROOT


def _cuda_available() -> bool:
    import warp as wp

    from research.warp_runtime import init_warp

    init_warp()
    return wp.is_cuda_available()


no_gpu = pytest.mark.skipif(_cuda_available(), reason="Warp sees a CUDA device here: cuda is accepted")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    env.pop("DRLAB_PROG", None)
    return env


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


# --------------------------------------------------------------------------- drlab: bad command lines

# (id, argv, expected one line: its start and a fragment of it)
CLI_CASES = [
    ("no-command", [], "drlab: ", "the following arguments are required: command"),
    ("unknown-command", ["bogus"], "drlab: ", "invalid choice: 'bogus'"),
    ("run-no-experiment", ["run"], "drlab run: ", "required: experiment"),
    ("run-unknown-experiment", ["run", "nope"], "drlab run: ", "unknown experiment 'nope'"),
    ("run-device-tpu", ["run", "kalman_tracking", "--device", "tpu"], "drlab run: ",
     "--device: expected 'cpu', 'cuda' or 'cuda:N', got 'tpu'"),
    ("run-device-empty", ["run", "kalman_tracking", "--device", ""], "drlab run: ",
     "--device: expected 'cpu', 'cuda' or 'cuda:N', got ''"),
    ("run-device-cuda-x", ["run", "kalman_tracking", "--device", "cuda:x"], "drlab run: ",
     "--device: expected 'cpu', 'cuda' or 'cuda:N', got 'cuda:x'"),
    ("run-device-missing-value", ["run", "kalman_tracking", "--device"], "drlab run: ",
     "--device: expected one argument"),
    ("run-out-empty", ["run", "kalman_tracking", "--out", ""], "drlab run: ",
     "--out: expected a directory path, got ''"),
    ("run-out-blank", ["run", "kalman_tracking", "--out", "  "], "drlab run: ",
     "--out: expected a directory path, got '  '"),
    ("run-seed-negative", ["run", "kalman_tracking", "--seed", "-5"], "drlab run: ",
     "--seed: expected an integer in [0, 2^32), got '-5'"),
    ("run-seed-text", ["run", "kalman_tracking", "--seed", "x"], "drlab run: ",
     "--seed: expected an integer in [0, 2^32), got 'x'"),
    ("run-seed-float", ["run", "kalman_tracking", "--seed", "1.5"], "drlab run: ",
     "--seed: expected an integer in [0, 2^32), got '1.5'"),
    ("run-seed-2^32", ["run", "kalman_tracking", "--seed", "4294967296"], "drlab run: ",
     "--seed: expected an integer in [0, 2^32), got '4294967296'"),
    ("run-unknown-option", ["run", "kalman_tracking", "--bogus"], "drlab run: ",
     "unrecognized arguments: --bogus"),
    ("extra-after-dashes-not-run", ["list", "--", "--smoke"], "drlab list: ",
     "options after `--` are only for `drlab run`: --smoke"),
    ("list-extra-argument", ["list", "x"], "drlab list: ", "unrecognized arguments: x"),
    ("gradcheck-unknown-name", ["gradcheck", "nosuch"], "drlab gradcheck: ",
     "kernels: no gradient check matches 'nosuch'"),
    ("gradcheck-unknown-among-known", ["gradcheck", "selftest", "corr.nosuch"], "drlab gradcheck: ",
     "no gradient check matches 'corr.nosuch'"),
    ("bench-unknown-family", ["bench", "nosuch"], "drlab bench: ", "families: unknown family ['nosuch']"),
    ("bench-unknown-families", ["bench", "a", "b"], "drlab bench: ", "families: unknown families ['a', 'b']"),
    ("bench-device-tpu", ["bench", "--device", "tpu"], "drlab bench: ", "--device: expected 'cpu', 'cuda'"),
    ("gradcheck-device-tpu", ["gradcheck", "selftest", "--device", "tpu"], "drlab gradcheck: ",
     "--device: expected 'cpu', 'cuda'"),
    ("reproduce-unknown-experiment", ["reproduce", "kalman_tracking", "nosuch"], "drlab reproduce: ",
     "experiments: unknown 'nosuch'; registered: "),
    ("reproduce-device-gpu", ["reproduce", "--device", "gpu"], "drlab reproduce: ",
     "--device: expected 'cpu', 'cuda' or 'cuda:N', got 'gpu'"),
    ("dataset-no-out", ["dataset", "--scene", "spheres"], "drlab dataset: ", "required: --out"),
    ("dataset-no-scene", ["dataset", "--out", "d"], "drlab dataset: ", "required: --scene"),
    ("dataset-out-empty", ["dataset", "--scene", "spheres", "--out", ""], "drlab dataset: ",
     "--out: expected a directory path, got ''"),
    ("dataset-views-text", ["dataset", "--scene", "spheres", "--out", "d", "--views", "x"], "drlab dataset: ",
     "--views: invalid int value: 'x'"),
    ("dataset-baseline-text", ["dataset", "--scene", "spheres", "--out", "d", "--baseline", "far"],
     "drlab dataset: ", "--baseline: invalid float value: 'far'"),
    ("dataset-resume-with-value", ["dataset", "--scene", "spheres", "--out", "d", "--resume=yes"],
     "drlab dataset: ", "--resume: ignored explicit argument 'yes'"),
]


@pytest.mark.parametrize("argv, start, fragment", [c[1:] for c in CLI_CASES], ids=[c[0] for c in CLI_CASES])
def test_cli_bad_input_is_one_line_and_exit_2(argv, start, fragment, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 2
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1, err
    assert err[0].startswith(start) and fragment in err[0], err[0]
    assert list(tmp_path.iterdir()) == []  # nothing created


# Dataset values the generator's configuration refuses: named, and refused before any file exists.
# (The exact wording belongs to research.datasets; the line must name the option, as a regex here.)
DATASET_VALUE_CASES = [
    ("views-0", ["--views", "0"], "views"),
    ("views-2", ["--views", "2"], "views"),
    ("res-0", ["--res", "0"], "res"),
    ("spp-negative", ["--spp", "-1"], "spp"),
    ("flow-frames-1", ["--flow", "--flow-frames", "1"], "flow[-_]frames"),
    ("baseline-negative", ["--stereo", "--baseline", "-0.5"], "baseline"),
]


@pytest.mark.parametrize("extra, name", [c[1:] for c in DATASET_VALUE_CASES], ids=[c[0] for c in DATASET_VALUE_CASES])
def test_dataset_bad_value_is_one_line_before_any_file(extra, name, capsys, tmp_path):
    out = tmp_path / "ds"
    assert cli.main(["dataset", "--scene", "spheres", "--out", str(out), *extra]) == 2
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and err[0].startswith("drlab dataset: ") and re.search(name, err[0]), err
    assert list(tmp_path.iterdir()) == []


@no_gpu
@pytest.mark.parametrize("argv", [["run", "kalman_tracking", "--device", "cuda"],
                                  ["run", "volume_render_spheres", "--device", "cuda:0"],
                                  ["reproduce", "--device", "cuda"],
                                  ["bench", "--device", "cuda"], ["gradcheck", "selftest", "--device", "cuda"]],
                         ids=["run-kalman-cuda", "run-volume-cuda0", "reproduce-cuda", "bench-cuda", "gradcheck-cuda"])
def test_cuda_without_gpu_is_one_line_before_any_work(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ran = []
    monkeypatch.setattr(cli, "_run_one", lambda *a: ran.append(a) or 0)
    assert cli.main(argv) == 2
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and "Warp sees no CUDA device on this machine; use --device cpu" in err[0], err
    assert ran == [] and list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- the experiment contract


def _dummy(body=None, warp=False) -> experiment.Experiment:
    def write(ctx):
        ctx.write_results(config={"k": 1}, metrics={"m": 1.0}, table_md="| m |\n")

    return experiment.Experiment("dummy", "a test experiment", body or write, sizes="-", warp=warp)


def _write_run(folder: Path, tag: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "metrics.json").write_text(json.dumps({"run": tag}))
    (folder / "table.md").write_text(f"| {tag} |\n")


EXPERIMENT_CASES = [
    ("device-tpu", ["--device", "tpu"], "--device: expected 'cpu', 'cuda' or 'cuda:N', got 'tpu'"),
    ("seed-negative", ["--seed", "-1"], "--seed: expected an integer in [0, 2^32), got '-1'"),
    ("seed-huge", ["--seed", str(2**40)], "--seed: expected an integer in [0, 2^32)"),
    ("out-empty", ["--out", ""], "--out: expected a directory path, got ''"),
    ("data-empty", ["--data", ""], "--data: expected a directory path, got ''"),
    ("quick-and-smoke", ["--quick", "--smoke"], "--smoke: not allowed with argument --quick"),
    ("unknown-option", ["--trials", "3"], "unrecognized arguments: --trials 3"),
    ("out-is-a-file", ["--out", "{file}"], "--out: expected a folder, but"),
    ("out-is-not-results", ["--out", "{home}"], "neither empty nor an experiment's results folder"),
]


@pytest.mark.parametrize("argv, fragment", [c[1:] for c in EXPERIMENT_CASES], ids=[c[0] for c in EXPERIMENT_CASES])
def test_experiment_bad_option_is_one_line_and_exit_2(argv, fragment, capsys, tmp_path, monkeypatch):
    monkeypatch.delenv("DRLAB_PROG", raising=False)
    (tmp_path / "file").write_text("x")
    (tmp_path / "home").mkdir()
    (tmp_path / "home" / "thesis.txt").write_text("mine")
    argv = [a.format(file=tmp_path / "file", home=tmp_path / "home") for a in argv]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "res")]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    assert _dummy().main(argv) == 2
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and err[0].startswith("python -m experiments.dummy: ") and fragment in err[0], err
    assert sorted(p.name for p in tmp_path.rglob("*")) == before
    assert (tmp_path / "home" / "thesis.txt").read_text() == "mine"


BODY_ERRORS = [
    ("value-error", ValueError("--data: no dataset at /x (run drlab dataset first)"),
     "--data: no dataset at /x (run drlab dataset first)"),
    ("file-not-found", FileNotFoundError(2, "No such file or directory", "/x/manifest.json"),
     "/x/manifest.json: no such file or directory"),
    ("permission", PermissionError(13, "Permission denied", "/ro/out"), "/ro/out: permission denied"),
    ("not-a-directory", NotADirectoryError(20, "Not a directory", "/x/file/y"), "/x/file/y: not a directory"),
    ("file-exists", FileExistsError(17, "File exists", "/x/d"), "/x/d: file exists"),
    ("multi-line-message", ValueError("first\n  second"), "first second"),
]


@pytest.mark.parametrize("exc, line", [c[1:] for c in BODY_ERRORS], ids=[c[0] for c in BODY_ERRORS])
def test_user_error_in_a_body_is_one_line_and_keeps_the_previous_results(exc, line, capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("DRLAB_PROG", "drlab run dummy")
    out = tmp_path / "res"
    _write_run(out, "first")

    def body(ctx):
        (ctx.out / "figure.png").write_bytes(b"half")
        raise exc

    assert _dummy(body).main(["--out", str(out)]) == 2
    assert _lines(capsys.readouterr().err) == [f"drlab run dummy: {line}"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]
    assert json.loads((out / "metrics.json").read_text()) == {"run": "first"}


# --------------------------------------------------------------------------- faults, in process


def test_keyboard_interrupt_in_a_body_exits_130_and_leaves_the_folder_as_it_was(capsys, tmp_path):
    out = tmp_path / "res"
    _write_run(out, "first")

    def body(ctx):
        (ctx.out / "metrics.json").write_text("{}")
        raise KeyboardInterrupt

    assert _dummy(body).main(["--out", str(out)]) == 130
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and "interrupted (Ctrl-C)" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]
    assert json.loads((out / "metrics.json").read_text()) == {"run": "first"}


def test_ctrl_c_between_the_two_renames_is_held_until_the_new_folder_is_in_place(capsys, tmp_path, monkeypatch):
    import signal as _signal

    out = tmp_path / "res"
    _write_run(out, "first")
    real_replace, calls = os.replace, []

    def replace_then_ctrl_c(src, dst):
        real_replace(src, dst)
        if Path(dst).parent != tmp_path:  # a file written inside the run's folder
            return
        calls.append(dst)
        if len(calls) == 1:  # the old folder is aside, the new one not yet in: the worst moment
            os.kill(os.getpid(), _signal.SIGINT)
            sum(range(10000))  # bytecode runs here, where an undeferred KeyboardInterrupt would be raised

    monkeypatch.setattr(os, "replace", replace_then_ctrl_c)
    assert _dummy().main(["--out", str(out)]) == 130
    monkeypatch.undo()
    assert len(calls) == 2
    assert json.loads((out / "metrics.json").read_text())["experiment"] == "dummy"  # the new run, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]
    assert len(_lines(capsys.readouterr().err)) == 1


def test_ctrl_c_re_raised_by_a_library_as_another_exception_still_exits_130(capsys, tmp_path):
    """Mitsuba's render (through Dr.Jit) turns Ctrl-C into a RuntimeError whose cause is the KeyboardInterrupt."""

    def body(ctx):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise RuntimeError("drjit.custom(...): error while performing a custom operation") from e

    assert _dummy(body).main(["--out", str(tmp_path / "res")]) == 130
    assert len(_lines(capsys.readouterr().err)) == 1
    assert list(tmp_path.iterdir()) == []


def test_keyboard_interrupt_in_a_command_exits_130_with_one_line(capsys, monkeypatch):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_cmd_list", interrupted)
    assert cli.main(["list"]) == 130
    assert _lines(capsys.readouterr().err) == ["drlab list: interrupted (Ctrl-C)"]


def test_debug_shows_the_exception_instead_of_one_line(tmp_path):
    with pytest.raises(ValueError, match="--device: expected 'cpu'"):
        cli.main(["--debug", "run", "kalman_tracking", "--device", "tpu"])
    with pytest.raises(ValueError, match="kernels: no gradient check matches"):
        cli.main(["gradcheck", "nosuch", "--debug"])  # accepted after the command too

    def body(ctx):
        raise FileNotFoundError(2, "No such file or directory", "/x")

    with pytest.raises(FileNotFoundError):
        _dummy(body).main(["--out", str(tmp_path / "res"), "--debug"])
    assert not (tmp_path / "res").exists()


def test_a_bug_is_not_turned_into_a_usage_error(tmp_path):
    """Only user mistakes become one line; an unexpected exception keeps its traceback."""

    def body(ctx):
        raise ZeroDivisionError("a bug")

    with pytest.raises(ZeroDivisionError):
        _dummy(body).main(["--out", str(tmp_path / "res")])


def test_stale_temporary_folders_of_dead_runs_are_swept_at_start(tmp_path):
    out = tmp_path / "res"
    _write_run(out, "first")
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / f"res.partial-{dead.pid}").mkdir()
    (tmp_path / f"res.partial-{dead.pid}" / "figure.png").write_bytes(b"")
    assert _dummy().main(["--out", str(out), "--no-progress"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]
    assert json.loads((out / "metrics.json").read_text())["experiment"] == "dummy"


@no_gpu
@pytest.mark.parametrize("name", sorted(EXPERIMENTS))
def test_every_experiment_refuses_cuda_without_a_gpu_before_any_work(name, capsys, tmp_path, monkeypatch):
    import importlib

    monkeypatch.delenv("DRLAB_PROG", raising=False)
    module = importlib.import_module(EXPERIMENTS[name].module)
    assert module.main(["--device", "cuda", "--smoke", "--out", str(tmp_path / "res")]) == 2
    err = _lines(capsys.readouterr().err)
    assert err == [f"python -m experiments.{name}: --device cuda: Warp sees no CUDA device on this machine; "
                   "use --device cpu"], err
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- faults, subprocesses


def test_no_cuda_driver_warning_on_a_cpu_only_machine():
    code = "from research.warp_runtime import init_warp; init_warp(); import warp as wp; wp.zeros(3)"
    r = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "CUDA driver" not in r.stderr and "CUDA driver" not in r.stdout
    if not _cuda_available():  # the check can fail: plain wp.init() prints the line on this machine
        plain = subprocess.run([sys.executable, "-c", "import warp as wp; wp.config.quiet = True; wp.init()"],
                               env=_env(), capture_output=True, text=True, timeout=120)
        if "Could not find or load the NVIDIA CUDA driver" not in plain.stderr:
            pytest.skip("this Warp build finds a CUDA driver library: nothing to filter here")


def _wait_for(predicate, proc: subprocess.Popen, timeout: float) -> None:
    t0 = time.monotonic()
    while not predicate():
        if proc.poll() is not None:
            raise AssertionError(f"the process ended first (exit {proc.returncode}): {proc.communicate()}")
        if time.monotonic() - t0 > timeout:
            proc.kill()
            raise AssertionError("timed out waiting for the run to start")
        time.sleep(0.05)


def test_ctrl_c_during_drlab_run_exits_130_with_one_line_and_nothing_half_written(tmp_path):
    out = tmp_path / "res"
    proc = subprocess.Popen([sys.executable, "-m", "research.cli", "run", "volume_render_spheres", "--smoke",
                             "--out", str(out), "--", "--no-progress"], cwd=REPO_ROOT, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    _wait_for(lambda: any(p.name.startswith("res.partial-") for p in tmp_path.iterdir()), proc, 120)
    time.sleep(0.3)
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C does: the whole foreground group
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stdout + stderr
    err = _lines(stderr)
    assert err == ["drlab run volume_render_spheres: interrupted (Ctrl-C); no half-written results were kept"], stderr
    assert list(tmp_path.iterdir()) == []  # no results folder, no temporary one


def test_ctrl_c_during_drlab_dataset_exits_130_and_resume_finishes_it(tmp_path):
    out = tmp_path / "ds"
    args = [sys.executable, "-m", "research.cli", "dataset", "--scene", "spheres", "--views", "40", "--res", "48",
            "--spp", "8", "--out", str(out)]
    proc = subprocess.Popen(args, cwd=REPO_ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    _wait_for(lambda: (tmp_path / "ds.partial" / "train").exists(), proc, 120)
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stdout + stderr
    assert "Traceback" not in stderr
    assert [line for line in _lines(stderr) if line.startswith("drlab dataset:")] == \
        ["drlab dataset: interrupted (Ctrl-C)"], stderr
    assert not out.exists()  # nothing half-written in place
    r = subprocess.run(args + ["--resume"], cwd=REPO_ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert all((out / f).is_file() for f in manifest["files"])
    # Only the dataset and its lock file (kept on purpose: removing a lock file races with a waiter).
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "ds.lock"]


@pytest.mark.parametrize("point", [0, 1, 2])
def test_sigkill_at_a_random_point_then_a_rerun_recovers_without_mixing_runs(point, tmp_path):
    """SIGKILL kalman_tracking --smoke at a seeded random moment; the previous folder survives whole, and
    the next run replaces it whole and sweeps what the killed one left."""
    out = tmp_path / "res"
    _write_run(out, "previous")
    args = [sys.executable, "-m", "experiments.kalman_tracking", "--smoke", "--no-progress", "--out", str(out)]
    delay = random.Random(1000 + point).uniform(0.0, 1.5)
    proc = subprocess.Popen(args, cwd=REPO_ROOT, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _wait_for(lambda: any(p.name.startswith("res.partial-") for p in tmp_path.iterdir()), proc, 120)
    time.sleep(delay)
    proc.kill()
    proc.wait()
    files = sorted(p.name for p in out.iterdir())
    doc = json.loads((out / "metrics.json").read_text())
    if doc.get("run") == "previous":  # killed before the swap: exactly the old folder
        assert files == ["metrics.json", "table.md"]
    else:  # finished before the kill: exactly the new one
        assert doc["experiment"] == "kalman_tracking"
    r = subprocess.run(args, cwd=REPO_ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["experiment"] == "kalman_tracking" and "run" not in doc
    assert (out / "table.md").read_text() != "| previous |\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]  # no .partial-/.old- left


def test_debug_through_drlab_run_reaches_the_experiment(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    (home / "notes.txt").write_text("mine")
    r = subprocess.run([sys.executable, "-m", "research.cli", "--debug", "run", "kalman_tracking",
                        "--out", str(home), "--", "--smoke"], cwd=REPO_ROOT, env=_env(), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 1 and "Traceback (most recent call last)" in r.stderr
    assert "ValueError: --out:" in r.stderr
    assert (home / "notes.txt").read_text() == "mine"
