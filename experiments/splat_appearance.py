#!/usr/bin/env python3
"""Per-image appearance for splats: no model vs one affine colour transform per image vs a bilateral grid.

Two image sets whose TRAINING views differ in exposure and colour from image to image while the
held-out views are clean, as in a capture shot with auto exposure and auto white balance:

  Mitsuba `objects`  the rendered views (linear radiance); every training view passes through its own
                     camera response: white balance (per-channel gains 2^u, u ~ U[-0.15, 0.15]), a
                     tone change E <- E^gamma (gamma = 2^u, u ~ U[-0.15, 0.15]) and then the
                     radiometric stress set (research/radiometry.py: blur, vignetting, exposure
                     U[-1, 1] stops, black level, Poisson-Gaussian noise, 8-bit sRGB) with its
                     defaults except the exposure range (its +-0.3 stops describe a stereo pair; a
                     capture's auto exposure moves more). Test views: the 8-bit encoding alone.
  LLFF fern          the real photographs (images_8, box-averaged 3x3 to 168x126 for the CPU budget).
                     Its 20 photos were shot at one setting (EXIF: 1/15 s, f/1.8, ISO 64, fixed white
                     balance, all alike), so the varying exposure is APPLIED to its 17 training photos
                     (linear: exposure U[-1, 1] stops and the white balance above, then clipped and
                     encoded to 8 bits); its 3 held-out photos (llffhold 8) stay as they are.

Three models per set, trained from the same initial points with the same schedule
(research.splats.train), the baseline in the same run:

  none        3DGS as it is;
  affine      one 3x4 affine colour transform per training image (research/splats/appearance.py);
  bilateral   gsplat's bilateral grid per training image (16 x 16 x 8, TV weight 10).

Held-out views are rendered with the identity appearance (gsplat's evaluation): PSNR and SSIM on
sRGB (research.metrics); "corrected PSNR" fits the best per-image affine transform of the render
to the held-out image first (least squares in linear RGB), as the bilateral-grid paper's evaluation
corrects colour, so it scores geometry and view-dependent colour without the global colour level
that an unseen view's exposure leaves undetermined. Also reported: how well each learned
per-image gain follows the applied exposure (correlation of log2 of the mean diagonal gain with
the applied stops).

Which data chose each setting: the grid size, TV weight and learning rates are gsplat's published
defaults (research/splats/appearance.py); the stress ranges above were written down before any
run as a description of an auto-exposure capture; the training schedule is fit_splats'. Nothing was
tuned on these scenes. Writes results/splat_appearance/{table.md, metrics.json, figure.png}.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from research.experiment import Context, Experiment
from research.results import image_grid, markdown_table

MODELS = ("none", "affine", "bilateral")
LLFF_NAME = "nerf_llff_data/fern"
EXPOSURE_STOPS = 1.0  # +- per training image
WB_STOPS = 0.15  # +- per channel
GAMMA_STOPS = 0.15  # gamma = 2^u, u in +- this
FERN_BOX = 3  # images_8 (504x378) box-averaged to 168x126


@dataclass(frozen=True)
class Response:
    """One training image's colour change: per-channel white-balance gains, gamma, the stress camera."""

    wb: tuple[float, float, float]
    gamma: float
    camera: object  # research.radiometry.Camera


def sizes(quick: bool, smoke: bool) -> dict:
    if smoke:
        return {"res": 32, "views": 10, "spp": 2, "iterations": 20, "init_points": 200, "max_gaussians": 600}
    if quick:
        return {"res": 48, "views": 30, "spp": 8, "iterations": 300, "init_points": 1500, "max_gaussians": 5000}
    return {"res": 64, "views": 50, "spp": 32, "iterations": 1500, "init_points": 4000, "max_gaussians": 12_000}


def add_options(p) -> None:
    p.add_argument("--iterations", type=int, default=None,
                   help="training iterations of every model (default 1500; quick 300; smoke 20)")
    p.add_argument("--llff", type=Path, default=None,
                   help=f"the LLFF fern folder (default <data>/{LLFF_NAME}; smoke mode writes a tiny LLFF folder "
                        "from its own renders); a missing folder is an error outside smoke mode")


def draw_responses(n: int, rng: np.random.Generator, stress_set: bool) -> list[Response]:
    """Each training image's colour change (module docstring), drawn in image order."""
    from research import radiometry

    params = radiometry.Stress(exposure_stops=EXPOSURE_STOPS)
    out = []
    for _ in range(n):
        wb = tuple(float(x) for x in 2.0 ** rng.uniform(-WB_STOPS, WB_STOPS, 3))
        gamma = float(2.0 ** rng.uniform(-GAMMA_STOPS, GAMMA_STOPS)) if stress_set else 1.0
        cam = radiometry.draw_camera(rng, params)
        if not stress_set:  # the photographs: exposure alone (no blur, vignetting, offset, noise)
            cam = radiometry.Camera(0.0, 0.0, cam.exposure_stops, 0.0)
        out.append(Response(wb, gamma, cam))
    return out


def apply_responses(linear: np.ndarray, responses: list[Response], rng: np.random.Generator,
                    stress_set: bool) -> np.ndarray:
    """The training images (N, H, W, 3) linear after their responses and the 8-bit sRGB encoding."""
    from research import io, radiometry

    params = radiometry.Stress(exposure_stops=EXPOSURE_STOPS) if stress_set else radiometry.Stress.none()
    out = []
    for img, r in zip(linear, responses):
        e = np.clip(np.asarray(img, np.float64) * np.asarray(r.wb), 0.0, 1.0) ** r.gamma
        u8 = radiometry.apply_camera(e, r.camera, rng, params)
        out.append(io.srgb_to_linear(u8.astype(np.float64) / 255.0))
    return np.stack(out).astype(np.float32)


def clean_8bit(linear: np.ndarray) -> np.ndarray:
    from research import io, radiometry

    return np.stack([io.srgb_to_linear(radiometry.clean(x).astype(np.float64) / 255.0) for x in linear]
                    ).astype(np.float32)


def box_average(images: np.ndarray, factor: int) -> np.ndarray:
    n, h, w, c = images.shape
    h2, w2 = h // factor, w // factor
    x = images[:, :h2 * factor, :w2 * factor].reshape(n, h2, factor, w2, factor, c)
    return x.mean(axis=(2, 4), dtype=np.float64).astype(np.float32)


def write_smoke_llff(root: Path, split, depth_bounds: tuple[float, float]) -> Path:
    """A tiny LLFF folder (poses_bounds.npy, images_8/) of `split`'s renders, for smoke mode."""
    from research import io, radiometry

    folder = root / "images_8"
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, (cam, img) in enumerate(zip(split.cameras, split.rgba)):
        R, t = cam.c2w[:3, :3], cam.c2w[:3, 3]
        hwf = (cam.height * 8, cam.width * 8, cam.fx * 8)
        rows.append(np.concatenate([np.column_stack([R[:, 1], R[:, 0], -R[:, 2], t, hwf]).reshape(-1), depth_bounds]))
        io.write_png_u8(folder / f"image{i:03d}.png", radiometry.clean(img[..., :3]))
    np.save(root / "poses_bounds.npy", np.stack(rows))
    return root


def mitsuba_set(ctx: Context, size: dict):
    from research import datasets
    from research.splats import model as sm

    dcfg = datasets.DatasetConfig("objects", views=size["views"], res=size["res"], spp=size["spp"], seed=ctx.seed)
    path = datasets.ensure(dcfg, datasets.cache_dir(dcfg, ctx.data), show_progress=ctx.progress)
    ds = datasets.load(path)
    tr, te = ds.load_split("train"), ds.load_split("test")
    rng = np.random.default_rng([ctx.seed, 31])
    responses = draw_responses(len(tr.cameras), rng, stress_set=True)
    train_rgb = apply_responses(tr.rgba[..., :3], responses, rng, stress_set=True)
    rgba = np.concatenate([train_rgb * (tr.rgba[..., 3:] > 0), tr.rgba[..., 3:]], axis=-1)
    points, colors = sm.points_from_depth(tr.cameras, rgba, tr.depth, size["init_points"], ctx.seed)
    return {"name": "Mitsuba objects", "path": str(path), "train_cams": tr.cameras, "train_rgb": train_rgb,
            "test_cams": te.cameras, "test_rgb": clean_8bit(te.rgba[..., :3]), "points": points, "colors": colors,
            "responses": responses, "split": tr}


def fern_set(ctx: Context, size: dict, smoke_split=None):
    from research.datasets import formats, open_dataset
    from research.splats import model as sm

    root = ctx.args.llff or ctx.data / LLFF_NAME
    box = FERN_BOX
    if ctx.smoke and ctx.args.llff is None:
        root = write_smoke_llff(ctx.data / "splat_appearance-smoke-llff", smoke_split, (1.0, 8.0))
        box = 1
    if not (root / "poses_bounds.npy").is_file():
        raise ValueError(f"--llff: {root} is not an LLFF folder (no poses_bounds.npy); give the fern folder "
                         f"({LLFF_NAME} of the NeRF release) with --llff or put it under --data")
    ds = open_dataset(root, "llff", None)
    tr, te = ds.load_split(ds.protocol.train_split), ds.load_split(ds.protocol.test_split)
    train_lin = box_average(formats.protocol_target_linear(tr, ds.protocol), box)
    test_rgb = box_average(formats.protocol_target_linear(te, ds.protocol), box)
    train_cams = [c.scaled(1.0 / box) for c in tr.cameras]
    test_cams = [c.scaled(1.0 / box) for c in te.cameras]
    rng = np.random.default_rng([ctx.seed, 32])
    responses = draw_responses(len(train_cams), rng, stress_set=False)
    train_rgb = apply_responses(train_lin, responses, rng, stress_set=False)
    bounds = ds.near_far[[i for i, v in enumerate(ds.views) if v.split == ds.protocol.train_split]]
    rgba = np.concatenate([train_rgb, np.ones_like(train_rgb[..., :1])], axis=-1)
    points, colors = sm.points_in_frusta(train_cams, rgba, bounds, size["init_points"], ctx.seed)
    return {"name": f"LLFF {ds.scene}" + (" (smoke stand-in)" if ctx.smoke and ctx.args.llff is None else ""),
            "path": str(root), "train_cams": train_cams, "train_rgb": train_rgb, "test_cams": test_cams,
            "test_rgb": test_rgb, "points": points, "colors": colors, "responses": responses}


def gain_correlation(app, responses: list[Response]) -> float | None:
    """Correlation of log2(mean diagonal gain of each image's model) with its applied exposure + mean WB stops."""
    if app is None or len(responses) < 3:
        return None
    diag = app.grids[..., [0, 5, 10]].reshape(len(responses), -1).mean(axis=1)
    applied = [r.camera.exposure_stops + float(np.mean(np.log2(r.wb))) for r in responses]
    if np.std(applied) == 0 or np.std(diag) == 0:
        return None
    return float(np.corrcoef(np.log2(np.maximum(diag, 1e-6)), applied)[0, 1])


def fit_set(ctx: Context, data: dict, size: dict) -> dict:
    import time

    from research.splats import appearance as ap, model as sm, train as st

    init = sm.from_points(data["points"], data["colors"])
    extent = sm.scene_extent(data["train_cams"])
    out = {}
    for kind in MODELS:
        tcfg = st.TrainConfig(iterations=size["iterations"], seed=ctx.seed,
                              densify=st.DensifyConfig(max_gaussians=size["max_gaussians"]),
                              appearance=ap.AppearanceConfig(kind))
        t0 = time.perf_counter()
        res = st.train(init, data["train_cams"], data["train_rgb"], extent, tcfg, device=ctx.device, progress=False)
        train_s = time.perf_counter() - t0
        ev = st.evaluate(res.model, data["test_cams"], data["test_rgb"], res.sh_degree, device=ctx.device)
        corrected = [ap.corrected_psnr(r, t) for r, t in zip(ev.renders, data["test_rgb"])]
        out[kind] = {"psnr": ev.psnr, "ssim": ev.ssim, "psnr_corrected": float(np.mean(corrected)),
                     "per_view": [{**p, "psnr_corrected": c} for p, c in zip(ev.per_view, corrected)],
                     "splats": res.model.n, "train_seconds": train_s,
                     "gain_vs_exposure_corr": gain_correlation(res.appearance, data["responses"]),
                     "render": ev.renders[0]}
    return out


def figure(sets: list[dict], fits: list[dict], path: Path) -> None:
    from research.metrics import srgb_on_black

    rows = [[(data["train_rgb"][0], f"{data['name']}\na training view (as trained on)"),
             (data["test_rgb"][0], "held-out view"),
             *((fit[k]["render"], f"{k}: {fit[k]['per_view'][0]['psnr']:.2f} dB") for k in MODELS)]
            for data, fit in zip(sets, fits)]
    image_grid([[(srgb_on_black(img), title) for img, title in row] for row in rows], path, cell=(2.3, 2.1),
               fontsize=7, interpolation="nearest")


def run(ctx: Context) -> int:
    size = sizes(ctx.quick, ctx.smoke)
    size["iterations"] = ctx.int_option("--iterations", size["iterations"])
    mitsuba = mitsuba_set(ctx, size)
    fern = fern_set(ctx, size, smoke_split=mitsuba["split"])
    sets = [mitsuba, fern]
    fits = [fit_set(ctx, d, size) for d in ctx.tqdm(sets, desc="image sets")]

    headers = ["image set", "model", "test PSNR", "test SSIM", "corrected PSNR", "gain ~ exposure (r)", "splats",
               "train s"]
    rows, record = [], {}
    for data, fit in zip(sets, fits):
        cam = data["test_cams"][0]
        key = data["name"]
        record[key] = {"path": data["path"], "train_views": len(data["train_cams"]),
                       "test_views": len(data["test_cams"]), "size": [cam.width, cam.height],
                       "responses": [{"wb": list(r.wb), "gamma": r.gamma, "exposure_stops": r.camera.exposure_stops,
                                      "offset": r.camera.offset, "vignetting": r.camera.vignetting,
                                      "blur_sigma": r.camera.blur_sigma} for r in data["responses"]],
                       "models": {k: {m: v for m, v in fit[k].items() if m != "render"} for k in MODELS}}
        for k in MODELS:
            f = fit[k]
            corr = "-" if f["gain_vs_exposure_corr"] is None else f"{f['gain_vs_exposure_corr']:.3f}"
            rows.append([f"{key} {cam.width}x{cam.height} ({len(data['train_cams'])} train / "
                         f"{len(data['test_cams'])} test)", k, f["psnr"], f["ssim"], f["psnr_corrected"], corr,
                         f["splats"], f["train_seconds"]])
    figure(sets, fits, ctx.out / "figure.png")
    table = (f"Splats trained {size['iterations']} iterations on training views whose exposure and colour vary per "
             f"image (Mitsuba `objects`: white balance +-{WB_STOPS} stops per channel, gamma 2^+-{GAMMA_STOPS}, "
             f"the radiometric stress set with exposure +-{EXPOSURE_STOPS} stops; LLFF fern: exposure "
             f"+-{EXPOSURE_STOPS} stops and the white balance applied to its photos, which were shot at one "
             "setting), held-out views clean. Appearance: none; one 3x4 affine per image; gsplat's bilateral "
             "grid (16x16x8, TV weight 10, its learning rates). Held-out views rendered with the identity "
             "appearance; PSNR (dB) and SSIM on sRGB; corrected PSNR after the best per-image affine fit of the "
             "render to the held-out image (linear least squares). gain ~ exposure: correlation of each "
             "training image's learned log2 gain with the applied stops. Train time: wall, this machine.\n\n"
             + markdown_table(headers, rows, floatfmt=".4g")
             + "\n\n![a training view, a held-out view and each model's held-out render](figure.png)\n")
    metrics = {"sets": record, "models": list(MODELS),
               "settings": {"exposure_stops": EXPOSURE_STOPS, "wb_stops": WB_STOPS, "gamma_stops": GAMMA_STOPS,
                            "fern_box": FERN_BOX}}
    ctx.write_results(config={**size}, metrics=metrics, table_md=table)
    return 0


main = Experiment("splat_appearance", __doc__, run, add_options,
                  seed_help="seed of the dataset's cameras, the per-image responses and training",
                  sizes="Full: Mitsuba objects 64x64 (50 views, 32 spp) and fern 168x126, 1500 iterations, at most "
                        "12000 splats; quick: 48x48 (30 views), 300 iterations; smoke: 32x32 (10 views), 20 "
                        "iterations, a tiny LLFF folder written from the renders.",
                  data_help="cache root of the Mitsuba renders, and where <data>/nerf_llff_data/fern is looked for"
                  ).script(__name__)
