"""One contract for every experiment in experiments/: options, device, results folder, provenance.

An experiment module defines a body that receives a `Context`, and the options that are its own:

    def add_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--trials", type=int, default=None, help="...")

    def run(ctx: Context) -> int | None:
        ...                                   # everything it writes goes under ctx.out
        ctx.write_results(config=..., metrics=..., table_md=...)   # and prints the table

    main = Experiment("kalman_tracking", __doc__, run, add_options, sizes="...").script(__name__)

so that it runs as `python -m experiments.<name>` and as `python experiments/<name>.py` (`script`
exits with the run's status when the module runs as a script; `main`, argv -> exit status, is what
the tests and `drlab run` call). The `experiments` package is installed with `research`, so no path
manipulation is needed.

Shared options, declared here once: --quick, --smoke (tiny sizes, seconds: what the tests run),
--device, --out, --seed, --data, --no-progress.

Device: resolved and validated once, before the body runs: `cpu`, or `cuda` / `cuda:N` when Warp
sees that device (otherwise a usage error naming --device). The body reads it from `ctx.device` and
hands it to every stage (training, evaluation, timing). An experiment that runs on the CPU only
(NumPy, Mitsuba's LLVM variant) declares `warp=False`: it accepts a valid --device (so `drlab
reproduce --device cuda` can run it) and records `cpu`.

Results folder: the body writes into a temporary sibling `<out>.partial-<pid>`; only when it returns
successfully does that folder replace `<out>` (the old folder is renamed aside, the new one renamed
into place, then the old one deleted). A run that raises deletes its temporary folder; a run that is
killed leaves it behind, and the next run into the same `<out>` deletes it (its process is gone). So
`<out>` always holds the files of exactly one finished run. Work that must see the finished folder
(e.g. a table gathered from several experiments' folders) goes in `ctx.after_commit(fn)`.

Provenance (commit, host, versions, config, seed, device, wall time) is written by
`ctx.write_results`, through research.results.write_results.

Errors, as in the `drlab` CLI (research.cli): a user mistake (a bad option or value, a missing or
unwritable file or folder) prints one line `<prog>: <message>` to stderr and exits with status 2
(`<prog>` is `drlab run <name>` under `drlab run`, else `python -m experiments.<name>`); `--debug`
shows the traceback instead. Ctrl-C exits with status 130 after one line, its temporary folder
deleted and `<out>` as it was (the two renames that swap the folder in hold Ctrl-C until done).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import shutil
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from research import registry, results

_PARTIAL = ".partial-"
_OLD = ".old-"


# --------------------------------------------------------------------------- device


def resolve_device(value: str) -> str:
    """The Warp device named by `--device`, validated: `cpu`, `cuda` or `cuda:N` that Warp can see.

    Raises ValueError naming --device otherwise.
    """
    if value == "cpu":
        return "cpu"
    if not re.fullmatch(r"cuda(:\d+)?", value or ""):
        raise ValueError(f"--device: expected 'cpu', 'cuda' or 'cuda:N', got {value!r}")
    import warp as wp

    from research.warp_runtime import init_warp

    init_warp()
    if not wp.is_cuda_available():
        raise ValueError(f"--device {value}: Warp sees no CUDA device on this machine; use --device cpu")
    try:
        return str(wp.get_device(value))
    except (RuntimeError, ValueError) as e:
        raise ValueError(f"--device: {value!r} is not a device Warp sees ({e})") from None


# --------------------------------------------------------------------------- results folder


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def _siblings(out: Path, marker: str) -> list[tuple[Path, int]]:
    """Folders `<out><marker><pid>` beside `out`, with their pids."""
    found = []
    if out.parent.is_dir():
        prefix = out.name + marker
        for p in out.parent.iterdir():
            if p.name.startswith(prefix) and p.name[len(prefix):].isdigit():
                found.append((p, int(p.name[len(prefix):])))
    return found


def clean_stale(out: str | Path) -> list[Path]:
    """Remove what killed runs left beside `out`; returns the paths removed.

    A `<out>.partial-<pid>` of a process that no longer runs is deleted. A `<out>.old-<pid>` of such a
    process is the previous results, moved aside by a run killed between its two renames: it is put
    back when `<out>` is missing, else deleted.
    """
    out = Path(out)
    removed = []
    for path, pid in _siblings(out, _OLD):
        if pid == os.getpid() or _pid_alive(pid):
            continue
        if not out.exists():
            os.replace(path, out)
        else:
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    for path, pid in _siblings(out, _PARTIAL):
        if pid != os.getpid() and not _pid_alive(pid):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


def check_replaceable(out: str | Path) -> None:
    """Raise ValueError unless `out` is absent, empty, or a results folder (it holds metrics.json).

    The whole folder is replaced, so `--out` must never name a folder with other contents (a home
    directory, a checkout).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out: expected a folder, but {out} is a file")
    if out.is_dir() and any(out.iterdir()) and not (out / "metrics.json").is_file():
        raise ValueError(f"--out: {out} is replaced whole by the run, but it is neither empty nor an "
                         "experiment's results folder (no metrics.json); choose another folder")


@contextlib.contextmanager
def results_folder(out: str | Path):
    """Yield a fresh temporary folder that replaces `out` when the block finishes without an exception.

    On an exception (KeyboardInterrupt and SystemExit included) the temporary folder is deleted and
    `out` is left as it was. `out` must pass `check_replaceable`.
    """
    out = Path(out).absolute()
    check_replaceable(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    clean_stale(out)
    tmp = out.with_name(f"{out.name}{_PARTIAL}{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    with _signals_deferred():  # Ctrl-C / SIGTERM between the two renames would leave no <out> in place
        commit_folder(tmp, out)


@contextlib.contextmanager
def _signals_deferred():
    """Hold SIGINT and SIGTERM until the block ends, then act on the first one that came.

    Python-level handlers that only record the signal, not a signal mask: a process-directed signal
    goes to any thread that does not block it (Warp, SciPy or tqdm threads), and Python would still
    raise KeyboardInterrupt in the main thread. Outside the main thread (where handlers cannot be
    set) this is a no-op.
    """
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    wanted = [s for s in (getattr(signal, "SIGINT", None), getattr(signal, "SIGTERM", None)) if s is not None]
    previous = {s: signal.getsignal(s) for s in wanted}
    for s in wanted:
        signal.signal(s, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
        if pending:
            signum, handler = pending[0], previous[pending[0]]
            if callable(handler):
                handler(signum, None)  # SIGINT's default handler raises KeyboardInterrupt here
            elif handler == signal.SIG_DFL:
                if signum == signal.SIGINT:
                    raise KeyboardInterrupt
                os.kill(os.getpid(), signum)  # the default action, now that the folder is in place


def commit_folder(tmp: Path, out: Path) -> None:
    """Replace `out` by `tmp` with renames: the old folder aside, the new one in, then the old one deleted."""
    old = out.with_name(f"{out.name}{_OLD}{os.getpid()}")
    if out.exists():
        os.replace(out, old)
    os.replace(tmp, out)
    if old.exists():
        shutil.rmtree(old)


# --------------------------------------------------------------------------- context


@dataclass
class Context:
    """What an experiment's body receives: its options, the validated device and where to write."""

    name: str
    args: argparse.Namespace  # every option, the experiment's own included
    device: str  # validated Warp device (always "cpu" for a NumPy-only experiment)
    out: Path  # the temporary results folder: write every file here
    final_out: Path  # where the folder lands when the run finishes
    t_start: float = field(default_factory=time.perf_counter)
    _after: list[Callable[[], Any]] = field(default_factory=list, repr=False)

    @property
    def quick(self) -> bool:
        """--quick or --smoke (a smoke run takes the quick code paths at smaller sizes)."""
        return bool(self.args.quick or self.args.smoke)

    @property
    def smoke(self) -> bool:
        return bool(self.args.smoke)

    @property
    def seed(self) -> int:
        return int(self.args.seed)

    @property
    def data(self) -> Path:
        return Path(self.args.data)

    @property
    def progress(self) -> bool:
        return not self.args.no_progress

    @property
    def mode(self) -> str:
        """"smoke", "quick" or "full"; a suffix for cached data of each size is `"" if full else "-" + mode`."""
        return "smoke" if self.smoke else "quick" if self.quick else "full"

    def elapsed(self) -> float:
        return time.perf_counter() - self.t_start

    def int_option(self, name: str, default: int, low: int = 1) -> int:
        """Option `name` ("--iterations": an int option whose argparse default is None) as an integer >= low
        (research.values.integer), or `default`, the mode's setting, when it was not given."""
        from research import values

        value = getattr(self.args, name.lstrip("-").replace("-", "_"))
        return default if value is None else values.integer(name, value, low=low)

    def tqdm(self, iterable: Iterable | None = None, **kwargs: Any):
        """tqdm over `iterable`, hidden under --no-progress."""
        from tqdm import tqdm

        if not self.progress:
            kwargs["disable"] = True
        return tqdm(iterable, **kwargs)

    def after_commit(self, fn: Callable[[], Any]) -> None:
        """Call `fn()` after the results folder is in place at `final_out` (its return value is printed)."""
        self._after.append(fn)

    def write_results(self, *, config: dict[str, Any], metrics: dict[str, Any], table_md: str,
                      device: str | None = None, compare: bool = False) -> Path:
        """metrics.json (with provenance and wall time so far) and table.md, into `out`; prints the table.

        The recorded config is `config` after `"quick": ctx.quick`, with `"smoke": true` last on a smoke run.

        `compare`: after a full run, refresh the comparison table of the results root
        (research.comparison), once the folder is in place (it reads this run's metrics.json).
        """
        config = {"quick": self.quick, **config, **({"smoke": True} if self.smoke else {})}
        path = results.write_results(self.out, experiment=self.name, config=config, seed=self.seed,
                                     device=device or self.device, wall_time_s=self.elapsed(), metrics=metrics,
                                     table_md=table_md)
        print(table_md)
        if compare and not self.quick:
            from research import comparison

            self.after_commit(lambda: comparison.update_comparison(self.final_out.parent))
        return path


# --------------------------------------------------------------------------- experiment


def rendered_cache_help(what: str, name: str) -> str:
    """--data help of an experiment that renders its datasets into <data>/<name>-<scene>[-quick|-smoke]."""
    return f"cache root of the {what} datasets: <data>/{name}-<scene>[-quick|-smoke], rendered if missing"


class Experiment:
    """An experiment: its name, its help text, its body and its own options (module docstring)."""

    def __init__(self, name: str, doc: str | None, body: Callable[[Context], int | None],
                 add_options: Callable[[argparse.ArgumentParser], None] | None = None, *,
                 sizes: str, data_help: str | None = None, seed_help: str = "seed of every random draw",
                 warp: bool = True):
        """`sizes`: what --quick and --smoke change, for --help. `data_help`: what --data means here
        (None: the experiment reads no dataset). `warp`: whether it runs Warp kernels on --device."""
        self.name, self.doc, self.body, self.add_options = name, doc, body, add_options
        self.sizes, self.data_help, self.seed_help, self.warp = sizes, data_help, seed_help, warp

    @property
    def prog(self) -> str:
        """The name its one-line errors start with: `drlab run <name>` under drlab, else the module."""
        return os.environ.get("DRLAB_PROG") or f"python -m experiments.{self.name}"

    def parser(self) -> argparse.ArgumentParser:
        from research.cli_common import Parser

        p = Parser(prog=f"python -m experiments.{self.name}", description=self.doc,
                    formatter_class=argparse.RawDescriptionHelpFormatter)
        g = p.add_argument_group("options every experiment has", description=f"Sizes. {self.sizes}")
        size = g.add_mutually_exclusive_group()
        size.add_argument("--quick", action="store_true", help="smaller settings (sizes above)")
        size.add_argument("--smoke", action="store_true",
                          help="tiny sizes, seconds (above): checks that the experiment runs end to end (the tests "
                               "run it); its numbers mean little")
        g.add_argument("--device", default="cpu",
                       help="Warp device: cpu (default), cuda or cuda:N when Warp sees one"
                            + ("" if self.warp else "; this experiment runs on the CPU whatever the device, and "
                                                    "records cpu"))
        g.add_argument("--out", type=_folder, default=None,
                       help=f"results folder (default: {registry.describe_default_out(self.name)}). It is "
                            "replaced whole when the run finishes; a killed run leaves it as it was")
        g.add_argument("--seed", type=_seed, default=0, help=f"{self.seed_help} (default: 0); 0 <= seed < 2^32")
        g.add_argument("--data", type=_folder, default=None,
                       help=(f"{self.data_help} (default: {registry.describe_default_data()})" if self.data_help
                             else "not used: this experiment generates its data in memory"))
        g.add_argument("--no-progress", action="store_true", help="hide the progress bars")
        g.add_argument("--debug", action="store_true", help="show the traceback of an error instead of one line")
        if self.add_options is not None:
            self.add_options(p.add_argument_group(f"options of {self.name}"))
        return p

    def script(self, module_name: str) -> Callable[[list[str] | None], int]:
        """An experiment module's `main`; when the module runs as a script (`module_name` is "__main__"),
        runs it on the command line and exits with its status."""
        if module_name == "__main__":
            sys.exit(self.main())
        return self.main

    def main(self, argv: list[str] | None = None) -> int:
        """Parse `argv`, resolve the device, run the body into a temporary folder, swap it in; exit status.

        User mistakes exit 2 and Ctrl-C exits 130, each after one line on stderr (module docstring).
        """
        from research.cli_common import EXIT_INTERRUPTED, EXIT_USAGE, USER_ERRORS, caused_by_interrupt, one_line

        argv = list(sys.argv[1:] if argv is None else argv)
        debug = "--debug" in argv
        try:
            try:
                return self._main(argv)
            except Exception as e:
                if caused_by_interrupt(e) and not debug:
                    raise KeyboardInterrupt from e  # Ctrl-C re-raised by a library as another exception
                raise
        except USER_ERRORS as e:
            if debug:
                raise
            print(f"{self.prog}: {one_line(e)}", file=sys.stderr, flush=True)
            return EXIT_USAGE
        except KeyboardInterrupt:
            if debug:
                raise
            print(f"{self.prog}: interrupted (Ctrl-C); no half-written results were kept", file=sys.stderr,
                  flush=True)
            return EXIT_INTERRUPTED

    def _main(self, argv: list[str]) -> int:
        p = self.parser()
        args = p.parse_args(argv)
        if args.data is None:
            args.data = registry.default_data_dir()
        device = resolve_device(args.device)  # ValueError naming --device: before any work
        if self.warp:
            from research.warp_runtime import init_warp

            init_warp(device)  # also Warp's default device, for objects an experiment creates without one
        elif device != "cpu":
            print(f"note: --device {args.device} accepted; {self.name} runs on the CPU")
            device = "cpu"
        final = Path(args.out) if args.out is not None else registry.default_out(self.name, quick=args.quick,
                                                                                   smoke=args.smoke)
        final = final.absolute()
        with _sigterm_as_exit():
            with results_folder(final) as tmp:  # checks first that `final` may be replaced
                ctx = Context(self.name, args, device, tmp, final)
                # A non-zero status (a check the body reports as failed) still finishes the run: its
                # folder, with the numbers that failed, replaces the old one.
                rc = int(self.body(ctx) or 0)
        for fn in ctx._after:
            said = fn()
            if said:
                print(said)
        print(f"{self.name}: wrote {final} in {ctx.elapsed():.1f} s", flush=True)
        return rc


def _folder(value: str) -> Path:
    """argparse type of --out and --data: a non-blank path."""
    from research.cli_common import directory_path

    return Path(directory_path(value))


def _seed(value: str) -> int:
    from research.cli_common import seed_value

    return seed_value(value)


@contextlib.contextmanager
def _sigterm_as_exit():
    """Turn SIGTERM into SystemExit so that a terminated run cleans its temporary folder."""
    if hasattr(signal, "SIGTERM") and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        try:
            previous = signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))
        except ValueError:  # not the main thread
            yield
            return
        try:
            yield
        finally:
            signal.signal(signal.SIGTERM, previous)
    else:
        yield
