#!/usr/bin/env python3
"""RGB-D SLAM with a Gaussian-splat map (SplaTAM-style) on a Mitsuba camera path that returns to its start.

Sequence: `drlab dataset --scene objects --flow --flow-path loop` (research.poses.se3.loop_path: one orbit
around the scene and back to the first frame, with Mitsuba's z-depth per frame): 60 frames at 128x128
(quick: the same 60 frames, fewer iterations per frame; smoke: the first 8 frames of the 60-frame loop
at 32x32). The dataset's
multi-view test and val images of the same scene, which SLAM never sees, are the held-out views.

SLAM (research/slam): the map starts from frame 0's pixels back-projected with their depth and colour
(its pose fixes the world frame); every later frame is tracked from a constant-velocity guess by Adam
on the se(3) pose, with the splat renderer's hand-written camera gradients, on a photometric + depth
loss over the rendered silhouette, for a fixed iteration budget; every `--keyframe-every`-th frame is
a keyframe: the map is densified where its silhouette is thin or its depth lies behind the measured
one, then optimised over the last `--window` keyframes. Tracking failures (loss far above the run's
median, or a pose jumping beyond a bound from the guess) are recorded in the table; three in a row stop
the run with an error rather than a trajectory of guesses.

Reported: ATE RMSE (after SE(3) Umeyama alignment of the camera centres) and RPE (frame to frame,
translation and rotation; TUM definitions, research.poses.se3) also as % of the ground-truth path length,
frames per second of the whole loop (tracking + mapping), tracking failures, the map's PSNR/SSIM on
the held-out views (rendered at their ground-truth poses: frame 0 anchors the map in the ground-truth
world frame) and its size. Beside it, on the same frames: the classical feature-VO baseline
(research.vo.odometry.run_vo with its defaults: ORB, essential matrix / PnP with RANSAC, local bundle
adjustment, before any loop closure) when that module is installed (another branch adds it; until then
its row says so). A VO run that loses track or rejects the sequence is reported with its message.

Writes results/splat_slam/{table.md, metrics.json, trajectory.png, map.png, estimate.tum, groundtruth.tum}
(and vo_estimate.tum when the baseline ran).
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from research.datasets import CACHE_ROOT_HELP
from research.experiment import Context, Experiment
from research.results import finish_figure, markdown_table, trajectory_error_panel, trajectory_top_view

TARGET_ATE_PCT = 1.0
LOOP_FRAMES = 60  # the smoke run renders the 60-frame loop (at 32x32) and tracks its first frames


def setup(quick: bool, smoke: bool) -> dict:
    """Sizes per mode. The quick budgets were set before the first 60-frame run and not changed after it;
    research/slam's settings say which of them were picked on the seed-0 sequence's first 10 frames (the
    reported quick run is that sequence; `--seed 1` is another start of the loop, untouched by the picks)."""
    if smoke:
        # the first 8 frames of the 60-frame loop: the same step between frames as the real run
        return dict(frames=8, res=32, spp=4, views=6, track_iters=10, map_iters=5, init_iters=20)
    if quick:
        return dict(frames=60, res=128, spp=16, views=20, track_iters=40, map_iters=20, init_iters=60)
    return dict(frames=60, res=128, spp=64, views=20, track_iters=80, map_iters=40, init_iters=100)


def add_options(p) -> None:
    p.add_argument("--frames", type=int, default=None, help="frames of the loop sequence (default 60; smoke 8)")
    p.add_argument("--track-iters", type=int, default=None,
                   help="tracking iterations per frame (default: 80 full, 40 quick, 10 smoke)")
    p.add_argument("--map-iters", type=int, default=None,
                   help="mapping iterations per keyframe (default: 40 full, 20 quick, 5 smoke)")
    p.add_argument("--keyframe-every", type=int, default=2, help="every N-th frame is a keyframe (default 2)")
    p.add_argument("--window", type=int, default=5, help="keyframes in the mapping window (default 5)")


def _check_args(args) -> None:
    for name in ("frames", "track_iters", "map_iters"):
        v = getattr(args, name)
        if v is not None and v < (4 if name == "frames" else 1):
            raise ValueError(f"--{name.replace('_', '-')}: expected an integer >= {4 if name == 'frames' else 1}, "
                             f"got {v}")
    for name in ("keyframe_every", "window"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')}: expected an integer >= 1, got {getattr(args, name)}")


def trajectory_figure(gt: np.ndarray, est_aligned: np.ndarray, errors: np.ndarray, failures: list[int],
                      path: Path, vo_aligned: np.ndarray | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
    ax = axes[0]
    ax.plot(gt[:, 0, 3], gt[:, 1, 3], "k.-", lw=1, ms=4, label="ground truth")
    ax.plot(est_aligned[:, 0, 3], est_aligned[:, 1, 3], ".-", c="tab:blue", lw=1, ms=4,
            label="splat SLAM (SE(3)-aligned)")
    if vo_aligned is not None:
        ax.plot(vo_aligned[:, 0, 3], vo_aligned[:, 1, 3], ".-", c="tab:orange", lw=1, ms=3,
                label="feature VO (SE(3)-aligned)")
    if failures:
        ax.scatter(est_aligned[failures, 0, 3], est_aligned[failures, 1, 3], c="tab:red", marker="x", s=40,
                   label="tracking failure", zorder=4)
    trajectory_top_view(ax, gt, "camera centres, top view")
    curves = {"splat SLAM": (errors, "tab:blue")}
    if vo_aligned is not None:
        curves["feature VO"] = (np.linalg.norm(vo_aligned[:, :3, 3] - gt[:, :3, 3], axis=1), "tab:orange")
    trajectory_error_panel(axes[1], curves)
    finish_figure(fig, path)


def map_figure(gt_imgs: np.ndarray, renders: np.ndarray, psnrs: list[float], titles: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research.metrics import srgb_on_black

    n = len(gt_imgs)
    fig, axes = plt.subplots(2, n, figsize=(2.6 * n, 5.4), squeeze=False)
    for i in range(n):
        axes[0, i].imshow(np.clip(srgb_on_black(gt_imgs[i]), 0, 1))
        axes[0, i].set_title(f"{titles[i]}: Mitsuba", fontsize=8)
        axes[1, i].imshow(np.clip(srgb_on_black(renders[i]), 0, 1))
        axes[1, i].set_title(f"map render, {psnrs[i]:.1f} dB", fontsize=8)
        for a in axes[:, i]:
            a.axis("off")
    finish_figure(fig, path)


def feature_vo(rgba: np.ndarray, depth: np.ndarray, K: np.ndarray, gt: np.ndarray) -> dict:
    """The feature-VO baseline (research.vo, experiments/feature_vo.py) on the same frames, before loop closure:
    its ATE/RPE/fps, or why there is none (the odometry stopped: its own one-line error)."""
    import time

    from research.poses import se3 as P
    from research.vo.odometry import run_vo

    t0 = time.perf_counter()
    try:
        res = run_vo(rgba, depth, K, gt[0])
    except (RuntimeError, ValueError) as e:
        return {"status": f"stopped: {e}"}
    seconds = time.perf_counter() - t0
    ate, rpe = P.ate(res.c2w, gt, align="se3"), P.rpe(res.c2w, gt, delta=1)
    return {"status": "ran", "c2w": res.c2w, "ate_rmse": ate.rmse, "rpe_trans_rmse": rpe.translation.rmse,
            "rpe_rot_rmse_deg": rpe.rotation_deg.rmse, "fps": len(gt) / seconds, "seconds": seconds,
            "failures": len(res.failures)}


def run(ctx: Context) -> int:
    from research import datasets
    from research.poses import se3 as P
    from research.slam import MapConfig, SlamConfig, TrackConfig, check_sequence, run_slam
    from research.splats.train import evaluate

    args = ctx.args
    _check_args(args)
    size = setup(ctx.quick, ctx.smoke)
    frames = args.frames or size["frames"]
    track_iters = args.track_iters or size["track_iters"]
    map_iters = args.map_iters or size["map_iters"]
    slam_cfg = SlamConfig(track=TrackConfig(iters=track_iters), map=MapConfig(iters=map_iters),
                          keyframe_every=args.keyframe_every, window=args.window, init_iters=size["init_iters"],
                          seed=ctx.seed)
    if frames < slam_cfg.window:  # before rendering anything
        raise ValueError(f"--frames: the sequence has {frames} frames, fewer than the keyframe window "
                         f"(--window {slam_cfg.window})")
    loop_frames = LOOP_FRAMES if ctx.smoke else frames
    dcfg = datasets.DatasetConfig("objects", views=size["views"], res=size["res"], spp=size["spp"], seed=ctx.seed,
                                  flow=True, flow_frames=loop_frames, flow_path="loop")
    data = datasets.ensure(dcfg, datasets.cache_dir(dcfg, ctx.data), show_progress=ctx.progress)
    seq = datasets.load_flow(data)
    rgba, depth = seq.frames[:frames], seq.depth[:frames]
    gt = np.array([c.c2w for c in seq.cameras])[:frames]
    cam0 = seq.cameras[0]
    check_sequence(rgba, depth, cam0.K, gt[0], slam_cfg.window)

    bar = ctx.tqdm(total=frames - 1, desc="splat SLAM")

    def progress(k: int, rec: dict) -> None:
        bar.update(1)
        bar.set_postfix(loss=f"{rec['loss']:.4f}", splats=rec["splats"])

    result = run_slam(rgba, depth, cam0.K, gt[0], slam_cfg, device=ctx.device, progress=progress)
    bar.close()
    fps = frames / result.seconds
    vo = feature_vo(rgba, depth, cam0.K, gt)

    length = P.path_length(gt)
    closing = (f", {P.path_length(np.concatenate([gt, gt[:1]])):.3f} with the step back to frame 0"
               if frames == len(seq.cameras) else f", the first {frames} frames of a {len(seq.cameras)}-frame loop")
    ate = P.ate(result.c2w, gt, align="se3")
    rpe = P.rpe(result.c2w, gt, delta=1)
    aligned = P.align_trajectory(result.c2w, gt, "se3")
    stamps = np.arange(frames, dtype=float)
    P.write_tum(ctx.out / "estimate.tum", stamps, result.c2w)
    P.write_tum(ctx.out / "groundtruth.tum", stamps, gt)
    if vo["status"] == "ran":
        P.write_tum(ctx.out / "vo_estimate.tum", stamps, vo["c2w"])
    failed = [f["frame"] for f in result.failures]

    ds = datasets.load(data)
    held = [ds.load_split(s) for s in ("test", "val")]
    cams = [c for s in held for c in s.cameras]
    imgs = np.concatenate([s.rgba[..., :3] for s in held]).astype(np.float32)
    ev = evaluate(result.model, cams, imgs, sh_degree=0, device=ctx.device)
    show = min(4, len(cams))
    map_figure(imgs[:show], ev.renders[:show], [p["psnr"] for p in ev.per_view[:show]],
               [f"held-out view {i}" for i in range(show)], ctx.out / "map.png")

    pct = 100.0 * ate.rmse / length
    vo_aligned = P.align_trajectory(vo["c2w"], gt, "se3") if vo["status"] == "ran" else None
    trajectory_figure(gt, aligned, ate.errors, failed, ctx.out / "trajectory.png", vo_aligned)
    step = length / (frames - 1)
    rows = [["splat SLAM (drlab, Warp CPU kernels)", f"{ate.rmse:.4f}", f"{pct:.2f}", f"{rpe.translation.rmse:.4f}",
             f"{100 * rpe.translation.rmse / step:.1f}", f"{rpe.rotation_deg.rmse:.3f}",
             f"{fps:.3f}", str(len(failed)), f"{ev.psnr:.2f}", f"{ev.ssim:.3f}", str(result.model.n)],
            ["feature VO (OpenCV ORB + PnP + local BA, before loop closure)"]]
    if vo["status"] == "ran":
        rows[1] += [f"{vo['ate_rmse']:.4f}", f"{100 * vo['ate_rmse'] / length:.2f}", f"{vo['rpe_trans_rmse']:.4f}",
                    f"{100 * vo['rpe_trans_rmse'] / step:.1f}", f"{vo['rpe_rot_rmse_deg']:.3f}", f"{vo['fps']:.3f}",
                    str(vo["failures"]), "", "", ""]
    else:
        rows[1] += [vo["status"]] + [""] * 9
    headers = ["method", "ATE RMSE", "ATE % of path", "RPE trans RMSE", "RPE trans % of step", "RPE rot RMSE (deg)",
               "frames/s", "tracking failures", "held-out PSNR (dB)", "held-out SSIM", "splats"]
    target = "met" if pct < TARGET_ATE_PCT and not failed else "NOT met"
    table = (f"`objects` loop sequence from `drlab dataset --flow --flow-path loop` ({frames} frames at "
             f"{size['res']}x{size['res']}, {size['spp']} spp; path length {length:.3f}{closing}), "
             f"device `{ctx.device}`. Tracking {track_iters} Adam iterations per frame (3x for frame 1), "
             f"mapping {map_iters} iterations per keyframe (every {slam_cfg.keyframe_every} frames, window "
             f"{slam_cfg.window}). ATE after SE(3) Umeyama alignment; RPE frame to frame (TUM definitions, "
             f"research.poses.se3). Held-out PSNR/SSIM (sRGB on black) on the dataset's {len(cams)} test and val views at "
             f"their ground-truth poses. Frames/s: the whole loop (tracking + mapping), {result.seconds:.1f} s.\n\n"
             + markdown_table(headers, rows)
             + f"\nTarget (ATE RMSE < {TARGET_ATE_PCT:g}% of the path length, no tracking failure): {target} "
               f"({pct:.2f}%)")
    if vo["status"] == "ran":
        table += (f"; ATE below the feature VO's ({100 * vo['ate_rmse'] / length:.2f}%): "
                  f"{'yes' if ate.rmse < vo['ate_rmse'] else 'NO'}")
    table += ".\n"
    if result.failures:
        table += "\nTracking failures: " + "; ".join(f"frame {f['frame']}: {f['reason']}" for f in result.failures)
        table += "\n"
    record = datasets.provenance(data)
    metrics = {
        "dataset": {"path": str(data), "config": dcfg.__dict__, "content_hash": record["content_hash"]},
        "frames": frames, "path_length": length,
        "ate": {"rmse": ate.rmse, "mean": ate.mean, "median": ate.median, "max": ate.max, "pct_of_path": pct},
        "rpe": {"translation_rmse": rpe.translation.rmse, "rotation_rmse_deg": rpe.rotation_deg.rmse},
        "fps": fps, "slam_seconds": result.seconds, "tracking_failures": result.failures,
        "keyframes": result.keyframes, "splats": result.model.n,
        "held_out": {"psnr": ev.psnr, "ssim": ev.ssim, "psnr_linear": ev.psnr_linear, "views": len(cams),
                     "per_view": ev.per_view},
        "per_frame": result.frames,
        "vo_baseline": {k: v for k, v in vo.items() if k != "c2w"},
        "target_ate_pct": TARGET_ATE_PCT, "target_met": bool(pct < TARGET_ATE_PCT and not failed),
    }
    config = {**size, "frames": frames, "track": asdict(slam_cfg.track),
              "map": asdict(slam_cfg.map), "keyframe_every": slam_cfg.keyframe_every, "window": slam_cfg.window}
    ctx.write_results(config=config, metrics=metrics, table_md=table)
    return 0


main = Experiment("splat_slam", __doc__, run, add_options,
                  seed_help="seed of the dataset's camera path start and of the mapping window's keyframe draws",
                  sizes="Full: 60 loop frames at 128x128, 64 spp, 80 tracking / 40 mapping iterations; quick: the "
                        "same 60 frames at 16 spp, 40 / 20 iterations; smoke: the first 8 frames of the 60-frame "
                        "loop at 32x32, 10 / 5. Measured on 2 shared, loaded CPU cores: quick 5-7 min, full 10.5 min "
                        "(dataset rendering included), smoke under a minute.",
                  data_help=CACHE_ROOT_HELP).script(__name__)
