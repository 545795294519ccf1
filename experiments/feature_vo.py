#!/usr/bin/env python3
"""Classical RGB-D feature visual odometry with local bundle adjustment and loop closure (research/vo).

Sequence: the `objects` scene's loop path, `drlab dataset --scene objects --flow --flow-path loop`
(research.poses.se3.loop_path: one orbit around the scene and back to the first frame, with Mitsuba's
z-depth per frame), 60 frames at 128x128: the same dataset configuration as splat_slam (quick: 16
spp, full: 64 spp, so the two experiments share the rendered data and their tables compare).
Smoke: the same 60-frame loop at 128x128 with 4 spp (fewer bundle-adjustment iterations made the
adjustment worse than none on the smoke data, so they are the same).

Odometry (research/vo/odometry.py): ORB features (OpenCV); frame 1 from the essential matrix with
RANSAC, its scale from the measured depth of the matched keypoints; then every frame by PnP with
RANSAC against the local map's landmarks (guided matching around the constant-velocity prediction);
a keyframe every `--keyframe-every` frames, whose new landmarks are triangulated from the previous
keyframe or back-projected from depth; a local bundle adjustment over the last `--window` keyframes
after each keyframe, with residuals and Jacobians from the Warp kernel kernels.ba (pixel residuals,
plus a relative depth residual where a keypoint has a measured depth), solved by scipy's sparse least
squares with a Huber loss. Frame 0's pose is the ground truth's (it fixes the world
frame, as in splat_slam).

Loop closure (research/vo/loop.py): late keyframes matched by descriptor with the first keyframes,
verified by PnP RANSAC; the verified loops and the odometry edges go into a pose-graph optimisation
(SE(3) relative-pose residuals, scipy least squares).

Reported, before and after the loop closure: ATE RMSE (after SE(3) Umeyama alignment of the camera
centres, research.poses.se3) and its % of the ground-truth path length, RPE frame to frame (translation
RMSE, also as % of the mean step, and rotation RMSE), frames per second (the odometry alone, and with
the loop closure), tracking failures, keyframes, landmarks, and the bundle adjustments' RMS
reprojection error before and after.

Writes results/feature_vo/{table.md, metrics.json, trajectory.png, vo.tum, vo_loop_closed.tum,
groundtruth.tum}.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from research.datasets import CACHE_ROOT_HELP
from research.experiment import Context, Experiment
from research.results import finish_figure, markdown_table, trajectory_error_panel, trajectory_top_view

LOOP_FRAMES = 60


def setup(quick: bool, smoke: bool) -> dict:
    """Sizes per mode: the dataset configuration of splat_slam's quick and full runs (views, res, spp)."""
    if smoke:
        return dict(res=128, spp=4, views=6, ba_max_nfev=20)
    if quick:
        return dict(res=128, spp=16, views=20, ba_max_nfev=20)
    return dict(res=128, spp=64, views=20, ba_max_nfev=20)


def add_options(p) -> None:
    p.add_argument("--features", type=int, default=1000, help="ORB keypoints per frame (default 1000)")
    p.add_argument("--keyframe-every", type=int, default=2, help="every N-th frame is a keyframe (default 2)")
    p.add_argument("--window", type=int, default=5, help="keyframes in the local map and the local BA (default 5)")
    p.add_argument("--ba-loss", default="huber", choices=["linear", "huber", "soft_l1", "cauchy", "arctan"],
                   help="robust loss of the bundle adjustment (scipy's; default huber, 2 px scale)")
    p.add_argument("--no-ba", action="store_true", help="skip the local bundle adjustment (an ablation)")
    p.add_argument("--ba-depth-weight", type=float, default=30.0,
                   help="weight of the bundle adjustment's relative depth residuals, pixels per unit relative depth "
                        "error; 0 uses the pixel residuals only (default 30, chosen on the smoke sequence)")


def _check_args(args) -> None:
    for name in ("features", "keyframe_every"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')}: expected an integer >= 1, got {getattr(args, name)}")
    if args.window < 2:
        raise ValueError(f"--window: expected an integer >= 2, got {args.window}")


def trajectory_figure(gt: np.ndarray, before: np.ndarray, after: np.ndarray, loops: list[tuple[int, int]],
                      err_before: np.ndarray, err_after: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
    ax = axes[0]
    ax.plot(gt[:, 0, 3], gt[:, 1, 3], "k.-", lw=1, ms=4, label="ground truth")
    ax.plot(before[:, 0, 3], before[:, 1, 3], ".-", c="tab:orange", lw=1, ms=4, label="VO before loop closure")
    ax.plot(after[:, 0, 3], after[:, 1, 3], ".-", c="tab:blue", lw=1, ms=4, label="VO after loop closure")
    for i, j in loops:
        ax.plot([after[i, 0, 3], after[j, 0, 3]], [after[i, 1, 3], after[j, 1, 3]], "g--", lw=1)
    trajectory_top_view(ax, gt, "camera centres, top view (SE(3)-aligned; dashed: loops)")
    trajectory_error_panel(axes[1], {"before loop closure": (err_before, "tab:orange"),
                                     "after loop closure": (err_after, "tab:blue")})
    finish_figure(fig, path)


def run(ctx: Context) -> int:
    import time

    from research import datasets
    from research.poses import se3 as P
    from research.vo.loop import LoopConfig, detect_loops, optimise_pose_graph
    from research.vo.odometry import VOConfig, check_sequence, run_vo

    args = ctx.args
    _check_args(args)
    size = setup(ctx.quick, ctx.smoke)
    try:
        cfg = VOConfig(n_features=args.features, keyframe_every=args.keyframe_every, window=args.window,
                       ba=not args.no_ba, ba_loss=args.ba_loss, ba_max_nfev=size["ba_max_nfev"],
                       ba_depth_weight=args.ba_depth_weight).validate()
    except ValueError as e:
        name, _, rest = str(e).partition(":")
        raise ValueError(f"--{name.replace('_', '-')}:{rest}") from None
    loop_cfg = LoopConfig().validate()
    dcfg = datasets.DatasetConfig("objects", views=size["views"], res=size["res"], spp=size["spp"], seed=ctx.seed,
                                  flow=True, flow_frames=LOOP_FRAMES, flow_path="loop")
    data = datasets.ensure(dcfg, datasets.cache_dir(dcfg, ctx.data), show_progress=ctx.progress)
    seq = datasets.load_flow(data)
    gt = np.array([c.c2w for c in seq.cameras])
    K = seq.cameras[0].K
    n = len(gt)
    check_sequence(seq.frames, seq.depth, K, gt[0], cfg.window)

    bar = ctx.tqdm(total=n - 1, desc="feature VO")

    def progress(k: int, rec: dict) -> None:
        bar.update(1)
        bar.set_postfix(inliers=rec.get("inliers", 0))

    vo = run_vo(seq.frames, seq.depth, K, gt[0], cfg, device=ctx.device, progress=progress)
    bar.close()
    t0 = time.perf_counter()
    loops, tried = detect_loops(vo, K, loop_cfg)
    kf_T, pgo = optimise_pose_graph(np.stack([kf.T for kf in vo.keyframes]), loops, loop_cfg.loop_weight)
    closed = vo.trajectory(kf_T)
    loop_s = time.perf_counter() - t0

    length = P.path_length(gt)
    step = length / (n - 1)
    rows, stats = [], {}
    for label, traj in (("before loop closure", vo.c2w), ("after loop closure", closed)):
        a = P.ate(traj, gt, align="se3")
        r = P.rpe(traj, gt, delta=1)
        stats[label] = (a, r, P.align_trajectory(traj, gt, "se3"))
        rows.append([f"feature VO (ORB + PnP + local BA), {label}", f"{a.rmse:.4f}", f"{100 * a.rmse / length:.2f}",
                     f"{r.translation.rmse:.4f}", f"{100 * r.translation.rmse / step:.1f}",
                     f"{r.rotation_deg.rmse:.3f}"])
    fps_vo = n / vo.seconds
    fps_all = n / (vo.seconds + loop_s)
    stamps = np.arange(n, dtype=float)
    P.write_tum(ctx.out / "vo.tum", stamps, vo.c2w)
    P.write_tum(ctx.out / "vo_loop_closed.tum", stamps, closed)
    P.write_tum(ctx.out / "groundtruth.tum", stamps, gt)
    frame_of = [kf.frame for kf in vo.keyframes]
    (a0, _, al0), (a1, _, al1) = stats["before loop closure"], stats["after loop closure"]
    trajectory_figure(gt, al0, al1, [(frame_of[lp.i], frame_of[lp.j]) for lp in loops], a0.errors, a1.errors,
                      ctx.out / "trajectory.png")

    loop_text = ", ".join(f"frame {frame_of[lp.j]} -> {frame_of[lp.i]}: {lp.inliers} PnP inliers" for lp in loops)
    headers = ["method", "ATE RMSE", "ATE % of path", "RPE trans RMSE", "RPE trans % of step", "RPE rot RMSE (deg)"]
    ba_before = [b["rms_before_px"] for b in vo.ba]
    ba_after = [b["rms_after_px"] for b in vo.ba]
    ba_text = (f"{len(vo.ba)} local bundle adjustments (Warp Jacobians, {cfg.ba_loss} loss, depth residual weight "
               f"{cfg.ba_depth_weight:g} px per unit relative depth error): mean RMS reprojection "
               f"error {np.mean(ba_before):.3f} -> {np.mean(ba_after):.3f} px" if vo.ba else "no bundle adjustment")
    table = (f"`objects` loop sequence from `drlab dataset --flow --flow-path loop` ({n} frames at "
             f"{size['res']}x{size['res']}, {size['spp']} spp; path length {length:.3f}, mean step {step:.4f}), "
             f"the dataset configuration of splat_slam's {ctx.mode} run. ATE after SE(3) Umeyama alignment; RPE "
             f"frame to frame (TUM definitions, research.poses.se3).\n\n"
             + markdown_table(headers, rows)
             + f"\nFrames/s: {fps_vo:.2f} for the odometry ({vo.seconds:.1f} s, with its bundle adjustments), "
               f"{fps_all:.2f} with loop detection and the pose graph ({loop_s:.1f} s). Keyframes: "
               f"{len(vo.keyframes)}; landmarks: {len(vo.points)}; tracking failures: {len(vo.failures)}. "
               f"Loops verified: {len(loops)} of {len(tried)} candidate keyframe pairs "
               f"({loop_text or 'none'}). "
               f"{ba_text}.\n")
    if vo.failures:
        table += "\nTracking failures: " + "; ".join(f"frame {f['frame']}: {f['reason']}" for f in vo.failures) + "\n"

    def stat_dict(label: str) -> dict:
        a, r, _ = stats[label]
        return {"ate_rmse": a.rmse, "ate_mean": a.mean, "ate_max": a.max, "ate_pct_of_path": 100 * a.rmse / length,
                "rpe_translation_rmse": r.translation.rmse,
                "rpe_translation_pct_of_step": 100 * r.translation.rmse / step,
                "rpe_rotation_rmse_deg": r.rotation_deg.rmse}

    record = datasets.provenance(data)
    metrics = {
        "dataset": {"path": str(data), "config": dcfg.__dict__, "content_hash": record["content_hash"]},
        "frames": n, "path_length": length,
        "before_loop_closure": stat_dict("before loop closure"), "after_loop_closure": stat_dict("after loop closure"),
        "fps_odometry": fps_vo, "fps_with_loop_closure": fps_all, "vo_seconds": vo.seconds, "loop_seconds": loop_s,
        "keyframes": len(vo.keyframes), "landmarks": int(len(vo.points)), "tracking_failures": vo.failures,
        "init_depth_scale": vo.init_scale, "loops": [{"early_frame": frame_of[lp.i], "frame": frame_of[lp.j],
                                                      "matches": lp.matches, "inliers": lp.inliers} for lp in loops],
        "loop_candidates": tried, "pose_graph": pgo, "bundle_adjustments": vo.ba, "per_frame": vo.frames,
    }
    config = {**size, "frames": n, "vo": asdict(cfg), "loop": asdict(loop_cfg)}
    ctx.write_results(config=config, metrics=metrics, table_md=table)
    return 0


main = Experiment("feature_vo", __doc__, run, add_options,
                  seed_help="seed of the dataset's camera path start",
                  sizes="Full: the 60-frame loop at 128x128, 64 spp; quick: the same at 16 spp (splat_slam's "
                        "quick dataset); smoke: the same at 4 spp (6 multi-view images).",
                  data_help=CACHE_ROOT_HELP).script(__name__)
