#!/usr/bin/env python3
"""Splat density control: 3DGS's clone / split / prune against 3DGS-MCMC's relocation and against AbsGS's
absolute-gradient densification, at equal splat count and at equal CPU time.

Data and schedule are fit_splats' (experiments/fit_splats.py Setup): the Mitsuba `objects` scene
(100 views at 128x128, 64 spp; quick 40 views at 64x64; smoke 8 at 32x32), splats initialised from
the train views' ground-truth depth, trained by research.splats.train on the 3DGS schedule scaled to
the iteration count, scored on the test split (PSNR and SSIM on sRGB, research.metrics).

Five models, in one run, in this order:

  3DGS             the default density control (research.splats.densify; fit_splats' cap on the count);
  MCMC, equal count   TrainConfig(strategy="mcmc") (research/splats/mcmc.py) with its hard cap set to the
                   count 3DGS ENDED with, the same iterations;
  MCMC, equal time    the same cap, with the iteration count (and so the scaled schedule) chosen to take
                   3DGS's training CPU time: iterations x (3DGS CPU s) / (equal-count MCMC CPU s),
                   rounded, i.e. the MCMC run's CPU time per iteration measured in this run is taken as
                   its cost per iteration. Its own CPU time is reported beside it (the match is only as
                   good as that prediction);
  AbsGS, equal count  3DGS's density control on AbsGS's absolute mean2d gradient
                   (DensifyConfig.absgs(): absgrad=True, threshold 0.0008), with the count capped at the
                   count 3DGS ended with (max_gaussians; pruning may leave it below), the same iterations;
  AbsGS, equal time   the same, with the iterations chosen as for MCMC's equal-time row, from the
                   equal-count AbsGS run's CPU time.

MCMC grows by gsplat's 1.05x per refinement, so the cap is reached only when the scaled schedule has
enough refinements: the full run's 48 (every 50 iterations from 100 to 2450) take 8000 splats to the
cap; quick's 13 (800 iterations) allow at most 3000 x 1.05^13 ~ 5660 of its ~12000, so there the MCMC
rows are at a cap, not at an equal count (the table's splat column says which).

CPU time is time.process_time() around training (every thread of the process); wall time beside it.
The MCMC models start from the same points with gsplat's "mcmc" initialisation (opacity 0.5, scales
0.1 x 3DGS's kNN scale: research.splats.mcmc.INIT_OPACITY, INIT_SCALE_FACTOR); 3DGS from 3DGS's
(0.1, 1 x). Settings: MCMC's are gsplat's MCMCStrategy / simple_trainer defaults (set by gsplat for
30k-iteration runs on its benchmark scenes), iteration numbers scaled to the run; the schedule and
cap are fit_splats'. AbsGS's threshold 0.0008 is the value gsplat's DefaultStrategy documentation
gives for absgrad=True (research.splats.densify.ABSGRAD_GRAD_THRESHOLD), everything else 3DGS's.
Nothing was tuned on this experiment's data. Writes
results/splat_densification/{table.md, metrics.json, figure.png}.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from experiments.fit_splats import setup_sizes
from research.datasets import CACHE_ROOT_HELP
from research.experiment import Context, Experiment
from research.results import finish_figure, image_panel, markdown_table


def add_options(p) -> None:
    p.add_argument("--iterations", type=int, default=None,
                   help="iterations of the 3DGS and equal-count MCMC models (default fit_splats': 3000; quick "
                        "800; smoke 40); the equal-time model's follow from the measured CPU times")


def figure(gt: np.ndarray, fits: dict[str, dict], path: Path) -> None:
    import matplotlib.pyplot as plt

    from research.metrics import srgb_on_black

    n = 1 + len(fits)
    fig = plt.figure(figsize=(2.4 * n, 5.2))
    axes = [fig.add_subplot(2, n, i + 1) for i in range(n)]
    image_panel(fig, axes[0], srgb_on_black(gt), "ground truth (Mitsuba)", fontsize=7, interpolation="nearest")
    for ax, (label, f) in zip(axes[1:], fits.items()):
        image_panel(fig, ax, srgb_on_black(f["render"]), f"{label}\n{f['psnr']:.2f} dB, {f['splats']} splats",
                    fontsize=7, interpolation="nearest")
    ax_n = fig.add_subplot(2, 2, 3)
    ax_l = fig.add_subplot(2, 2, 4)
    for label, f in fits.items():
        it = [h["iteration"] for h in f["history"]]
        ax_n.plot(it, [h["gaussians"] for h in f["history"]], label=label)
        ax_l.plot(it, [h["l1"] for h in f["history"]], label=label)
    ax_n.set_xlabel("iteration")
    ax_n.set_ylabel("splats")
    ax_l.set_xlabel("iteration")
    ax_l.set_ylabel("train L1 (mean over the log interval)")
    ax_l.set_yscale("log")
    ax_n.legend(fontsize=7)
    finish_figure(fig, path)


def run(ctx: Context) -> int:
    from experiments.fit_splats import setup
    from research import datasets
    from research.datasets import formats
    from research.splats import mcmc, model as sm, train as st

    cfg = setup(ctx.quick, ctx.smoke)
    iterations = ctx.int_option("--iterations", cfg.iterations)
    dcfg = datasets.DatasetConfig("objects", views=cfg.views, res=cfg.res, spp=cfg.spp, seed=ctx.seed)
    path = datasets.ensure(dcfg, datasets.cache_dir(dcfg, ctx.data), show_progress=ctx.progress)
    ds = datasets.load(path)
    train_split, test_split = ds.load_split("train"), ds.load_split("test")
    train_rgb = formats.protocol_target_linear(train_split, ds.protocol)
    test_rgb = formats.protocol_target_linear(test_split, ds.protocol)
    points, colors = sm.points_from_depth(train_split.cameras, train_split.rgba, train_split.depth,
                                          cfg.init_points, ctx.seed)
    init_3dgs = sm.from_points(points, colors)
    init_mcmc = sm.from_points(points, colors, init_opacity=mcmc.INIT_OPACITY)
    init_mcmc.log_scales += np.float32(np.log(mcmc.INIT_SCALE_FACTOR))
    extent = sm.scene_extent(train_split.cameras)

    def fit(label: str, init, tcfg) -> dict:
        cpu0, wall0 = time.process_time(), time.perf_counter()
        res = st.train(init, train_split.cameras, train_rgb, extent, tcfg, device=ctx.device, progress=ctx.progress)
        cpu_s, wall_s = time.process_time() - cpu0, time.perf_counter() - wall0
        ev = st.evaluate(res.model, test_split.cameras, test_rgb, res.sh_degree, device=ctx.device)
        relocated = sum(e.get("relocated", 0) for e in res.events)
        return {"label": label, "strategy": tcfg.strategy, "iterations": tcfg.iterations, "psnr": ev.psnr,
                "ssim": ev.ssim, "psnr_linear": ev.psnr_linear, "splats": res.model.n, "cpu_seconds": cpu_s,
                "wall_seconds": wall_s, "relocated": relocated, "history": res.history, "events": res.events,
                "render": ev.renders[0], "train": asdict(tcfg)}

    base = st.TrainConfig(iterations=iterations, seed=ctx.seed,
                          densify=st.DensifyConfig(max_gaussians=cfg.max_gaussians))
    fits = {}
    bar = ctx.tqdm(total=5, desc="models")
    fits["3DGS"] = fit("3DGS", init_3dgs, base)
    bar.update()
    cap = fits["3DGS"]["splats"]
    mcfg = st.MCMCConfig(cap_max=cap)
    equal_n = st.TrainConfig(iterations=iterations, seed=ctx.seed, strategy="mcmc", mcmc=mcfg)
    fits["MCMC, equal count"] = fit("MCMC, equal count", init_mcmc, equal_n)
    bar.update()
    iters_t = max(1, round(iterations * fits["3DGS"]["cpu_seconds"] / fits["MCMC, equal count"]["cpu_seconds"]))
    equal_t = st.TrainConfig(iterations=iters_t, seed=ctx.seed, strategy="mcmc", mcmc=mcfg)
    fits["MCMC, equal time"] = fit("MCMC, equal time", init_mcmc, equal_t)
    bar.update()
    abs_cfg = st.DensifyConfig.absgs(max_gaussians=min(cfg.max_gaussians, cap))
    abs_n = st.TrainConfig(iterations=iterations, seed=ctx.seed, densify=abs_cfg)
    fits["AbsGS, equal count"] = fit("AbsGS, equal count", init_3dgs, abs_n)
    bar.update()
    iters_abs = max(1, round(iterations * fits["3DGS"]["cpu_seconds"] / fits["AbsGS, equal count"]["cpu_seconds"]))
    abs_t = st.TrainConfig(iterations=iters_abs, seed=ctx.seed, densify=abs_cfg)
    fits["AbsGS, equal time"] = fit("AbsGS, equal time", init_3dgs, abs_t)
    bar.update()
    bar.close()

    figure(test_rgb[0], fits, ctx.out / "figure.png")
    headers = ["model", "iterations", "splats", "test PSNR (dB)", "test SSIM", "PSNR linear (dB)", "relocated",
               "train CPU s", "CPU / 3DGS", "train wall s"]
    t0 = fits["3DGS"]["cpu_seconds"]
    rows = [[f["label"], f["iterations"], f["splats"], f"{f['psnr']:.2f}", f"{f['ssim']:.4f}",
             f"{f['psnr_linear']:.2f}", f["relocated"] if f["strategy"] == "mcmc" else "-",
             f"{f['cpu_seconds']:.1f}", f"{f['cpu_seconds'] / t0:.2f}", f"{f['wall_seconds']:.1f}"]
            for f in fits.values()]
    cam0 = test_split.cameras[0]
    table = (f"Mitsuba `objects` {cam0.width}x{cam0.height}, {len(train_split.cameras)} train / "
             f"{len(test_split.cameras)} test views (fit_splats' data and schedule; {cfg.init_points} initial points "
             f"from depth). 3DGS: default density control, at most {cfg.max_gaussians} splats. MCMC: "
             f"research.splats.mcmc with gsplat's defaults and a hard cap of {cap} (the count 3DGS ended with); "
             "equal time: iterations = 3DGS iterations x 3DGS CPU s / equal-count MCMC CPU s. AbsGS: 3DGS's "
             f"density control on the absolute mean2d gradient, threshold {abs_cfg.grad_threshold:g} (gsplat's "
             f"documented value for absgrad, not tuned here), at most {abs_cfg.max_gaussians} splats; its equal "
             "time likewise from the equal-count AbsGS CPU s. CPU s: process "
             "time of training (all threads); wall s on this machine, shared. PSNR/SSIM on sRGB, test split.\n\n"
             + markdown_table(headers, rows) + "\n\n![a test view and the training curves](figure.png)\n")
    metrics = {"dataset": {"path": str(path), "config": dcfg.__dict__}, "cap": cap,
               "equal_time_rule": "iterations x 3DGS CPU s / equal-count (MCMC or AbsGS) CPU s",
               "absgrad_threshold": {"value": abs_cfg.grad_threshold,
                                     "source": "gsplat DefaultStrategy docstring (absgrad=True), not tuned here"},
               "models": {k: {kk: vv for kk, vv in f.items() if kk != "render"} for k, f in fits.items()}}
    ctx.write_results(config={**asdict(cfg), "iterations": iterations}, metrics=metrics,
                      table_md=table)
    return 0


main = Experiment("splat_densification", __doc__, run, add_options,
                  seed_help="seed of the dataset's cameras, the initial points and training",
                  sizes=setup_sizes("~40 min on 2 shared cores"),
                  data_help=CACHE_ROOT_HELP).script(__name__)
