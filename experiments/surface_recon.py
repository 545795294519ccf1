#!/usr/bin/env python3
"""Surface reconstruction by TSDF fusion of depth maps, scored against the Mitsuba scene's true geometry.

Data: the `objects` scene (`drlab dataset --scene objects`: 100 views at 128x128, 64 spp, the dataset
of fit_splats and fit_nerf; quick: 40 views at 64x64, 16 spp; smoke: 8 views at 32x32, 4 spp). The
train views' depth maps of three sources are fused, each by drlab (kernels.tsdf: Warp TSDF integration
and marching cubes, research/surface/fusion.py) and by Open3D's UniformTSDFVolume on the same depth
maps and the same voxels (the baseline, when the `open3d-cpu` wheel of the `[bench]` extra is
installed; else its rows say so):

  (a) Mitsuba's ground-truth z-depth;
  (b) the expected depth of a 3D Gaussian splat fit (research.splats, fit_splats' recipe: depth
      initialisation, 3DGS loss and schedule; 3000 iterations, 800 quick, 40 smoke: fit_splats' own
      schedules, not longer);
  (c) the expected depth of a hash-grid radiance field (fit_nerf's `hashgrid` plan and schedule:
      1300 iterations, 400 quick, 20 smoke).

(b) and (c) keep pixels with opacity >= 0.5 (research/surface/depth.py).

Grid (fixed before any run, from the scene's size, not tuned): voxel size = largest side of the scene
box / 192 (quick 128, smoke 48), truncation 4 voxels, the box grown by the truncation plus a voxel.

True geometry (research/surface/groundtruth.py): points sampled uniformly in area on the scene's
Mitsuba shapes with their normals, kept where a train view saw them (|z - depth| < 0.5% of the box
diagonal at the pixel they project to). Each mesh is sampled uniformly in area (research/surface/
mesh.py) with as many points. Scores (research/surface/metrics.py): accuracy, completeness and
chamfer (their mean) in scene units, precision / recall / F-score at 0.25%, 0.5% and 1% of the box
diagonal (Tanks and Temples' definitions), normal consistency; and the fusion's wall time (integration
plus mesh extraction).

Writes results/surface_recon/{table.md, metrics.json, errors.png}; the drlab meshes go to
build/surface_recon[-quick|-smoke]/<source>.ply (binary PLY, not committed: a few MB each), and are read
back to check the round trip.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from research import registry
from research.datasets import CACHE_ROOT_HELP
from research.experiment import Context, Experiment
from research.results import finish_figure, markdown_table

SOURCES = ("gt", "splats", "field")
SOURCE_LABEL = {"gt": "Mitsuba GT depth", "splats": "splat depth (3DGS fit)", "field": "field depth (hash grid)"}
THRESHOLDS_PCT = (0.25, 0.5, 1.0)  # of the scene box's diagonal
VISIBLE_PCT = 0.5


@dataclass(frozen=True)
class Setup:
    views: int
    res: int
    spp: int
    splat_iterations: int
    init_points: int
    max_gaussians: int
    voxels_per_side: int  # the scene box's largest side / voxel size
    truncation_voxels: float
    samples: int  # ground-truth and mesh surface samples


def setup(quick: bool, smoke: bool) -> Setup:
    if smoke:
        return Setup(views=8, res=32, spp=4, splat_iterations=40, init_points=300, max_gaussians=1000,
                     voxels_per_side=48, truncation_voxels=4.0, samples=4000)
    if quick:
        return Setup(views=40, res=64, spp=16, splat_iterations=800, init_points=3000, max_gaussians=12_000,
                     voxels_per_side=128, truncation_voxels=4.0, samples=50_000)
    return Setup(views=100, res=128, spp=64, splat_iterations=3000, init_points=8000, max_gaussians=30_000,
                 voxels_per_side=192, truncation_voxels=4.0, samples=200_000)


def add_options(p) -> None:
    p.add_argument("--sources", nargs="+", choices=SOURCES, default=list(SOURCES),
                   help="depth maps to fuse: gt (Mitsuba), splats (a splat fit), field (a hash-grid fit); default all")
    p.add_argument("--no-open3d", action="store_true", help="skip Open3D's fusion (the baseline)")
    p.add_argument("--ply-dir", type=Path, default=None,
                   help="where to write the drlab meshes (default build/surface_recon[-quick|-smoke], in the checkout "
                        "when run from one, else under the current directory)")


def fit_splat_depths(ctx: Context, cfg: Setup, train) -> tuple[np.ndarray, dict]:
    from research.splats import model as sm, train as st
    from research.surface.depth import splat_depths

    points, colors = sm.points_from_depth(train.cameras, train.rgba, train.depth, cfg.init_points, ctx.seed)
    model = sm.from_points(points, colors)
    extent = sm.scene_extent(train.cameras)
    tcfg = st.TrainConfig(iterations=cfg.splat_iterations, seed=ctx.seed,
                          densify=st.DensifyConfig(max_gaussians=cfg.max_gaussians))
    result = st.train(model, train.cameras, train.rgba[..., :3], extent, tcfg, device=ctx.device,
                      progress=ctx.progress)
    depths = splat_depths(result.model, train.cameras, result.sh_degree, device=ctx.device)
    return depths, {"iterations": cfg.splat_iterations, "splats": result.model.n, "train_s": result.seconds}


def fit_field_depths(ctx: Context, train, bbox: np.ndarray) -> tuple[np.ndarray, dict]:
    from experiments.fit_nerf import fit_one, plans
    from research.nerf.train import RayBank
    from research.surface.depth import field_depths

    bank = RayBank.from_views(train.cameras, train.rgba)
    plan = plans(ctx.quick, bbox, ctx.smoke)["hashgrid"]
    field, occupancy, log = fit_one("hashgrid", plan, bank, bbox, ctx.quick, ctx.seed, ctx.progress)
    depths = field_depths(field, occupancy, bbox, plan["config"]["step"], train.cameras)
    return depths, {"field": "hashgrid", "iterations": sum(s["iters"] for s in log["stages"]),
                    "train_s": log["train_s"]}


def depth_error(depths: np.ndarray, gt: np.ndarray) -> dict:
    both = (depths > 0) & (gt > 0)
    return {"mae_where_both": float(np.abs(depths - gt)[both].mean()) if both.any() else float("nan"),
            "coverage_of_gt": float(both.sum() / max(1, (gt > 0).sum())),
            "pixels_outside_gt": int(((depths > 0) & (gt <= 0)).sum())}


def errors_figure(panels: list[tuple[str, np.ndarray, np.ndarray]], vmax: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(panels)
    cols = min(3, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.0 * rows), squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for ax, (title, pts, dist) in zip(axes.ravel(), panels):
        order = np.argsort(pts[:, 2])  # draw low points first, so tops stay visible from above
        ax.set_facecolor("0.8")
        sc = ax.scatter(pts[order, 0], pts[order, 1], c=np.minimum(dist[order], vmax), s=0.8, cmap="inferno",
                        vmin=0, vmax=vmax, linewidths=0)
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(sc, ax=ax, shrink=0.8, label=f"distance to the true surface (clipped at {vmax:.3f})")
    finish_figure(fig, path)


def run(ctx: Context) -> int:
    from research import datasets
    from research.surface import fusion, groundtruth, mesh, metrics

    args = ctx.args
    cfg = setup(ctx.quick, ctx.smoke)
    o3d = None if args.no_open3d else fusion.open3d_module()
    dcfg = datasets.DatasetConfig("objects", views=cfg.views, res=cfg.res, spp=cfg.spp, seed=ctx.seed)
    data = datasets.ensure(dcfg, datasets.cache_dir(dcfg, ctx.data), show_progress=ctx.progress)
    ds = datasets.load(data)
    train = ds.load_split("train")
    bbox = ds.bbox.copy()
    diag = float(np.linalg.norm(bbox[1] - bbox[0]))
    h = float((bbox[1] - bbox[0]).max()) / cfg.voxels_per_side
    tau = cfg.truncation_voxels * h
    thresholds = [p / 100 * diag for p in THRESHOLDS_PCT]
    grid = fusion.fusion_grid(bbox, h, tau)[1]

    gt_pts, gt_nrm, shapes = groundtruth.sample_scene_surface("objects", cfg.samples, ctx.seed)
    seen = groundtruth.observed(gt_pts, train.cameras, train.depth, VISIBLE_PCT / 100 * diag)
    gt_pts, gt_nrm = gt_pts[seen], gt_nrm[seen]

    depth_maps: dict[str, np.ndarray] = {}
    fits: dict[str, Any] = {}
    for src in args.sources:
        if src == "gt":
            depth_maps[src] = train.depth.astype(np.float32)
        elif src == "splats":
            depth_maps[src], fits[src] = fit_splat_depths(ctx, cfg, train)
        else:
            depth_maps[src], fits[src] = fit_field_depths(ctx, train, bbox)
    suffix = "" if ctx.mode == "full" else "-" + ctx.mode
    ply_dir = (args.ply_dir or registry.base_dir() / "build" / f"surface_recon{suffix}").absolute()

    results: dict[str, dict] = {}
    panels = []
    bar = ctx.tqdm(total=len(depth_maps) * (2 if o3d else 1), desc="fusion")
    for k, (src, depths) in enumerate(depth_maps.items()):
        methods = {"drlab": lambda: fusion.fuse(depths, train.cameras, bbox, h, tau, device=ctx.device)}
        if o3d is not None:
            methods["open3d"] = lambda: fusion.fuse_open3d(depths, train.cameras, bbox, h, tau)
        for method, fn in methods.items():
            fused = fn()
            row: dict[str, Any] = {"source": src, "method": method, "seconds": fused.seconds,
                                   "integrate_seconds": fused.integrate_seconds,
                                   "extract_seconds": fused.extract_seconds, "views": fused.views,
                                   "skipped": fused.skipped, "vertices": len(fused.vertices),
                                   "faces": len(fused.faces)}
            if len(fused.faces):
                pts, nrm = mesh.sample_mesh(fused.vertices, fused.faces, cfg.samples, ctx.seed + 1 + k)
                row["area"] = mesh.mesh_area(fused.vertices, fused.faces)
            else:
                pts, nrm = np.zeros((0, 3)), np.zeros((0, 3))
            m = metrics.surface_metrics(pts, nrm, gt_pts, gt_nrm, thresholds, device=ctx.device)
            dist = m.pop("pred_distances", None)
            m.pop("gt_distances", None)
            row.update(m)
            if method == "drlab":
                ply = mesh.write_ply(ply_dir / f"{src}.ply", fused.vertices, fused.faces)
                v2, f2 = mesh.read_ply(ply)
                row["ply"] = {"path": str(ply.relative_to(registry.REPO_ROOT)) if ply.is_relative_to(registry.REPO_ROOT)
                              else str(ply), "bytes": ply.stat().st_size,
                              "round_trip_identical": bool(np.array_equal(f2, fused.faces) and np.array_equal(
                                  v2, fused.vertices.astype(np.float32).astype(np.float64)))}
                if not row["ply"]["round_trip_identical"]:
                    raise RuntimeError(f"{ply}: the mesh read back differs from the one written")
            if dist is not None and len(pts):
                sub = np.random.default_rng(ctx.seed).permutation(len(pts))[:30_000]
                panels.append((f"{method}: {SOURCE_LABEL[src]}", pts[sub], dist[sub]))
            results[f"{src}/{method}"] = row
            bar.update(1)
    bar.close()
    errors_figure(panels, thresholds[-1], ctx.out / "errors.png")

    headers = ["depth maps", "fusion", "chamfer", "accuracy", "completeness",
               *[f"F @ {p:g}% (P / R)" for p in THRESHOLDS_PCT], "normal consistency", "triangles", "fusion s"]
    rows = []
    for key, r in results.items():
        rows.append([SOURCE_LABEL[r["source"]], "drlab (Warp)" if r["method"] == "drlab" else "Open3D",
                     f"{r['chamfer']:.4f}", f"{r['accuracy']:.4f}", f"{r['completeness']:.4f}",
                     *[f"{t['fscore']:.3f} ({t['precision']:.3f} / {t['recall']:.3f})" for t in r["per_threshold"]],
                     f"{r['normal_consistency']:.3f}", f"{r['faces']:,}", f"{r['seconds']:.2f}"])
        if o3d is None and r["method"] == "drlab":
            rows.append([SOURCE_LABEL[r["source"]], "Open3D: not installed (pip install open3d-cpu)", *["-"] * 9])
    fit_text = "".join(
        f" Splat fit: {f['iterations']} iterations, {f['splats']} splats, {f['train_s']:.0f} s." if s == "splats" else
        f" Field fit: hash grid, {f['iterations']} iterations, {f['train_s']:.0f} s." for s, f in fits.items())
    derr = {s: depth_error(d, train.depth) for s, d in depth_maps.items() if s != "gt"}
    derr_text = "".join(f" {SOURCE_LABEL[s]}: depth MAE {e['mae_where_both']:.4f} where both have depth, "
                        f"{100 * e['coverage_of_gt']:.1f}% of the GT pixels covered." for s, e in derr.items())
    table = (f"`objects` from `drlab dataset` ({cfg.views} views, {cfg.res}x{cfg.res}, {cfg.spp} spp): the "
             f"{len(train.cameras)} train views' depth maps fused into a TSDF (voxel {h:.4f} = box side / "
             f"{cfg.voxels_per_side}, truncation {tau:.4f} = {cfg.truncation_voxels:g} voxels), device "
             f"`{ctx.device}`. Ground truth: {len(gt_pts):,} points on the Mitsuba shapes seen by a train view (of "
             f"{cfg.samples:,} sampled); each mesh sampled with {cfg.samples:,} points. Distances in scene units "
             f"(box diagonal {diag:.3f}); F-score thresholds {', '.join(f'{t:.4f}' for t in thresholds)} "
             f"({', '.join(f'{p:g}%' for p in THRESHOLDS_PCT)} of the diagonal). Fusion s: integration of every "
             "view plus mesh extraction, wall time, the same depth maps for both methods; drlab's grid is "
             f"{'x'.join(map(str, grid))} = {np.prod(grid):,} voxels, Open3D's uniform volume the cube of its largest "
             f"side, {max(grid) ** 3:,} voxels with the same centres (it has no box shape)." + fit_text + derr_text
             + "\n\n" + markdown_table(headers, rows)
             + "\n![error-coloured samples of each mesh, top view](errors.png)\n")
    record = datasets.provenance(data)
    metrics_out = {"dataset": {"path": str(data), "config": dcfg.__dict__, "content_hash": record["content_hash"]},
                   "voxel_size": h, "truncation": tau, "grid": list(grid), "open3d_grid": [max(grid)] * 3,
                   "box_diagonal": diag, "thresholds": thresholds, "thresholds_pct_of_diagonal": list(THRESHOLDS_PCT),
                   "gt_points": int(len(gt_pts)), "gt_sampled": cfg.samples, "gt_shapes": shapes,
                   "open3d": None if o3d is None else o3d.__version__, "fits": fits, "depth_errors": derr,
                   "results": results}
    ctx.write_results(config={**asdict(cfg), "sources": args.sources}, metrics=metrics_out,
                      table_md=table)
    return 0


main = Experiment("surface_recon", __doc__, run, add_options, data_help=CACHE_ROOT_HELP,
                  seed_help="seed of the dataset's cameras, the fits and the surface samples",
                  sizes="Full: 100 views at 128x128, 64 spp, voxel = box side / 192, 200k samples (about 15 "
                        "minutes on 2 cores, mostly the two fits); quick: 40 views at 64x64, voxel / 128, 50k; smoke: "
                        "8 views at 32x32, voxel / 48, 4k samples, tiny fits.").script(__name__)
