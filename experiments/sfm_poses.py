#!/usr/bin/env python3
"""SfM on drlab's own renders given as bare images: registered views, pose error, and what it costs splats.

Capture: the Mitsuba `objects` scene (research.datasets: its scene, renderer and camera path) seen
from a closed camera path around it (research.cameras.smooth_path over 360 degrees, elevation 40 +-
15 degrees, distance 3.2 x (1 +- 0.2) from the scene's target, closer than the dataset generator's
4.2 so that the objects fill more of the frame): the default is 64 views at 256x256, 32 spp (quick: 48
views, 8 spp; smoke: 48 views, 4 spp; both at 256x256). What registers (trials on this path, 8 spp,
chosen before any default run): 16 views at 128x128, none; 24 at 160x160, 2; 32 at 192x192, 16 of 32
with a median rotation error of 22 degrees; 48 at 256x256 (4 spp), all, 1.8 degrees. A flat ring at the
generator's distance 4.2 (elevation 25 +- 3 degrees) registered all 48 views at 256x256 but with 2.4
degrees and the focal length 9% short: orbiting one axis while fixating one point is a critical motion
for self-calibration; the elevation and distance wobble of this path breaks it. The PNGs are written to
<data>/sfm_poses-objects[-quick|-smoke]/images/ and only that folder is handed to research.poses.sfm
(`drlab sfm`'s code: pycolmap SIFT, exhaustive matching, incremental mapping, one shared camera
with the SIMPLE_PINHOLE model: square pixels and no distortion, as the renderer's, with the focal
length estimated, not given); the ground-truth cameras are kept aside.

Reported:
* images registered / total;
* the SfM camera poses against the Mitsuba ground truth after a Sim(3) Umeyama alignment of the
  camera centres (research.poses.align): rotation error (degrees) and translation error, in scene units
  and in % of the scene radius (half the diagonal of the scene's box, 2.87 for `objects`); the
  estimated focal length against the true one;
* splats (research.splats, fit_splats's trainer) trained on the SfM poses against splats trained on
  the ground-truth poses, on the same views. Protocol: the registered images sorted by name, every
  8th (index % 8 == 0) a test view, the rest train (llffhold 8, as research.datasets.colmap reads
  the SfM folder); both fits use the same train images, the same initial points (the SfM points and
  their colours: in the SfM frame for the SfM fit, mapped by the Sim(3) into the ground-truth frame
  for the other), the same schedule and seed, at half the capture's resolution (box-averaged;
  intrinsics scaled). Each is scored on the test images with its own test cameras: the SfM fit with
  the SfM poses of the test images (registered with the rest, as the Mip-NeRF 360 / 3DGS protocol
  does), the other with the ground-truth poses. PSNR and SSIM as fit_splats (research.metrics, sRGB
  on black). The ground-truth fit's initial points carry the alignment's residual (they are placed by
  the Sim(3) fitted to the camera centres), which can favour the SfM fit slightly: in the runs so far
  (smoke, quick, default) the SfM fit scored 0.7, 0.45 and 0.08 dB above it.

Writes table.md, metrics.json, trajectories.png (ground truth vs aligned SfM camera centres and
viewing directions) and renders.png (a test view: target, both fits, their difference).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from research.experiment import Context, Experiment
from research.results import finish_figure, image_panel, markdown_table

SCENE = "objects"
DISTANCE, ELEVATION_DEG, ELEVATION_WOBBLE_DEG, RADIUS_WOBBLE = 3.2, 40.0, 15.0, 0.2


@dataclass(frozen=True)
class Setup:
    views: int
    res: int
    spp: int
    fit_factor: int  # splats train at res / fit_factor
    iterations: int
    max_gaussians: int


def setup(quick: bool, smoke: bool) -> Setup:
    if smoke:
        return Setup(views=48, res=256, spp=4, fit_factor=8, iterations=30, max_gaussians=2000)
    if quick:
        return Setup(views=48, res=256, spp=8, fit_factor=4, iterations=300, max_gaussians=10_000)
    return Setup(views=64, res=256, spp=32, fit_factor=2, iterations=600, max_gaussians=20_000)


def capture_cameras(cfg: Setup):
    """The closed camera path of the capture (module docstring), OpenCV cameras at cfg.res."""
    from research.cameras import Camera, smooth_path
    from research.datasets import get_scene

    spec = get_scene(SCENE)
    poses = smooth_path(cfg.views + 1, DISTANCE, spec.target, spec.up, sweep_deg=360.0,
                        elevation_deg=ELEVATION_DEG, elevation_wobble_deg=ELEVATION_WOBBLE_DEG,
                        radius_wobble=RADIUS_WOBBLE)[:-1]  # the last pose repeats the first
    return [Camera.from_fov(spec.fov_x_deg, cfg.res, cfg.res, p) for p in poses]


def render_capture(cfg: Setup, root: Path, seed: int, ctx: Context) -> list:
    """Render the capture into root/images (reused when root/capture.json records the same one)."""
    from research import atomic, io
    from research.datasets import get_scene
    from research.datasets.render import SceneRenderer

    cams = capture_cameras(cfg)
    record = {"scene": SCENE, "seed": seed, **asdict(cfg), "cameras": [c.to_dict() for c in cams]}
    keys = ("scene", "seed", "views", "res", "spp")
    meta = root / "capture.json"
    names = [f"v_{k:03d}.png" for k in range(len(cams))]
    if meta.is_file() and all((root / "images" / n).is_file() for n in names):
        old = json.loads(meta.read_text())
        if all(old.get(k) == record[k] for k in keys):
            return cams
    (root / "images").mkdir(parents=True, exist_ok=True)
    renderer = SceneRenderer(get_scene(SCENE), spp=cfg.spp)
    for k, cam in enumerate(ctx.tqdm(cams, desc="render capture", unit="view")):
        view_seed = int(np.random.default_rng([seed, k]).integers(0, 2**31 - 1))
        io.write_png(root / "images" / names[k], renderer.render_rgba(cam, view_seed))
    atomic.write_json(meta, {k: record[k] for k in (*keys, "cameras")})
    return cams


def scene_radius() -> float:
    from research.datasets import get_scene

    return float(np.linalg.norm(get_scene(SCENE).bbox[1] - get_scene(SCENE).bbox[0]) / 2.0)


def downscaled(cameras: list, images: np.ndarray, factor: int):
    """Cameras and (N, H, W, C) images at 1/factor (box average; K scaled, pixel centres kept)."""
    from research.cameras import Camera

    if factor == 1:
        return cameras, images
    n, h, w, c = images.shape
    small = images.reshape(n, h // factor, factor, w // factor, factor, c).mean(axis=(2, 4), dtype=np.float64)
    S = np.diag([1.0 / factor, 1.0 / factor, 1.0])
    return [Camera(S @ cam.K, cam.c2w, cam.width // factor, cam.height // factor) for cam in cameras], \
        small.astype(np.float32)


def fit(ctx: Context, cfg: Setup, points, colors, train_cams, train_rgb, test_cams, test_rgb, label: str):
    from research.splats import model as sm, train as st

    model = sm.from_points(points, colors)
    tcfg = st.TrainConfig(iterations=cfg.iterations, seed=ctx.seed, background=(0.0, 0.0, 0.0),
                          densify=st.DensifyConfig(max_gaussians=cfg.max_gaussians))
    print(f"sfm_poses: splats on {label} poses", flush=True)
    result = st.train(model, train_cams, train_rgb, sm.scene_extent(train_cams), tcfg, device=ctx.device,
                      progress=ctx.progress)
    ev = st.evaluate(result.model, test_cams, test_rgb, result.sh_degree, device=ctx.device)
    return result, ev


def trajectories_figure(gt: np.ndarray, aligned: np.ndarray, path: Path, rot_err: np.ndarray) -> None:
    """Top view and side view of the camera centres, with viewing directions; (n, 4, 4) c2w each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.4))
    for ax, (i, j), title in ((axes[0], (0, 1), "top view (x, y)"), (axes[1], (0, 2), "side view (x, z)")):
        for poses, color, label in ((gt, "k", "ground truth (Mitsuba)"), (aligned, "C1", "SfM, Sim(3)-aligned")):
            c = poses[:, :3, 3]
            loop = np.vstack([c, c[:1]])
            ax.plot(loop[:, i], loop[:, j], "-", color=color, lw=0.8, alpha=0.6)
            ax.scatter(c[:, i], c[:, j], s=10, color=color, label=label)
            d = poses[:, :3, 2] * 0.5
            ax.quiver(c[:, i], c[:, j], d[:, i], d[:, j], color=color, angles="xy", scale_units="xy", scale=1,
                      width=0.003, alpha=0.7)
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="upper right")
    fig.suptitle(f"camera centres and viewing directions; rotation error median {np.median(rot_err):.2f} deg",
                 fontsize=9)
    finish_figure(fig, path)


def renders_figure(target, sfm_render, gt_render, sfm_psnr, gt_psnr, name, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research import io

    to_srgb = lambda x: io.linear_to_srgb(np.clip(x, 0, 1))  # noqa: E731
    panels = [(to_srgb(target), f"target {name}"), (to_srgb(gt_render), f"splats, GT poses: {gt_psnr:.2f} dB"),
              (to_srgb(sfm_render), f"splats, SfM poses: {sfm_psnr:.2f} dB"),
              (np.abs(to_srgb(sfm_render) - to_srgb(gt_render)).mean(axis=2), "|SfM - GT fit| (sRGB)")]
    fig, axes = plt.subplots(1, 4, figsize=(12, 3.3))
    for ax, (img, title) in zip(axes, panels):
        image_panel(fig, ax, img, title, colorbar=img.ndim == 2, cmap="magma" if img.ndim == 2 else None, vmin=0,
                    vmax=0.25 if img.ndim == 2 else 1)
    finish_figure(fig, path)


def add_options(p) -> None:
    p.add_argument("--views", type=int, default=None, help="views on the camera path (default: 64; quick, smoke 48)")
    p.add_argument("--res", type=int, default=None, help="capture width and height in pixels (default 256)")
    p.add_argument("--iterations", type=int, default=None,
                   help="splat iterations per fit (default 600; quick 300; smoke 30)")
    p.add_argument("--matcher", choices=["exhaustive", "sequential"], default="exhaustive",
                   help="SfM matching (default exhaustive; sequential matches each view with the next 10)")
    p.add_argument("--threads", type=int, default=1,
                   help="SfM threads (default 1: reproducible; -1, every core, is faster but COLMAP's matching and "
                        "mapping then vary from run to run)")


def run(ctx: Context) -> int:
    from research.poses import sfm
    from research.poses.align import pose_errors
    from research.datasets import formats, load_colmap
    from research.splats import model as sm

    args = ctx.args
    cfg = setup(ctx.quick, ctx.smoke)
    cfg = Setup(**{**asdict(cfg), "views": ctx.int_option("--views", cfg.views, low=8),
                   "res": ctx.int_option("--res", cfg.res),
                   "iterations": ctx.int_option("--iterations", cfg.iterations)})
    if cfg.res % cfg.fit_factor or cfg.res < 16 * cfg.fit_factor:  # splats fit at res / fit_factor >= 16 (SSIM)
        raise ValueError(f"--res: expected a multiple of {cfg.fit_factor}, at least {16 * cfg.fit_factor}, got "
                         f"{cfg.res}")
    # built (and so checked) before any render or folder
    opts = sfm.SfmOptions(matcher=args.matcher, shared_camera=True, camera_model="SIMPLE_PINHOLE",
                          seed=ctx.seed % 2**31, threads=args.threads,
                          min_registered=max(8, cfg.views // 2))
    opts.validate()
    suffix = "" if ctx.mode == "full" else "-" + ctx.mode
    root = (ctx.data / f"sfm_poses-{SCENE}{suffix}").absolute()

    gt_all = render_capture(cfg, root, ctx.seed, ctx)
    result = sfm.run_sfm(root / "images", root / "sfm", opts, force=True, progress=ctx.progress)
    ds = load_colmap(root / "sfm", factor=1)
    index = {f"v_{k:03d}.png": k for k in range(cfg.views)}
    names = [v.name for v in ds.views]
    gt = [gt_all[index[n]] for n in names]
    est = [v.camera for v in ds.views]
    pe = pose_errors(np.array([c.c2w for c in est]), np.array([c.c2w for c in gt]))
    radius = scene_radius()
    f_est, f_true = float(np.mean([c.fx for c in est])), gt_all[0].fx

    # splats: the same views, points and schedule; SfM poses vs ground-truth poses
    train_split, test_split = ds.load_split("train"), ds.load_split("test")
    train_rgb = formats.protocol_target_linear(train_split, ds.protocol)
    test_rgb = formats.protocol_target_linear(test_split, ds.protocol)
    by_name = dict(zip(names, gt))
    gt_train = [by_name[v.name] for v in ds.split_views("train")]
    gt_test = [by_name[v.name] for v in ds.split_views("test")]
    f = cfg.fit_factor
    sfm_train_c, train_small = downscaled(train_split.cameras, train_rgb, f)
    sfm_test_c, test_small = downscaled(test_split.cameras, test_rgb, f)
    gt_train_c, _ = downscaled(gt_train, train_rgb, f)
    gt_test_c, _ = downscaled(gt_test, test_rgb, f)
    points, colors = sm.points_from_sfm(ds.points, ds.point_colors, cfg.max_gaussians, ctx.seed)
    fit_sfm, ev_sfm = fit(ctx, cfg, points, colors, sfm_train_c, train_small, sfm_test_c, test_small, "SfM")
    fit_gt, ev_gt = fit(ctx, cfg, pe.sim3.apply(points), colors, gt_train_c, train_small, gt_test_c, test_small,
                        "ground-truth")

    s = pe.summary()
    test_names = [v.name for v in ds.split_views("test")]
    metrics = {
        "scene": SCENE,
        "capture": {**asdict(cfg), "path": {"distance": DISTANCE, "elevation_deg": ELEVATION_DEG,
                                            "elevation_wobble_deg": ELEVATION_WOBBLE_DEG,
                                            "radius_wobble": RADIUS_WOBBLE}},
        "registered": len(names), "total": cfg.views, "unregistered": result.unregistered,
        "sfm_points": result.points, "sfm_reprojection_error_px": result.mean_reprojection_error,
        "sfm_seconds": result.seconds, "sfm_options": asdict(opts),
        "pose_errors": s, "scene_radius": radius,
        "translation_median_pct": 100 * s["translation_median"] / radius,
        "translation_max_pct": 100 * s["translation_max"] / radius,
        "focal_estimated": f_est, "focal_true": f_true, "focal_error_pct": 100 * (f_est / f_true - 1.0),
        "per_view": [{"name": n, "rotation_deg": float(r), "translation": float(t)}
                     for n, r, t in zip(names, pe.rotation_deg, pe.translation)],
        "splats": {
            "train_views": len(gt_train), "test_views": test_names, "resolution": f"{cfg.res // f}x{cfg.res // f}",
            "iterations": cfg.iterations, "init_points": len(points),
            "sfm_poses": {"psnr": ev_sfm.psnr, "ssim": ev_sfm.ssim, "splats": fit_sfm.model.n,
                          "train_seconds": fit_sfm.seconds, "per_view": ev_sfm.per_view},
            "gt_poses": {"psnr": ev_gt.psnr, "ssim": ev_gt.ssim, "splats": fit_gt.model.n,
                         "train_seconds": fit_gt.seconds, "per_view": ev_gt.per_view},
            "psnr_gap_db": ev_gt.psnr - ev_sfm.psnr},
        "data": str(root), "eval_protocol": "llffhold 8 over the registered images by name; research.metrics "
                                            "(sRGB on black, clipped; SSIM 11x11 Gaussian, sigma 1.5)",
    }
    rows = [
        ["images registered", f"{len(names)} / {cfg.views}"],
        ["SfM points; mean reprojection error", f"{result.points}; {result.mean_reprojection_error:.3f} px"],
        ["rotation error (deg): median / mean / max",
         f"{s['rotation_deg_median']:.3f} / {s['rotation_deg_mean']:.3f} / {s['rotation_deg_max']:.3f}"],
        ["translation error (scene units): median / max",
         f"{s['translation_median']:.4f} / {s['translation_max']:.4f}"],
        ["translation error (% of scene radius {:.2f}): median / max".format(radius),
         f"{metrics['translation_median_pct']:.2f}% / {metrics['translation_max_pct']:.2f}%"],
        ["focal length (px): estimated / true", f"{f_est:.2f} / {f_true:.2f} ({metrics['focal_error_pct']:+.2f}%)"],
        ["Sim(3) scale (SfM -> scene units)", f"{s['sim3_scale']:.4f}"],
        ["SfM time (features, matching, mapping, undistortion)",
         " + ".join(f"{result.seconds[k]:.1f}" for k in ("features", "matching", "mapping", "undistortion")) + " s"],
    ]
    fits = [["ground-truth poses", f"{ev_gt.psnr:.2f}", f"{ev_gt.ssim:.4f}", fit_gt.model.n, f"{fit_gt.seconds:.0f} s"],
            ["SfM poses", f"{ev_sfm.psnr:.2f}", f"{ev_sfm.ssim:.4f}", fit_sfm.model.n, f"{fit_sfm.seconds:.0f} s"]]
    table = (f"`drlab sfm`'s code (pycolmap SIFT, {args.matcher} matching, incremental "
             f"mapping; one shared SIMPLE_PINHOLE camera, focal estimated) on {cfg.views} bare PNGs of Mitsuba "
             f"`{SCENE}` ({cfg.res}x{cfg.res}, {cfg.spp} spp) on a closed camera path; errors against the Mitsuba "
             "cameras after a Sim(3) Umeyama alignment of the camera centres.\n\n"
             + markdown_table(["quantity", "value"], rows)
             + f"\nSplats ({cfg.iterations} iterations at {cfg.res // f}x{cfg.res // f}, the same {len(gt_train)} "
               f"train views and {len(points)} initial SfM points) scored on the same {len(test_names)} test views "
               "(every 8th registered image by name), each fit with its own poses of those views:\n\n"
             + markdown_table(["poses", "test PSNR (dB)", "test SSIM", "splats", "train time"], fits)
             + f"\nPSNR gap (GT - SfM poses): {ev_gt.psnr - ev_sfm.psnr:+.2f} dB.\n\n"
               "![trajectories](trajectories.png)\n\n![renders](renders.png)\n")
    aligned = np.array([pe.sim3.apply_c2w(c.c2w) for c in est])
    trajectories_figure(np.array([c.c2w for c in gt]), aligned, ctx.out / "trajectories.png", pe.rotation_deg)
    renders_figure(test_small[0], ev_sfm.renders[0], ev_gt.renders[0], ev_sfm.per_view[0]["psnr"],
                   ev_gt.per_view[0]["psnr"], test_names[0], ctx.out / "renders.png")
    ctx.write_results(config={**asdict(cfg), "matcher": args.matcher}, metrics=metrics,
                      table_md=table)
    return 0


main = Experiment("sfm_poses", __doc__, run, add_options,
                  data_help="cache root of the rendered capture and its SfM model: <data>/sfm_poses-objects[-quick|"
                            "-smoke]/{images,capture.json,sfm}",
                  seed_help="seed of the render noise, the SfM mapper and the splat fits",
                  sizes="Default: 64 views at 256x256, 32 spp, splats 600 iterations at 128x128 (about 5 min on 2 "
                        "cores). Quick: 48 views at 256x256, 8 spp, 300 iterations at 64x64. Smoke: 48 views at "
                        "256x256, 4 spp, 30 iterations at 32x32 (real SfM; about 30 s).").script(__name__)
