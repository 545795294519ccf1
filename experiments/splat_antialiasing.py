#!/usr/bin/env python3
"""Anti-aliased splats across scales: 3DGS's dilation against Mip-Splatting's 2D and 3D filters.

Mip-Splatting's single-scale protocol (Yu et al., CVPR 2024, the Blender "train at one scale, test at
others" tables), on drlab's Mitsuba `objects` scene: every view is rendered once at TWICE the
training resolution, and every lower resolution is its exact box average (a pixel of the lower
resolution integrates the radiance over its footprint, as a camera's pixel does). Splats are trained
at 1x (the 2x renders averaged 2x2) and scored on the held-out views at 1/4, 1/2, 1 and 2 times the
training resolution (the camera's K scaled with the pixel grid).

Four models, each trained from the same initial points with the same schedule (research.splats.train):

  3DGS              the 0.3 px^2 screen-space dilation (kernels/splat, mode "3dgs");
  2D Mip filter     Mip-Splatting's 2D filter alone: a 0.1 px^2 dilation with the opacity compensation
                    (antialiased=True, dilation=0.1);
  3D filter         Mip-Splatting's 3D smoothing filter (research/splats/mip.py, s = 0.2) with the 3DGS
                    dilation;
  Mip-Splatting     both filters, as the paper's method.

The filter sizes (s = 0.2, 0.1 px^2) are Mip-Splatting's published values; the training schedule is
fit_splats' (chosen on drlab's own `objects` renders). Nothing was tuned on this experiment's data.
Reported: PSNR and SSIM (research.metrics, sRGB) per test scale and their mean, splat counts, training
wall time; figure.png shows one held-out view at every scale for every model. Writes
results/splat_antialiasing/{table.md, metrics.json, figure.png}.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from research.datasets import CACHE_ROOT_HELP
from research.experiment import Context, Experiment
from research.results import image_grid, markdown_table

SCALES = (0.25, 0.5, 1.0, 2.0)  # test resolution / training resolution


@dataclass(frozen=True)
class Model:
    label: str
    antialiased: bool
    dilation: float | None
    filter_3d: float


MODELS = (Model("3DGS", False, None, 0.0),
          Model("2D Mip filter", True, 0.1, 0.0),
          Model("3D filter", False, None, 0.2),
          Model("Mip-Splatting (3D + 2D)", True, 0.1, 0.2))


def sizes(quick: bool, smoke: bool) -> dict:
    """Training resolution (the renders are twice it), views, spp, iterations, initial points, splat cap."""
    if smoke:
        return {"res": 48, "views": 8, "spp": 2, "iterations": 20, "init_points": 200, "max_gaussians": 800}
    if quick:
        return {"res": 64, "views": 40, "spp": 16, "iterations": 600, "init_points": 2000, "max_gaussians": 8000}
    return {"res": 128, "views": 100, "spp": 64, "iterations": 3000, "init_points": 8000, "max_gaussians": 30_000}


def box_average(images: np.ndarray, factor: int) -> np.ndarray:
    """(N, H, W, C) -> (N, H / factor, W / factor, C): the mean of each factor x factor block."""
    n, h, w, c = images.shape
    if h % factor or w % factor:
        raise ValueError(f"images: {w}x{h} is not divisible by {factor}")
    return images.reshape(n, h // factor, factor, w // factor, factor, c).mean(axis=(2, 4), dtype=np.float64
                                                                              ).astype(np.float32)


def add_options(p) -> None:
    p.add_argument("--iterations", type=int, default=None,
                   help="training iterations of every model (default 3000; quick 600; smoke 20)")


def figure(gt: dict[float, np.ndarray], renders: dict[str, dict[float, np.ndarray]], path: Path) -> None:
    from research.metrics import srgb_on_black

    rows = {"ground truth": gt, **renders}
    image_grid([[(srgb_on_black(images[s]), f"{label}, {s:g}x" if c == 0 else f"{s:g}x") for c, s in enumerate(SCALES)]
                for label, images in rows.items()], path, cell=(2.2, 2.2), fontsize=7, interpolation="nearest")


def run(ctx: Context) -> int:
    import time

    from research import datasets
    from research.datasets import formats
    from research.splats import model as sm, train as st

    size = sizes(ctx.quick, ctx.smoke)
    size["iterations"] = ctx.int_option("--iterations", size["iterations"])
    dcfg = datasets.DatasetConfig("objects", views=size["views"], res=2 * size["res"], spp=size["spp"],
                                  seed=ctx.seed)
    path = datasets.ensure(dcfg, datasets.cache_dir(dcfg, ctx.data), show_progress=ctx.progress)
    ds = datasets.load(path)
    train_split, test_split = ds.load_split("train"), ds.load_split("test")
    train_hi = formats.protocol_target_linear(train_split, ds.protocol)
    test_hi = formats.protocol_target_linear(test_split, ds.protocol)
    train_cams = [c.scaled(0.5) for c in train_split.cameras]
    train_rgb = box_average(train_hi, 2)
    test_cams = {s: [c.scaled(s / 2) for c in test_split.cameras] for s in SCALES}
    test_rgb = {s: test_hi if s == 2.0 else box_average(test_hi, round(2 / s)) for s in SCALES}

    points, colors = sm.points_from_depth(train_split.cameras, train_split.rgba, train_split.depth,
                                          size["init_points"], ctx.seed)
    init = sm.from_points(points, colors)
    extent = sm.scene_extent(train_cams)
    rows, results, renders = [], {}, {}
    for m in ctx.tqdm(MODELS, desc="models"):
        tcfg = st.TrainConfig(iterations=size["iterations"], seed=ctx.seed, antialiased=m.antialiased,
                              dilation=m.dilation, filter_3d=m.filter_3d,
                              densify=st.DensifyConfig(max_gaussians=size["max_gaussians"]))
        t0 = time.perf_counter()
        res = st.train(init, train_cams, train_rgb, extent, tcfg, device=ctx.device, progress=False)
        train_s = time.perf_counter() - t0
        per_scale = {}
        renders[m.label] = {}
        for s in SCALES:
            ev = st.evaluate(res.model, test_cams[s], test_rgb[s], res.sh_degree, antialiased=m.antialiased,
                             device=ctx.device, dilation=m.dilation)
            per_scale[s] = {"psnr": ev.psnr, "ssim": ev.ssim}
            renders[m.label][s] = ev.renders[0]
        mean_psnr = float(np.mean([v["psnr"] for v in per_scale.values()]))
        mean_ssim = float(np.mean([v["ssim"] for v in per_scale.values()]))
        results[m.label] = {"model": asdict(m), "per_scale": {f"{s:g}x": v for s, v in per_scale.items()},
                            "mean_psnr": mean_psnr, "mean_ssim": mean_ssim, "splats": res.model.n,
                            "train_seconds": train_s}
        rows.append([m.label, *(per_scale[s]["psnr"] for s in SCALES), mean_psnr,
                     *(per_scale[s]["ssim"] for s in SCALES), mean_ssim, res.model.n, train_s])
    figure({s: test_rgb[s][0] for s in SCALES}, renders, ctx.out / "figure.png")

    r = size["res"]
    headers = ["model", *(f"PSNR {s:g}x" for s in SCALES), "PSNR mean", *(f"SSIM {s:g}x" for s in SCALES),
               "SSIM mean", "splats", "train s"]
    table = (f"Mitsuba `objects`, trained at {r}x{r} ({len(train_cams)} views, {size['iterations']} iterations), "
             f"scored on {len(test_split.cameras)} held-out views at "
             + ", ".join(f"{int(r * s)}x{int(r * s)} ({s:g}x)" for s in SCALES)
             + f". Every resolution is the box average of one {2 * r}x{2 * r} render ({size['spp']} spp). "
             "PSNR (dB) and SSIM on sRGB. Filter sizes are Mip-Splatting's (3D s = 0.2; 2D 0.1 px^2 with the "
             "opacity compensation); 3DGS dilates by 0.3 px^2. Train time: wall, this machine.\n\n"
             + markdown_table(headers, rows, floatfmt=".4g") + "\n\n![every model at every scale](figure.png)\n")
    metrics = {"dataset": {"path": str(path), "config": dcfg.__dict__}, "scales": list(SCALES), "models": results}
    ctx.write_results(config={**size}, metrics=metrics, table_md=table)
    return 0


main = Experiment("splat_antialiasing", __doc__, run, add_options,
                  seed_help="seed of the dataset's cameras and of training",
                  sizes="Full: trained at 128x128 (renders 256x256, 64 spp), 100 views, 3000 iterations; quick: 64x64, "
                        "40 views, 600 iterations; smoke: 48x48 (SSIM needs 11x11 at 1/4), 8 views, 2 spp, 20 iterations.",
                  data_help=CACHE_ROOT_HELP).script(__name__)
