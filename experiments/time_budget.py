#!/usr/bin/env python3
"""PSNR against training time: what a fit on the CPU gives in 10, 30 and 60 minutes.

One dataset, read with its paper's protocol exactly as fit_splats and fit_nerf read it (--data,
--format, --resolution; default: the official NeRF-synthetic lego under <data>/nerf_synthetic/lego
at 1/4, 200x200), fitted several times with longer and longer schedules:
  * splats: fit_splats' training (research.splats.train) at each of --splat-iterations; the 3DGS
    schedule is scaled to the iteration count (densification window, opacity resets, SH degree
    steps and the position learning rate's decay all follow it), so every point of the curve is a
    complete schedule of that length, not a snapshot of a longer run;
  * fields: fit_nerf's plan for each of --fields, with every stage's iteration count multiplied by
    each of --field-scales (the learning-rate decay and the coarse-to-fine stages follow).
Each run of a method starts from the same initialisation and is scored on the whole test split
(PSNR and SSIM on sRGB, the protocol's background). Without --data, each method reads its own
experiment's default Mitsuba `objects` render (the two differ in quick mode). Training time is
measured two ways: wall-clock seconds, and CPU seconds of the process over all its threads
(time.process_time), which grows much less than wall time when other jobs share the machine.
Evaluation is not counted.

The budget table answers "what do I get in B minutes": for each budget in --budgets, the best test
PSNR among the runs whose training wall time fits in B, per method. Nothing here is tuned: the
schedules are fit_splats' and fit_nerf's defaults (chosen on drlab's Mitsuba data), only stretched.

Writes results/time_budget/{table.md, metrics.json, curve.png}.
"""

from __future__ import annotations

import time
from dataclasses import asdict, replace
from typing import Any

from experiments.fit_splats import DATA_HELP
from research.experiment import Context, Experiment
from research.results import finish_figure, markdown_table

LEGO = "nerf_synthetic/lego"


def sizes(quick: bool, smoke: bool) -> dict[str, Any]:
    """The default iteration counts, field scales and budgets per mode."""
    if smoke:
        return {"splat_iterations": [10, 30], "field_scales": [0.5, 1.0], "budgets": [1, 2]}
    if quick:
        return {"splat_iterations": [200, 800], "field_scales": [0.5, 1.0], "budgets": [2, 5, 10]}
    return {"splat_iterations": [1000, 3000, 10000], "field_scales": [1.0, 4.0], "budgets": [10, 30, 60]}


def add_options(p) -> None:
    from experiments.fit_nerf import FIELDS
    from experiments.fit_splats import add_data_options, add_splat_options

    add_data_options(p)
    p.add_argument("--splat-iterations", type=int, nargs="*", default=None, metavar="N",
                   help="splat schedules to run, in iterations (default 1000 3000 10000; quick 200 800; smoke 10 30); "
                        "none: no splat runs")
    p.add_argument("--fields", nargs="*", default=["hashgrid"], choices=FIELDS,
                   help="fields to run (default hashgrid, the fastest of fit_nerf's at equal PSNR on lego 1/4); "
                        "none: no field runs")
    p.add_argument("--field-scales", type=float, nargs="+", default=None, metavar="S",
                   help="multiples of each field's default schedule (default 1 4; quick and smoke 0.5 1)")
    p.add_argument("--budgets", type=float, nargs="+", default=None, metavar="MIN",
                   help="wall-time budgets of the budget table, in minutes (default 10 30 60)")
    add_splat_options(p)


def resolve_data(ctx: Context) -> None:
    """--data: a dataset folder as given, else <data>/nerf_synthetic/lego when present (at 1/4 unless
    --resolution says otherwise), else the Mitsuba `objects` renders cached under --data."""
    from research.datasets import detect_format

    args = ctx.args
    if args.format == "auto" and detect_format(ctx.data) is None and (ctx.data / LEGO).is_dir():
        args.data = str(ctx.data / LEGO)
    if args.resolution is None and (args.format == "blender" or detect_format(ctx.data) == "blender"):
        args.resolution = 4


def splat_runs(ctx: Context, iterations: list[int]) -> tuple[list[dict], Any]:
    """fit_splats' training and test scoring at each iteration count; the rows and the prepared data."""
    from experiments import fit_splats as fs

    base = fs.setup(ctx.quick, ctx.smoke)
    prep = fs.prepare(ctx, base)
    rows = []
    for n in iterations:
        _, result, ev, cpu = fs.train_and_score(prep, replace(base, iterations=n), ctx)
        rows.append({"method": "splats", "schedule": f"{n} iterations", "iterations": n, "psnr": ev.psnr,
                     "ssim": ev.ssim, "wall_s": result.seconds, "cpu_s": cpu, "size": result.model.n,
                     "size_unit": "splats", "max_gaussians": base.max_gaussians})
        print(f"splats {n} it: PSNR {ev.psnr:.2f} dB, {result.seconds:.0f} s wall, {cpu:.0f} s CPU, "
              f"{result.model.n} splats", flush=True)
    return rows, prep


def field_runs(ctx: Context, fields: list[str], scales: list[float]) -> tuple[list[dict], Any]:
    """fit_nerf's fit of each field with its stages' iterations times each scale; the rows and the data."""
    from experiments import fit_nerf as fn

    fd = fn.prepare(ctx)
    plans = fn.plans(ctx.quick, fd.bbox, ctx.smoke)
    rows = []
    for name in fields:
        for s in scales:
            stages = [replace(st, iters=max(1, round(st.iters * s))) for st in plans[name]["stages"]]
            plan = {**plans[name], "stages": stages}
            wall0, cpu0 = time.perf_counter(), time.process_time()
            field, occupancy, _ = fn.fit_one(name, plan, fd.bank, fd.bbox, ctx.quick, ctx.seed, ctx.progress,
                                             random_background=fd.external)
            wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
            ev = fn.evaluate(field, occupancy, fd.bbox, plan["config"]["step"], fd.test_split, fd.gt,
                             fd.background, fd.ds.ndc)
            iters = sum(st.iters for st in stages)
            rows.append({"method": name, "schedule": f"{s:g}x default, {iters} iterations", "iterations": iters,
                         "scale": s, "psnr": ev["mean"]["psnr"], "ssim": ev["mean"]["ssim"],
                         "wall_s": wall, "cpu_s": cpu, "size": field.n_params(), "size_unit": "parameters"})
            print(f"{name} x{s:g}: PSNR {ev['mean']['psnr']:.2f} dB, {wall:.0f} s wall, {cpu:.0f} s CPU",
                  flush=True)
    return rows, fd


def budget_table(rows: list[dict], budgets: list[float]) -> tuple[list[str], list[list[str]]]:
    """Per budget (minutes of training wall time) and method: the best PSNR among the runs that fit in it."""
    methods = list(dict.fromkeys(r["method"] for r in rows))
    table = []
    for b in budgets:
        cells = [f"{b:g} min"]
        for m in methods:
            fit = [r for r in rows if r["method"] == m and r["wall_s"] <= 60 * b]
            best = max(fit, key=lambda r: r["psnr"]) if fit else None
            cells.append(f"{best['psnr']:.2f} ({best['schedule']})" if best else "- (no run fits)")
        table.append(cells)
    return ["budget (training wall time)", *methods], table


def curve_figure(rows: list[dict], budgets: list[float], path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FixedLocator, FormatStrFormatter, NullFormatter

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
    for ax, key, label in ((axes[0], "wall_s", "training wall time (min)"),
                           (axes[1], "cpu_s", "training CPU time, all threads (min)")):
        for i, m in enumerate(dict.fromkeys(r["method"] for r in rows)):
            pts = sorted((r[key] / 60, r["psnr"]) for r in rows if r["method"] == m)
            ax.plot(*zip(*pts), "o-", color=f"C{i}", label=m)
        if key == "wall_s":
            for b in budgets:
                ax.axvline(b, color="0.75", lw=0.8, ls="--")
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(FixedLocator([0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 30, 60, 120, 240]))
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("test PSNR (dB)")
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=9)
    finish_figure(fig, path)


def run(ctx: Context) -> int:
    import os

    from experiments import fit_splats as fs
    from experiments.fit_splats import data_record

    args = ctx.args
    resolve_data(ctx)
    d = sizes(ctx.quick, ctx.smoke)
    iterations = d["splat_iterations"] if args.splat_iterations is None else args.splat_iterations
    scales = args.field_scales or d["field_scales"]
    budgets = args.budgets or d["budgets"]
    for name, values in (("--splat-iterations", iterations), ("--field-scales", scales), ("--budgets", budgets)):
        if any(v <= 0 for v in values):
            raise ValueError(f"{name}: expected positive values, got {values}")
    if not iterations and not args.fields:
        raise ValueError("--splat-iterations and --fields are both empty: nothing to run")

    rows: list[dict] = []
    data = []  # (dataset, its path, test split, train split) of each method's data
    if iterations:
        splat_rows, prep = splat_runs(ctx, sorted(iterations))
        rows += splat_rows
        data.append((prep.ds, prep.path, prep.train_split, prep.test_split))
    if args.fields:
        field_rows, fd = field_runs(ctx, args.fields, sorted(scales))
        rows += field_rows
        data.append((fd.ds, fd.data, fd.train_split, fd.test_split))
    ds, path, train_split, test_split = data[0]
    record = data_record(ds, path)
    cam0 = test_split.cameras[0]
    source = "drlab's Mitsuba render" if ds.format == "drlab" else f"{ds.format} format, {record['protocol']}"
    scene = (f"{record['scene']} ({source}) {cam0.width}x{cam0.height}, "
             f"{len(train_split.cameras)} train / {len(test_split.cameras)} test views")
    cpus = os.cpu_count()
    title = f"{scene}; {cpus}-CPU machine, device {ctx.device}"
    curve_figure(rows, budgets, ctx.out / "curve.png", title)

    headers = ["method", "schedule", "test PSNR (dB)", "test SSIM", "train wall", "train CPU", "size"]
    runs = [[r["method"], r["schedule"], f"{r['psnr']:.2f}", f"{r['ssim']:.4f}", f"{r['wall_s'] / 60:.1f} min",
             f"{r['cpu_s'] / 60:.1f} min", f"{r['size']:,} {r['size_unit']}"] for r in rows]
    bh, brows = budget_table(rows, budgets)
    table = (f"PSNR against training time on {scene}, device `{ctx.device}` ({cpus} CPUs visible). Evaluation: "
             f"{record['eval_protocol']}. Each row is a complete schedule of that length (fit_splats' 3DGS schedule "
             "scaled to the iteration count; fit_nerf's stages times the scale), from the same initialisation. "
             "Train CPU is the process time of all threads; wall time grows when other jobs share the machine, "
             "CPU time mostly not.\n\n" + markdown_table(headers, runs)
             + "\nBest test PSNR (dB) among the runs whose training wall time fits in the budget:\n\n"
             + markdown_table(bh, brows) + "\n![PSNR against training time](curve.png)\n")
    metrics = {"scene": scene, "data": record, "eval_protocol": record["eval_protocol"], "cpus": cpus,
               "runs": rows, "budgets_min": budgets,
               "budget_table": [dict(zip(bh, r)) for r in brows]}
    ctx.write_results(config={"splat_iterations": iterations, "fields": args.fields,
                              "field_scales": scales, "budgets": budgets, "resolution": args.resolution,
                              "splat_setup": asdict(fs.setup(ctx.quick, ctx.smoke))},
                      metrics=metrics, table_md=table)
    return 0


main = Experiment("time_budget", __doc__, run, add_options, data_help=DATA_HELP + "; a folder holding "
                  f"{LEGO} stands for that scene",
                  seed_help="seed of the initial points, the fields' initialisation and the training batches",
                  sizes="Quick: 200 and 800 splat iterations and half and full field schedules on the data given "
                        "(Mitsuba `objects` at 64x64 without data); smoke: Mitsuba `objects` at 32x32, 10 and 30 "
                        "iterations.").script(__name__)
