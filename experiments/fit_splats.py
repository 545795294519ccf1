#!/usr/bin/env python3
"""Fit 3D Gaussian splats to the Mitsuba `objects` scene on the CPU, and measure them.

Renders the multi-view dataset (`drlab dataset --scene objects`: 100 views at
128x128, 64 spp, into data/fit_splats-objects-128; the quick mode uses 40 views
at 64x64, 16 spp), initialises splats from the ground-truth depth of the train
views back-projected to coloured points (or, with --init random, from random
points in the scene box), and trains them as 3DGS does (research.splats.train:
L1 + 0.2 D-SSIM, Adam with the 3DGS learning rates, the SH degree schedule and
densification on the 3DGS schedule scaled to the iteration count), on the
Warp kernels of kernels/splat/ with their hand-written backward.

Reported on the test split: PSNR and SSIM (research.metrics; images clipped to
[0, 1] and sRGB-encoded as the dataset's PNGs, premultiplied on black, the
training background), the linear-space PSNR, the number of splats, the training
wall time, the forward render rate (frames per second over the test views,
median of 3 passes after a warm-up) and the size of the PLY file (standard 3DGS
layout, written and read back; the reloaded model must render the same image).

Writes results/fit_splats/{table.md, metrics.json, renders.png, training.png};
the PLY goes to build/fit_splats/point_cloud.ply (not committed: ~7.5 MB at 30k splats).
Outside quick mode, when results/fit_nerf/metrics.json exists too, also writes
results/comparison/table.md (3DGS Table 1 form: research.comparison).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from research import registry
from research.datasets import CACHE_ROOT_HELP
from research.experiment import Context, Experiment
from research.results import markdown_table, save_figure

REPO = registry.REPO_ROOT


@dataclass(frozen=True)
class Setup:
    views: int
    res: int
    spp: int
    iterations: int
    init_points: int
    max_gaussians: int


def setup(quick: bool, smoke: bool = False) -> Setup:
    if smoke:
        return Setup(views=8, res=32, spp=4, iterations=40, init_points=300, max_gaussians=1000)
    if quick:
        return Setup(views=40, res=64, spp=16, iterations=800, init_points=3000, max_gaussians=12_000)
    return Setup(views=100, res=128, spp=64, iterations=3000, init_points=8000, max_gaussians=30_000)


def renders_figure(gt: np.ndarray, renders: np.ndarray, per_view: list[dict], path: Path, n: int = 4) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research import io

    n = min(n, len(gt))
    fig, axes = plt.subplots(n, 3, figsize=(7.5, 2.6 * n), squeeze=False)
    for i in range(n):
        a, b = np.clip(gt[i], 0, 1), np.clip(renders[i], 0, 1)
        err = np.abs(io.linear_to_srgb(a) - io.linear_to_srgb(b)).mean(axis=2)
        for j, (img, title) in enumerate([(io.linear_to_srgb(a), "ground truth (Mitsuba)"),
                                          (io.linear_to_srgb(b), f"splats: {per_view[i]['psnr']:.2f} dB"),
                                          (err, "|error| (sRGB, mean over RGB)")]):
            ax = axes[i, j]
            im = ax.imshow(img, cmap="magma" if img.ndim == 2 else None, vmin=0, vmax=0.25 if img.ndim == 2 else 1)
            if img.ndim == 2:
                fig.colorbar(im, ax=ax, fraction=0.046)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(title, fontsize=9)
            elif j == 1:
                ax.set_title(f"{per_view[i]['psnr']:.2f} dB", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def training_figure(history: list[dict], events: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    it = [h["iteration"] for h in history]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.2))
    ax1.plot(it, [h["loss"] for h in history], label="loss (0.8 L1 + 0.2 D-SSIM)")
    ax1.plot(it, [h["l1"] for h in history], label="L1")
    ax1.set_yscale("log")
    ax1.set_xlabel("iteration")
    ax1.legend(fontsize=8)
    ax2.plot(it, [h["gaussians"] for h in history], color="C2")
    for e in events:
        if e.get("opacity_reset"):
            ax2.axvline(e["iteration"], color="0.7", lw=0.8, ls="--")
    ax2.set_xlabel("iteration")
    ax2.set_ylabel("splats (dashed: opacity reset)")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def add_options(p) -> None:
    p.add_argument("--ply", type=Path, default=None,
                   help="where to write the PLY (default build/fit_splats[-quick|-smoke]/point_cloud.ply, in the "
                        "checkout when run from one, else under the current directory)")
    p.add_argument("--init", choices=["depth", "random"], default="depth",
                   help="initial points: ground-truth depth of the train views, or random in the scene box")
    p.add_argument("--iterations", type=int, default=None, help="override the number of training iterations")


def run(ctx: Context) -> int:
    import warp as wp

    from research import datasets
    from research.metrics import EVAL_PROTOCOL
    from research.splats import model as sm, train as st

    args = ctx.args
    cfg = setup(ctx.quick, ctx.smoke)
    if args.iterations is not None:
        cfg = Setup(**{**asdict(cfg), "iterations": args.iterations})
    suffix = "" if ctx.mode == "full" else "-" + ctx.mode
    dcfg = datasets.DatasetConfig("objects", views=cfg.views, res=cfg.res, spp=cfg.spp, seed=ctx.seed)
    path = datasets.ensure(dcfg, datasets.cache_dir(dcfg, ctx.data), show_progress=ctx.progress)
    ds = datasets.load(path)
    train_split, test_split = ds.load_split("train"), ds.load_split("test")

    if args.init == "depth":
        points, colors = sm.points_from_depth(train_split.cameras, train_split.rgba, train_split.depth,
                                              cfg.init_points, ctx.seed)
    else:
        points, colors = sm.random_points(ds.bbox, cfg.init_points, ctx.seed)
    model = sm.from_points(points, colors)
    extent = sm.scene_extent(train_split.cameras)
    tcfg = st.TrainConfig(iterations=cfg.iterations, seed=ctx.seed,
                          densify=st.DensifyConfig(max_gaussians=cfg.max_gaussians))
    result = st.train(model, train_split.cameras, train_split.rgba[..., :3], extent, tcfg, device=ctx.device,
                      progress=ctx.progress)
    model = result.model

    ev = st.evaluate(model, test_split.cameras, test_split.rgba[..., :3], result.sh_degree, device=ctx.device)
    ev_train = st.evaluate(model, train_split.cameras[:10], train_split.rgba[:10, ..., :3], result.sh_degree,
                           device=ctx.device)
    fps = st.render_fps(model, test_split.cameras, result.sh_degree, device=ctx.device)

    ply_path = (args.ply or registry.base_dir() / "build" / f"fit_splats{suffix}" / "point_cloud.ply").absolute()
    same = st.ply_round_trip_identical(ply_path, model, test_split.cameras[0], result.sh_degree,
                                       device=ctx.device)
    ply_bytes = ply_path.stat().st_size
    if not same:
        raise RuntimeError(f"{ply_path}: the reloaded model renders a different image")

    metrics = {
        "method": "3DGS (drlab Warp kernels, CPU)" if ctx.device == "cpu" else "3DGS (drlab Warp kernels)",
        "scene": f"objects {cfg.res}x{cfg.res}, {len(train_split.cameras)} train / {len(test_split.cameras)} test",
        "eval_protocol": EVAL_PROTOCOL,
        "test_psnr": ev.psnr, "test_ssim": ev.ssim, "test_psnr_linear": ev.psnr_linear,
        "train_views_psnr": ev_train.psnr, "gaussians": model.n, "train_seconds": result.seconds,
        "train_iterations": cfg.iterations, "render_fps": fps, "ply_bytes": ply_bytes,
        "ply_path": str(ply_path.relative_to(REPO)) if ply_path.is_relative_to(REPO) else str(ply_path),
        "ply_roundtrip_identical": same, "init": args.init, "init_points": len(points), "extent": extent,
        "schedule": asdict(st.Schedule.scaled(cfg.iterations)), "per_view": ev.per_view,
        "history": result.history, "densify_events": result.events, "dataset": str(path.relative_to(REPO))
        if path.is_relative_to(REPO) else str(path), "dataset_hash": ds.manifest.get("content_hash"),
    }
    headers = ["scene", "train / test views", "iterations", "init", "splats", "test PSNR (dB)", "test SSIM",
               "PSNR linear (dB)", "train-view PSNR", "train time", "render FPS", "PLY size"]
    rows = [[f"objects {cfg.res}x{cfg.res}", f"{len(train_split.cameras)} / {len(test_split.cameras)}",
             cfg.iterations, f"{args.init} ({len(points)} pts)", model.n, f"{ev.psnr:.2f}", f"{ev.ssim:.4f}",
             f"{ev.psnr_linear:.2f}", f"{ev_train.psnr:.2f}", f"{result.seconds:.0f} s", f"{fps:.1f}",
             f"{ply_bytes / 1e6:.2f} MB"]]
    table = (f"3D Gaussian splatting fitted with drlab's Warp kernels (hand-written backward) on Warp device "
             f"`{wp.get_device(ctx.device)}`: 3DGS loss, learning rates and schedule scaled to {cfg.iterations} "
             f"iterations, at most {cfg.max_gaussians} splats (a CPU-time cap on densification). Evaluation: "
             f"{EVAL_PROTOCOL}. Render FPS: forward only (projection, binning, sorting, rasterisation) at the "
             "test resolution. Train-view PSNR on the first 10 train views.\n\n" + markdown_table(headers, rows)
             + "\n![renders beside the ground truth](renders.png)\n\n![training](training.png)\n")
    renders_figure(test_split.rgba[..., :3], ev.renders, ev.per_view, ctx.out / "renders.png")
    training_figure(result.history, result.events, ctx.out / "training.png")
    train_config = {k: (asdict(v) if hasattr(v, "__dataclass_fields__") else v) for k, v in asdict(tcfg).items()}
    ctx.write_results(config={"quick": ctx.quick, **asdict(cfg), "train": train_config},
                      metrics=metrics, table_md=table, compare=True)
    return 0


main = Experiment("fit_splats", __doc__, run, add_options, data_help=CACHE_ROOT_HELP,
                  seed_help="seed of the dataset render, the initial points and training",
                  sizes="Quick: 40 views at 64x64, 800 iterations (a few minutes on 2 cores); smoke: 8 views at "
                        "32x32, 4 spp, 40 iterations.").script(__name__)
