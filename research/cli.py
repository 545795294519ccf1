"""The `drlab` command line.

    drlab dataset --scene NAME [--views N --res R --spp S --stereo --flow] --out DIR [--resume] [--force] [--ray]
    drlab run EXPERIMENT [--quick|--smoke] [--device cpu|cuda] [--out DIR] [--seed N] [-- EXPERIMENT OPTIONS]
    drlab reproduce [EXP ...] [--quick] [--ray [--ray-address A]]   registered experiments, then results/README.md
    drlab sweep SPEC [--jobs N] [--ray [--ray-address A]]  a grid of runs from a TOML file (research.sweep)
    drlab gradcheck [KERNEL ...] [--device D]  finite-difference table; exit status 1 on any failure
    drlab bench [FAMILY ...] [--json] [--compare]  timings (median of >= 3 runs after a warm-up)
    drlab list                         registered experiments, gradient checks and bench families
    drlab sfm IMAGES_DIR --out DIR [--matcher exhaustive|sequential] [--shared-camera] [--intrinsics FX,FY,CX,CY]
                                       photos -> a COLMAP folder (images/, sparse/0/) through pycolmap (research.poses.sfm)

Errors: a user mistake (a bad option or value, a folder that exists or is missing, a file that
cannot be written, an unknown name) prints one line `drlab <command>: <message>` to stderr and
exits with status 2; `drlab --debug ...` shows the traceback instead (and passes --debug on to
experiments). Ctrl-C exits with status 130 after one line; the dataset generator and the
experiment contract write to temporary names, so nothing half-written is left in place.
`--device cuda` on a machine where Warp sees no GPU is refused the same way before any work.

Experiments run as their own processes (`python -m experiments.<name> ...`), so
research never imports experiments and every experiment also works on its own.
Default folders (research.registry): results/<name> in a checkout, ./results/<name>
under the current directory when drlab is installed from a wheel.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from research import atomic, registry
from research.cli_common import (EXIT_INTERRUPTED, EXIT_USAGE, USER_ERRORS, Parser, UsageError, caused_by_interrupt,
                                 directory_path, experiment_env, integer_type, one_line, seed_value)
from research.registry import EXPERIMENTS, family_modules


def _check_device(value: str) -> str:
    """`--device` resolved by the experiment contract's rule; ValueError naming --device otherwise."""
    from research.experiment import resolve_device

    return resolve_device(value)


def _cmd_dataset(args: argparse.Namespace) -> int:
    from research.datasets import DatasetConfig, generate

    cfg = DatasetConfig(scene=args.scene, views=args.views, res=args.res, spp=args.spp, seed=args.seed,
                        stereo=args.stereo, stereo_pairs=args.stereo_pairs, baseline=args.baseline,
                        flow=args.flow, flow_frames=args.flow_frames, flow_path=args.flow_path)
    ray = None
    if _uses_ray(args):
        from research.sweep import RayOptions, require_ray

        cfg.validate()  # its one-line errors before Ray starts
        require_ray()
        ray = RayOptions(address=args.ray_address)
    t0 = time.perf_counter()
    out = generate(cfg, args.out, resume=args.resume, force=args.force, ray=ray)
    manifest = json.loads((out / "manifest.json").read_text())
    print(f"wrote {out} in {time.perf_counter() - t0:.1f} s ({len(manifest['files'])} files, "
          f"variant {manifest['mitsuba_variant']}, content hash {manifest['content_hash'][:16]})")
    return 0


def _experiment_command(name: str, quick: bool, device: str, out: Path | None, seed: int | None,
                        extra: list[str] = ()) -> list[str]:
    # -P (Python 3.11+): the current directory is not put on sys.path, so a folder there named
    # `experiments` cannot shadow the package; the code comes from PYTHONPATH or site-packages.
    safe_path = ["-P"] if sys.version_info >= (3, 11) else []
    cmd = [sys.executable, *safe_path, "-m", EXPERIMENTS[name].module, "--device", device]
    if out is not None:
        cmd += ["--out", str(Path(out).absolute())]
    if quick:
        cmd.append("--quick")
    if seed is not None:
        cmd += ["--seed", str(seed)]
    return cmd + list(extra)


def _check_experiment(name: str) -> None:
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; registered: {', '.join(sorted(EXPERIMENTS)) or 'none'}")


def _run_one(name: str, quick: bool, device: str, out: Path | None, seed: int | None, extra: list[str] = ()) -> int:
    """Run one experiment in its own process; its exit status (130 when Ctrl-C stopped it)."""
    _check_experiment(name)
    if out is None:
        out = registry.default_out(name, quick=quick)
    cmd = _experiment_command(name, quick, device, out, seed, extra)
    print(f"drlab run {name}: {' '.join(cmd[1:])}", flush=True)
    t0 = time.perf_counter()
    # The current directory is kept, so relative paths among the extra options mean what they say.
    # The child is in our process group, so Ctrl-C reaches it too: it cleans its temporary folder and
    # says so in one line; we wait for that instead of killing it half-way.
    proc = subprocess.Popen(cmd, env={**experiment_env(), "DRLAB_PROG": f"drlab run {name}"})
    try:
        rc = proc.wait()
    except KeyboardInterrupt:
        try:
            rc = proc.wait(timeout=30)
        except (subprocess.TimeoutExpired, KeyboardInterrupt):
            proc.kill()
            proc.wait()
        raise _ChildInterrupted() from None
    status = "ok" if rc == 0 else f"FAILED (exit {rc})"
    print(f"drlab run {name}: {status} in {time.perf_counter() - t0:.1f} s", flush=True)
    return rc


class _ChildInterrupted(KeyboardInterrupt):
    """Ctrl-C during an experiment's process, which has already said so on stderr."""


def _cmd_run(args: argparse.Namespace) -> int:
    _check_experiment(args.experiment)
    _check_device(args.device)
    out = Path(args.out) if args.out is not None else None
    if out is None and args.smoke:
        out = registry.default_out(args.experiment, smoke=True)
    extra = (["--smoke"] if args.smoke else []) + args.extra + (["--debug"] if args.debug else [])
    return _run_one(args.experiment, args.quick, args.device, out, args.seed, extra)


def _provenance(metrics_path: Path) -> str:
    """Where an experiment's numbers came from: commit, device and wall time, from its metrics.json."""
    try:
        doc = json.loads(metrics_path.read_text())
    except (OSError, json.JSONDecodeError):
        return "metrics.json missing or unreadable"
    source = doc.get("source") or {}
    if source.get("commit"):
        commit = f"commit `{source['commit'][:10]}`" + (" with local changes" if source.get("dirty") else "")
    else:
        commit = "commit not recorded (written before drlab recorded it)"
    quick = " --quick" if (doc.get("config") or {}).get("quick") else ""
    machine = doc.get("host") or {}
    where = f"`{doc.get('device', '?')}`" + (f" ({machine['cpu']}, {machine['cpus']} CPUs)" if machine else "")
    return f"Run{quick} at {commit} on {where}, {doc.get('wall_time_s', 0.0) / 60:.1f} min."


def write_results_index(results_dir: Path, names: list[str], quick: bool) -> Path:
    """results/README.md: every experiment's table.md (in registration order), then the comparison table."""
    parts = ["# drlab results\n",
             "Gathered by `drlab reproduce" + (" --quick" if quick else "") + "`. Each section is "
             "`<experiment>/table.md`; `metrics.json` beside it has the configuration, seed, device, versions, "
             "wall time and the commit of the code that produced it (shown under each heading).\n"]
    for name in names:
        table = results_dir / name / "table.md"
        parts.append(f"\n## {name}\n\n{EXPERIMENTS[name].description}\n")
        if table.exists():
            parts.append(f"\n{_provenance(results_dir / name / 'metrics.json')}\n\n" + table.read_text())
        else:
            parts.append("\n_No table: the experiment did not finish._\n")
        pngs = sorted(p.name for p in (results_dir / name).glob("*.png")) if (results_dir / name).exists() else []
        if pngs:
            parts.append("\nFigures: " + ", ".join(f"[{p}]({name}/{p})" for p in pngs) + "\n")
    comparison = results_dir / "comparison" / "table.md"
    if comparison.exists():
        parts.append("\n## comparison\n\nNovel-view synthesis methods on the same data (written by fit_splats and "
                     "fit_nerf: research.comparison).\n\n" + comparison.read_text())
    path = results_dir / "README.md"
    atomic.write_text(path, "".join(parts))
    return path


def _cmd_reproduce(args: argparse.Namespace) -> int:
    _check_device(args.device)
    names = list(EXPERIMENTS)
    if not names:
        print("drlab reproduce: no experiments are registered yet")
        return 0
    unknown = [n for n in args.experiments if n not in EXPERIMENTS]
    if unknown:
        raise ValueError(f"experiments: unknown {', '.join(map(repr, unknown))}; registered: {', '.join(names)}")
    # A subset reruns only those experiments; the index still gathers every registered experiment's
    # folder, each section naming the commit that produced it.
    selected = [n for n in names if n in args.experiments] if args.experiments else names
    for name in list(selected):
        why = registry.missing_data(name)
        if why:  # the index still shows its last committed table
            print(f"drlab reproduce: {name} skipped: {why}", flush=True)
            selected.remove(name)
    results_dir = registry.results_dir(quick=args.quick)
    failed = []
    if _uses_ray(args):
        failed = _reproduce_on_ray(args, selected, results_dir)
    else:
        for name in selected:
            if _run_one(name, args.quick, args.device, results_dir / name, registry.reproduce_seed(name, args.quick),
                        ["--debug"] if args.debug else []) != 0:
                failed.append(name)
    index = write_results_index(results_dir, names, args.quick)
    print(f"drlab reproduce: wrote {index}")
    if failed:
        print(f"drlab reproduce: failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def _add_ray_options(p: argparse.ArgumentParser, local_help: str, cluster_help: str) -> None:
    """--ray (the command's work as Ray tasks on a local Ray instance) and --ray-address (on a cluster)."""
    p.add_argument("--ray", action="store_true", help=local_help)
    p.add_argument("--ray-address", type=_ray_address, default=None, help=cluster_help)


def _uses_ray(args: argparse.Namespace) -> bool:
    """--ray, or --ray-address (which implies it)."""
    return bool(args.ray or args.ray_address is not None)


def _ray_address(value: str) -> str:
    """argparse type of --ray-address: host:port, ray://host:port or `auto`."""
    if not value.strip() or any(c.isspace() for c in value):
        raise argparse.ArgumentTypeError(f"expected host:port, ray://host:port or auto, got {value!r}")
    return value


def _cmd_sweep(args: argparse.Namespace) -> int:
    from research import sweep

    spec = sweep.load_spec(args.spec)  # ValueError naming the file: before any run
    if args.smoke:
        spec = spec.smoke_variant()
    root = Path(args.results) if args.results is not None else registry.results_dir()
    if (root / spec.name).exists() and not (root / spec.name).is_dir():
        raise ValueError(f"--results: {root / spec.name} is a file, expected the sweep's folder")
    if _uses_ray(args):
        sweep.require_ray()
        opts = sweep.RayOptions(address=args.ray_address, num_cpus=args.jobs)
        executor = sweep.ray_executor(opts, spec.cpus, spec.gpus, spec.max_retries)
        name = f"ray ({args.ray_address})" if args.ray_address else "ray (local instance)"
    else:
        executor, name = sweep.local_executor(args.jobs or 1), f"local (--jobs {args.jobs or 1})"
    runs = spec.runs()
    print(f"drlab sweep {spec.name}: {len(runs)} runs of {spec.experiment} ({len(spec.points)} configurations x "
          f"{len(spec.seeds)} seeds), {name}, into {(root / spec.name).absolute()}", flush=True)
    result = sweep.run_sweep(spec, root, executor, progress=not args.no_progress, executor_name=name)
    skipped = len(runs) - len(result.executed)
    print(f"drlab sweep {spec.name}: {len(result.executed)} ran, {skipped} already complete; wrote {result.table_md}"
          + (f" and {result.figure.name}" if result.figure else ""), flush=True)
    if result.failed:
        print(f"drlab sweep: {len(result.failed)} of {len(runs)} runs failed (table.md lists them; logs in "
              f"{result.sweep_dir / 'logs'})", file=sys.stderr, flush=True)
    return min(len(result.failed), 100)


def _reproduce_on_ray(args: argparse.Namespace, names: list[str], results_dir: Path) -> list[str]:
    """Every registered experiment as a Ray task (1 CPU each, bounded retries); the names that failed.

    Each task runs the same `python -m experiments.<name> --out results/<name>` as a local reproduce, so
    the folders are the same, timings aside; each experiment's output goes to build/logs/reproduce/.
    """
    from research import sweep

    sweep.require_ray()
    log_dir = registry.base_dir() / "build" / "logs" / ("reproduce-quick" if args.quick else "reproduce")
    jobs = sweep.reproduce_jobs(names, results_dir, args.quick, args.device, log_dir,
                                ["--debug"] if args.debug else [])
    where = args.ray_address or "a local Ray instance"
    print(f"drlab reproduce: {len(jobs)} experiments as Ray tasks on {where}; logs in {log_dir}", flush=True)
    failed: list[str] = []

    def done(outcome: dict) -> None:
        status = "ok" if outcome["status"] == "ok" else f"FAILED: {outcome['error']}"
        print(f"drlab reproduce: {outcome['key']}: {status} ({outcome['wall_s']:.1f} s on {outcome['host'] or '?'})",
              flush=True)
        if outcome["status"] != "ok":
            failed.append(outcome["key"])

    sweep.ray_executor(sweep.RayOptions(address=args.ray_address), cpus=1, gpus=0, max_retries=2)(jobs, done)
    return [n for n in names if n in failed]


def _cmd_gradcheck(args: argparse.Namespace) -> int:
    from research.gradcheck import _select, format_table, load_checks, run_checks

    load_checks()
    try:
        _select(args.kernels or None)
    except KeyError as e:  # an unknown name is a usage error, named before anything runs
        raise ValueError(f"kernels: {e.args[0]}") from None
    device = _check_device(args.device)
    _quiet_warp()
    from kernels._arrays import default_device_scope

    with default_device_scope(device):  # the checks' NumPy inputs and fields go to that device
        results = run_checks(args.kernels or None)
    print(format_table(results))
    failed = [r for r in results if not r.passed]
    print(f"\n{len(results) - len(failed)} passed, {len(failed)} failed")
    return 1 if failed else 0


def _quiet_warp() -> None:
    """Keep Warp's start-up banner off stdout (it would break `--json` output)."""
    from research.warp_runtime import init_warp

    init_warp()


def _cmd_bench(args: argparse.Namespace) -> int:
    from research.bench import run_bench

    unknown = [f for f in args.families if f not in family_modules("bench")]
    if unknown:
        raise ValueError(f"families: unknown famil{'y' if len(unknown) == 1 else 'ies'} {unknown}; "
                         f"registered: {sorted(family_modules('bench'))}")
    device = _check_device(args.device)
    _quiet_warp()
    rows = run_bench(args.families or None, device, args.quick, compare=args.compare)
    for row in rows:
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            print("  ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
    return 0


def _cmd_sfm(args: argparse.Namespace) -> int:
    from research.poses import sfm

    intrinsics = sfm.parse_intrinsics(args.intrinsics) if args.intrinsics is not None else None
    opts = sfm.SfmOptions(matcher=args.matcher, overlap=args.overlap, shared_camera=args.shared_camera,
                          camera_model=args.camera_model, intrinsics=intrinsics, min_registered=args.min_registered,
                          max_features=args.max_features, threads=args.threads, seed=args.seed,
                          undistort=not args.no_undistort)
    result = sfm.run_sfm(args.images_dir, args.out, opts, force=args.force, progress=not args.no_progress,
                         verbose=args.verbose)
    print(f"drlab sfm: {sfm.describe(result)}")
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    from research.gradcheck import CHECKS, load_checks

    load_checks()
    print("experiments:")
    for spec in EXPERIMENTS.values():
        print(f"  {spec.name:28s} {spec.description}")
    print("gradient checks:")
    for name in CHECKS:
        print(f"  {name}")
    print("bench families:", ", ".join(family_modules("bench")))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="drlab", description="drlab: differentiable rendering and 3D/video vision.")
    p.add_argument("--debug", action="store_true",
                   help="show the traceback of an error instead of one line (anywhere before `--`; passed on to "
                        "experiments)")
    sub = p.add_subparsers(dest="command", required=True, parser_class=Parser)

    d = sub.add_parser("dataset", help="render a Mitsuba ground-truth dataset")
    d.add_argument("--scene", required=True, help="built-in scene: spheres, objects or cornell")
    d.add_argument("--views", type=int, default=100, help="multi-view cameras (split train/val/test)")
    d.add_argument("--res", type=int, default=256, help="image width and height in pixels")
    d.add_argument("--spp", type=int, default=64, help="path-tracing samples per pixel")
    d.add_argument("--seed", type=int, default=0, help="seed for poses, splits and render noise")
    d.add_argument("--stereo", action="store_true", help="add rectified stereo pairs with disparity")
    d.add_argument("--stereo-pairs", type=int, default=10, help="number of stereo pairs")
    d.add_argument("--baseline", type=float, default=None, help="stereo baseline (default 8%% of camera distance)")
    d.add_argument("--flow", action="store_true", help="add a camera-path sequence with forward flow")
    d.add_argument("--flow-frames", type=int, default=12, help="frames in the flow sequence")
    d.add_argument("--flow-path", default="arc", help="camera path of the flow sequence: arc (an open arc of "
                   "1.5-degree steps) or loop (one orbit that returns to its start, for SLAM loop closure)")
    d.add_argument("--out", required=True, type=directory_path, help="output directory")
    d.add_argument("--resume", action="store_true", help="finish an interrupted run (<out>.partial)")
    d.add_argument("--force", action="store_true", help="replace an existing dataset")
    _add_ray_options(d, "render the views as Ray tasks on a local Ray instance; same manifest and content hash "
                        "as a single-process render on the same kind of machine",
                     "render them on this Ray cluster instead (implies --ray); --out must be a path every node sees")
    d.set_defaults(fn=_cmd_dataset)

    r = sub.add_parser(
        "run", help="run one registered experiment", usage="drlab run EXPERIMENT [options] [-- EXPERIMENT OPTIONS]",
        description="Run one experiment in a fresh process (python -m experiments.EXPERIMENT). Options after "
                    "`--` go to the experiment itself, e.g. `drlab run fit_nerf -- --fields grid --no-progress`; "
                    "`python -m experiments.EXPERIMENT --help` lists them.")
    r.add_argument("experiment", help="a registered experiment (drlab list)")
    size = r.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="small settings (minutes on 2 cores)")
    size.add_argument("--smoke", action="store_true",
                      help="tiny sizes (seconds): checks that the experiment runs end to end; passed on to it")
    r.add_argument("--device", default="cpu", help="Warp device: cpu, cuda or cuda:N (default cpu)")
    r.add_argument("--out", default=None, type=directory_path,
                   help="results folder (default: results/EXPERIMENT, with --quick build/results-quick/EXPERIMENT; "
                        "in the checkout when drlab runs from one, else under the current directory)")
    r.add_argument("--seed", type=seed_value, default=None, help="the experiment's seed (default: its own, 0)")
    r.set_defaults(fn=_cmd_run)

    rp = sub.add_parser("reproduce", help="run every registered experiment and write results/README.md")
    rp.add_argument("experiments", nargs="*", metavar="EXPERIMENT",
                    help="rerun only these registered experiments (default: all); results/README.md still "
                         "gathers every experiment's latest folder, each with the commit that wrote it")
    rp.add_argument("--quick", action="store_true",
                    help="quick settings, written to build/results-quick (in the checkout, else under the current "
                         "directory)")
    rp.add_argument("--device", default="cpu", help="Warp device: cpu, cuda or cuda:N (default cpu)")
    _add_ray_options(rp, "run the experiments as Ray tasks on a local Ray instance (no dashboard, loopback only)",
                     "run them on this Ray cluster instead (implies --ray); results/ must be a path every node sees")
    rp.set_defaults(fn=_cmd_reproduce)

    sw = sub.add_parser(
        "sweep", help="run a grid of runs of one experiment from a TOML sweep file",
        description="Run every configuration x seed of a sweep file (research.sweep describes the format) into "
                    "<results>/<sweep>/<run-key>/, skipping runs already complete, then write table.md, "
                    "table.json, figure.png and runs.json there. Exit status: the number of failed runs (0: all "
                    "succeeded).")
    sw.add_argument("spec", help="sweep file (TOML), e.g. experiments/sweeps/raft_ablation.toml")
    sw.add_argument("--jobs", type=integer_type(1), default=None,
                    help="runs at a time (local executor, default 1); with --ray, the CPUs of the local Ray instance")
    _add_ray_options(sw, "run each run as a Ray task on a local Ray instance (no dashboard, loopback only)",
                     "join this Ray cluster instead (`ray start --head` prints it; implies --ray)")
    sw.add_argument("--results", type=directory_path, default=None,
                    help="results root (default: results/ in the checkout, else ./results)")
    sw.add_argument("--smoke", action="store_true",
                    help="tiny sizes: every run gets --smoke (instead of --quick); results in <sweep>-smoke")
    sw.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    sw.set_defaults(fn=_cmd_sweep)

    g = sub.add_parser("gradcheck", help="finite-difference checks of every registered backward pass")
    g.add_argument("kernels", nargs="*", help="check names or prefixes (default: all)")
    g.add_argument("--device", default="cpu", help="Warp device the checks run on: cpu, cuda or cuda:N (default cpu)")
    g.set_defaults(fn=_cmd_gradcheck)

    b = sub.add_parser("bench", help="timings of registered kernels")
    b.add_argument("families", nargs="*", help=f"families (default: all of {', '.join(family_modules('bench'))})")
    b.add_argument("--json", action="store_true", help="one JSON object per line")
    b.add_argument("--device", default="cpu", help="Warp device: cpu, cuda or cuda:N (default cpu)")
    b.add_argument("--quick", action="store_true", help="smaller sizes, for smoke tests")
    b.add_argument("--compare", action="store_true",
                   help="also time the reference library (PyTorch, OpenCV: the [bench] extra) on the same "
                        "inputs, interleaved; adds ref, ref_<phase>_s and speedup_<phase> (> 1: drlab faster), "
                        "or ref_missing when the library is not installed")
    b.set_defaults(fn=_cmd_bench)

    sf = sub.add_parser(
        "sfm", help="structure from motion: a folder of photos -> a COLMAP model (pycolmap, CPU)",
        description="Run pycolmap's SIFT feature extraction, matching and incremental mapping on the images "
                    "directly in IMAGES_DIR, then undistort them (unless --no-undistort), and write a COLMAP "
                    "folder that fit_splats/fit_nerf --data read: OUT/images/, OUT/sparse/0/ and OUT/sfm.json "
                    "(research/poses/sfm.py). OUT appears only when complete. Fewer registered images than --min-registered is an error (exit 2).")
    sf.add_argument("images_dir", type=directory_path, help="folder of .png/.jpg images (sub-folders are ignored)")
    sf.add_argument("--out", required=True, type=directory_path, help="output folder (must not exist; see --force)")
    sf.add_argument("--matcher", choices=["exhaustive", "sequential"], default="exhaustive",
                    help="exhaustive: every pair (unordered photos); sequential: each image with the next --overlap "
                         "images by name (video frames, camera paths). Default exhaustive")
    sf.add_argument("--overlap", type=int, default=10, help="sequential matching: images matched ahead (default 10)")
    sf.add_argument("--shared-camera", action="store_true",
                    help="one camera for every image (COLMAP's single-camera mode; the images must have one size)")
    sf.add_argument("--camera-model", default="SIMPLE_RADIAL",
                    choices=["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE"],
                    help="camera model to estimate (default SIMPLE_RADIAL, COLMAP's; a distorted model is "
                         "undistorted at the end unless --no-undistort)")
    sf.add_argument("--no-undistort", action="store_true",
                    help="write the estimated cameras as they are (with their distortion) and copy the registered "
                         "images unchanged: fit_splats and fit_nerf read SIMPLE_RADIAL, RADIAL, OPENCV and "
                         "OPENCV_FISHEYE through their lens models (kernels/lens.py)")
    sf.add_argument("--intrinsics", default=None, metavar="FX,FY,CX,CY",
                    help="known intrinsics in pixels: one PINHOLE camera for every image, kept fixed in bundle "
                         "adjustment (overrides --camera-model)")
    sf.add_argument("--min-registered", type=int, default=None,
                    help="fewest registered images accepted (default: half of them, at least 3)")
    sf.add_argument("--max-features", type=int, default=8192, help="SIFT features per image (default 8192)")
    sf.add_argument("--threads", type=int, default=-1,
                    help="CPU threads (default -1: every core; COLMAP's matching and mapping then vary from run to run, 1 thread is reproducible)")
    sf.add_argument("--seed", type=seed_value, default=0, help="the mapper's random seed (default 0)")
    sf.add_argument("--force", action="store_true", help="replace --out when it is a previous `drlab sfm` output")
    sf.add_argument("--verbose", action="store_true", help="show COLMAP's own log (hidden by default)")
    sf.add_argument("--no-progress", action="store_true", help="hide the progress bars")
    sf.set_defaults(fn=_cmd_sfm)

    ls = sub.add_parser("list", help="list registered experiments, gradient checks and bench families")
    ls.set_defaults(fn=_cmd_list)
    return p


def _command_name(argv: list[str]) -> str:
    """`drlab <command>` for messages: the first word that is a command, else plain `drlab`."""
    commands = {"dataset", "run", "reproduce", "sweep", "gradcheck", "bench", "list", "sfm"}
    word = next((a for a in argv if a in commands), None)
    return f"drlab {word}" if word else "drlab"


def main(argv: list[str] | None = None) -> int:
    """Parse `argv` and run the command; its exit status (module docstring: errors, Ctrl-C)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    # Everything after the first `--` belongs to the experiment (`drlab run X -- --its-option`).
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]  # global: accepted before or after the command
    prog = _command_name(argv)
    try:
        try:
            args = build_parser().parse_args(argv)
            if extra and args.command != "run":
                raise UsageError(f"options after `--` are only for `drlab run`: {' '.join(extra)}")
            args.extra, args.debug = extra, debug
            return int(args.fn(args) or 0)
        except USER_ERRORS as e:
            if debug:
                raise
            print(f"{prog}: {one_line(e)}", file=sys.stderr, flush=True)
            return EXIT_USAGE
        except Exception as e:
            if caused_by_interrupt(e):
                raise KeyboardInterrupt from e
            raise
    except _ChildInterrupted:
        return EXIT_INTERRUPTED  # the experiment's process has said so
    except KeyboardInterrupt:
        if debug:
            raise
        print(f"{prog}: interrupted (Ctrl-C)", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
