#!/usr/bin/env python3
"""Fit radiance fields to a Mitsuba multi-view dataset and evaluate novel views.

Three fields, each fitted with Adam on an MSE loss over random ray batches (research/nerf/train.py)
with an occupancy grid for empty-space skipping and early ray termination (kernels.volume):
  * grid     dense voxel grid, trilinear density + RGB (Plenoxels/DVGO style), fitted coarse to fine
             (65 -> 129 -> 257 vertices along x) with a total-variation prior;
  * hashgrid multiresolution hash encoding (12 levels, 2^15 entries, 2 features) + MLP [24, 64, 64, 4]
             (instant-ngp; the table is kept small so that it stays in the CPU's cache);
  * pe_mlp   frequency positional encoding + MLP [3 + 6K, 64, 64, 4] (NeRF, at a width the CPU can train).
The dataset is `drlab dataset --scene objects` (train split; default 100 views at 128x128, 64 spp),
fitted in sRGB over a black background. Every test view is rendered with research.nerf.render_image
and compared with the ground truth over a black background: PSNR, SSIM (research.metrics), the
mean absolute error of the expected z-depth against Mitsuba's z-depth inside the ground-truth mask,
training seconds, and seconds per rendered test image.

Other data (`--data PATH` with `--format`/`--resolution`, as fit_splats; research.datasets.formats): a
NeRF-synthetic/Blender or COLMAP / Mip-NeRF 360 folder is fitted inside its scene bound (the SfM
points' box for COLMAP, else the declared box or the cameras' bound) and scored with its paper's
protocol: the fields train on random backgrounds against the files' sRGB composited on them
(instant-ngp's recipe), and the test views are rendered on the protocol's background (white for
NeRF-synthetic) and compared with the files composited on it; no depth error and no noise floor
(there is no ground-truth depth or second render). An LLFF forward-facing folder is fitted in NeRF's NDC
(research.nerf.ndc: the rays mapped by kernels.volume.ndc_rays, the fields' box the cameras' frusta in
NDC, samples evenly spaced in the NDC ray parameter, i.e. in disparity), scored as above without a
background (the photographs are opaque).

Writes results/fit_nerf/{table.md, metrics.json, renders_<field>.png, loss.png}.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field as dc_field
from pathlib import Path
from typing import Any

import numpy as np

from experiments.fit_splats import DATA_HELP
from research.experiment import Context, Experiment
from research.results import finish_figure, image_panel, loss_figure, markdown_table

FIELDS = ("grid", "hashgrid", "pe_mlp")


@dataclass
class Stage:
    """One training stage: the field's resolution (grids) and a TrainConfig's keyword arguments."""

    iters: int
    resolution: tuple[int, int, int] | None = None
    overrides: dict[str, Any] = dc_field(default_factory=dict)


def grid_resolution(bbox: np.ndarray, n_max: int) -> tuple[int, int, int]:
    ext = bbox[1] - bbox[0]
    return tuple(int(max(2, round(e / ext.max() * (n_max - 1)) + 1)) for e in ext)


def plans(quick: bool, bbox: np.ndarray, smoke: bool = False) -> dict[str, dict[str, Any]]:
    """Per field: constructor, training stages and the TrainConfig options shared by its stages.

    Chosen by short tuning runs on the default dataset: exp density activation
    for every field; black-background training (the metric's background); occupancy threshold
    sigma > 1 (sigma * step ~ 0.016, instant-ngp's minimum optical thickness of 0.01 at this step).
    """
    from kernels.volume import GridField, HashGridField, PEMLPField

    ext = float((bbox[1] - bbox[0]).max())
    if smoke:  # tiny: every stage runs, the numbers mean little
        step = ext / 64
        occ_res = tuple(max(1, r - 1) for r in grid_resolution(bbox, 17))
        grid_res = [grid_resolution(bbox, r) for r in (9, 17)]
        grid_iters = (15, 15)
        common = dict(step=step, occupancy_res=occ_res, occupancy_threshold=1.0, batch_rays=256)
    else:
        step = ext / (128 if quick else 256)
        occ_res = tuple(max(1, r - 1) for r in grid_resolution(bbox, 65 if quick else 129))
        grid_res = [grid_resolution(bbox, r) for r in ((33, 65, 129) if quick else (65, 129, 257))]
        grid_iters = (300, 300, 300) if quick else (400, 500, 800)
        common = dict(step=step, occupancy_res=occ_res, occupancy_threshold=1.0, batch_rays=2048 if quick else 4096)
    mlp_iters, mlp_batch = (20, 256) if smoke else (None, 2048)
    return {
        "grid": dict(
            make=lambda seed: GridField(bbox, grid_res[0], density_bias=-3.0, density_activation="exp", seed=seed),
            stages=[Stage(i, r) for i, r in zip(grid_iters, grid_res)],
            config=dict(common, lr={"density": 0.1, "color": 0.1}, tv_weight={"density": 0.01, "color": 0.001})),
        "hashgrid": dict(
            make=lambda seed: HashGridField(bbox, n_levels=12, n_features=2, log2_table_size=15, base_resolution=16,
                                            max_resolution=256 if quick else 512, density_bias=-1.0, seed=seed),
            # 1300 full-size iterations: +0.22 dB over 1200 on --seed 1 (chosen there), in about the time 1200
            # iterations of the slower per-iteration code took (docs/performance.md, "Targets").
            stages=[Stage(mlp_iters or (400 if quick else 1300))],
            config=dict(common, lr=1e-2, batch_rays=mlp_batch)),
        "pe_mlp": dict(
            make=lambda seed: PEMLPField(bbox, n_freqs=8, density_bias=-1.0, seed=seed),
            stages=[Stage(mlp_iters or (400 if quick else 1500))],
            config=dict(common, lr=5e-3, batch_rays=mlp_batch)),
    }


def dataset_config(quick: bool, seed: int, smoke: bool = False):
    from research.datasets import DatasetConfig

    if smoke:
        return DatasetConfig("objects", views=8, res=32, spp=4, seed=seed)
    if quick:
        return DatasetConfig("objects", views=40, res=64, spp=32, seed=seed)
    return DatasetConfig("objects", views=100, res=128, spp=64, seed=seed)


def noise_floor(ds, split, gt_srgb: np.ndarray, n_views: int, seed: int) -> dict[str, float]:
    """PSNR between the test images and a second Mitsuba render of the same views (another seed).

    Both are Monte Carlo estimates with independent noise, so a perfect (noise-free) prediction would
    score about this PSNR + 3.01 dB against the ground truth: the best any field can reach.
    """
    from research.datasets import get_scene
    from research.datasets.render import SceneRenderer
    from research.metrics import psnr
    from research.metrics import srgb_targets

    renderer = SceneRenderer(get_scene(ds.manifest["config"]["scene"]), spp=ds.manifest["config"]["spp"])
    values = []
    for i in range(min(n_views, len(split.cameras))):
        other = srgb_targets(renderer.render_rgba(split.cameras[i], seed=10_007 + seed + i)[None])[0]
        values.append(psnr(other[..., :3], gt_srgb[i, ..., :3]))
    pair = float(np.mean(values))
    return {"views": len(values), "psnr_between_two_renders": pair, "psnr_ceiling": pair + 10 * np.log10(2.0)}


def evaluate(field, occupancy, bbox, step: float, split, gt_srgb: np.ndarray,
             background=(0.0, 0.0, 0.0), ndc=None) -> dict[str, Any]:
    from research.metrics import psnr, ssim
    from research.nerf.render import render_image

    rows, images = [], []
    for i, cam in enumerate(split.cameras):
        t0 = time.perf_counter()
        img = render_image(cam, field, bbox, step=step, occupancy=occupancy, background=background, ndc=ndc)
        seconds = time.perf_counter() - t0
        pred = np.clip(img.rgb, 0.0, 1.0)
        row = {"psnr": psnr(pred, gt_srgb[i, ..., :3]), "ssim": ssim(pred, gt_srgb[i, ..., :3])}
        if split.depth is not None:
            row["depth_mae"] = float(np.abs(img.depth - split.depth[i])[split.mask[i]].mean())
        rows.append({**row, "seconds": seconds, "samples_per_ray": img.n_samples / (cam.width * cam.height)})
        images.append(img)
    mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
    return {"mean": mean, "per_view": rows, "images": images}


def fit_one(name: str, plan: dict[str, Any], bank, bbox, quick: bool, seed: int, progress: bool,
            random_background: bool = False):
    from kernels.volume import OccupancyGrid
    from research.nerf.train import TrainConfig, train, upsample_grid

    field = plan["make"](seed)
    base = dict(plan["config"])
    occupancy = OccupancyGrid(bbox, base["occupancy_res"], threshold=base.get("occupancy_threshold", 0.01))
    losses, seconds, spr = [], 0.0, []
    for k, stage in enumerate(plan["stages"]):
        if stage.resolution is not None and tuple(stage.resolution) != tuple(field.resolution):
            field = upsample_grid(field, stage.resolution)
        last = k == len(plan["stages"]) - 1
        cfg = TrainConfig(iters=stage.iters, seed=seed * 1000 + k, random_background=random_background,
                          occupancy_start=plan.get("occupancy_start", 100) if k == 0 else 0,
                          lr_decay_from=0.5 if last else 1.0, **{**base, **stage.overrides})
        log = train(field, bank, bbox, cfg, occupancy, progress=progress, desc=f"{name} stage {k + 1}")
        losses += log.losses
        spr += log.samples_per_ray
        seconds += log.seconds
    return field, occupancy, {"losses": losses, "samples_per_ray": spr, "train_s": seconds, "config": base,
                              "stages": [{"iters": s.iters, "resolution": s.resolution} for s in plan["stages"]]}


def figures(results: dict[str, Any], split, gt_srgb: np.ndarray, out: Path, n_views: int = 3) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for name, r in results.items():
        views = min(n_views, len(split.cameras))
        has_depth = split.depth is not None
        fig, axes = plt.subplots(views, 5 if has_depth else 3, figsize=(13 if has_depth else 8, 2.7 * views),
                                 squeeze=False)
        dmax = float(split.depth[:views].max()) if has_depth else 1.0
        for v in range(views):
            img = r["images"][v]
            pred = np.clip(img.rgb, 0, 1)
            psnr_v = r["eval"]["per_view"][v]["psnr"]
            panels = [(gt_srgb[v, ..., :3], "ground truth", None), (pred, f"{name} ({psnr_v:.1f} dB)", None),
                      (np.abs(pred - gt_srgb[v, ..., :3]).mean(axis=2), "|error| (mean RGB)", (0, 0.25))]
            if has_depth:
                panels += [(np.ma.masked_where(~split.mask[v], split.depth[v]), "GT z-depth", (0, dmax)),
                           (np.ma.masked_where(img.opacity < 0.5, img.depth), "expected z-depth", (0, dmax))]
            for ax, (im, title, lim) in zip(axes[v], panels):
                image_panel(fig, ax, im, title if v == 0 or "dB" in title else None, colorbar=np.ndim(im) == 2,
                            cmap=None if np.ndim(im) == 3 else "viridis", vmin=None if lim is None else lim[0],
                            vmax=None if lim is None else lim[1])
        finish_figure(fig, out / f"renders_{name}.png")
    loss_figure({name: r["train"]["losses"] for name, r in results.items()}, "training MSE (sRGB)", out / "loss.png")


def add_options(p) -> None:
    from experiments.fit_splats import add_data_options

    p.add_argument("--fields", nargs="+", default=list(FIELDS), choices=FIELDS, help="fields to fit (default: all)")
    add_data_options(p)


@dataclass
class FieldData:
    """The data of a field fit: the dataset, its splits, the scene box, the training rays and the test targets."""

    ds: Any
    data: Path
    config: Any  # the DatasetConfig of a Mitsuba dataset
    dataset_s: float
    train_split: Any
    test_split: Any
    bbox: np.ndarray
    bank: Any
    external: bool
    background: tuple[float, float, float]
    gt: np.ndarray


def prepare(ctx: Context) -> FieldData:
    """Open --data (or render the Mitsuba dataset) and build the training rays and the sRGB test targets."""
    from research.datasets import cache_dir, ensure, formats, load
    from research.metrics import srgb_targets
    from research.nerf.train import RayBank

    from experiments.fit_splats import open_external

    cfg = dataset_config(ctx.quick, 0, ctx.smoke)
    t0 = time.perf_counter()
    ds = open_external(ctx)
    if ds is None:
        data = cache_dir(cfg, ctx.data)
        ds = load(ensure(cfg, data, show_progress=ctx.progress))
    else:
        data = ds.root.absolute()
        if ds.format == "drlab":  # a `drlab dataset` folder given by --data: its own configuration
            from dataclasses import fields

            from research.datasets import DatasetConfig

            names = {f.name for f in fields(DatasetConfig)}
            cfg = DatasetConfig(**{k: v for k, v in ds.manifest.get("config", {}).items() if k in names})
    dataset_s = time.perf_counter() - t0
    splits = (ds.protocol.train_split, ds.protocol.test_split) if ds.protocol else ("train", "test")
    train_split, test_split = ds.load_split(splits[0]), ds.load_split(splits[1])
    if not train_split.cameras or not test_split.cameras:
        raise ValueError(f"--data: {data} has {len(train_split.cameras)} train and {len(test_split.cameras)} test "
                         "views; the fit needs both")
    bbox = ds.bbox.copy() if ds.ndc is None else ds.ndc.bbox_for([v.camera for v in ds.views])
    bank = RayBank.from_views(train_split.cameras, train_split.rgba, ndc=ds.ndc)
    external = ds.format != "drlab"
    background = tuple(ds.protocol.background) if ds.protocol and ds.protocol.background else (0.0, 0.0, 0.0)
    if external:  # the files' sRGB x alpha: composited on each ray's random background as the papers do
        bank.rgba = formats.protocol_srgb(train_split, ds.protocol).reshape(-1, 4)
    gt = formats.protocol_target_srgb(test_split, ds.protocol) if external else srgb_targets(test_split.rgba)
    return FieldData(ds, data, cfg, dataset_s, train_split, test_split, bbox, bank, external, background, gt)


def run(ctx: Context) -> int:
    import warp as wp

    from experiments.fit_splats import data_record

    args = ctx.args
    fd = prepare(ctx)
    ds, data, cfg, dataset_s, bbox, bank = fd.ds, fd.data, fd.config, fd.dataset_s, fd.bbox, fd.bank
    train_split, test_split, external, background, gt = (fd.train_split, fd.test_split, fd.external,
                                                         fd.background, fd.gt)
    floor = None if external else noise_floor(ds, test_split, gt, 3, ctx.seed)
    record = data_record(ds, data)

    results: dict[str, Any] = {}
    all_plans = plans(ctx.quick, bbox, ctx.smoke)
    for name in args.fields:
        field, occupancy, log = fit_one(name, all_plans[name], bank, bbox, ctx.quick, ctx.seed, ctx.progress,
                                        random_background=external)
        ev = evaluate(field, occupancy, bbox, all_plans[name]["config"]["step"], test_split, gt, background,
                      ds.ndc)
        results[name] = {"train": log, "eval": {k: v for k, v in ev.items() if k != "images"},
                         "images": ev["images"], "params": field.n_params(),
                         "bytes_per_param": wp.types.type_size_in_bytes(field.dtype),
                         "occupied_fraction": occupancy.occupied_fraction()}
        m = ev["mean"]
        depth = f", depth MAE {m['depth_mae']:.3f}" if "depth_mae" in m else ""
        print(f"{name}: PSNR {m['psnr']:.2f} dB, SSIM {m['ssim']:.3f}{depth}, "
              f"train {log['train_s']:.0f} s, {m['seconds']:.2f} s/image", flush=True)

    figures(results, test_split, gt, ctx.out)
    rows = []
    for name, r in results.items():
        m, t = r["eval"]["mean"], r["train"]
        rows.append([name, f"{r['params']:,}", sum(s["iters"] for s in t["stages"]), f"{m['psnr']:.2f}",
                     f"{m['ssim']:.3f}", f"{m['depth_mae']:.3f}" if "depth_mae" in m else "-",
                     f"{t['train_s']:.0f}", f"{m['seconds']:.2f}",
                     f"{np.mean(t['samples_per_ray'][-100:]):.1f}", f"{m['samples_per_ray']:.1f}"])
    headers = ["field", "parameters", "iterations", "test PSNR (dB)", "test SSIM", "depth MAE in mask",
               "train s", "s / image", "samples/ray (train, last 100 it)", "samples/ray (test)"]
    if external:
        cam0 = test_split.cameras[0]
        table = (f"`{ds.scene}` ({ds.format} format) at {cam0.width}x{cam0.height}: "
                 f"{len(train_split.cameras)} training and {len(test_split.cameras)} test views, "
                 f"device `{ctx.device}`. Evaluation: {record['eval_protocol']}. Scene bound "
                 f"{np.round(bbox, 3).tolist()}{' (from the SfM points)' if ds.points is not None else ''}"
                 f"{' in NDC (NeRF forward-facing: the frusta of the cameras)' if ds.ndc is not None else ''}; "
                 "no ground-truth depth.\n\n" + markdown_table(headers, rows))
    else:
        table = (f"`objects` from `drlab dataset` ({cfg.views} views, {cfg.res}x{cfg.res}, {cfg.spp} spp): "
                 f"{len(train_split.cameras)} training and {len(test_split.cameras)} test views, "
                 f"device `{ctx.device}`, "
                 "2-core CPU. PSNR and SSIM in sRGB over a black background; depth MAE is |expected z-depth - "
                 "Mitsuba z-depth| inside the ground-truth mask (scene units; the cameras are ~4.2 away).\n\n"
                 + markdown_table(headers, rows)
                 + f"\nGround-truth noise: two {cfg.spp}-spp Mitsuba renders of the same test views differ by "
                 f"{floor['psnr_between_two_renders']:.2f} dB PSNR, so a noise-free prediction would score about "
                 f"{floor['psnr_ceiling']:.2f} dB against this ground truth (mean of {floor['views']} views).\n")
    metrics = {"eval_protocol": record["eval_protocol"], "data": record,
               "dataset": {"path": str(data), "config": None if external else cfg.__dict__,
                           "seconds_if_rendered": dataset_s, "content_hash": record["content_hash"],
                           "bbox": bbox.tolist(), "ndc": None if ds.ndc is None else vars(ds.ndc),
                           "train_views": len(train_split.cameras),
                           "test_views": len(test_split.cameras)},
               "noise_floor": floor,
               "fields": {name: {"params": r["params"], "bytes_per_param": r["bytes_per_param"],
                                 "occupied_fraction": r["occupied_fraction"],
                                 "eval": r["eval"], "train_s": r["train"]["train_s"],
                                 "stages": r["train"]["stages"],
                                 "config": {k: v for k, v in r["train"]["config"].items()},
                                 "final_loss": float(np.mean(r["train"]["losses"][-100:]))}
                          for name, r in results.items()}}
    ctx.write_results(config={"fields": args.fields}, metrics=metrics, table_md=table,
                      compare=True)
    return 0


main = Experiment("fit_nerf", __doc__, run, add_options, data_help=DATA_HELP,
                  seed_help="seed of the fields' initialisation, ray batches and the noise-floor render",
                  sizes="Quick: 40 views at 64x64 (32 spp) and short schedules, all three fields in a few minutes; "
                        "smoke: 8 views at 32x32, 4 spp, tens of iterations.").script(__name__)
