#!/usr/bin/env python3
"""Render the Mitsuba ground-truth datasets, time them, and check their geometry.

For each built-in scene this renders a multi-view dataset with stereo pairs and
a flow sequence into data/<scene>/ (reused by the other experiments), then
measures how well the stored geometry agrees with Mitsuba itself
(research.datasets.consistency):

  * position AOV -> our camera model: max distance to the pixel centre;
  * multi-view: view A's depth and pose reprojected into B vs B's surface (exact ray casts);
  * stereo: left (x, y) vs right (x - d, y), non-occluded pixels;
  * flow: frame 2's surface sampled at x + flow, projected back to frame 1 (median).

Writes results/datasets/{table.md, metrics.json, preview.png}.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from research.experiment import Context, Experiment
from research.results import finish_figure, image_panel, markdown_table

SCENES = ("objects", "spheres", "cornell")


def configs(quick: bool, seed: int, smoke: bool = False):
    from research.datasets import DatasetConfig

    if smoke:
        return [DatasetConfig(s, views=4, res=32, spp=4, seed=seed, stereo=True, stereo_pairs=2, flow=True,
                              flow_frames=3) for s in SCENES]
    if quick:
        return [DatasetConfig(s, views=12, res=64, spp=16, seed=seed, stereo=True, stereo_pairs=3, flow=True,
                              flow_frames=4) for s in SCENES]
    # The headline configuration for `objects`; fewer views for the other two scenes.
    return [DatasetConfig("objects", views=100, res=256, spp=64, seed=seed, stereo=True, flow=True)] + [
        DatasetConfig(s, views=40, res=256, spp=64, seed=seed, stereo=True, flow=True) for s in SCENES[1:]]


def preview(paths: dict[str, Path], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research import io
    from research.datasets import load, load_flow, load_stereo

    cols = ["RGB", "z-depth", "normals", "stereo disparity", "stereo non-occluded", "flow (u)", "flow valid"]
    fig, axes = plt.subplots(len(paths), len(cols), figsize=(2.4 * len(cols), 2.5 * len(paths)), squeeze=False)
    for row, (scene, path) in enumerate(paths.items()):
        view = load(path).split_views("test")[0]
        pair = load_stereo(path)[0]
        seq = load_flow(path)
        depth = io.read_exr(view.path("_depth.exr"))
        normal = io.read_exr(view.path("_normal.exr"))
        imgs = [io.read_png(view.path(".png"), linear=False),
                np.ma.masked_where(depth <= 0, depth),
                np.clip(0.5 + 0.5 * normal, 0, 1) * (depth > 0)[..., None],
                np.ma.masked_where(~pair.mask, pair.disparity), pair.noc,
                np.ma.masked_where(seq.depth[0] <= 0, seq.flow[0][..., 0]), seq.valid[0]]
        for col, img in enumerate(imgs):
            image_panel(fig, axes[row, col], img, cols[col] if row == 0 else None,
                        colorbar=img.ndim == 2 and img.dtype != bool, cmap=None if img.ndim == 3 else "viridis")
        axes[row, 0].set_ylabel(scene)
    finish_figure(fig, out)


def run(ctx: Context) -> int:
    from research.datasets import consistency, generate, get_scene, load, load_flow, load_stereo
    from research.datasets.render import SceneRenderer
    from research.mitsuba_env import select_variant

    variant = select_variant()
    rows, metrics, paths = [], {}, {}
    for cfg in configs(ctx.quick, ctx.seed, ctx.smoke):
        path = ctx.data / (cfg.scene + ("" if ctx.mode == "full" else "-" + ctx.mode))
        t0 = time.perf_counter()
        # Always regenerated: the render time is one of the results.
        generate(cfg, path, force=True, show_progress=ctx.progress)
        seconds = time.perf_counter() - t0
        renderer = SceneRenderer(get_scene(cfg.scene), spp=1)
        ds = load(path, verify_hashes=True)
        aov = consistency.aov_reprojection(ds, renderer)
        mv = consistency.multiview_reprojection(ds, renderer)
        st = consistency.stereo_correspondence(load_stereo(path), renderer)
        fl = consistency.flow_correspondence(load_flow(path), renderer)
        n_images = cfg.views + (2 * cfg.stereo_pairs if cfg.stereo else 0) + (cfg.flow_frames if cfg.flow else 0)
        metrics[cfg.scene] = {"config": asdict(cfg), "seconds": seconds,
                              "rendered_images": n_images, "content_hash": ds.manifest["content_hash"],
                              "aov": aov, "multiview": mv, "stereo": st, "flow": fl}
        rows.append([cfg.scene, f"{cfg.views}+{cfg.stereo_pairs}x2+{cfg.flow_frames}", f"{cfg.res}x{cfg.res}",
                     cfg.spp, f"{seconds:.1f}", f"{aov['pixel_err_max']:.1e}",
                     f"{mv['depth_rel_err_p999']:.1e} ({mv['depth_rel_outliers']} of {mv['points']:,})",
                     f"{mv['pixel_err_max']:.1e}", f"{st['pixel_err_max']:.1e}", f"{fl['pixel_err_median']:.1e}",
                     f"{st['noc_fraction']:.3f}", f"{fl['valid_fraction']:.3f}"])
        paths[cfg.scene] = path

    headers = ["scene", "images (views+stereo+flow)", "res", "spp", "render s", "AOV->pixel max px",
               "multi-view depth rel p99.9 (points > 1e-3)", "multi-view max px", "stereo max px",
               "flow median px", "stereo noc frac", "flow valid frac"]
    table = (f"Mitsuba variant `{variant}`, 2-core CPU. Errors compare the stored geometry with Mitsuba's own "
             "position AOV and exact ray casts (research/datasets/consistency.py). Multi-view depth: relative "
             "error of view A's depth reprojected into B against B's ray-cast surface, at the 99.9th percentile, "
             "with the number of points above 1e-3 (the maximum, in metrics.json, can be a single point where "
             "the camera ray grazes an occluder's edge that the visibility ray misses).\n\n"
             + markdown_table(headers, rows))
    preview(paths, ctx.out / "preview.png")
    ctx.write_results(config={"scenes": list(SCENES)}, device="cpu",
                      metrics={"mitsuba_variant": variant, "scenes": metrics}, table_md=table)
    return 0


main = Experiment("datasets", __doc__, run, warp=False,
                  data_help="where the datasets are written: <data>/<scene> (with --quick <scene>-quick, with --smoke "
                            "<scene>-smoke), always regenerated",
                  seed_help="seed of camera poses, splits and render noise",
                  sizes="Quick: 12 views at 64x64, 16 spp, per scene (about a minute); smoke: 4 views at 32x32, "
                        "4 spp.").script(__name__)
