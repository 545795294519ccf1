#!/usr/bin/env python3
"""Splat depth and normals against the true geometry: expected vs median depth, with and without 2DGS's
depth-normal consistency loss.

Data and schedule are fit_splats' (experiments/fit_splats.py Setup): the Mitsuba `objects` scene (100
views at 128x128, 64 spp; quick 40 views at 64x64; smoke 8 at 32x32), splats initialised from the
train views' ground-truth depth, trained by research.splats.train on the 3DGS schedule scaled to the
iteration count. Two models, in one run:

  3DGS         the baseline: L1 + 0.2 D-SSIM, no geometry loss;
  3DGS + L_n   the same, plus lambda L_n (research/splats/geometry.py): 2DGS's depth-normal consistency
               loss between the alpha-blended shortest-axis splat normals (PGSR's normal for 3D
               Gaussians) and the normals of the rendered depth map (--loss-depth: expected, the default,
               or median), lambda = 0.05 from iteration 7/30 of the run on (2DGS's lambda_n and its start
               at 7000 of 30000 iterations; research.splats.train.NORMAL_WEIGHT_2DGS, NORMAL_FROM).

Each model is scored on the test views with both depth maps (kernels/splat/depth.py): expected depth
D / A (gsplat's "ED") and median depth (2DGS's: the z where the transmittance first crosses 1/2).

  depth error    against the true z-depth the dataset stores (r_NNN_depth.exr), over the pixels whose
                 centre ray hits a surface (the stored mask): AbsRel = mean |d - d*| / d*,
                 RMSE = sqrt(mean (d - d*)^2) (scene units); a pixel the splats leave empty counts with d = 0;
  normal error   the angle between the normals of the depth map (kernels/splat/normals.py: central
                 differences of the back-projected depth, cross product, normalised) and the true
                 normals: the dataset's stored shading normals (r_NNN_normal.exr, world frame), rotated
                 into the camera and turned to face it, over the surface pixels whose 4 neighbours are
                 surface pixels too (no silhouette edge inside the difference stencil), off the border;
                 mean and median in degrees. The blended splat normals N / |N| are scored the same way
                 (the "splat normals" column), and, as the floor of the depth-to-normal operator at this
                 resolution, the normals of the TRUE depth map (the "true depth" row).

Test PSNR/SSIM (sRGB, research.metrics) shows what the loss costs the images. Settings: lambda and
its start are 2DGS's published defaults, the schedule and splat cap fit_splats'; nothing was tuned on
this experiment's data. Writes results/splat_geometry/{table.md, metrics.json, figure.png}.
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

DEPTHS = ("expected", "median")


def add_options(p) -> None:
    p.add_argument("--iterations", type=int, default=None,
                   help="training iterations of both models (default fit_splats': 3000; quick 800; smoke 40)")
    p.add_argument("--loss-depth", choices=DEPTHS, default="expected",
                   help="the depth map whose normals the consistency loss compares with the splat normals")
    p.add_argument("--normal-weight", type=float, default=None,
                   help="lambda of the consistency loss (default 2DGS's 0.05)")


def camera_normals(normals_world: np.ndarray, cam) -> np.ndarray:
    """World normals (H, W, 3) in the camera frame of `cam` (a SplatCamera), turned to face it."""
    R = np.asarray(cam.viewmat)[:3, :3]
    n = normals_world.astype(np.float64) @ R.T
    K = cam.K
    x, y = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    rays = np.stack([(x - K[0, 2]) / K[0, 0], (y - K[1, 2]) / K[1, 1], np.ones_like(x)], -1)
    n = np.where((np.sum(n * rays, -1) > 0)[..., None], -n, n)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


def normal_mask(surface: np.ndarray) -> np.ndarray:
    """Surface pixels off the border whose 4 neighbours are surface pixels."""
    m = np.zeros_like(surface)
    s = surface
    m[1:-1, 1:-1] = s[1:-1, 1:-1] & s[:-2, 1:-1] & s[2:, 1:-1] & s[1:-1, :-2] & s[1:-1, 2:]
    return m


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, -1), -1.0, 1.0)))


def depth_errors(d: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    e = d[mask] - truth[mask]
    return {"absrel": float(np.mean(np.abs(e) / truth[mask])), "rmse": float(np.sqrt(np.mean(e * e)))}


def normal_errors(ang: list[np.ndarray]) -> dict[str, float]:
    a = np.concatenate(ang)
    return {"normal_mean_deg": float(np.mean(a)), "normal_median_deg": float(np.median(a)), "pixels": int(a.size)}


def normal_rgb(n: np.ndarray) -> np.ndarray:
    return np.clip((n * np.array([1.0, -1.0, -1.0]) + 1.0) / 2.0, 0, 1) * (np.linalg.norm(n, axis=-1) > 0)[..., None]


def figure(view: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    cols = ["true"] + [k for k in view if k != "true"]
    fig, axes = plt.subplots(2, len(cols), figsize=(2.3 * len(cols), 5.0), squeeze=False)
    vmax = float(view["true"]["depth"].max())
    for j, k in enumerate(cols):
        image_panel(fig, axes[0, j], view[k]["depth"], f"{k}\ndepth", cmap="viridis", vmin=0, vmax=vmax, fontsize=7,
                    interpolation="nearest")
        image_panel(fig, axes[1, j], normal_rgb(view[k]["normals"]), "normals" + (" (stored)" if k == "true" else
                                                                                   " from depth"),
                    fontsize=7, interpolation="nearest")
    finish_figure(fig, path)


def run(ctx: Context) -> int:
    from experiments.fit_splats import setup
    from kernels.splat import normals as kn
    from research import datasets, io, metrics
    from research.datasets import formats
    from research.splats import geometry, model as sm, train as st

    cfg = setup(ctx.quick, ctx.smoke)
    iterations = ctx.int_option("--iterations", cfg.iterations)
    weight = st.NORMAL_WEIGHT_2DGS if ctx.args.normal_weight is None else ctx.args.normal_weight
    if not weight > 0:
        raise ValueError(f"--normal-weight: expected a positive weight, got {weight}")
    dcfg = datasets.DatasetConfig("objects", views=cfg.views, res=cfg.res, spp=cfg.spp, seed=ctx.seed)
    path = datasets.ensure(dcfg, datasets.cache_dir(dcfg, ctx.data), show_progress=ctx.progress)
    ds = datasets.load(path)
    train_split, test_split = ds.load_split("train"), ds.load_split("test")
    train_rgb = formats.protocol_target_linear(train_split, ds.protocol)
    test_rgb = formats.protocol_target_linear(test_split, ds.protocol)
    cams = [sm.splat_camera(c) for c in test_split.cameras]
    true_n = [camera_normals(io.read_exr(v.path("_normal.exr")), c) for v, c in zip(ds.split_views("test"), cams)]
    depth_masks = list(test_split.mask)
    n_masks = [normal_mask(m) for m in test_split.mask]
    points, colors = sm.points_from_depth(train_split.cameras, train_split.rgba, train_split.depth, cfg.init_points,
                                          ctx.seed)
    init = sm.from_points(points, colors)
    extent = sm.scene_extent(train_split.cameras)
    base = st.TrainConfig(iterations=iterations, seed=ctx.seed, densify=st.DensifyConfig(max_gaussians=cfg.max_gaussians))
    configs = {"3DGS": base,
               "3DGS + L_n": st.TrainConfig(**{**base.__dict__, "normal_weight": weight,
                                               "normal_depth": ctx.args.loss_depth})}
    rows, models, fig_view = {}, {}, {}
    operator = normal_errors([angles_deg(np.asarray(kn.normals_from_depth(d.astype(np.float64), c))[m], n[m])
                              for d, c, m, n in zip(test_split.depth, cams, n_masks, true_n)])
    fig_view["true"] = {"depth": test_split.depth[0], "normals": np.where(n_masks[0][..., None], true_n[0], 0.0)}
    bar = ctx.tqdm(total=len(configs), desc="models")
    for label, tcfg in configs.items():
        cpu0, wall0 = time.process_time(), time.perf_counter()
        res = st.train(init, train_split.cameras, train_rgb, extent, tcfg, device=ctx.device, progress=ctx.progress)
        cpu_s, wall_s = time.process_time() - cpu0, time.perf_counter() - wall0
        ev = st.evaluate(res.model, test_split.cameras, test_rgb, res.sh_degree, device=ctx.device)
        g = res.model.inputs(ctx.device)
        per_depth = {k: {"d": [], "n": []} for k in DEPTHS}
        splat_ang = []
        for i, cam in enumerate(cams):
            for kind in DEPTHS:
                geo = geometry.render_geometry(g, cam, None, depth=kind, sh_degree=res.sh_degree)
                per_depth[kind]["d"].append(geo.depth)
                per_depth[kind]["n"].append(angles_deg(geo.depth_normals[n_masks[i]], true_n[i][n_masks[i]]))
                if i == 0:
                    fig_view[f"{label}, {kind}"] = {"depth": geo.depth, "normals": geo.depth_normals}
            nm = geo.normal_map
            covered = n_masks[i] & (np.linalg.norm(nm, axis=-1) > 0)
            splat_ang.append(angles_deg(nm[covered], true_n[i][covered]))
        splat_err = normal_errors(splat_ang)
        models[label] = {"psnr": ev.psnr, "ssim": ev.ssim, "splats": res.model.n, "cpu_seconds": cpu_s,
                         "wall_seconds": wall_s, "splat_normals": splat_err, "history": res.history,
                         "train": asdict(tcfg)}
        for kind in DEPTHS:
            d = np.stack(per_depth[kind]["d"])
            errs = depth_errors(d, test_split.depth, np.stack(depth_masks))
            rows[f"{label}, {kind}"] = {"model": label, "depth": kind, **errs,
                                        **normal_errors(per_depth[kind]["n"])}
        bar.update()
    bar.close()

    figure(fig_view, ctx.out / "figure.png")
    headers = ["model", "depth map", "AbsRel", "RMSE", "normal mean (deg)", "normal median (deg)",
               "splat normals mean / median (deg)", "test PSNR (dB)", "splats", "train CPU s"]
    table_rows = []
    for r in rows.values():
        m = models[r["model"]]
        table_rows.append([r["model"], r["depth"], f"{r['absrel']:.4f}", f"{r['rmse']:.4f}",
                           f"{r['normal_mean_deg']:.2f}", f"{r['normal_median_deg']:.2f}",
                           f"{m['splat_normals']['normal_mean_deg']:.2f} / {m['splat_normals']['normal_median_deg']:.2f}",
                           f"{m['psnr']:.2f}", m["splats"], f"{m['cpu_seconds']:.1f}"])
    table_rows.append(["true depth (operator floor)", "stored z", "0", "0", f"{operator['normal_mean_deg']:.2f}",
                       f"{operator['normal_median_deg']:.2f}", "-", "-", "-", "-"])
    cam0 = test_split.cameras[0]
    table = (f"Mitsuba `objects` {cam0.width}x{cam0.height}, {len(train_split.cameras)} train / "
             f"{len(test_split.cameras)} test views (fit_splats' data and schedule, {iterations} iterations, at most "
             f"{cfg.max_gaussians} splats). 3DGS + L_n: 2DGS's depth-normal consistency loss on the "
             f"{ctx.args.loss_depth} depth's normals against the blended shortest-axis splat normals, lambda "
             f"{weight:g} from iteration {round(st.NORMAL_FROM * iterations)} (2DGS's defaults, not tuned here). "
             "Depth errors over the stored surface mask (AbsRel, RMSE in scene units); normal errors (angle to the "
             "stored shading normals, in the camera frame) over surface pixels whose 4 neighbours are surface, "
             f"{operator['pixels']} pixels; the last row is the same operator on the true depth.\n\n"
             + markdown_table(headers, table_rows) + "\n\n![test view 0: depth and normals](figure.png)\n")
    metrics_out = {"dataset": {"path": str(path), "config": dcfg.__dict__}, "normal_weight": weight,
                   "normal_from_iteration": round(st.NORMAL_FROM * iterations), "loss_depth": ctx.args.loss_depth,
                   "settings_source": "lambda 0.05 from 7000/30000: 2DGS's defaults; schedule: fit_splats'",
                   "rows": rows, "operator_floor": operator, "models": models}
    ctx.write_results(config={**asdict(cfg), "iterations": iterations}, metrics=metrics_out,
                      table_md=table)
    return 0


main = Experiment("splat_geometry", __doc__, run, add_options,
                  seed_help="seed of the dataset's cameras, the initial points and training",
                  sizes=setup_sizes("~23 min on 2 shared cores"),
                  data_help=CACHE_ROOT_HELP).script(__name__)
