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

Other data (`--data PATH`, the format detected or given by `--format`; research.datasets.formats):
a NeRF-synthetic/Blender folder or a COLMAP / Mip-NeRF 360 folder is trained and scored with its
paper's protocol (the dataset's Protocol: split, resolution, background; PSNR and SSIM as above, on
the sRGB targets of that protocol): on white for NeRF-synthetic, opaque photographs at images_N for
Mip-NeRF 360. The splats start from the SfM points with their colours when the data has them
(COLMAP, as 3DGS does: every point, up to the splat cap), else from random points in the scene
bound (3DGS's synthetic-scene start); an LLFF forward-facing folder (no SfM points, but per-view
near/far bounds) starts from points in the training views' frusta between their bounds, uniform in
disparity, coloured by their pixel (research.splats.model.points_in_frusta; --init frustum).
`--resolution N` reads the images at 1/N.

Writes results/fit_splats/{table.md, metrics.json, renders.png, training.png};
the PLY goes to build/fit_splats/point_cloud.ply (not committed: ~7.5 MB at 30k splats).
Outside quick mode, when results/fit_nerf/metrics.json exists too, also writes
results/comparison/table.md (3DGS Table 1 form: research.comparison).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from research import registry
from research.datasets import CACHE_ROOT_HELP
from research.experiment import Context, Experiment
from research.results import finish_figure, image_panel, markdown_table

REPO = registry.REPO_ROOT
DATA_HELP = ("a NeRF-synthetic/Blender, COLMAP / Mip-NeRF 360, LLFF or `drlab dataset` folder, read with its paper's "
             "protocol (see --format); any other folder is the " + CACHE_ROOT_HELP)


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


def setup_sizes(full_time: str) -> str:
    """The --help sizes of an experiment that trains on `setup`'s data and schedule; `full_time`: how long
    its full run takes."""
    full, quick, smoke = setup(False), setup(True), setup(False, smoke=True)
    return (f"Full: fit_splats' ({full.views} views at {full.res}x{full.res}, {full.spp} spp, {full.iterations} "
            f"iterations, cap {full.max_gaussians}; {full_time}); quick: {quick.views} views at "
            f"{quick.res}x{quick.res}, {quick.iterations} iterations; smoke: {smoke.views} views at "
            f"{smoke.res}x{smoke.res}, {smoke.iterations} iterations.")


def renders_figure(gt: np.ndarray, renders: np.ndarray, per_view: list[dict], path: Path, n: int = 4,
                   gt_label: str = "ground truth (Mitsuba)") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research import io

    n = min(n, len(gt))
    fig, axes = plt.subplots(n, 3, figsize=(7.5, 2.6 * n), squeeze=False)
    for i in range(n):
        a, b = np.clip(gt[i], 0, 1), np.clip(renders[i], 0, 1)
        err = np.abs(io.linear_to_srgb(a) - io.linear_to_srgb(b)).mean(axis=2)
        for j, (img, title) in enumerate([(io.linear_to_srgb(a), gt_label),
                                          (io.linear_to_srgb(b), f"splats: {per_view[i]['psnr']:.2f} dB"),
                                          (err, "|error| (sRGB, mean over RGB)")]):
            shown = title if i == 0 else f"{per_view[i]['psnr']:.2f} dB" if j == 1 else None
            image_panel(fig, axes[i, j], img, shown, colorbar=img.ndim == 2, cmap="magma" if img.ndim == 2 else None,
                        vmin=0, vmax=0.25 if img.ndim == 2 else 1)
    finish_figure(fig, path)


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
    finish_figure(fig, path)


def add_data_options(p) -> None:
    """--format and --resolution (shared with fit_nerf)."""
    from research.datasets.formats import FORMATS

    p.add_argument("--format", choices=["auto", *FORMATS], default="auto",
                   help="format of --data: a `drlab dataset` folder, a NeRF-synthetic/Blender folder "
                        "(transforms_*.json), a COLMAP / Mip-NeRF 360 folder (sparse/0, images*/), an LLFF folder "
                        "(poses_bounds.npy, images_N/; it wins over a sparse/ beside it); auto (default) "
                        "detects it, and a folder of none of them is the cache root of the Mitsuba renders")
    p.add_argument("--resolution", type=int, default=None,
                   help="read the images at 1/N of their size (Blender: box-averaged; COLMAP, LLFF: the images_N "
                        "folder); default: the protocol's (Blender 1; Mip-NeRF 360: 4 outdoors, 2 indoors; LLFF 8)")


def open_external(ctx: Context):
    """The dataset that --data names in another format (or --format drlab), or None for the cache root.

    Raises ValueError (research.datasets.DatasetError) on a folder that is not what --format says.
    """
    from research.datasets import detect_format, open_dataset

    args = ctx.args
    fmt = detect_format(ctx.data) if args.format == "auto" else args.format
    if args.resolution is not None and args.resolution < 1:
        raise ValueError(f"--resolution: expected an integer >= 1, got {args.resolution}")
    if fmt is None:
        if args.resolution is not None:
            raise ValueError(f"--resolution: applies to a --data folder in Blender, COLMAP or LLFF format; {ctx.data} "
                             "is neither (it is used as the cache root of the Mitsuba renders)")
        return None
    ds = open_dataset(ctx.data, fmt, args.resolution)
    from research.metrics import SSIM_WINDOW

    small = [v for v in ds.split_views("test") if min(v.camera.width, v.camera.height) < SSIM_WINDOW]
    if small:
        cam = small[0].camera
        raise ValueError(f"--data: the test images of {ctx.data} are {cam.width}x{cam.height} at this resolution; "
                         f"SSIM needs at least {SSIM_WINDOW}x{SSIM_WINDOW} (choose a smaller --resolution)")
    return ds


def data_record(ds, path: Path) -> dict:
    """What metrics.json says about the data: format, scene, protocol, resolution, content hash."""
    from research.metrics import EVAL_PROTOCOL

    proto = ds.protocol
    return {"format": ds.format, "scene": ds.scene or ds.manifest.get("config", {}).get("scene", ""),
            "protocol": proto.name if proto else "drlab", "resolution": proto.resolution if proto else "",
            "background": list(proto.background) if proto and proto.background else None,
            "eval_protocol": proto.description if proto else EVAL_PROTOCOL,
            "path": str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path),
            "content_hash": ds.manifest.get("content_hash")}


def add_splat_options(p) -> None:
    """--init and --mode (shared with time_budget)."""
    p.add_argument("--init", choices=["depth", "random", "sfm", "frustum"], default=None,
                   help="initial points: ground-truth depth of the train views (drlab data), the SfM points (COLMAP "
                        "data), points in the train views' frusta between their near/far bounds (LLFF data), or "
                        "random in the scene box (default: depth for drlab data, sfm when the data has SfM points, "
                        "frustum when it has bounds, else random)")
    p.add_argument("--mode", choices=["3dgs", "gsplat"], default="3dgs",
                   help="projection and compositing conventions (kernels/splat/modes.py): the original 3DGS "
                        "code's (default) or gsplat's (its frustum clamp, radius floor, 0.999 alpha clamp and "
                        "<= stop), for comparing against gsplat-trained numbers")


def add_options(p) -> None:
    p.add_argument("--ply", type=Path, default=None,
                   help="where to write the PLY (default build/fit_splats[-quick|-smoke]/point_cloud.ply, in the "
                        "checkout when run from one, else under the current directory)")
    add_data_options(p)
    p.add_argument("--iterations", type=int, default=None, help="override the number of training iterations")
    add_splat_options(p)


@dataclass
class Prepared:
    """The data of one fit: the dataset, its protocol's splits and targets, and the initial points."""

    ds: Any
    path: Path
    splits: tuple[str, str]
    train_split: Any
    test_split: Any
    train_rgb: np.ndarray
    test_rgb: np.ndarray
    background: tuple[float, float, float]
    init: str
    points: np.ndarray
    colors: np.ndarray


def prepare(ctx: Context, cfg: Setup) -> Prepared:
    """Open --data (or render the Mitsuba dataset), check it, and choose the initial points (--init)."""
    from research import datasets
    from research.datasets import formats
    from research.splats import model as sm

    args = ctx.args
    ds = open_external(ctx)
    if ds is None:
        dcfg = datasets.DatasetConfig("objects", views=cfg.views, res=cfg.res, spp=cfg.spp, seed=ctx.seed)
        path = datasets.ensure(dcfg, datasets.cache_dir(dcfg, ctx.data), show_progress=ctx.progress)
        ds = datasets.load(path)
    else:
        path = ds.root.absolute()
    splits = (ds.protocol.train_split, ds.protocol.test_split) if ds.protocol else ("train", "test")
    train_split, test_split = ds.load_split(splits[0]), ds.load_split(splits[1])
    if not train_split.cameras or not test_split.cameras:
        raise ValueError(f"--data: {path} has {len(train_split.cameras)} train and {len(test_split.cameras)} test "
                         "views; the fit needs both")
    train_rgb = formats.protocol_target_linear(train_split, ds.protocol)
    test_rgb = formats.protocol_target_linear(test_split, ds.protocol)
    background = tuple(ds.protocol.background) if ds.protocol and ds.protocol.background else (0.0, 0.0, 0.0)
    init = args.init or ("depth" if train_split.depth is not None else "sfm" if ds.points is not None
                         else "frustum" if ds.near_far is not None else "random")
    if init == "depth" and train_split.depth is None:
        raise ValueError(f"--init depth: {path} has no ground-truth depth; use --init sfm or random")
    if init == "sfm" and ds.points is None:
        raise ValueError(f"--init sfm: {path} has no SfM points; use --init random")
    if init == "frustum" and ds.near_far is None:
        raise ValueError(f"--init frustum: {path} has no per-view near/far bounds (LLFF's); use --init random")

    if init == "depth":
        points, colors = sm.points_from_depth(train_split.cameras, train_split.rgba, train_split.depth,
                                              cfg.init_points, ctx.seed)
    elif init == "sfm":
        points, colors = sm.points_from_sfm(ds.points, ds.point_colors, cfg.max_gaussians, ctx.seed)
    elif init == "frustum":
        bounds = ds.near_far[[i for i, v in enumerate(ds.views) if v.split == splits[0]]]
        points, colors = sm.points_in_frusta(train_split.cameras, train_split.rgba, bounds, cfg.init_points, ctx.seed)
    else:
        points, colors = sm.random_points(ds.bbox, cfg.init_points, ctx.seed)
    return Prepared(ds, path, splits, train_split, test_split, train_rgb, test_rgb, background, init, points, colors)


def train_and_score(prep: Prepared, cfg: Setup, ctx: Context):
    """Train splats from the prepared points on cfg's schedule and score the test split.

    Returns (TrainConfig, TrainResult, test Evaluation, CPU seconds of training over all threads);
    the TrainResult's `seconds` is the training wall time.
    """
    import time

    from research.splats import model as sm, train as st

    model = sm.from_points(prep.points, prep.colors)
    extent = sm.scene_extent(prep.train_split.cameras)
    tcfg = st.TrainConfig(iterations=cfg.iterations, seed=ctx.seed, background=prep.background,
                          densify=st.DensifyConfig(max_gaussians=cfg.max_gaussians), mode=ctx.args.mode)
    cpu0 = time.process_time()
    result = st.train(model, prep.train_split.cameras, prep.train_rgb, extent, tcfg, device=ctx.device,
                      progress=ctx.progress)
    cpu_s = time.process_time() - cpu0
    ev = st.evaluate(result.model, prep.test_split.cameras, prep.test_rgb, result.sh_degree,
                     background=prep.background, device=ctx.device, mode=ctx.args.mode)
    return tcfg, result, ev, cpu_s


def run(ctx: Context) -> int:
    import warp as wp

    from research.splats import model as sm, train as st

    args = ctx.args
    cfg = setup(ctx.quick, ctx.smoke)
    cfg = Setup(**{**asdict(cfg), "iterations": ctx.int_option("--iterations", cfg.iterations)})
    suffix = "" if ctx.mode == "full" else "-" + ctx.mode
    prep = prepare(ctx, cfg)
    ds, path, points, init = prep.ds, prep.path, prep.points, prep.init
    train_split, test_split, train_rgb, test_rgb = prep.train_split, prep.test_split, prep.train_rgb, prep.test_rgb
    background = prep.background
    tcfg, result, ev, train_cpu_s = train_and_score(prep, cfg, ctx)
    model = result.model
    extent = sm.scene_extent(train_split.cameras)

    ev_train = st.evaluate(model, train_split.cameras[:10], train_rgb[:10], result.sh_degree, background=background,
                           device=ctx.device, mode=args.mode)
    fps = st.render_fps(model, test_split.cameras, result.sh_degree, device=ctx.device, mode=args.mode)

    ply_path = (args.ply or registry.base_dir() / "build" / f"fit_splats{suffix}" / "point_cloud.ply").absolute()
    same = st.ply_round_trip_identical(ply_path, model, test_split.cameras[0], result.sh_degree,
                                       device=ctx.device)
    ply_bytes = ply_path.stat().st_size
    if not same:
        raise RuntimeError(f"{ply_path}: the reloaded model renders a different image")

    data = data_record(ds, path)
    cam0 = test_split.cameras[0]
    scene = (f"{data['scene']} {cam0.width}x{cam0.height}" if ds.format == "drlab"
             else f"{data['scene']} ({ds.format}, {ds.protocol.name}) {cam0.width}x{cam0.height}")
    metrics = {
        "method": ("3DGS (drlab Warp kernels, CPU)" if ctx.device == "cpu" else "3DGS (drlab Warp kernels)")
        + ("" if args.mode == "3dgs" else f", {args.mode} conventions"),
        "mode": args.mode,
        "scene": f"{scene}, {len(train_split.cameras)} train / {len(test_split.cameras)} test",
        "eval_protocol": data["eval_protocol"], "data": data,
        "test_psnr": ev.psnr, "test_ssim": ev.ssim, "test_psnr_linear": ev.psnr_linear,
        "train_views_psnr": ev_train.psnr, "gaussians": model.n, "train_seconds": result.seconds,
        "train_cpu_seconds": train_cpu_s,
        "train_iterations": cfg.iterations, "render_fps": fps, "ply_bytes": ply_bytes,
        "ply_path": str(ply_path.relative_to(REPO)) if ply_path.is_relative_to(REPO) else str(ply_path),
        "ply_roundtrip_identical": same, "init": init, "init_points": len(points), "extent": extent,
        "schedule": asdict(st.Schedule.scaled(cfg.iterations)), "per_view": ev.per_view,
        "history": result.history, "densify_events": result.events, "dataset": str(path.relative_to(REPO))
        if path.is_relative_to(REPO) else str(path), "dataset_hash": data["content_hash"],
    }
    headers = ["scene", "train / test views", "iterations", "init", "splats", "test PSNR (dB)", "test SSIM",
               "PSNR linear (dB)", "train-view PSNR", "train time", "render FPS", "PLY size"]
    rows = [[scene, f"{len(train_split.cameras)} / {len(test_split.cameras)}",
             cfg.iterations, f"{init} ({len(points)} pts)", model.n, f"{ev.psnr:.2f}", f"{ev.ssim:.4f}",
             f"{ev.psnr_linear:.2f}", f"{ev_train.psnr:.2f}", f"{result.seconds:.0f} s", f"{fps:.1f}",
             f"{ply_bytes / 1e6:.2f} MB"]]
    table = (f"3D Gaussian splatting fitted with drlab's Warp kernels (hand-written backward) on Warp device "
             f"`{wp.get_device(ctx.device)}`: 3DGS loss, learning rates and schedule scaled to {cfg.iterations} "
             f"iterations, at most {cfg.max_gaussians} splats (a CPU-time cap on densification); projection and "
             f"compositing follow {'the original 3DGS code' if args.mode == '3dgs' else 'gsplat'} "
             f"(kernels/splat/modes.py). Evaluation: "
             f"{data['eval_protocol']}. Render FPS: forward only (projection, binning, sorting, rasterisation) at the "
             "test resolution. Train-view PSNR on the first 10 train views.\n\n" + markdown_table(headers, rows)
             + "\n![renders beside the ground truth](renders.png)\n\n![training](training.png)\n")
    renders_figure(test_rgb, ev.renders, ev.per_view, ctx.out / "renders.png",
                   gt_label="ground truth (Mitsuba)" if ds.format == "drlab" else f"ground truth ({ds.scene})")
    training_figure(result.history, result.events, ctx.out / "training.png")
    ctx.write_results(config={**asdict(cfg), "train": asdict(tcfg)},
                      metrics=metrics, table_md=table, compare=True)
    return 0


main = Experiment("fit_splats", __doc__, run, add_options, data_help=DATA_HELP,
                  seed_help="seed of the dataset render, the initial points and training",
                  sizes="Quick: 40 views at 64x64, 800 iterations (a few minutes on 2 cores); smoke: 8 views at "
                        "32x32, 4 spp, 40 iterations.").script(__name__)
