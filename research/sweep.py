"""Sweeps: a grid of runs of one experiment, run locally or as Ray tasks, gathered into one table.

    drlab sweep SPEC [--jobs N] [--ray [--ray-address ADDRESS]] [--results DIR]

A sweep file (TOML) names an experiment, the options every run gets, a grid and/or a list of option
values, the seeds, the resources of one run, and how to gather the table:

    [sweep]
    name = "kalman-q"                 # results/<name>/ (default: the file's stem)
    experiment = "kalman_tracking"
    seeds = [0, 1, 2]                 # every configuration runs once per seed (default [0])
    device = "cpu"                    # --device of every run (default cpu)
    options = ["--smoke"]             # argv words every run gets

    [grid]                            # every combination of these values
    "--trials" = [20, 40]

    [[list]]                          # explicit points, each crossed with the grid and the seeds
    "--tune-trials" = 5

    [resources]                       # of one run
    cpus = 1                          # Ray: CPUs the task reserves (and --jobs sizes a local instance)
    gpus = 0                          # Ray: GPUs the task reserves (pass --device cuda in [sweep] too)
    max_retries = 2                   # Ray: retries of a task whose worker process died
    timeout_s = 3600                  # a run still going after this is killed and counted as failed

    [table]
    group_by = ["--trials"]           # options that key the rows (default: every option that varies)
    rows = "methods"                  # optional: a dict in metrics.json whose keys become rows too
    metrics = ["filter_rmse.mean"]    # dotted paths into metrics.json's "metrics" (under each row item)
    figure = "filter_rmse.mean"       # the metric drawn in figure.png (default: the first)

Option values: `true` is a flag, `false` leaves it out, a list is several words (`nargs="+"`),
anything else is one word; `{seed}` in a value (or in an [sweep] options word) becomes the run's seed.
`--out`, `--seed`, `--device` and `--no-progress` belong to the sweep. `--data` works as in `drlab
run` (a relative path is taken from the current directory, which every run keeps); an experiment that
renders its data into --data from its seed (stereo_depth, raft_flow) should get one folder per seed,
e.g. `options = ["--data", "data/sweeps/seed{seed}"]`, so that concurrent runs never share a cache
that depends on the seed. On a cluster --data must be a path every node sees (README).
`drlab sweep SPEC --smoke` runs the same sweep at smoke sizes into `<name>-smoke`.

Runs. Each run is `python -m experiments.<name> --out <results>/<sweep>/<run-key> --seed S ...`, the
experiment contract (research.experiment) with its atomic folder swap, so a half-finished run never
leaves a folder that looks finished. The run key is the first 16 hex digits of the SHA-256 of the
run's full configuration (experiment, device, seed and every option, as written in the spec). After a
run exits 0, `sweep-run.json` (key, configuration) is written into its folder; a run counts as
complete when its metrics.json names the experiment and seed and its sweep-run.json names its key.
Started again, a sweep skips complete runs and redoes all others (missing, half-written, failed).

Faults. A run that exits non-zero (or times out) is recorded as failed with the last line it printed,
in the table and in runs.json, and the sweep goes on. Under Ray, a task whose worker process dies is
retried up to `max_retries` times (Ray's own retries); the experiment process dies with its worker
(Linux: PR_SET_PDEATHSIG), so a retry never races an orphan. Each run's output goes to
`<sweep>/logs/<run-key>.log` (one header line per attempt).

Gathered at `<results>/<sweep>/`: table.md and table.json (mean ± std over seeds per group; no
timings, so the local and the Ray executor write identical files), figure.png and runs.json (every
run: key, configuration, status, error, wall time, host).

Exit status of `drlab sweep`: 0 when every run succeeded, else the number of failed runs (at most
100), after a last line `drlab sweep: N of M runs failed` on stderr. A bad spec is a usage error
(status 2, one line naming the file) before any run starts.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

RUN_FILE = "sweep-run.json"
KEY_DIGITS = 16
_RESERVED = {"--out", "--seed", "--device", "--no-progress"}
_SPEC_SECTIONS = {"sweep", "grid", "list", "resources", "table"}


# --------------------------------------------------------------------------- the spec


@dataclass(frozen=True)
class Run:
    """One run of a sweep: the experiment, its device, seed and options (argv words), and its key."""

    experiment: str
    device: str
    seed: int
    options: tuple[tuple[str, Any], ...]  # (option, value as in the spec), in spec order

    def config(self) -> dict[str, Any]:
        return {"experiment": self.experiment, "device": self.device, "seed": self.seed,
                "options": {k: v for k, v in self.options}}

    @property
    def key(self) -> str:
        blob = json.dumps(self.config(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()[:KEY_DIGITS]

    def argv(self) -> list[str]:
        """The experiment's options (without --out, --seed, --device); `{seed}` in a value is the run's seed."""
        words: list[str] = []
        for name, value in self.options:
            if value is True:
                words.append(name)
            elif value is False:
                continue
            elif isinstance(value, list):
                words += [name, *(self._word(v) for v in value)]
            else:
                words += [name, self._word(value)]
        return words

    def _word(self, value: Any) -> str:
        return _word(value).replace("{seed}", str(self.seed))


def _word(value: Any) -> str:
    return repr(value) if isinstance(value, float) else str(value)


@dataclass
class Spec:
    path: Path
    name: str
    experiment: str
    seeds: list[int]
    device: str
    fixed: list[str]  # argv words every run gets
    points: list[dict[str, Any]]  # option dicts (grid x list), without seeds
    cpus: float = 1.0
    gpus: float = 0.0
    max_retries: int = 2
    timeout_s: float = 3600.0
    group_by: list[str] = field(default_factory=list)
    rows: str | None = None
    metrics: list[str] = field(default_factory=list)
    figure: str | None = None

    def smoke_variant(self) -> "Spec":
        """The same sweep at smoke sizes: --smoke for every run (instead of --quick), into `<name>-smoke`."""
        from dataclasses import replace

        fixed = [w for w in self.fixed if w not in ("--quick", "--smoke")]
        return replace(self, name=f"{self.name}-smoke", fixed=["--smoke", *fixed])

    def runs(self) -> list[Run]:
        fixed = tuple(_fixed_options(self.fixed))
        out = []
        for point in self.points:
            for seed in self.seeds:
                out.append(Run(self.experiment, self.device, seed, fixed + tuple(point.items())))
        return out


def _fixed_options(words: list[str]) -> list[tuple[str, Any]]:
    """["--smoke", "--trials", "5"] -> [("--smoke", True), ("--trials", "5")] (for the run key and table)."""
    out: list[tuple[str, Any]] = []
    i = 0
    while i < len(words):
        name, vals = words[i], []
        i += 1
        while i < len(words) and not words[i].startswith("--"):
            vals.append(words[i])
            i += 1
        out.append((name, True if not vals else vals[0] if len(vals) == 1 else vals))
    return out


def load_spec(path: str | Path) -> Spec:
    """Read and check a sweep file; ValueError (one line naming the file and the entry) when it is wrong."""
    from research.registry import EXPERIMENTS

    try:
        import tomllib
    except ImportError:  # Python 3.10
        raise ValueError("sweep files need Python 3.11 or newer (tomllib)") from None
    path = Path(path)
    where = str(path)
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise ValueError(f"{where}: no such sweep file") from None
    except IsADirectoryError:
        raise ValueError(f"{where}: expected a sweep file (TOML), got a folder") from None
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{where}: not valid TOML: {e}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{where}: not valid TOML: not UTF-8 text") from None

    def bad(entry: str, expected: str, got: Any) -> ValueError:
        return ValueError(f"{where}: {entry}: expected {expected}, got {got!r}")

    unknown = sorted(set(doc) - _SPEC_SECTIONS)
    if unknown:
        raise bad(f"[{unknown[0]}]", "only the sections " + ", ".join(f"[{s}]" for s in sorted(_SPEC_SECTIONS)),
                  unknown[0])
    for section in ("sweep", "grid", "resources", "table"):
        if section in doc and not isinstance(doc[section], dict):
            raise bad(f"[{section}]", "a table", doc[section])
    sw = doc.get("sweep")
    if sw is None:
        raise ValueError(f"{where}: [sweep]: missing; it names at least the experiment")
    allowed = {"name", "experiment", "seeds", "device", "options"}
    if set(sw) - allowed:
        k = sorted(set(sw) - allowed)[0]
        raise bad(f"[sweep] {k}", "one of " + ", ".join(sorted(allowed)), k)
    experiment = sw.get("experiment")
    if experiment not in EXPERIMENTS:
        raise bad("[sweep] experiment", "a registered experiment (" + ", ".join(sorted(EXPERIMENTS)) + ")", experiment)
    name = sw.get("name", path.stem)
    if not isinstance(name, str) or not name or not all(c.isalnum() or c in "-_." for c in name) or name[0] == ".":
        raise bad("[sweep] name", "a folder name (letters, digits, - _ .)", name)
    seeds = sw.get("seeds", [0])
    if (not isinstance(seeds, list) or not seeds or len(set(map(repr, seeds))) != len(seeds)
            or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**32 for s in seeds)):
        raise bad("[sweep] seeds", "a non-empty list of distinct integers in [0, 2^32)", seeds)
    device = sw.get("device", "cpu")
    if not isinstance(device, str) or not (device == "cpu" or device.startswith("cuda")):
        raise bad("[sweep] device", "'cpu', 'cuda' or 'cuda:N'", device)
    fixed = sw.get("options", [])
    if not isinstance(fixed, list) or not all(isinstance(w, str) and w for w in fixed) or (fixed and not fixed[0].startswith("--")):
        raise bad("[sweep] options", "a list of argv words starting with an option (e.g. [\"--smoke\"])", fixed)
    for w in fixed:
        if w.split("=")[0] in _RESERVED:
            raise bad("[sweep] options", "no " + ", ".join(sorted(_RESERVED)) + " (the sweep sets them)", w)

    def check_values(entry: str, table: Any, as_list: bool) -> dict[str, Any]:
        if not isinstance(table, dict):
            raise bad(entry, "a table of option = value", table)
        for opt, val in table.items():
            if not opt.startswith("--") or len(opt) < 3:
                raise bad(f"{entry} {opt!r}", "an option name starting with --", opt)
            if opt in _RESERVED:
                raise bad(f"{entry} {opt!r}", "not " + opt + (" (use [sweep] seeds)" if opt == "--seed" else
                                                                 " (use [sweep] device)" if opt == "--device" else
                                                                 " (the sweep sets it)"), opt)
            if opt in _fixed_names:
                raise bad(f"{entry} {opt!r}", "an option not already in [sweep] options", opt)
            vals = val if as_list else [val]
            if as_list and (not isinstance(val, list) or not val):
                raise bad(f"{entry} {opt!r}", "a non-empty list of values", val)
            for v in vals:
                if isinstance(v, dict) or (isinstance(v, list) and not all(isinstance(x, (str, int, float)) for x in v)):
                    raise bad(f"{entry} {opt!r}", "strings, numbers, booleans or lists of them", v)
        return table

    _fixed_names = {n for n, _ in _fixed_options(fixed)}
    grid = check_values("[grid]", doc.get("grid", {}), as_list=True)
    points_list = doc.get("list", [{}])
    if not isinstance(points_list, list) or not points_list:
        raise bad("[[list]]", "one or more tables of option = value", points_list)
    points_list = [check_values(f"[[list]] #{i + 1}", p, as_list=False) for i, p in enumerate(points_list)]
    points: list[dict[str, Any]] = []
    names = list(grid)
    for combo in itertools.product(*(grid[n] for n in names)):
        for extra in points_list:
            both = set(names) & set(extra)
            if both:
                raise bad(f"[[list]] {sorted(both)[0]!r}", "an option not also in [grid]", sorted(both)[0])
            points.append({**dict(zip(names, combo)), **extra})
    keys = [json.dumps(p, sort_keys=True) for p in points]
    if len(set(keys)) != len(keys):
        raise ValueError(f"{where}: [grid] and [[list]] give the same configuration twice: "
                         f"{next(k for k in keys if keys.count(k) > 1)}")

    res = doc.get("resources", {})
    allowed_res = {"cpus", "gpus", "max_retries", "timeout_s"}
    if set(res) - allowed_res:
        k = sorted(set(res) - allowed_res)[0]
        raise bad(f"[resources] {k}", "one of " + ", ".join(sorted(allowed_res)), k)

    def number(key: str, default: float, lo: float, integer: bool = False) -> Any:
        v = res.get(key, default)
        ok = isinstance(v, int) if integer else isinstance(v, (int, float))
        if isinstance(v, bool) or not ok or not math.isfinite(v) or v < lo:
            raise bad(f"[resources] {key}", f"{'an integer' if integer else 'a number'} >= {lo:g}", v)
        return v

    cpus = number("cpus", 1, 0)
    gpus = number("gpus", 0, 0)
    max_retries = number("max_retries", 2, 0, integer=True)
    if max_retries > 10:
        raise bad("[resources] max_retries", "an integer in [0, 10] (bounded retries)", max_retries)
    timeout_s = number("timeout_s", 3600, 1)

    table = doc.get("table", {})
    allowed_table = {"group_by", "rows", "metrics", "figure"}
    if set(table) - allowed_table:
        k = sorted(set(table) - allowed_table)[0]
        raise bad(f"[table] {k}", "one of " + ", ".join(sorted(allowed_table)), k)
    varying = [n for n in dict.fromkeys(k for p in points for k in p)
               if len({json.dumps(p.get(n)) for p in points}) > 1]
    group_by = table.get("group_by", varying)
    all_opts = set(_fixed_names) | {k for p in points for k in p}
    if not isinstance(group_by, list) or not all(isinstance(g, str) and g in all_opts for g in group_by):
        raise bad("[table] group_by", "a list of options the sweep sets (" + ", ".join(sorted(all_opts)) + ")", group_by)
    rows = table.get("rows")
    if rows is not None and (not isinstance(rows, str) or not rows):
        raise bad("[table] rows", "a dotted path into metrics.json's metrics", rows)
    metrics = table.get("metrics")
    if not isinstance(metrics, list) or not metrics or not all(isinstance(m, str) and m for m in metrics):
        raise bad("[table] metrics", "a non-empty list of dotted paths into metrics.json's metrics", metrics)
    figure = table.get("figure", metrics[0])
    if figure not in metrics:
        raise bad("[table] figure", "one of [table] metrics", figure)
    return Spec(path, name, experiment, seeds, device, fixed, points, cpus, gpus, max_retries, timeout_s,
                group_by, rows, metrics, figure)


# --------------------------------------------------------------------------- one run (both executors)


def _pdeathsig_hook() -> Callable[[], None] | None:
    """A preexec_fn that makes the experiment process get SIGTERM when the thread that started it dies
    (Linux PR_SET_PDEATHSIG), so a run never outlives its Ray worker. Everything it needs is resolved
    here, in the parent: between fork and exec the child only calls prctl (no import, no lock)."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes
    import signal

    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    args = (ctypes.c_int(1), ctypes.c_ulong(int(signal.SIGTERM)))  # PR_SET_PDEATHSIG

    def hook() -> None:  # pragma: no cover - runs in the child
        prctl(*args)

    return hook


def _stop(proc, grace_s: float = 30.0) -> int:
    """SIGTERM (the experiment deletes its temporary folder), then SIGKILL after `grace_s`; the exit status."""
    import subprocess

    proc.terminate()
    try:
        return proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def execute_run(job: dict[str, Any]) -> dict[str, Any]:
    """Run one experiment process for `job` (a plain dict, so it travels to Ray workers); its outcome.

    Used by the local executor and, unchanged, inside each Ray task. Only the standard library is
    imported here: the worker needs the experiment's code on PYTHONPATH (job["env"]), not the driver's.
    Returns {"key", "status": "ok"|"failed", "rc", "error", "wall_s", "host", "pid"}. job["seed"] None:
    the experiment's own default; job["record"] False: no sweep-run.json (drlab reproduce --ray).
    """
    import subprocess

    out, log = Path(job["out"]), Path(job["log"])
    log.parent.mkdir(parents=True, exist_ok=True)
    safe_path = ["-P"] if sys.version_info >= (3, 11) else []
    cmd = [sys.executable, *safe_path, "-m", f"experiments.{job['experiment']}", "--device", job["device"],
           "--out", str(out), *(["--seed", str(job["seed"])] if job["seed"] is not None else []),
           "--no-progress", *job["argv"]]
    env = {**os.environ, **job["env"]}
    env.pop("DRLAB_PROG", None)
    t0 = time.perf_counter()
    host = socket.gethostname()
    with open(log, "ab") as f:
        start = f.tell()
        f.write(f"== drlab sweep: run {job['key']} on {host}, worker pid {os.getpid()}, "
                f"{time.strftime('%Y-%m-%d %H:%M:%S')}: {' '.join(cmd[1:])}\n".encode())
        f.flush()
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                cwd=job["cwd"], env=env, preexec_fn=_pdeathsig_hook())
        try:
            rc = proc.wait(timeout=job["timeout_s"])
            timed_out = False
        except subprocess.TimeoutExpired:
            rc = _stop(proc)
            timed_out = True
        except BaseException:  # Ctrl-C, or Ray cancelling the task
            _stop(proc)
            raise
    wall = time.perf_counter() - t0
    result = {"key": job["key"], "rc": rc, "wall_s": wall, "host": host, "pid": os.getpid()}
    if rc == 0 and not timed_out:
        if not job.get("record", True):
            return {**result, "status": "ok", "error": ""}
        record = {"key": job["key"], "config": job["config"], "status": "ok"}
        tmp = out / f".{RUN_FILE}.tmp-{os.getpid()}"
        tmp.write_text(json.dumps(record, indent=2) + "\n")
        os.replace(tmp, out / RUN_FILE)
        return {**result, "status": "ok", "error": ""}
    if timed_out:
        error = f"timed out after {job['timeout_s']:g} s (stopped)"
    else:
        with open(log, "rb") as f:
            f.seek(start)
            lines = [ln.strip() for ln in f.read().decode(errors="replace").splitlines() if ln.strip()]
        lines = [ln for ln in lines[1:] if not ln.startswith("== drlab sweep:")]
        error = (lines[-1] if lines else "") or f"exit status {rc}"
        if rc < 0:
            error = f"killed by signal {-rc}" + (f"; last line: {lines[-1]}" if lines else "")
    return {**result, "status": "failed", "error": f"exit {rc}: {error}" if rc > 0 and not timed_out else error}


def is_complete(run: Run, folder: Path) -> bool:
    """Whether `folder` holds the finished results of `run` (metrics.json and sweep-run.json agree)."""
    try:
        doc = json.loads((folder / "metrics.json").read_text())
        record = json.loads((folder / RUN_FILE).read_text())
    except (OSError, ValueError):
        return False
    return (isinstance(doc, dict) and doc.get("experiment") == run.experiment and doc.get("seed") == run.seed
            and isinstance(doc.get("metrics"), dict) and isinstance(record, dict)
            and record.get("key") == run.key and record.get("status") == "ok")


# --------------------------------------------------------------------------- executors


Executor = Callable[[list[dict[str, Any]], Callable[[dict[str, Any]], None]], None]


def local_executor(jobs: int) -> Executor:
    """Runs in threads of this process, each waiting on one experiment process; `jobs` at a time."""

    def execute(todo: list[dict[str, Any]], done: Callable[[dict[str, Any]], None]) -> None:
        if jobs == 1:
            for job in todo:
                done(execute_run(job))
            return
        from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

        pool = ThreadPoolExecutor(max_workers=jobs)
        try:
            pending = {pool.submit(execute_run, job) for job in todo}
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in finished:
                    done(fut.result())
        finally:
            pool.shutdown(wait=True, cancel_futures=True)

    return execute


def _ray_task(job: dict[str, Any]) -> dict[str, Any]:
    return execute_run(job)


def require_ray() -> None:
    """ValueError naming --ray unless Ray can be imported (checked before any work)."""
    import importlib.util

    if importlib.util.find_spec("ray") is None:
        raise ValueError("--ray: Ray is not installed; pip install 'drlab[cluster]' (or ray>=2.9)")


@dataclass
class RayOptions:
    address: str | None = None  # join this cluster; None: start a local instance
    num_cpus: int | None = None  # CPUs of a local instance (None: all of this machine's)
    temp_dir: str | None = None  # Ray's session folder of a local instance (None: Ray's default)


def ray_session(opts: RayOptions):
    """Context manager: connect to `opts.address` or start a bounded local Ray instance; shut down after.

    A local instance has no dashboard and listens on the loopback address only. Already connected
    (ray.is_initialized(), e.g. by a test), it is used as it is and left running.
    """
    import contextlib

    @contextlib.contextmanager
    def session():
        try:
            import ray
        except ImportError:
            raise ValueError("--ray: Ray is not installed; pip install 'drlab[cluster]' (or ray>=2.9)") from None
        if ray.is_initialized():
            yield ray
            return
        if opts.address:
            ray.init(address=opts.address, log_to_driver=False, logging_level="ERROR")
        else:
            from research import registry

            # Workers of a local instance inherit this environment: they import this checkout's code.
            saved = os.environ.get("PYTHONPATH")
            if registry.in_checkout():
                os.environ["PYTHONPATH"] = os.pathsep.join([str(registry.REPO_ROOT)] + ([saved] if saved else []))
            try:
                ray.init(num_cpus=opts.num_cpus, include_dashboard=False, _node_ip_address="127.0.0.1",
                         log_to_driver=False, logging_level="ERROR", _temp_dir=opts.temp_dir,
                         configure_logging=True)
            finally:
                if saved is None:
                    os.environ.pop("PYTHONPATH", None)
                else:
                    os.environ["PYTHONPATH"] = saved
        try:
            yield ray
        finally:
            ray.shutdown()

    return session()


def ray_executor(opts: RayOptions, cpus: float, gpus: float, max_retries: int) -> Executor:
    """Each run is a Ray task running the same `execute_run`; a task whose worker died is retried."""

    def execute(todo: list[dict[str, Any]], done: Callable[[dict[str, Any]], None]) -> None:
        with ray_session(opts) as ray:
            remote = ray.remote(_ray_task).options(num_cpus=cpus, num_gpus=gpus, max_retries=max_retries,
                                                   retry_exceptions=False)
            refs = {remote.remote(job): job for job in todo}
            pending = list(refs)
            try:
                while pending:
                    finished, pending = ray.wait(pending, num_returns=1)
                    for ref in finished:
                        try:
                            done(ray.get(ref))
                        except Exception as e:  # the worker died more than max_retries times, or Ray failed
                            job = refs[ref]
                            done({"key": job["key"], "status": "failed", "rc": None, "wall_s": 0.0, "host": "",
                                  "pid": None, "error": f"Ray task failed after {max_retries} retries: "
                                                        f"{type(e).__name__}: {_first_line(e)}"})
            except BaseException:
                for ref in pending:
                    ray.cancel(ref, force=True)
                raise

    return execute


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else ""


def reproduce_jobs(names: list[str], results_dir: Path, quick: bool, device: str, log_dir: Path,
                   extra: list[str]) -> list[dict[str, Any]]:
    """`drlab reproduce --ray`: one job per registered experiment, into results_dir/<name> as a local
    reproduce writes it (no sweep-run.json), its output in log_dir/<name>.log."""
    from research.cli import _experiment_env

    env = _experiment_env()
    keep = {k: env[k] for k in ("PYTHONPATH",) if k in env}
    return [{"key": name, "experiment": name, "device": device, "seed": None,
             "argv": (["--quick"] if quick else []) + list(extra), "config": {"experiment": name, "quick": quick},
             "out": str(Path(results_dir).absolute() / name), "log": str(Path(log_dir).absolute() / f"{name}.log"),
             "cwd": os.getcwd(), "env": keep, "timeout_s": 24 * 3600.0, "record": False} for name in names]


# --------------------------------------------------------------------------- the sweep


def _job(spec: Spec, run: Run, sweep_dir: Path) -> dict[str, Any]:
    from research.cli import _experiment_env

    env = _experiment_env()
    keep = {k: env[k] for k in ("PYTHONPATH",) if k in env}
    return {"key": run.key, "experiment": run.experiment, "device": run.device, "seed": run.seed,
            "argv": run.argv(), "config": run.config(), "out": str(sweep_dir / run.key),
            "log": str(sweep_dir / "logs" / f"{run.key}.log"), "cwd": os.getcwd(), "env": keep,
            "timeout_s": float(spec.timeout_s)}


@dataclass
class SweepResult:
    sweep_dir: Path
    runs: list[Run]
    outcomes: dict[str, dict[str, Any]]  # key -> outcome (status "ok", "failed" or "skipped")
    table_md: Path
    figure: Path | None

    @property
    def failed(self) -> list[str]:
        return [k for k, o in self.outcomes.items() if o["status"] == "failed"]

    @property
    def executed(self) -> list[str]:
        return [k for k, o in self.outcomes.items() if o["status"] != "skipped"]


def run_sweep(spec: Spec, results_root: Path, executor: Executor, *, progress: bool = True,
              executor_name: str = "local") -> SweepResult:
    """Run every incomplete run of `spec` with `executor`, then gather the table and the figure."""
    from tqdm import tqdm

    from research import atomic

    sweep_dir = (Path(results_root) / spec.name).absolute()
    runs = spec.runs()
    sweep_dir.mkdir(parents=True, exist_ok=True)
    outcomes: dict[str, dict[str, Any]] = {}
    todo = []
    for run in runs:
        if is_complete(run, sweep_dir / run.key):
            outcomes[run.key] = {"key": run.key, "status": "skipped", "error": ""}
        else:
            todo.append(_job(spec, run, sweep_dir))
    failures = 0
    bar = tqdm(total=len(runs), initial=len(runs) - len(todo), desc=f"sweep {spec.name}", unit="run",
               disable=not progress, dynamic_ncols=True)
    bar.set_postfix(failed=0)

    def done(outcome: dict[str, Any]) -> None:
        nonlocal failures
        outcomes[outcome["key"]] = outcome
        if outcome["status"] == "failed":
            failures += 1
            bar.set_postfix(failed=failures)
            bar.write(f"drlab sweep: run {outcome['key']} failed: {outcome['error']} "
                      f"(log: {sweep_dir / 'logs' / (outcome['key'] + '.log')})")
        bar.update(1)

    try:
        if todo:
            executor(todo, done)
    finally:
        bar.close()
        _write_runs(sweep_dir, spec, runs, outcomes, executor_name, atomic)
    table_md, figure = gather(spec, sweep_dir, runs, outcomes)
    return SweepResult(sweep_dir, runs, outcomes, table_md, figure)


def _write_runs(sweep_dir: Path, spec: Spec, runs: list[Run], outcomes: dict[str, dict[str, Any]],
                executor_name: str, atomic) -> None:
    rows = []
    for run in runs:
        o = outcomes.get(run.key, {"status": "not run", "error": "the sweep stopped before this run"})
        rows.append({"key": run.key, **run.config(), "status": o["status"], "error": o.get("error", ""),
                     "rc": o.get("rc"), "wall_s": o.get("wall_s"), "host": o.get("host")})
    atomic.write_json(sweep_dir / "runs.json", {"sweep": spec.name, "spec": str(spec.path),
                                                 "executor": executor_name, "runs": rows})


def _lookup(doc: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        if not isinstance(doc, dict) or part not in doc:
            return None
        doc = doc[part]
    return doc


def _fmt_value(v: Any) -> str:
    if isinstance(v, list):
        return " ".join(_fmt_value(x) for x in v)
    if v is True:
        return "yes"
    if v is False or v is None:
        return "no"
    return _word(v)


def gather(spec: Spec, sweep_dir: Path, runs: list[Run], outcomes: dict[str, dict[str, Any]]
           ) -> tuple[Path, Path | None]:
    """table.md, table.json and figure.png from the runs' metrics.json: mean ± std over seeds per group."""
    from research import atomic
    from research.results import markdown_table

    groups: dict[tuple, dict[str, Any]] = {}
    failed_rows = []
    for run in runs:
        opts = dict(run.options)
        gkey = tuple(_fmt_value(opts.get(g, False)) for g in spec.group_by)
        o = outcomes.get(run.key, {"status": "not run"})
        group = groups.setdefault(gkey, {"values": {}, "seeds": [], "failed": []})
        if o["status"] == "failed" or o["status"] == "not run":
            group["failed"].append(run.seed)
            failed_rows.append([run.key, *gkey, run.seed, o.get("error", "not run")])
            continue
        try:
            metrics = json.loads((sweep_dir / run.key / "metrics.json").read_text())["metrics"]
        except (OSError, ValueError, KeyError) as e:
            group["failed"].append(run.seed)
            failed_rows.append([run.key, *gkey, run.seed, f"metrics.json unreadable: {e}"])
            continue
        group["seeds"].append(run.seed)
        items = {"": metrics}
        if spec.rows:
            base = _lookup(metrics, spec.rows)
            items = base if isinstance(base, dict) else {}
        for item, sub in items.items():
            for m in spec.metrics:
                v = _lookup(sub, m)
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    group["values"].setdefault((item, m), []).append(float(v))

    headers = [*spec.group_by] + ([spec.rows] if spec.rows else []) + spec.metrics + ["seeds", "failed"]
    md_rows, json_rows = [], []
    for gkey, group in groups.items():
        items = list(dict.fromkeys(item for item, _ in group["values"])) or [""]
        for item in items:
            cells, stats = [], {}
            for m in spec.metrics:
                vals = group["values"].get((item, m), [])
                if vals:
                    mean = sum(vals) / len(vals)
                    std = math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else 0.0
                    cells.append(f"{mean:.4g} ± {std:.2g}" if len(vals) > 1 else f"{mean:.4g}")
                    stats[m] = {"mean": mean, "std": std, "n": len(vals)}
                else:
                    cells.append("—")
                    stats[m] = None
            row = [*gkey] + ([item] if spec.rows else []) + cells + [
                ", ".join(map(str, group["seeds"])) or "none", ", ".join(map(str, group["failed"])) or "none"]
            md_rows.append(row)
            json_rows.append({"group": dict(zip(spec.group_by, gkey)), **({"row": item} if spec.rows else {}),
                              "metrics": stats, "seeds": group["seeds"], "failed_seeds": group["failed"]})
    text = (f"# sweep {spec.name}\n\n`{spec.experiment}` {' '.join(spec.fixed)}, seeds {spec.seeds}; mean ± std "
            f"(sample std) over the seeds that finished. Spec: `{spec.path.name}`.\n\n"
            + markdown_table(headers, md_rows))
    if failed_rows:
        text += ("\n## Failed runs\n\n" + markdown_table(["run", *spec.group_by, "seed", "error"],
                                                         [[f"`{r[0]}`", *r[1:-1], r[-1].replace("|", "\\|")]
                                                          for r in failed_rows]))
    atomic.write_text(sweep_dir / "table.md", text)
    atomic.write_json(sweep_dir / "table.json", {"sweep": spec.name, "experiment": spec.experiment,
                                                  "group_by": spec.group_by, "rows": spec.rows,
                                                  "metrics": spec.metrics, "table": json_rows,
                                                  "failed": [{"key": r[0], "seed": r[-2], "error": r[-1]}
                                                             for r in failed_rows]})
    figure = _figure(spec, sweep_dir, json_rows)
    return sweep_dir / "table.md", figure


def _figure(spec: Spec, sweep_dir: Path, rows: list[dict[str, Any]]) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research.results import save_figure

    shown = [r for r in rows if r["metrics"].get(spec.figure)]
    if not shown:
        return None
    labels = [", ".join(f"{k.lstrip('-')}={v}" for k, v in r["group"].items()) + (f" {r['row']}" if "row" in r else "")
              for r in shown]
    means = [r["metrics"][spec.figure]["mean"] for r in shown]
    stds = [r["metrics"][spec.figure]["std"] for r in shown]
    fig, ax = plt.subplots(figsize=(max(4.0, 0.45 * len(shown) + 2), 3.6))
    ax.bar(range(len(shown)), means, yerr=stds, capsize=3, color="tab:blue")
    ax.set_xticks(range(len(shown)), [lab.strip() or "all" for lab in labels], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel(spec.figure)
    ax.set_title(f"{spec.name}: {spec.figure} (mean ± std over seeds)", fontsize=9)
    fig.tight_layout()
    path = sweep_dir / "figure.png"
    save_figure(fig, path)
    plt.close(fig)
    return path
