"""One run of a sweep and the executors that run many: local processes (--jobs) or Ray tasks."""

from __future__ import annotations

import json
import os
import shutil
import socket
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from research import atomic
from research.sweep.spec import RUN_FILE, Run

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
        atomic.write_json(out / RUN_FILE, record)
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


# Ray's switch between "this machine only" and "a cluster" (ray._private.ray_constants.ENABLE_RAY_CLUSTER,
# read from this variable when Ray is imported). On Linux it defaults to cluster mode, in which Ray
# replaces a node address of 127.0.0.1 by the machine's outward address, and the GCS server, the
# raylet and the workers then listen on that interface (measured with Ray 2.60). Switched off, the
# node address stays 127.0.0.1 and every one of them listens on the loopback interface only.
_CLUSTER_SWITCH = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def _local_instance_on_loopback() -> None:
    """Make the local instance that ray.init is about to start listen on the loopback address only."""
    os.environ[_CLUSTER_SWITCH] = "0"
    ray_constants = sys.modules.get("ray._private.ray_constants")
    if ray_constants is not None:  # Ray was imported before the variable was set: set what it read
        ray_constants.ENABLE_RAY_CLUSTER = False


def _remove_after_exit(folder: str, wait_s: float = 90.0) -> None:
    """Remove a local instance's session folder once no process names it, waiting at most `wait_s`.

    The raylet, GCS server and workers exit after ray.shutdown returns: within a second on a quiet
    machine, but tens of seconds on a loaded 2-core one, and a process still exiting can write its
    last log lines into the folder after a first removal. So the removal is repeated until the folder
    stays gone with no process naming it, or the time is up.
    """
    deadline = time.monotonic() + wait_s
    gone_since = None
    while True:
        if os.path.exists(folder) and not _processes_naming(folder):
            shutil.rmtree(folder, ignore_errors=True)
        now = time.monotonic()
        if os.path.exists(folder):
            gone_since = None
        elif gone_since is None:
            gone_since = now
        elif now - gone_since >= 1.0:  # workers (whose command line does not name it) have stopped writing
            return
        if now >= deadline:
            shutil.rmtree(folder, ignore_errors=True)
            return
        time.sleep(0.2)


def _processes_naming(text: str) -> bool:
    """Whether a process other than this one has `text` in its command line (Linux /proc; elsewhere False)."""
    proc = Path("/proc")
    if not proc.is_dir():
        return False
    for entry in proc.iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            if text.encode() in (entry / "cmdline").read_bytes():
                return True
        except OSError:
            continue
    return False


def ray_session(opts: RayOptions):
    """Context manager: connect to `opts.address` or start a bounded local Ray instance; shut down after.

    A local instance has no dashboard and listens on the loopback address only. Already connected
    (ray.is_initialized(), e.g. by a test), it is used as it is and left running.
    """
    import contextlib

    @contextlib.contextmanager
    def session():
        if not opts.address:
            _local_instance_on_loopback()
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
            # Without a session folder of the caller's, the instance gets its own, removed after it stops
            # (Ray's default, /tmp/ray, keeps every session's logs and sockets).
            own_folder = None if opts.temp_dir else tempfile.mkdtemp(prefix="drlab-ray-", dir="/tmp")
            try:
                ray.init(num_cpus=opts.num_cpus, include_dashboard=False, _node_ip_address="127.0.0.1",
                         log_to_driver=False, logging_level="ERROR", _temp_dir=opts.temp_dir or own_folder,
                         configure_logging=True)
            except BaseException:
                if own_folder:
                    shutil.rmtree(own_folder, ignore_errors=True)
                raise
            finally:
                if saved is None:
                    os.environ.pop("PYTHONPATH", None)
                else:
                    os.environ["PYTHONPATH"] = saved
        try:
            yield ray
        finally:
            ray.shutdown()
            if not opts.address and own_folder:
                _remove_after_exit(own_folder)

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


def child_env() -> dict[str, str]:
    """What a job's `env` carries: PYTHONPATH of the experiment's environment (research.cli_common), when set."""
    from research.cli_common import experiment_env

    env = experiment_env()
    return {k: env[k] for k in ("PYTHONPATH",) if k in env}


def reproduce_jobs(names: list[str], results_dir: Path, quick: bool, device: str, log_dir: Path,
                   extra: list[str]) -> list[dict[str, Any]]:
    """`drlab reproduce --ray`: one job per registered experiment, into results_dir/<name> as a local
    reproduce writes it (no sweep-run.json), its output in log_dir/<name>.log."""
    from research import registry

    keep = child_env()
    return [{"key": name, "experiment": name, "device": device, "seed": registry.reproduce_seed(name, quick),
             "argv": (["--quick"] if quick else []) + list(extra), "config": {"experiment": name, "quick": quick},
             "out": str(Path(results_dir).absolute() / name), "log": str(Path(log_dir).absolute() / f"{name}.log"),
             "cwd": os.getcwd(), "env": keep, "timeout_s": 24 * 3600.0, "record": False} for name in names]


