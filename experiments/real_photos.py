#!/usr/bin/env python3
"""Real photographs with calibrated cameras: `drlab sfm` against the calibration, and splats on both.

Data: a Middlebury multi-view folder (research.datasets.middlebury_mview: `<name>_par.txt`, x ~ K (R X
+ t), and its PNGs), given with `--data`: the folder itself, or a folder holding
middlebury_mview/templeRing or templeRing (the default --data, data/, is searched the same way;
`drlab reproduce` skips this experiment in one line when data/middlebury_mview/templeRing is absent).
The photographs are never copied: SfM reads them where they are, and its model goes to
build/real_photos/<scene>[-quick]-sfm (smoke: <data>/<scene>-smoke-sfm; reused when its sfm.json records
the same images and options). Smoke mode without such a folder renders a tiny synthetic capture into
<data>/real_photos-smoke (a voxel-textured sphere on black, written as a *_par.txt and PNGs, so the
reader is exercised too).

1. SfM against the calibration. research.poses.sfm (`drlab sfm`'s code: pycolmap SIFT, exhaustive
   matching, incremental mapping) on every image of the folder, with one shared SIMPLE_PINHOLE
   camera (square pixels, principal point at the image centre, no distortion; the focal length
   estimated, not given): the calibration is a distortion-free pinhole too, and a pinhole model
   makes the SfM images the original pixels (undistortion copies them unchanged), so both fits
   below see the same images. 1 thread (COLMAP's threaded matching and mapping vary from run to
   run), seed --seed. Reported: images registered / total; rotation error (degrees, median and
   max) and camera-centre error after a Sim(3) Umeyama alignment of the registered SfM centres to
   the calibrated ones (research.poses.align), as % of the scene radius, here the median distance of the
   calibrated camera centres from their centroid; the SfM focal length against the calibrated
   (fx + fy) / 2 (median over the images), in %. SfM holds the principal point at the image centre;
   where the calibrated one lies d pixels off it, the SfM cameras turn by about atan(d / f) to make up
   for it, and the rotation error contains that. Beside them, the SfM feature tracks (every SfM point's
   observations) re-triangulated by linear least squares (DLT) with each set of cameras held fixed,
   and their reprojection error: with the SfM cameras, and with the calibrated ones at the reader's
   pixel-centre offset of 0.5 and at 0 and 1 instead (a check of that convention: the offset the
   calibration was made with should reproject best). The tracks are SfM's own inliers, chosen under
   its cameras, which favours the SfM cameras.

2. Splats (research.splats, fit_splats's trainer: 3DGS loss, learning rates and densification on
   fit_splats' default schedule, 3000 iterations, at most 30 000 splats) fitted twice on the same
   train images from the same initial points, once with the calibrated cameras, once with the SfM
   cameras, each scored on the held-out views with its own cameras of those views. Protocol
   (middlebury_mview's "middlebury-mview-hold8"): the cameras sorted by name, every 8th (index % 8
   == 0) a test view, the rest train (templeRing: 6 test, 41 train). SfM registers all the images,
   test views included, and the SfM fit is scored with the SfM poses of the test views (as the
   Mip-NeRF 360 / 3DGS protocol scores COLMAP poses); only views SfM registered are used, by both
   fits. Initial points: the SfM points and colours (3DGS's start), in the SfM frame for the SfM fit
   and mapped by the Sim(3) into the calibration's frame for the other (so the calibrated fit's start
   carries the alignment's residual). Resolution: the photographs box-averaged to 1/2 (320x240 for
   templeRing; K scaled), because 640x480 runs at about 1 iteration/s on the 2 loaded cores where
   320x240 runs at about 4 (quick: 1/4 and 600 iterations; smoke: the synthetic capture at full size,
   30 iterations). Nothing was tuned on templeRing.

   Background: the photographs are opaque; the background is the real black cloth of the capture rig
   (dark, not exactly 0, with shadows). It is trained and scored like every other pixel, and the
   splats render on black. PSNR and SSIM (research.metrics) on sRGB in [0, 1] over the whole image
   are the reported figures; since the dark background is easy to fit and fills most of the frame,
   the PSNR inside the object's box is given beside them: the pixels whose rays cross the tight
   bounding box that the dataset's README.txt states (templeRing: 43% of the pixels), projected with
   the calibrated test cameras, the same pixels for both fits.

Writes table.md, metrics.json and real_photos.png (camera centres, calibrated vs aligned SfM; a
test view: target, both fits).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from research import registry
from research.experiment import Context, Experiment
from research.results import finish_figure, image_panel, markdown_table

DATA_NAMES = ("middlebury_mview/templeRing", "templeRing")  # looked for under --data (after --data itself)


@dataclass(frozen=True)
class Setup:
    factor: int  # splats train and are scored at 1/factor of the photographs
    iterations: int
    max_gaussians: int


def setup(quick: bool, smoke: bool) -> Setup:
    if smoke:
        return Setup(factor=1, iterations=30, max_gaussians=2000)
    if quick:
        return Setup(factor=4, iterations=600, max_gaussians=10_000)
    return Setup(factor=2, iterations=3000, max_gaussians=30_000)  # fit_splats' default schedule and cap


# --------------------------------------------------------------------------- the smoke capture


def write_synthetic_capture(root: Path, seed: int, views: int = 16, width: int = 240, height: int = 180) -> list:
    """A tiny Middlebury-format capture: a unit sphere coloured by random voxel colours at four scales
    (voxel sides 1/2 to 1/16, summed: a texture SIFT can match at every scale), on black, seen from a ring (elevation 25 +- 12 degrees, distance 4 +- 10%),
    ray cast in NumPy; `<root>/synth_par.txt` and `<root>/synth%04d.png`. Returns the cameras."""
    from research import atomic, io
    from research.cameras import Camera, intrinsics_from_fov, look_at
    from research.datasets.middlebury_mview import par_line

    rng = np.random.default_rng(seed)
    scales = (2, 4, 8, 16)  # voxels per unit length
    palettes = [rng.uniform(-1.0, 1.0, size=(2 * k + 2,) * 3 + (3,)) for k in scales]
    cams, lines = [], []
    root.mkdir(parents=True, exist_ok=True)
    for k in range(views):
        a = 2 * np.pi * k / views
        el = np.radians(25.0 + 12.0 * np.sin(3 * a))
        r = 4.0 * (1.0 + 0.1 * np.cos(2 * a))
        eye = r * np.array([np.cos(el) * np.cos(a), np.cos(el) * np.sin(a), np.sin(el)])
        cam = Camera(intrinsics_from_fov(40.0, width, height), look_at(eye, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
                     width, height)
        o, d = cam.rays()
        b = np.einsum("hwc,hwc->hw", o, d)
        disc = b * b - (np.einsum("hwc,hwc->hw", o, o) - 1.0)
        hit = disc > 0
        t = -b - np.sqrt(np.where(hit, disc, 0.0))
        p = o + t[..., None] * d
        rgb = np.full(p.shape, 0.55)
        for n, pal in zip(scales, palettes):
            cell = np.clip(np.floor((p + 1.0) * n).astype(int), 0, 2 * n + 1)
            rgb += 0.18 * pal[cell[..., 0], cell[..., 1], cell[..., 2]]
        shade = np.clip(np.einsum("hwc,c->hw", p, np.array([0.3, 0.5, 0.81])), 0, 1) * 0.5 + 0.5
        rgb = rgb * shade[..., None]
        img = np.where(hit[..., None], rgb, 0.02)
        name = f"synth{k + 1:04d}.png"
        io.write_png(root / name, io.srgb_to_linear(np.clip(img, 0, 1)).astype(np.float32))
        cams.append(cam)
        lines.append(par_line(name, cam))
    atomic.write_text(root / "synth_par.txt", f"{views}\n" + "\n".join(lines) + "\n")
    return cams


def find_data(ctx: Context) -> Path:
    """The Middlebury folder: --data itself, or DATA_NAMES under it; smoke mode writes its own capture."""
    from research.datasets import detect_format

    for cand in (ctx.data, *(ctx.data / n for n in DATA_NAMES)):
        if detect_format(cand) == "middlebury_mview":
            return cand
    if ctx.smoke:
        root = ctx.data / "real_photos-smoke"
        if detect_format(root) != "middlebury_mview":
            write_synthetic_capture(root, seed=3)
        return root
    raise ValueError(f"--data: {ctx.data} is not a Middlebury multi-view folder (no *_par.txt) and holds none of "
                     f"{', '.join(DATA_NAMES)}; give the folder of templeR_par.txt and its images")


# --------------------------------------------------------------------------- SfM


def cached_sfm(images: Path, out: Path, opts, ctx: Context):
    """research.poses.sfm on `images` into `out`, reused when out/sfm.json records the same images and options."""
    from research.poses import sfm

    doc = out / sfm.SUMMARY
    if doc.is_file():
        old = json.loads(doc.read_text())
        names = [p.name for p in sfm.list_images(images, False)[0]]
        if old.get("images_dir") == str(images.absolute()) and old.get("options") == asdict(opts) and \
                sorted(old.get("registered", []) + old.get("unregistered", [])) == names:
            print(f"real_photos: reusing the SfM model in {out}", flush=True)
            return old, True
    out.parent.mkdir(parents=True, exist_ok=True)
    sfm.run_sfm(images, out, opts, force=True, progress=ctx.progress)
    return json.loads(doc.read_text()), False


def feature_tracks(model_dir: Path) -> list:
    """Every SfM point's observations [(image name, (x, y) in pixels, centres at +0.5)], from the model."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model_dir))
    names = {i: im.name for i, im in rec.images.items()}
    return [[(names[e.image_id], np.asarray(rec.images[e.image_id].points2D[e.point2D_idx].xy, dtype=np.float64))
             for e in p.track.elements] for p in rec.points3D.values()]


def track_reprojection(tracks: list, cameras: dict) -> dict:
    """Reprojection error (px) of the feature tracks under fixed `cameras`: each point triangulated by the
    linear (DLT) least-squares solution from all its observations, then projected back into each."""
    P = {n: c.K @ c.w2c[:3] for n, c in cameras.items()}
    errs = []
    for obs in tracks:
        A = np.concatenate([[xy[0] * P[n][2] - P[n][0], xy[1] * P[n][2] - P[n][1]] for n, xy in obs])
        X = np.linalg.svd(A)[2][-1]
        for n, xy in obs:
            x = P[n] @ X
            errs.append(float(np.hypot(x[0] / x[2] - xy[0], x[1] / x[2] - xy[1])))
    e = np.array(errs)
    return {"mean": float(e.mean()), "median": float(np.median(e)), "rms": float(np.sqrt((e**2).mean())),
            "observations": len(e)}


def small(cameras: list, factor: int) -> list:
    from research.cameras import Camera

    S = np.diag([1.0 / factor, 1.0 / factor, 1.0])
    return [Camera(S @ c.K, c.c2w, c.width // factor, c.height // factor) for c in cameras]


# --------------------------------------------------------------------------- figure


def figure(gt_c2w, sfm_c2w, target, renders, labels, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research import io

    c = gt_c2w[:, :3, 3]
    mu = c.mean(axis=0)
    _, _, Vt = np.linalg.svd(c - mu)
    basis = Vt[:2].T  # the plane of the ring

    fig, axes = plt.subplots(1, 4, figsize=(15, 3.6))
    ax = axes[0]
    for poses, color, label in ((gt_c2w, "k", "calibration"), (sfm_c2w, "C1", "SfM, Sim(3)-aligned")):
        p = (poses[:, :3, 3] - mu) @ basis
        ax.scatter(p[:, 0], p[:, 1], s=12, color=color, label=label)
        d = poses[:, :3, 2] @ basis
        scale = 0.15 * float(np.abs(p).max() or 1.0)
        ax.quiver(p[:, 0], p[:, 1], d[:, 0] * scale, d[:, 1] * scale, color=color, angles="xy", scale_units="xy",
                  scale=1, width=0.004, alpha=0.6)
    ax.set_aspect("equal")
    ax.set_title("camera centres (plane of the ring)", fontsize=9)
    ax.legend(fontsize=7)
    panels = [(target, "test view (photograph)")] + list(zip(renders, labels))
    for ax, (img, title) in zip(axes[1:], panels):
        image_panel(fig, ax, io.linear_to_srgb(np.clip(img, 0, 1)), title)
    finish_figure(fig, path)


# --------------------------------------------------------------------------- run


def add_options(p) -> None:
    p.add_argument("--iterations", type=int, default=None,
                   help="splat iterations per fit (default 3000, fit_splats' default; quick 600; smoke 30)")
    p.add_argument("--resolution", type=int, default=None,
                   help="fit and score at 1/N of the photographs, box-averaged (default 2; quick 4; smoke 1)")
    p.add_argument("--threads", type=int, default=1,
                   help="SfM threads (default 1: reproducible; -1, every core, is faster but varies run to run)")


def fit(ctx: Context, cfg: Setup, points, colors, train_cams, train_rgb, test_cams, test_rgb, label: str):
    from research.splats import model as sm, train as st

    tcfg = st.TrainConfig(iterations=cfg.iterations, seed=ctx.seed, background=(0.0, 0.0, 0.0),
                          densify=st.DensifyConfig(max_gaussians=cfg.max_gaussians))
    print(f"real_photos: splats with the {label} cameras", flush=True)
    result = st.train(sm.from_points(points, colors), train_cams, train_rgb, sm.scene_extent(train_cams), tcfg,
                      device=ctx.device, progress=ctx.progress)
    ev = st.evaluate(result.model, test_cams, test_rgb, result.sh_degree, device=ctx.device)
    return result, ev


def run(ctx: Context) -> int:
    from research import metrics as rm
    from research.poses import sfm
    from research.poses.align import pose_errors
    from research.datasets import formats, load_colmap
    from research.datasets.middlebury_mview import box_mask, load_middlebury_mview, read_object_box, scene_radius
    from research.splats import model as sm

    args = ctx.args
    cfg = setup(ctx.quick, ctx.smoke)
    cfg = Setup(**{**asdict(cfg), "iterations": ctx.int_option("--iterations", cfg.iterations),
                   "factor": ctx.int_option("--resolution", cfg.factor)})
    opts = sfm.SfmOptions(shared_camera=True, camera_model="SIMPLE_PINHOLE", threads=args.threads,
                          seed=ctx.seed % 2**31)
    opts.validate()
    root = find_data(ctx).absolute()
    ds = load_middlebury_mview(root, factor=1)  # checks the calibration before any work
    scene = ds.scene
    if min(ds.views[0].camera.width, ds.views[0].camera.height) // cfg.factor < rm.SSIM_WINDOW:
        raise ValueError(f"--resolution: {cfg.factor} leaves images smaller than the {rm.SSIM_WINDOW}-pixel SSIM window")
    calib = {v.name: v.camera for v in ds.views}
    suffix = "" if ctx.mode == "full" else "-" + ctx.mode
    # the SfM model never goes into the data folder; smoke runs keep theirs beside their capture
    sfm_out = (ctx.data if ctx.smoke else registry.base_dir() / "build" / "real_photos") / f"{scene}{suffix}-sfm"

    summary, reused = cached_sfm(root, sfm_out, opts, ctx)
    sds = load_colmap(sfm_out, factor=1)
    est = {v.name: v.camera for v in sds.views}
    names = sorted(n for n in est if n in calib)
    gt_c2w = np.array([calib[n].c2w for n in names])
    est_c2w = np.array([est[n].c2w for n in names])
    pe = pose_errors(est_c2w, gt_c2w)
    radius = scene_radius(list(calib.values()))
    s = pe.summary()
    f_calib = float(np.median([(c.fx + c.fy) / 2 for c in calib.values()]))
    f_sfm = float(summary["cameras"][0]["params"][0])
    focal_err = 100.0 * (f_sfm / f_calib - 1.0)
    # the SfM feature tracks reprojected under each set of cameras (the calibration with the reader's
    # +0.5 pixel-centre offset, and with 0 or 1 instead, which tests that convention)
    from research.cameras import Camera
    from research.datasets.middlebury_mview import PIXEL_CENTRE_OFFSET

    tracks = feature_tracks(sfm_out / "sparse" / "0")
    shifted = lambda off: {n: Camera(c.K + np.array([[0, 0, off - PIXEL_CENTRE_OFFSET], [0, 0, off - PIXEL_CENTRE_OFFSET],  # noqa: E731
                                                     [0, 0, 0]]), c.c2w, c.width, c.height) for n, c in calib.items()}
    reproj = {"sfm": track_reprojection(tracks, est),
              **{f"calibrated_offset_{off:g}": track_reprojection(tracks, shifted(off)) for off in (0.0, 0.5, 1.0)}}

    # splats: the same train / test images (the calibrated split, views SfM registered), two sets of cameras
    train_views = [v for v in ds.split_views("train") if v.name in est]
    test_views = [v for v in ds.split_views("test") if v.name in est]
    if not train_views or not test_views:
        raise ValueError(f"--data: SfM registered {len(train_views)} train and {len(test_views)} test views of {root}; "
                         "the fits need both")
    sub = load_middlebury_mview(root, factor=cfg.factor)
    by = {v.name: v for v in sub.views}
    train_split = sub.split_loader([by[v.name] for v in train_views])
    test_split = sub.split_loader([by[v.name] for v in test_views])
    train_rgb = formats.protocol_target_linear(train_split, sub.protocol)
    test_rgb = formats.protocol_target_linear(test_split, sub.protocol)
    cal_train, cal_test = train_split.cameras, test_split.cameras
    sfm_train = small([est[v.name] for v in train_views], cfg.factor)
    sfm_test = small([est[v.name] for v in test_views], cfg.factor)
    points, colors = sm.points_from_sfm(sds.points, sds.point_colors, cfg.max_gaussians, ctx.seed)
    fit_cal, ev_cal = fit(ctx, cfg, pe.sim3.apply(points), colors, cal_train, train_rgb, cal_test, test_rgb,
                          "calibrated")
    fit_sfm, ev_sfm = fit(ctx, cfg, points, colors, sfm_train, train_rgb, sfm_test, test_rgb, "SfM")

    box = read_object_box(root)
    masks = [box_mask(c, box) for c in cal_test] if box is not None else None

    def boxed(ev) -> float | None:
        if masks is None:
            return None
        vals = [rm.psnr(rm.srgb_on_black(r), rm.srgb_on_black(t), mask=m)
                for r, t, m in zip(ev.renders, test_rgb, masks)]
        return float(np.mean(vals))

    box_cal, box_sfm = boxed(ev_cal), boxed(ev_sfm)
    w, h = cal_test[0].width, cal_test[0].height
    w0, h0 = ds.views[0].camera.width, ds.views[0].camera.height
    seconds = summary.get("seconds", {})
    metrics = {
        "scene": scene, "data": {"path": str(root), "format": ds.format, "content_hash": ds.manifest["content_hash"],
                                 "protocol": ds.protocol.name, "eval_protocol": sub.protocol.description},
        "images": len(calib), "registered": len(names), "unregistered": sorted(set(calib) - set(est)),
        "sfm": {"options": asdict(opts), "points": summary["points"],
                "mean_reprojection_error_px": summary["mean_reprojection_error"], "seconds": seconds,
                "reused_cached_model": reused, "model": str(sfm_out), "pycolmap": summary.get("pycolmap")},
        "pose_errors": s, "scene_radius": radius,
        "scene_radius_definition": "median distance of the calibrated camera centres from their centroid",
        "centre_error_median_pct": 100 * s["translation_median"] / radius,
        "centre_error_max_pct": 100 * s["translation_max"] / radius,
        "focal_sfm": f_sfm, "focal_calibrated": f_calib,
        "focal_calibrated_fx_fy": [float(np.median([c.fx for c in calib.values()])),
                                   float(np.median([c.fy for c in calib.values()]))],
        "focal_error_pct": focal_err,
        "track_reprojection_px": reproj,
        "principal_point_calibrated": [float(np.median([c.cx for c in calib.values()])),
                                       float(np.median([c.cy for c in calib.values()]))],
        "per_view": [{"name": n, "rotation_deg": float(r), "centre_error": float(t)}
                     for n, r, t in zip(names, pe.rotation_deg, pe.translation)],
        "splats": {
            "resolution": f"{w}x{h}", "factor": cfg.factor, "iterations": cfg.iterations,
            "max_gaussians": cfg.max_gaussians, "train_views": len(train_views),
            "test_views": [v.name for v in test_views], "init_points": len(points),
            "object_box": None if box is None else box.tolist(),
            "object_box_pixel_fraction": None if masks is None else float(np.mean([m.mean() for m in masks])),
            "calibrated": {"psnr": ev_cal.psnr, "ssim": ev_cal.ssim, "psnr_object_box": box_cal,
                           "splats": fit_cal.model.n, "train_seconds": fit_cal.seconds, "per_view": ev_cal.per_view},
            "sfm": {"psnr": ev_sfm.psnr, "ssim": ev_sfm.ssim, "psnr_object_box": box_sfm,
                    "splats": fit_sfm.model.n, "train_seconds": fit_sfm.seconds, "per_view": ev_sfm.per_view},
            "psnr_gap_db": ev_cal.psnr - ev_sfm.psnr},
        "eval_protocol": sub.protocol.description,
    }
    rows = [
        ["images registered", f"{len(names)} / {len(calib)}"],
        ["SfM points; mean reprojection error", f"{summary['points']}; {summary['mean_reprojection_error']:.3f} px"],
        ["rotation error (deg): median / max", f"{s['rotation_deg_median']:.3f} / {s['rotation_deg_max']:.3f}"],
        [f"camera-centre error (% of the scene radius {radius:.4g}): median / max",
         f"{metrics['centre_error_median_pct']:.2f}% / {metrics['centre_error_max_pct']:.2f}%"],
        ["focal length (px): SfM / calibrated (fx + fy) / 2",
         f"{f_sfm:.1f} / {f_calib:.1f} ({focal_err:+.2f}%)"],
        ["principal point (px): SfM (fixed at the centre) / calibrated",
         f"({w0 / 2:g}, {h0 / 2:g}) / ({metrics['principal_point_calibrated'][0]:.2f}, "
         f"{metrics['principal_point_calibrated'][1]:.2f})"],
        ["SfM tracks re-triangulated, reprojection error mean / median (px): SfM cameras",
         f"{reproj['sfm']['mean']:.3f} / {reproj['sfm']['median']:.3f}"],
        ["the same, calibrated cameras with pixel-centre offset 0.5 (the reader's) / 0 / 1",
         " ; ".join(f"{reproj[f'calibrated_offset_{o}']['mean']:.3f} / {reproj[f'calibrated_offset_{o}']['median']:.3f}"
                    for o in ("0.5", "0", "1"))],
        ["SfM time (features + matching + mapping + undistortion)",
         " + ".join(f"{seconds.get(k, 0.0):.1f}" for k in ("features", "matching", "mapping", "undistortion"))
         + " s" + (" (cached model)" if reused else "")],
    ]
    box_txt = lambda v: "n/a" if v is None else f"{v:.2f}"  # noqa: E731
    fits = [["calibrated (K[R|t] of the par file)", f"{ev_cal.psnr:.2f}", f"{ev_cal.ssim:.4f}", box_txt(box_cal),
             fit_cal.model.n, f"{fit_cal.seconds:.0f} s"],
            ["SfM (registered with the rest)", f"{ev_sfm.psnr:.2f}", f"{ev_sfm.ssim:.4f}", box_txt(box_sfm),
             fit_sfm.model.n, f"{fit_sfm.seconds:.0f} s"]]
    box_note = ("" if masks is None else
                f" PSNR in the object box: over the pixels whose rays cross the dataset's stated tight bounding box "
                f"(calibrated test cameras; {100 * metrics['splats']['object_box_pixel_fraction']:.0f}% of the pixels)."
                )
    table = (f"Middlebury multi-view `{scene}` ({len(calib)} photographs, {ds.views[0].camera.width}x"
             f"{ds.views[0].camera.height}, calibrated K[R|t]). `drlab sfm`'s code (pycolmap SIFT, exhaustive "
             "matching, incremental mapping; one shared SIMPLE_PINHOLE camera, focal estimated; 1 thread) against "
             "the calibration, after a Sim(3) Umeyama alignment of the camera centres; the scene radius is the "
             "median distance of the calibrated centres from their centroid.\n\n"
             + markdown_table(["quantity", "value"], rows)
             + f"\nSplats (fit_splats' trainer, {cfg.iterations} iterations, at most {cfg.max_gaussians} splats, at "
               f"{w}x{h}: the photographs at 1/{cfg.factor}) from the same {len(points)} SfM points on the same "
               f"{len(train_views)} train views, scored on the {len(test_views)} held-out views (every 8th by name), "
               "each fit with its own cameras of those views. The black cloth background is scored like every "
               "pixel (splats render on black); PSNR and SSIM on sRGB in [0, 1]." + box_note + "\n\n"
             + markdown_table(["cameras", "test PSNR (dB)", "test SSIM", "PSNR in object box (dB)", "splats",
                               "train time"], fits)
             + f"\nPSNR gap (calibrated - SfM): {ev_cal.psnr - ev_sfm.psnr:+.2f} dB.\n\n![real_photos](real_photos.png)\n")
    aligned = np.array([pe.sim3.apply_c2w(c) for c in est_c2w])
    figure(gt_c2w, aligned, test_rgb[0], [ev_cal.renders[0], ev_sfm.renders[0]],
           [f"calibrated cameras: {ev_cal.per_view[0]['psnr']:.2f} dB",
            f"SfM cameras: {ev_sfm.per_view[0]['psnr']:.2f} dB"], ctx.out / "real_photos.png")
    ctx.write_results(config={**asdict(cfg), "sfm_threads": args.threads}, metrics=metrics,
                      table_md=table)
    return 0


main = Experiment("real_photos", __doc__, run, add_options,
                  data_help="a Middlebury multi-view folder (<name>_par.txt and its PNGs), or a folder holding "
                            "middlebury_mview/templeRing or templeRing",
                  seed_help="seed of the SfM mapper, the splats' initial subsample and training",
                  sizes="Default: splats at 1/2 of the photographs (320x240 for templeRing), 3000 iterations, at most "
                        "30 000 splats, two fits (about 40 min on 2 loaded cores) after SfM (about 1 min). Quick: 1/4, "
                        "600 iterations. Smoke: a 16-view synthetic capture at 240x180 written into "
                        "<data>/real_photos-smoke, 30 iterations.").script(__name__)
