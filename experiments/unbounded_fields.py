#!/usr/bin/env python3
"""Unbounded scenes for the radiance fields: mip-NeRF 360's contraction + a proposal sampler vs the bounded box.

Two fields per scene, fitted on the same training views with the same number of training rays:
  * baseline    fit_nerf's hash-grid field (12 levels, 2^15 entries, max resolution 256; its quick
                schedule, 400 iterations of 2048 rays) on the scene's bounded box, with its ray
                marcher and occupancy grid (research.nerf.train) -- on forward-facing data
                (LLFF) in NeRF's NDC, as fit_nerf fits it;
  * contracted  the same hash grid on [-2, 2]^3 behind mip-NeRF 360's contraction (L2), sampled by a
                proposal field (nerfacto's first proposal network: 5 levels, max resolution 128,
                2^17 entries, one hidden layer of 16) through the s-space spacing (linear up to tau,
                disparity beyond, far = 1000), K = 64 proposal and M = 32 main intervals per ray,
                800 iterations of 1024 rays, the interlevel loss with weight 1 (research/nerf/unbounded.py).
Scenes: `backdrop` (research.datasets.scenes: objects on a table inside a panorama wall 15 away on a
ground disk of radius 14, under a sky; cameras orbit at 2.6 looking in, elevations 3-30 degrees),
rendered by Mitsuba; and the real LLFF `fern` (forward-facing; its images_8 box-averaged 2x to 252x189,
LLFF's every-8th-image test split). Scores: test PSNR and SSIM (sRGB) on the full image and on the
background pixels alone -- on `backdrop` the pixels whose ground-truth surface lies outside the
baseline's box (or that see the sky), and the foreground (the rest) beside them; `fern` has no
ground-truth geometry, so it is scored on full images only.

Which data chose each setting: the contraction's frame follows mip-NeRF 360's normalisation
(centre = the orbit's target, radius = the cameras' distance, so the cameras lie on the unit sphere
and tau = that radius) on `backdrop`; on `fern` the centre is the mean camera centre and the radius
and tau are 1, the depth of NeRF's NDC near plane in LLFF's rescaled frame (the scene lies beyond
it, in the contracted part, as NDC maps it to disparity). The learning rates (1e-2 for both fields)
are nerfacc's, the interlevel weight mip-NeRF 360's, the histogram padding (0.01) nerfstudio's, the
proposal field nerfacto's; the sample counts are nerfacto's 256/48 scaled down for a CPU, and the
baseline is fit_nerf's quick plan as published there (chosen on Mitsuba `objects`). Nothing was
tuned on the scenes reported here.

Writes results/unbounded_fields/{table.md, metrics.json, renders.png, loss.png}.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from research.datasets import CACHE_ROOT_HELP
from research.experiment import Context, Experiment
from research.results import finish_figure, image_panel, loss_figure, markdown_table

FERN = Path("/work/realdata/nerf_llff_data/fern")
METHODS = ("baseline", "contracted")


def sizes(quick: bool, smoke: bool) -> dict[str, Any]:
    if smoke:
        return {"views": 8, "res": 32, "spp": 4, "iters": 20, "batch": 256, "n_proposal": 16, "n_main": 8,
                "fern_scale": 0.5, "fern_test": 1}
    if quick:
        return {"views": 24, "res": 48, "spp": 16, "iters": 200, "batch": 1024, "n_proposal": 64, "n_main": 32,
                "fern_scale": 0.5, "fern_test": 1}
    return {"views": 48, "res": 64, "spp": 32, "iters": 800, "batch": 1024, "n_proposal": 64, "n_main": 32,
            "fern_scale": 0.5, "fern_test": None}


def _box_average(images: np.ndarray, scale: float) -> np.ndarray:
    k = round(1.0 / scale)
    n, h, w, c = images.shape
    h2, w2 = h // k, w // k
    return images[:, :h2 * k, :w2 * k].reshape(n, h2, k, w2, k, c).mean(axis=(2, 4))


def _bank(cameras, rgba_srgb: np.ndarray, ndc=None):
    from research.nerf.render import camera_rays
    from research.nerf.train import RayBank

    rays = [camera_rays(c, np.float32, ndc) for c in cameras]
    return RayBank(*(np.concatenate([r[i] for r in rays]) for i in range(3)),
                   rgba_srgb.reshape(-1, 4).astype(np.float64))


def backdrop_scene(ctx: Context, sz: dict) -> dict[str, Any]:
    from research.datasets import DatasetConfig, cache_dir, ensure, get_scene, load
    from research.metrics import srgb_targets

    cfg = DatasetConfig("backdrop", views=sz["views"], res=sz["res"], spp=sz["spp"], seed=ctx.seed)
    ds = load(ensure(cfg, cache_dir(cfg, ctx.data), show_progress=ctx.progress))
    train, test = ds.load_split("train"), ds.load_split("test")
    spec = get_scene("backdrop")
    bbox = ds.bbox.copy()
    background = []
    for cam, depth, mask in zip(test.cameras, test.depth, test.mask):
        p = cam.backproject(depth)
        inside = np.all((p >= bbox[0]) & (p <= bbox[1]), axis=-1)
        background.append(~(mask & inside))
    rgba = srgb_targets(train.rgba)
    return {"name": "backdrop", "data": f"`drlab dataset --scene backdrop` ({cfg.views} views, {cfg.res}x{cfg.res}, {cfg.spp} spp)", "train_cams": train.cameras,
            "test_cams": test.cameras, "bank": _bank(train.cameras, rgba), "gt": srgb_targets(test.rgba)[..., :3],
            "background_mask": np.array(background), "bbox": bbox, "ndc": None, "random_background": False,
            "frame": {"center": list(spec.target), "radius": spec.radius, "tau": spec.radius, "near": 0.05}}


def fern_scene(ctx: Context, sz: dict, path: Path) -> dict[str, Any]:
    from research.datasets import formats, open_dataset

    ds = open_dataset(path, "llff", 8)
    train, test = ds.load_split(ds.protocol.train_split), ds.load_split(ds.protocol.test_split)
    s = sz["fern_scale"]
    n_test = sz["fern_test"] or len(test.cameras)
    train_cams = [c.scaled(s) for c in train.cameras]
    test_cams = [c.scaled(s) for c in test.cameras][:n_test]
    rgba = _box_average(formats.protocol_srgb(train, ds.protocol), s)
    gt = _box_average(formats.protocol_target_srgb(test, ds.protocol), s)[:n_test]
    centre = np.mean([c.center for c in train.cameras], axis=0)
    return {"name": "fern", "data": f"LLFF {path} images_8 box-averaged to {train_cams[0].width}x{train_cams[0].height}",
            "train_cams": train_cams, "test_cams": test_cams, "bank": _bank(train_cams, rgba),
            "bank_ndc": _bank(train_cams, rgba, ds.ndc), "gt": gt, "background_mask": None,
            "bbox": ds.ndc.bbox_for(train_cams), "ndc": ds.ndc, "random_background": True,
            "frame": {"center": centre.tolist(), "radius": 1.0, "tau": 1.0, "near": 1.0}}


def _scores(pred: np.ndarray, gt: np.ndarray, bg: np.ndarray | None) -> dict[str, float]:
    from research.metrics import psnr, ssim

    pred = np.clip(pred, 0.0, 1.0)
    row = {"psnr": psnr(pred, gt), "ssim": ssim(pred, gt)}
    if bg is not None:
        row["bg_psnr"] = psnr(pred, gt, mask=bg)
        row["bg_ssim"] = ssim(pred, gt, mask=bg)
        row["fg_psnr"] = psnr(pred, gt, mask=~bg)
        row["fg_ssim"] = ssim(pred, gt, mask=~bg)
        row["bg_fraction"] = float(bg.mean())
    return row


def fit_baseline(scene: dict, ctx: Context) -> dict[str, Any]:
    from experiments.fit_nerf import fit_one, plans
    from research.nerf.render import render_image

    bbox = scene["bbox"]
    plan = plans(not ctx.smoke, bbox, ctx.smoke)["hashgrid"]  # fit_nerf's quick plan (smoke: its smoke plan)
    bank = scene.get("bank_ndc", scene["bank"])
    field, occupancy, log = fit_one("hashgrid", plan, bank, bbox, True, ctx.seed, ctx.progress,
                                    random_background=scene["random_background"])
    images, rows, t0 = [], [], time.perf_counter()
    for i, cam in enumerate(scene["test_cams"]):
        img = render_image(cam, field, bbox, step=plan["config"]["step"], occupancy=occupancy, ndc=scene["ndc"])
        images.append(np.clip(img.rgb, 0, 1))
        rows.append(_scores(img.rgb, scene["gt"][i], None if scene["background_mask"] is None
                            else scene["background_mask"][i]))
    return {"images": images, "rows": rows, "train_s": log["train_s"], "losses": log["losses"],
            "render_s": (time.perf_counter() - t0) / len(images), "params": field.n_params(),
            "iters": sum(s["iters"] for s in log["stages"]), "batch_rays": log["config"]["batch_rays"]}


def fit_contracted(scene: dict, ctx: Context, sz: dict) -> dict[str, Any]:
    from research.nerf.unbounded import UnboundedConfig, contracted_hashgrid, render_image_unbounded, train_unbounded

    fr = scene["frame"]
    small = ctx.smoke
    main = contracted_hashgrid(fr["center"], fr["radius"], n_levels=4 if small else 12,
                               log2_table_size=12 if small else 15, max_resolution=64 if small else 256, seed=ctx.seed)
    prop = contracted_hashgrid(fr["center"], fr["radius"], n_levels=3 if small else 5,
                               log2_table_size=12 if small else 17, max_resolution=32 if small else 128, hidden=(16,),
                               seed=ctx.seed + 1)
    cfg = UnboundedConfig(iters=sz["iters"], batch_rays=sz["batch"], n_proposal=sz["n_proposal"], n_main=sz["n_main"],
                          near=fr["near"], tau=fr["tau"], seed=ctx.seed)
    log = train_unbounded(main, prop, scene["bank"], cfg, progress=ctx.progress, desc=f"{scene['name']} contracted")
    images, rows, t0 = [], [], time.perf_counter()
    for i, cam in enumerate(scene["test_cams"]):
        img = render_image_unbounded(cam, main, prop, cfg)
        images.append(np.clip(img.rgb, 0, 1))
        rows.append(_scores(img.rgb, scene["gt"][i], None if scene["background_mask"] is None
                            else scene["background_mask"][i]))
    return {"images": images, "rows": rows, "train_s": log["train_s"], "losses": log["losses"],
            "interlevel": log["interlevel"], "render_s": (time.perf_counter() - t0) / len(images),
            "params": main.n_params() + prop.n_params(), "iters": cfg.iters, "batch_rays": cfg.batch_rays,
            "config": cfg.to_dict(), "frame": fr}


def figure(scenes: list[dict], results: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(scenes), 4, figsize=(12, 3.0 * len(scenes)), squeeze=False)
    for row, scene in zip(axes, scenes):
        r = results[scene["name"]]
        bg = scene["background_mask"]
        panels = [(scene["gt"][0], f"{scene['name']}: ground truth")]
        for m in METHODS:
            panels.append((r[m]["images"][0], f"{m} ({r[m]['rows'][0]['psnr']:.1f} dB)"))
        panels.append((bg[0].astype(float) if bg is not None else np.abs(r["contracted"]["images"][0]
                       - scene["gt"][0]).mean(axis=2),
                       "background pixels" if bg is not None else "|error| contracted"))
        for ax, (im, title) in zip(row, panels):
            image_panel(fig, ax, im, title, cmap="gray" if np.ndim(im) == 2 else None, vmin=0, vmax=1)
    finish_figure(fig, out / "renders.png")
    loss_figure({f"{s['name']} {m}": results[s["name"]][m]["losses"] for s in scenes for m in METHODS},
                "training MSE (sRGB)", out / "loss.png")


def add_options(p) -> None:
    p.add_argument("--fern", type=Path, default=None,
                   help=f"the LLFF fern folder (default: {FERN} when it exists; the smoke run uses it only when given)")
    p.add_argument("--scenes", nargs="+", default=["backdrop", "fern"], choices=["backdrop", "fern"],
                   help="scenes to fit (default: both; fern is skipped when its folder is missing)")


def run(ctx: Context) -> int:
    args = ctx.args
    sz = sizes(ctx.quick, ctx.smoke)
    fern = args.fern if args.fern is not None else (None if ctx.smoke or not FERN.is_dir() else FERN)
    scenes = []
    if "backdrop" in args.scenes:
        scenes.append(backdrop_scene(ctx, sz))
    if "fern" in args.scenes and fern is not None:
        scenes.append(fern_scene(ctx, sz, fern))
    results: dict[str, Any] = {}
    for scene in scenes:
        results[scene["name"]] = {"baseline": fit_baseline(scene, ctx), "contracted": fit_contracted(scene, ctx, sz)}
        for m in METHODS:
            r = results[scene["name"]][m]
            r["mean"] = {k: float(np.mean([row[k] for row in r["rows"]])) for k in r["rows"][0]}
            print(f"{scene['name']} {m}: " + ", ".join(f"{k} {v:.3f}" for k, v in r["mean"].items())
                  + f", train {r['train_s']:.0f} s", flush=True)
    figure(scenes, results, ctx.out)
    rows = []
    for scene in scenes:
        for m in METHODS:
            r = results[scene["name"]][m]
            mean = r["mean"]
            rows.append([scene["name"], m, f"{mean['psnr']:.2f}", f"{mean['ssim']:.3f}",
                         f"{mean['bg_psnr']:.2f}" if "bg_psnr" in mean else "-",
                         f"{mean['bg_ssim']:.3f}" if "bg_ssim" in mean else "-",
                         f"{mean['fg_psnr']:.2f}" if "fg_psnr" in mean else "-",
                         f"{mean['fg_ssim']:.3f}" if "fg_ssim" in mean else "-",
                         r["iters"], r["batch_rays"], f"{r['params']:,}", f"{r['train_s']:.0f}", f"{r['render_s']:.1f}"])
    headers = ["scene", "field", "test PSNR (dB)", "test SSIM", "background PSNR (dB)", "background SSIM",
               "foreground PSNR (dB)", "foreground SSIM",
               "iterations", "rays / iteration", "parameters", "train s", "s / test image"]
    lines = [f"- `{s['name']}`: {s['data']}; {len(s['train_cams'])} training and {len(s['test_cams'])} test views"
             + (f", background = {100 * s['background_mask'].mean():.0f}% of the test pixels (outside the box "
                f"{np.round(s['bbox'], 2).tolist()} or sky)" if s["background_mask"] is not None else
                ", no ground-truth geometry (no background score)") for s in scenes]
    table = ("Baseline: fit_nerf's hash grid on the bounded box (NDC for fern) with its ray marcher; contracted: the same "
             "hash grid behind mip-NeRF 360's contraction (L2) with a proposal field and s-space sampling "
             f"(experiments/unbounded_fields.py). Device `{ctx.device}`, 2-core CPU; sRGB PSNR/SSIM.\n\n"
             + "\n".join(lines) + "\n\n" + markdown_table(headers, rows))
    metrics = {"sizes": sz, "scenes": {
        s["name"]: {"data": s["data"], "train_views": len(s["train_cams"]), "test_views": len(s["test_cams"]),
                    "bbox": np.asarray(s["bbox"]).tolist(), "frame": s["frame"],
                    "background_fraction": None if s["background_mask"] is None else float(s["background_mask"].mean()),
                    "methods": {m: {k: v for k, v in results[s["name"]][m].items() if k not in ("images", "losses",
                                                                                            "interlevel")}
                                | {"final_loss": float(np.mean(results[s["name"]][m]["losses"][-50:]))}
                                for m in METHODS}} for s in scenes}}
    ctx.write_results(config={"scenes": [s["name"] for s in scenes]}, metrics=metrics,
                      table_md=table)
    return 0


main = Experiment("unbounded_fields", __doc__, run, add_options, data_help=CACHE_ROOT_HELP,
                  seed_help="seed of the dataset's cameras, the fields' initialisation and the ray batches",
                  sizes="Full: backdrop 48 views at 64x64 (32 spp), fern at 252x189; baseline 400 x 2048 rays, "
                        "contracted 800 x 1024 rays. Quick: backdrop 24 views at 48x48, fern at 252x189 (one test "
                        "view), 200 contracted iterations. Smoke: backdrop 8 views at 32x32, tens of iterations, "
                        "no fern unless --fern is given.").script(__name__)
