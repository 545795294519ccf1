"""Reliability of `drlab sweep`: bad sweep files and options.

Each case is a sweep file (or command line) and the one line `drlab sweep` must print to stderr,
with exit status 2, before any run starts and before any results folder is created. A TOML syntax
error names the file and the line. Also the --ray options of `drlab reproduce` and `drlab dataset`. Faults of real runs (a killed Ray worker, Ctrl-C and resume, a
failing run) are in test_sweep.py.
"""

from __future__ import annotations

import pytest

from research import cli

GOOD = """
[sweep]
experiment = "kalman_tracking"
seeds = [0, 1]
options = ["--smoke"]
[grid]
"--trials" = [5, 8]
[table]
metrics = ["trials"]
"""

# (id, spec text, expected fragment of the one line after "drlab sweep: <file>: ")
SPEC_CASES = [
    ("toml-syntax", "[sweep\nexperiment = 1\n", "not valid TOML: "),
    ("unknown-section", GOOD + "[extra]\nx = 1\n", "[extra]: expected only the sections"),
    ("no-sweep-section", '[grid]\n"--trials" = [5]\n', "[sweep]: missing; it names at least the experiment"),
    ("sweep-not-table", 'sweep = 3\n', "[sweep]: expected a table, got 3"),
    ("unknown-sweep-key", GOOD.replace("seeds =", "sedes ="), "[sweep] sedes: expected one of"),
    ("unknown-experiment", GOOD.replace("kalman_tracking", "nope"), "[sweep] experiment: expected a registered experiment"),
    ("experiment-missing", GOOD.replace('experiment = "kalman_tracking"\n', ""),
     "[sweep] experiment: expected a registered experiment"),
    ("name-with-slash", GOOD.replace("[sweep]\n", '[sweep]\nname = "a/b"\n'), "[sweep] name: expected a folder name"),
    ("name-dotdot", GOOD.replace("[sweep]\n", '[sweep]\nname = ".."\n'), "[sweep] name: expected a folder name"),
    ("seeds-empty", GOOD.replace("seeds = [0, 1]", "seeds = []"), "[sweep] seeds: expected a non-empty list"),
    ("seeds-negative", GOOD.replace("seeds = [0, 1]", "seeds = [-1]"), "[sweep] seeds: expected a non-empty list"),
    ("seeds-repeated", GOOD.replace("seeds = [0, 1]", "seeds = [1, 1]"), "distinct integers"),
    ("seeds-float", GOOD.replace("seeds = [0, 1]", "seeds = [0.5]"), "[sweep] seeds: expected"),
    ("device-tpu", GOOD.replace("[sweep]\n", '[sweep]\ndevice = "tpu"\n'), "[sweep] device: expected 'cpu', 'cuda'"),
    ("options-not-list", GOOD.replace('options = ["--smoke"]', 'options = "--smoke"'), "[sweep] options: expected a list"),
    ("options-out", GOOD.replace('options = ["--smoke"]', 'options = ["--out", "x"]'),
     "[sweep] options: expected no --device, --no-progress, --out, --seed (the sweep sets them), got '--out'"),
    ("grid-seed", GOOD.replace('"--trials" = [5, 8]', '"--seed" = [1, 2]'),
     "[grid] '--seed': expected not --seed (use [sweep] seeds)"),
    ("grid-not-option", GOOD.replace('"--trials" = [5, 8]', 'trials = [5, 8]'),
     "[grid] 'trials': expected an option name starting with --"),
    ("grid-scalar", GOOD.replace('"--trials" = [5, 8]', '"--trials" = 5'),
     "[grid] '--trials': expected a non-empty list of values, got 5"),
    ("grid-empty-list", GOOD.replace('"--trials" = [5, 8]', '"--trials" = []'),
     "[grid] '--trials': expected a non-empty list of values"),
    ("grid-table-value", GOOD.replace('"--trials" = [5, 8]', '"--trials" = [{a = 1}]'),
     "[grid] '--trials': expected strings, numbers, booleans or lists of them"),
    ("grid-repeats-fixed", GOOD.replace('"--trials" = [5, 8]', '"--smoke" = [true, false]'),
     "[grid] '--smoke': expected an option not already in [sweep] options"),
    ("list-and-grid", GOOD + '[[list]]\n"--trials" = 3\n', "[[list]] '--trials': expected an option not also in [grid]"),
    ("duplicate-config", GOOD.replace('"--trials" = [5, 8]', '"--trials" = [5, 5]'),
     "[grid] and [[list]] give the same configuration twice"),
    ("resources-cpus-negative", GOOD + "[resources]\ncpus = -1\n", "[resources] cpus: expected a number >= 0, got -1"),
    ("resources-retries-unbounded", GOOD + "[resources]\nmax_retries = 50\n",
     "[resources] max_retries: expected an integer in [0, 10] (bounded retries), got 50"),
    ("resources-retries-float", GOOD + "[resources]\nmax_retries = 1.5\n",
     "[resources] max_retries: expected an integer >= 0, got 1.5"),
    ("resources-timeout-zero", GOOD + "[resources]\ntimeout_s = 0\n", "[resources] timeout_s: expected a number >= 1"),
    ("resources-unknown", GOOD + "[resources]\nmemory = 3\n", "[resources] memory: expected one of"),
    ("table-no-metrics", GOOD.replace('metrics = ["trials"]', ""), "[table] metrics: expected a non-empty list"),
    ("table-group-unknown", GOOD.replace("[table]\n", '[table]\ngroup_by = ["--nope"]\n'),
     "[table] group_by: expected a list of options the sweep sets"),
    ("table-figure-unknown", GOOD.replace("[table]\n", '[table]\nfigure = "x"\n'),
     "[table] figure: expected one of [table] metrics, got 'x'"),
    ("table-rows-empty", GOOD.replace("[table]\n", '[table]\nrows = ""\n'), "[table] rows: expected a dotted path"),
]


def _run(argv: list[str], capsys) -> tuple[int, list[str]]:
    rc = cli.main(argv)
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    return rc, err


@pytest.mark.parametrize("text,expected", [c[1:] for c in SPEC_CASES], ids=[c[0] for c in SPEC_CASES])
def test_bad_sweep_file_is_one_line_before_any_run(tmp_path, capsys, text, expected):
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    results = tmp_path / "results"
    rc, err = _run(["sweep", str(spec), "--results", str(results)], capsys)
    assert rc == cli.EXIT_USAGE
    assert len(err) == 1, err
    assert err[0].startswith(f"drlab sweep: {spec}: "), err[0]
    assert expected in err[0], err[0]
    assert not results.exists()


def test_toml_syntax_error_names_the_line(tmp_path, capsys):
    spec = tmp_path / "bad.toml"
    spec.write_text(GOOD + "\n[table\n")
    rc, err = _run(["sweep", str(spec), "--results", str(tmp_path / "r")], capsys)
    assert rc == cli.EXIT_USAGE and len(err) == 1
    assert f"line {len((GOOD + chr(10)).splitlines()) + 1}" in err[0], err[0]


# (id, argv after `sweep`, with {spec} and {tmp}; expected fragment)
ARGV_CASES = [
    ("missing-spec-file", ["{tmp}/none.toml"], "drlab sweep: {tmp}/none.toml: no such sweep file"),
    ("spec-is-folder", ["{tmp}"], "drlab sweep: {tmp}: expected a sweep file (TOML), got a folder"),
    ("jobs-zero", ["{spec}", "--jobs", "0"], "drlab sweep: --jobs: expected an integer >= 1, got '0'"),
    ("jobs-word", ["{spec}", "--jobs", "two"], "drlab sweep: --jobs: expected an integer >= 1, got 'two'"),
    ("ray-address-blank", ["{spec}", "--ray-address", " "],
     "drlab sweep: --ray-address: expected host:port, ray://host:port or auto, got ' '"),
    ("results-blank", ["{spec}", "--results", " "], "drlab sweep: --results: expected a directory path, got ' '"),
    ("sweep-folder-is-file", ["{spec}", "--results", "{tmp}/res"],
     "drlab sweep: --results: {tmp}/res/good is a file, expected the sweep's folder"),
    ("extra-after-dashdash", ["{spec}", "--", "--trials", "3"], "drlab sweep: options after `--` are only for `drlab run`: --trials 3"),
]


@pytest.mark.parametrize("argv,expected", [c[1:] for c in ARGV_CASES], ids=[c[0] for c in ARGV_CASES])
def test_bad_sweep_command_line_is_one_line(tmp_path, capsys, argv, expected):
    spec = tmp_path / "good.toml"
    spec.write_text(GOOD)
    (tmp_path / "res").mkdir()
    (tmp_path / "res" / "good").write_text("not a folder")
    fill = {"spec": str(spec), "tmp": str(tmp_path)}
    rc, err = _run(["sweep", *[a.format(**fill) for a in argv]], capsys)
    assert rc == cli.EXIT_USAGE
    assert len(err) == 1, err
    assert expected.format(**fill) in err[0], err[0]
    assert sorted(p.name for p in (tmp_path / "res").iterdir()) == ["good"]  # nothing created


# --ray-address of the other commands that run on Ray: (id, argv with {tmp}, expected one line)
OTHER_RAY_CASES = [
    ("reproduce-ray-address-blank", ["reproduce", "--ray-address", ""],
     "drlab reproduce: --ray-address: expected host:port, ray://host:port or auto, got ''"),
    ("dataset-ray-address-space", ["dataset", "--scene", "spheres", "--out", "{tmp}/ds", "--ray-address", "a b"],
     "drlab dataset: --ray-address: expected host:port, ray://host:port or auto, got 'a b'"),
    ("dataset-ray-bad-views", ["dataset", "--scene", "spheres", "--views", "0", "--out", "{tmp}/ds", "--ray"],
     "drlab dataset: --views"),
]


@pytest.mark.parametrize("argv,expected", [c[1:] for c in OTHER_RAY_CASES], ids=[c[0] for c in OTHER_RAY_CASES])
def test_bad_ray_options_of_reproduce_and_dataset(tmp_path, capsys, argv, expected):
    rc, err = _run([a.format(tmp=tmp_path) for a in argv], capsys)
    assert rc == cli.EXIT_USAGE
    assert len(err) == 1, err
    assert err[0].startswith(expected.format(tmp=tmp_path)), err[0]
    assert list(tmp_path.iterdir()) == []  # no dataset folder, no lock, no Ray started


# (id, argv with {spec} and {tmp}, the command's prefix): Ray missing is refused before any work
NO_RAY_CASES = [
    ("sweep-ray", ["sweep", "{spec}", "--ray", "--results", "{tmp}/res2"], "drlab sweep: "),
    ("sweep-ray-address", ["sweep", "{spec}", "--ray-address", "10.0.0.1:6379", "--results", "{tmp}/res2"],
     "drlab sweep: "),
    ("reproduce-ray", ["reproduce", "--ray"], "drlab reproduce: "),
    ("dataset-ray", ["dataset", "--scene", "spheres", "--out", "{tmp}/ds", "--ray"], "drlab dataset: "),
]


@pytest.mark.parametrize("argv,prefix", [c[1:] for c in NO_RAY_CASES], ids=[c[0] for c in NO_RAY_CASES])
def test_ray_not_installed_is_one_line(tmp_path, capsys, monkeypatch, argv, prefix):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a))
    spec = tmp_path / "good.toml"
    spec.write_text(GOOD)
    rc, err = _run([a.format(spec=spec, tmp=tmp_path) for a in argv], capsys)
    assert rc == cli.EXIT_USAGE
    assert err == [f"{prefix}--ray: Ray is not installed; pip install 'drlab[cluster]' (or ray>=2.9)"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.toml"]
