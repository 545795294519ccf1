#!/usr/bin/env python3
"""Depth from stereo on Mitsuba rectified pairs: drlab's cost volumes and SGM against OpenCV.

For the scenes `objects` and `cornell` this renders rectified pairs with exact
disparity (`drlab dataset --stereo`, into data/stereo_depth-<scene>), converts
them to 8-bit grayscale as a camera would store them, and runs

  * drlab: every cost (SAD, ZNCC, census, Birchfield-Tomasi, census+grad = kernels.stereo.adcensus,
    feature correlation on patch features) x every aggregation (none = plain winner-take-all, SGM over 4
    paths, SGM over 8 paths), each followed by WTA with the sub-pixel
    parabola and the left-right check; plus soft-argmin in place of WTA on the
    best SGM configuration;
  * OpenCV StereoSGBM and StereoBM;
  * "drlab default": research.stereo.matching.DEFAULT_CONFIG as it is, not tuned here (its parameters were
    chosen on the real Middlebury 2001 pairs tsukuba and venus and on these tuning pairs p_000, clean
    and stressed; research.stereo.matching's docstring), never the "best" or "robust" pick below.

Protocol. Pair p_000 of each scene is a tuning pair; the others are the
evaluation pairs. Every method's free parameters (drlab: window, P1, P2, soft-
argmin temperature; OpenCV: block size, mode, P2, uniqueness) are chosen from
a small grid by mean D1 on the tuning pairs, and "the best drlab configuration"
is chosen the same way, so nothing is selected on the pairs it is scored on.

Clean and stressed pairs. Each pair is scored twice: clean (the render's luminance, sRGB-encoded
to 8 bits) and stressed, the same luminance through research.radiometry's radiometric stress set
(per-camera exposure/gain and black level, vignetting, slight blur, Poisson-Gaussian noise, 8-bit
sRGB quantisation; its default ranges, seeded by the run's seed, the scene and the pair). Every
method, OpenCV's included, is tuned on the clean tuning pairs only and reported on both, so the
stressed evaluation pairs test whether the chosen defaults hold. "The robust choice" is the drlab
configuration, among those chosen, with the lowest mean of its clean and its stressed tuning D1
(p_000 stressed: held out from the evaluation like p_000 clean).

Scoring (research.stereo.matching): invalid pixels are filled as KITTI's devkit does,
then EPE, bad-1/2/3, D1 and depth abs-rel over the non-occluded ground truth
(noc) and D1 over every pixel with ground truth (all); pooled over pairs
(pixel-weighted). Time is wall time per pair on this machine: drlab with its
CPU threads (kernels.launch), OpenCV with cv2.getNumThreads() threads.

Writes results/stereo_depth/{table.md, metrics.json, disparity_maps.png, d1_by_method.png}.

One configuration (`--cost C [--aggregation A] [--radius R] [--p1 X] [--p2 Y] [--zncc-eps E]`): instead
of tuning the grid, scores that one drlab configuration (no OpenCV) on the tuning pairs (its
`tuning_d1`, which a sweep chooses by) and on the evaluation pairs, with the same metrics.json layout
("methods" holds one row). experiments/sweeps/stereo_tuning.toml spreads the grid over such runs.

Benchmarks (`--data PATH` of a Middlebury 2014/2021, Middlebury 2001/2003, KITTI 2012/2015 or ETH3D
two-view folder, its format detected or given with `--format`; research.datasets.stereo_benchmarks reads
it; `--gt-scale` overrides Middlebury 2001/2003's ground-truth scale table): runs drlab's default
(research.stereo.matching.DEFAULT_CONFIG, chosen on Middlebury 2001 tsukuba + venus and the Mitsuba tuning pairs),
the drlab configurations the default run chose on its Mitsuba tuning pairs (BENCHMARK_DRLAB: BT + SGM-4
soft-argmin, its best; ZNCC + SGM-4, its robust choice; SAD + SGM-4 soft-argmin, the best before BT;
census + SGM-8; nothing is tuned on the benchmark) and OpenCV StereoSGBM with standard
parameters (blockSize 3 and, as a second row, 5; P1 = 8 * cn * 3^2, P2 = 32 * cn * 3^2 for cn image channels, 3-way, uniqueness
10, speckle window 100 and range 32, disp12MaxDiff 1, preFilterCap 63) on every pair, over
disparities [0, D) with D the pair's ndisp (calib.txt) rounded up to a multiple of 16, or
`--max-disp` (KITTI's default 256). drlab matches the stored images through research.images'
normalisation (colour to grey, uint8 / 255); SGBM gets the stored 8-bit images (16-bit ones shifted
to 8 bits). Scores follow the benchmark's protocol (research.stereo.matching.protocol_metrics: Middlebury
bad-0.5/1/2/4 and avgerr on nonocc and all; KITTI D1-bg/fg/all on noc and occ; ETH3D bad-1/2 and
avgerr; Middlebury 2001/2003 bad-0.5/1/2/4, avgerr = EPE and D1 over every pixel with known ground
truth, as these sets come without occlusion masks, plus a per-pair table), at `--resolution` (full, half or quarter of the stored Middlebury/ETH3D files). Such a run
needs its own `--out` (the default results/stereo_depth holds the Mitsuba table) and writes table.md,
metrics.json and disparity_maps.png (the first pair); --smoke reads the first 2 pairs, --quick the first 5.

Three runs share this module (the Mitsuba tuning table, one configuration, and the benchmark
protocols of --data, whose run lives in research.stereo.benchmark), and some of their table code.
"""

from __future__ import annotations

import itertools
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from research.cli_common import integer_type, number_type
from research.experiment import Context, Experiment, rendered_cache_help
from research.results import finish_figure, image_panel, markdown_table
from research.stereo.benchmark import DEFAULT_NAME, run_benchmark

SCENES = ("objects", "cornell")
LUMA_709 = np.array([0.2126, 0.7152, 0.0722])  # research.stereo.matching.to_gray_u8's weights


def _stress_params() -> Any:
    from research.radiometry import Stress

    return Stress()  # research.radiometry's defaults: a consumer camera pair, chosen before any result


STRESS = _stress_params()
METRIC_KEYS = ("epe", "bad1", "bad2", "bad3", "d1", "abs_rel", "density")


@dataclass(frozen=True)
class Setup:
    res: int
    spp: int
    pairs: int
    dmax: int  # disparities [0, dmax); a multiple of 16 for OpenCV


def setup(quick: bool, smoke: bool = False) -> Setup:
    # Ground-truth disparities reach ~43 px at 256x256 (~22 px at 128x128) in both scenes.
    if smoke:
        return Setup(res=64, spp=4, pairs=2, dmax=16)
    return Setup(res=128, spp=16, pairs=3, dmax=32) if quick else Setup(res=256, spp=64, pairs=6, dmax=64)


# --------------------------------------------------------------------------- data


@dataclass
class Pair:
    scene: str
    name: str
    left: np.ndarray  # uint8 (H, W)
    right: np.ndarray
    gt: np.ndarray  # (H, W) disparity
    masks: dict[str, np.ndarray]
    depth: np.ndarray
    focal: float
    baseline: float
    left_rgb: np.ndarray
    condition: str = "clean"  # or "stressed" (research.radiometry)


CONDITIONS = ("clean", "stressed")


def stress_seed(seed: int, scene: str, pair: str) -> int:
    """The radiometric stress seed of one pair: fixed by the run's seed, the scene and the pair name."""
    return int(np.random.SeedSequence([seed, SCENES.index(scene), int(pair.split("_")[-1])]).generate_state(1)[0])


def load_pairs(ctx: Context, st: Setup, used: dict[str, Any]) -> list[Pair]:
    """Every stereo pair of every scene; `used` receives each dataset's provenance."""
    from research.datasets import DatasetConfig, ensure, load_stereo, provenance
    from research.io import linear_to_srgb
    from research.radiometry import stress_pair
    from research.stereo.matching import to_gray_u8

    pairs = []
    for scene in SCENES:
        cfg = DatasetConfig(scene, views=3, res=st.res, spp=st.spp, seed=ctx.seed, stereo=True,
                            stereo_pairs=st.pairs)
        suffix = "" if ctx.mode == "full" else "-" + ctx.mode
        path = ensure(cfg, ctx.data / f"stereo_depth-{scene}{suffix}", show_progress=ctx.progress)
        used[scene] = provenance(path)
        for p in load_stereo(path):
            has_gt = p.disparity > 0
            clean = Pair(scene, p.name, to_gray_u8(p.left), to_gray_u8(p.right), p.disparity,
                         {"noc": p.noc & has_gt, "all": p.mask & has_gt}, p.depth, p.left_camera.fx,
                         p.baseline, np.clip(linear_to_srgb(p.left[..., :3]), 0, 1))
            # The same luminance through two stressed cameras (research.radiometry): to_gray_u8 is its clean
            # encoding, so the two conditions differ only by the stress.
            lum_l, lum_r = (np.maximum(np.asarray(x, np.float64)[..., :3] @ LUMA_709, 0.0) for x in (p.left, p.right))
            left_s, right_s = stress_pair(lum_l, lum_r, stress_seed(ctx.seed, scene, p.name), STRESS)
            pairs += [clean, replace(clean, left=left_s, right=right_s, condition="stressed")]
    return pairs


# --------------------------------------------------------------------------- methods


@dataclass
class Method:
    name: str
    family: str  # "drlab" or "opencv"
    params: dict[str, Any]
    run: Callable[[Pair], tuple[np.ndarray, np.ndarray, float]]  # -> disparity, valid, seconds


# P1 of the tuning grid's middle, about one cost unit of each cost (research.stereo.matching: units).
P1_BASE = {"sad": 0.01, "zncc": 0.1, "census": 8.0, "bt": 0.01, "adcensus": 0.2, "corr": 0.01}


def drlab_grid(cost: str, aggregation: str) -> list[dict[str, Any]]:
    """Candidate parameters of one drlab cost x aggregation (research.stereo.matching.StereoConfig fields)."""
    windows = {"sad": [{"radius": r} for r in (1, 2, 3, 4)],
               "zncc": [{"radius": r, "zncc_eps": e} for r in (2, 3, 4, 5) for e in (1e-4, 1e-3)],
               "census": [{"census_radii": rr} for rr in ((2, 3), (3, 4))],
               "bt": [{"radius": r} for r in (1, 2, 3)],
               "adcensus": [{"radius": r} for r in (1, 2)],
               "corr": [{"radius": r} for r in (2, 3)]}[cost]
    if aggregation == "none":
        return windows
    p1_base = P1_BASE[cost]
    return [{**w, "p1": p1_base * f, "p2": p1_base * f * ratio}
            for w in windows for f in (0.5, 1.0, 2.0, 4.0) for ratio in (4.0, 8.0, 16.0)]


def opencv_methods(dmax: int) -> list[Method]:
    import cv2

    def sgbm(block: int, mode: int, p2_mult: int, uniqueness: int) -> Callable:
        matcher = cv2.StereoSGBM_create(minDisparity=0, numDisparities=dmax, blockSize=block, P1=8 * block * block,
                                        P2=p2_mult * block * block, disp12MaxDiff=1, uniquenessRatio=uniqueness,
                                        speckleWindowSize=100, speckleRange=2, mode=mode)
        return lambda p: _run_cv(matcher, p)

    def bm(block: int, uniqueness: int) -> Callable:
        matcher = cv2.StereoBM_create(numDisparities=dmax, blockSize=block)
        matcher.setUniquenessRatio(uniqueness)
        matcher.setTextureThreshold(10)
        matcher.setSpeckleWindowSize(100)
        matcher.setSpeckleRange(32)
        matcher.setDisp12MaxDiff(1)
        return lambda p: _run_cv(matcher, p)

    modes = {"SGBM": cv2.STEREO_SGBM_MODE_SGBM, "HH": cv2.STEREO_SGBM_MODE_HH, "3WAY": cv2.STEREO_SGBM_MODE_SGBM_3WAY}
    out = [Method("OpenCV StereoSGBM", "opencv", {"blockSize": b, "mode": m, "P1": 8 * b * b, "P2": q * b * b,
                                                  "uniquenessRatio": u}, sgbm(b, modes[m], q, u))
           for b, m, q, u in itertools.product((3, 5, 7, 9), modes, (32, 96), (5, 10))]
    out += [Method("OpenCV StereoBM", "opencv", {"blockSize": b, "uniquenessRatio": u}, bm(b, u))
            for b, u in itertools.product((5, 9, 15, 21), (5, 15))]
    return out


def _run_cv(matcher: Any, p: Pair) -> tuple[np.ndarray, np.ndarray, float]:
    t0 = time.perf_counter()
    raw = matcher.compute(p.left, p.right)
    seconds = time.perf_counter() - t0
    disp = raw.astype(np.float32) / 16.0  # fixed point, 4 fractional bits; invalid = (minDisparity - 1) * 16
    return disp, disp >= 0, seconds


# --------------------------------------------------------------------------- scoring


def score(disp: np.ndarray, valid: np.ndarray, p: Pair) -> dict[str, dict[str, float]]:
    from research.stereo.matching import evaluate

    return evaluate(disp, valid, p.gt, p.masks, p.depth, p.focal, p.baseline)


def pooled(rows: list[dict[str, dict[str, float]]]) -> dict[str, float]:
    """Pixel-weighted means over pairs: noc metrics, plus d1_all."""
    w = np.array([r["noc"]["pixels"] for r in rows], dtype=np.float64)
    out = {k: float(np.sum(w * [r["noc"][k] for r in rows]) / w.sum()) for k in METRIC_KEYS if k != "abs_rel"}
    wd = w * np.array([r["noc"]["depth_valid_fraction"] for r in rows])
    out["abs_rel"] = float(np.sum(wd * [np.nan_to_num(r["noc"]["abs_rel"]) for r in rows]) / max(wd.sum(), 1.0))
    wa = np.array([r["all"]["pixels"] for r in rows], dtype=np.float64)
    out["d1_all"] = float(np.sum(wa * [r["all"]["d1"] for r in rows]) / wa.sum())
    out["pixels"] = int(w.sum())
    return out


def tune(candidates: list[Method], tuning: list[Pair], desc: str, ctx: Context) -> tuple[Method, list[dict]]:
    """The candidate with the lowest mean D1 (noc) on the tuning pairs, and every candidate's score.

    A smoke run tries only the first and the last candidate of each grid.
    """
    if ctx.smoke:
        candidates = candidates[:1] + candidates[1:][-1:]
    scores = []
    for m in ctx.tqdm(candidates, desc=desc, leave=False):
        d1 = float(np.mean([score(*m.run(p)[:2], p)["noc"]["d1"] for p in tuning]))
        scores.append({"params": m.params, "tuning_d1": d1})
    best = int(np.argmin([s["tuning_d1"] for s in scores]))
    return candidates[best], scores


def drlab_candidates(cost: str, aggregation: str, dmax: int, device: str, cache: dict) -> list[Method]:
    """drlab methods for one cost x aggregation; the cost volume of each pair is computed once and shared."""
    from research.stereo.matching import StereoConfig, cost_volume, disparity_from_cost, uses_compact

    out = []
    for params in drlab_grid(cost, aggregation):
        cfg = StereoConfig(cost=cost, aggregation=aggregation, **params)

        def run_tuning(p: Pair, cfg: StereoConfig = cfg) -> tuple[np.ndarray, np.ndarray, float]:
            key = (p.scene, p.name, p.condition, cfg.cost, cfg.radius, cfg.census_radii, cfg.zncc_eps,
                   uses_compact(cfg, *p.left.shape, dmax))
            if key not in cache:
                cache[key] = cost_volume(p.left / 255.0, p.right / 255.0, 0, dmax, cfg, device)
            r = disparity_from_cost(cache[key], 0, cfg, device)
            return r.disparity, r.valid, r.timings["total_s"]

        out.append(Method(cfg.label, "drlab", cfg.to_dict(), run_tuning))
    return out


def drlab_method(cfg: Any, dmax: int, device: str) -> Method:
    from research.stereo.matching import match

    def run(p: Pair) -> tuple[np.ndarray, np.ndarray, float]:
        r = match(p.left / 255.0, p.right / 255.0, 0, dmax, cfg, device)
        return r.disparity, r.valid, r.timings["total_s"]

    return Method(cfg.label, "drlab", cfg.to_dict(), run)


# --------------------------------------------------------------------------- figures


def figures(best: dict[str, Method], pairs: list[Pair], results: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research.stereo.matching import fill_invalid

    shown = [next(p for p in pairs if p.scene == s) for s in SCENES]
    names = list(best)
    cols = ["left image", "ground truth"] + [f"{n}" for n in names] + [f"|error| {n}" for n in names]
    fig, axes = plt.subplots(len(shown), len(cols), figsize=(2.6 * len(cols), 2.7 * len(shown)), squeeze=False)
    for row, p in enumerate(shown):
        vmax = float(p.gt.max())
        gt = np.ma.masked_where(~p.masks["all"], p.gt)
        imgs: list[tuple[Any, dict]] = [(p.left_rgb, {}), (gt, {"vmin": 0, "vmax": vmax})]
        errs = []
        for n in names:
            d, v, _ = best[n].run(p)
            dense = fill_invalid(d, v)
            imgs.append((dense, {"vmin": 0, "vmax": vmax}))
            err = np.abs(dense - p.gt)
            errs.append((np.ma.masked_where(~p.masks["all"], err), {"vmin": 0, "vmax": 5, "cmap": "inferno"}))
        for col, (img, kw) in enumerate(imgs + errs):
            image_panel(fig, axes[row, col], img, cols[col] if row == 0 else None, colorbar=col >= 1, fontsize=8,
                        **kw)
        axes[row, 0].set_ylabel(f"{p.scene} {p.name}")
    fig.suptitle("Disparity (px) after KITTI fill; error clipped at 5 px; masked: no ground truth", fontsize=9)
    finish_figure(fig, out / "disparity_maps.png")

    labels = list(results)
    fig, ax = plt.subplots(figsize=(max(8, 0.55 * len(labels)), 4))
    x = np.arange(len(labels))
    for j, scene in enumerate(SCENES):
        ax.bar(x + (j - 0.5) * 0.4, [results[m]["scenes"][scene]["d1"] for m in labels], 0.4, label=scene)
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("D1 (noc), evaluation pairs")
    ax.legend()
    finish_figure(fig, out / "d1_by_method.png")


# --------------------------------------------------------------------------- evaluation

POOLED = {"clean": "pooled", "stressed": "pooled_stressed"}
SCENES_KEY = {"clean": "scenes", "stressed": "scenes_stressed"}
HEADERS = ["method", "EPE px", "bad-1", "bad-2", "bad-3", "D1 noc", "D1 all", "depth abs-rel", "density", "time ms"]
STRESS_NOTE = (f"each camera of a pair draws its own exposure (+-{STRESS.exposure_stops:g} stops), black level "
               f"(+-{STRESS.offset:g}), vignetting (corner falloff up to {STRESS.vignetting:g}), blur (sigma up to "
               f"{STRESS.blur_sigma:g} px) and Poisson-Gaussian noise (shot {STRESS.shot_noise:g}, read "
               f"{STRESS.read_noise:g}) before sRGB {STRESS.bits}-bit quantisation (research.radiometry, seeded by "
               "the run's seed, scene and pair)")


def evaluate_method(m: Method, evaluation: list[Pair], tuning_d1: float, ctx: Context) -> dict[str, Any]:
    """One method on every evaluation pair: pooled scores per condition ("pooled" is clean), per scene, per pair."""
    rows, seconds = [], []
    for p in ctx.tqdm(evaluation, desc=f"evaluate {m.name}", leave=False):
        d, v, s = m.run(p)
        rows.append(score(d, v, p))
        seconds.append(s)
    out: dict[str, Any] = {"family": m.family, "params": m.params, "tuning_d1": tuning_d1}
    for c in CONDITIONS:
        sel = [(r, p) for r, p in zip(rows, evaluation) if p.condition == c]
        out[POOLED[c]] = pooled([r for r, _ in sel])
        out[SCENES_KEY[c]] = {s: pooled([r for r, p in sel if p.scene == s]) for s in SCENES}
    out["time_s_mean"] = float(np.mean([t for t, p in zip(seconds, evaluation) if p.condition == "clean"]))
    out["pairs"] = {f"{p.condition}/{p.scene}/{p.name}": {**r, "seconds": t}
                    for r, p, t in zip(rows, evaluation, seconds)}
    return out


def _row(name: str, r: dict[str, Any], key: str) -> list[Any]:
    q = r[key]
    return [name, f"{q['epe']:.3f}", f"{q['bad1']:.4f}", f"{q['bad2']:.4f}", f"{q['bad3']:.4f}", f"{q['d1']:.4f}",
            f"{q['d1_all']:.4f}", f"{q['abs_rel']:.4f}", f"{q['density']:.3f}", f"{1000 * r['time_s_mean']:.1f}"]


# --------------------------------------------------------------------------- main


def run(ctx: Context) -> int:
    import cv2

    from kernels.launch import default_threads
    from research.stereo.matching import AGGREGATIONS, COSTS, DEFAULT_CONFIG, StereoConfig

    fmt = benchmark_format(ctx)
    if fmt is not None:
        return run_benchmark(ctx, fmt)
    single = single_config(ctx.args)
    load_start = os.getloadavg()[0]
    st = setup(ctx.quick, ctx.smoke)
    datasets: dict[str, Any] = {}
    pairs = load_pairs(ctx, st, datasets)
    # Every choice is made on the clean tuning pairs; the stressed pairs are never used to choose anything.
    tuning = [p for p in pairs if p.name == "p_000" and p.condition == "clean"]
    evaluation = [p for p in pairs if p.name != "p_000"]
    if single is not None:
        return run_single(ctx, single, st, tuning, evaluation, datasets)

    # ---- tuning: one configuration per drlab cost x aggregation, one per OpenCV matcher
    chosen: dict[str, Method] = {}
    tuning_log: dict[str, Any] = {}
    tuning_d1: dict[str, float] = {}

    def keep(m: Method, log: list[dict]) -> None:
        chosen[m.name] = m
        tuning_log[m.name] = {"chosen": m.params, "candidates": log}
        tuning_d1[m.name] = min(c["tuning_d1"] for c in log)

    for cost in COSTS:
        cache: dict = {}  # cost volumes of the tuning pairs, shared by this cost's candidates
        for agg in AGGREGATIONS:
            m, log = tune(drlab_candidates(cost, agg, st.dmax, ctx.device, cache), tuning, f"tune {cost}+{agg}", ctx)
            keep(drlab_method(StereoConfig(**m.params), st.dmax, ctx.device), log)
        del cache
    best_sgm = min((k for k in chosen if "SGM" in k), key=lambda k: tuning_d1[k])
    base = chosen[best_sgm].params
    soft = [drlab_method(StereoConfig(**{**base, "disparity": "soft_argmin", "temperature": base["p1"] * f}),
                         st.dmax, ctx.device) for f in (0.25, 1.0, 4.0)]
    keep(*tune(soft, tuning, "tune soft-argmin", ctx))
    for name in ("OpenCV StereoSGBM", "OpenCV StereoBM"):
        keep(*tune([c for c in opencv_methods(st.dmax) if c.name == name], tuning, f"tune {name}", ctx))
    best_drlab = min((k for k in chosen if chosen[k].family == "drlab"), key=lambda k: tuning_d1[k])
    # drlab's default (research.stereo.matching.DEFAULT_CONFIG), fixed, not tuned here: its own choice was made on
    # Middlebury 2001 tsukuba + venus and these tuning pairs (research.stereo.matching's docstring).
    default = drlab_method(DEFAULT_CONFIG, st.dmax, ctx.device)
    default.name = DEFAULT_NAME
    default.family = "drlab-default"
    chosen[DEFAULT_NAME] = default
    tuning_d1[DEFAULT_NAME] = float(np.mean([score(*default.run(p)[:2], p)["noc"]["d1"] for p in tuning]))
    tuning_log[DEFAULT_NAME] = {"chosen": default.params, "candidates": [], "fixed": True}
    # The robust choice: among the chosen configurations, the lowest mean of the clean tuning D1 and the
    # D1 on the stressed tuning pairs (the same held-out p_000 pairs, stressed; never scored below).
    stressed_tuning = [p for p in pairs if p.name == "p_000" and p.condition == "stressed"]
    tuning_d1_stressed = {name: float(np.mean([score(*m.run(p)[:2], p)["noc"]["d1"] for p in stressed_tuning]))
                          for name, m in chosen.items()}
    robust_drlab = min((k for k in chosen if chosen[k].family == "drlab"),
                       key=lambda k: 0.5 * (tuning_d1[k] + tuning_d1_stressed[k]))

    # ---- evaluation, clean and stressed
    results = {name: evaluate_method(m, evaluation, tuning_d1[name], ctx) for name, m in chosen.items()}
    for name in results:
        results[name]["tuning_d1_stressed"] = tuning_d1_stressed[name]
    sgbm = results["OpenCV StereoSGBM"]
    best = results[best_drlab]
    dflt = results[DEFAULT_NAME]
    robust = results[robust_drlab]
    threads = default_threads()
    load_end = os.getloadavg()[0]
    clean_eval = [p for p in evaluation if p.condition == "clean"]
    gt_max = max(float(p.gt[p.masks["all"]].max()) for p in clean_eval)
    d1_note = (f" Ground-truth disparities reach at most {gt_max:.1f} px; below 60 px, 5 % of d_gt is under 3 px, "
               "so D1 equals bad-3 here." if gt_max < 60.0 else "")
    verdicts = {c: "beats" if best[POOLED[c]]["d1"] < sgbm[POOLED[c]]["d1"] else "does NOT beat" for c in CONDITIONS}
    table = (
        f"Scenes {', '.join(SCENES)} at {st.res}x{st.res}, {st.spp} spp, disparities [0, {st.dmax}); "
        f"{len(clean_eval)} evaluation pairs, each clean and stressed. **Which data chose the parameters**: every "
        f"method's parameters (and the best drlab configuration) by mean D1 noc on the clean tuning pairs, p_000 "
        f"of each scene, which are never scored; the robust choice below also by those pairs stressed; no "
        f"stressed evaluation pair chooses anything. Stressed: "
        f"{STRESS_NOTE}. Metrics over non-occluded ground truth (noc) after KITTI fill, pooled over pairs; D1 all "
        f"counts occluded pixels too. Time: wall per clean pair on this machine, drlab with {threads} CPU threads "
        f"(device {ctx.device}), OpenCV with {cv2.getNumThreads()} threads; the machine is shared, 1-minute "
        f"load average {load_start:.1f} at the start and {load_end:.1f} at the end.{d1_note}\n\n"
        f"**Goal**: the best drlab configuration chosen on the tuning pairs, **{best_drlab}**, has D1 noc "
        f"{best['pooled']['d1']:.4f} against OpenCV SGBM's {sgbm['pooled']['d1']:.4f} on clean pairs: it "
        f"{verdicts['clean']} SGBM (D1 all {best['pooled']['d1_all']:.4f} vs {sgbm['pooled']['d1_all']:.4f}); on "
        f"stressed pairs {best['pooled_stressed']['d1']:.4f} against {sgbm['pooled_stressed']['d1']:.4f}: it "
        f"{verdicts['stressed']} SGBM; at {1000 * best['time_s_mean']:.1f} ms per pair against SGBM's "
        f"{1000 * sgbm['time_s_mean']:.1f} ms.\n\n"
        f"**drlab's default** ({DEFAULT_NAME}: research.stereo.matching.DEFAULT_CONFIG, not tuned in this run; chosen on "
        f"Middlebury 2001 tsukuba + venus and the tuning pairs p_000, clean and stressed) has D1 noc "
        f"{dflt['pooled']['d1']:.4f} clean and {dflt['pooled_stressed']['d1']:.4f} stressed, against SGBM's "
        f"{sgbm['pooled']['d1']:.4f} and {sgbm['pooled_stressed']['d1']:.4f}, at {1000 * dflt['time_s_mean']:.1f} ms "
        "per pair.\n\n"
        f"**Robust choice**: chosen by the mean of the clean and the stressed tuning D1 (p_000 of each scene, "
        f"clean and stressed; no evaluation pair), **{robust_drlab}** has D1 noc {robust['pooled']['d1']:.4f} "
        f"clean and {robust['pooled_stressed']['d1']:.4f} stressed, against SGBM's {sgbm['pooled']['d1']:.4f} and "
        f"{sgbm['pooled_stressed']['d1']:.4f}.\n\n"
        + "Clean pairs:\n\n" + markdown_table(HEADERS, [_row(n, results[n], "pooled") for n in results])
        + "\nStressed pairs (the same pairs through research.radiometry):\n\n"
        + markdown_table(HEADERS, [_row(n, results[n], "pooled_stressed") for n in results])
        + "\nPer scene (evaluation pairs), D1 noc / EPE, clean | stressed:\n\n"
        + markdown_table(["method"] + [f"{s} {c}" for c in CONDITIONS for s in SCENES],
                         [[n] + [f"{results[n][SCENES_KEY[c]][s]['d1']:.4f} / {results[n][SCENES_KEY[c]][s]['epe']:.2f}"
                                 for c in CONDITIONS for s in SCENES] for n in results])
        + "\nChosen parameters (by D1 noc on the clean tuning pairs), and the D1 of that choice on the stressed "
          "tuning pairs:\n\n"
        + markdown_table(["method", "tuning D1", "stressed tuning D1", "parameters"],
                         [[n, f"{tuning_d1[n]:.4f}", f"{tuning_d1_stressed[n]:.4f}", _short(results[n]["params"])]
                          for n in results])
    )
    figures({best_drlab: chosen[best_drlab], "OpenCV StereoSGBM": chosen["OpenCV StereoSGBM"]}, clean_eval, results,
            ctx.out)
    config = {"scenes": list(SCENES), **asdict(st), "tuning_pairs": [f"{p.scene}/{p.name}"
              for p in tuning], "stressed_tuning_pairs": [f"{p.scene}/{p.name}" for p in stressed_tuning],
              "evaluation_pairs": [f"{p.scene}/{p.name}" for p in clean_eval],
              "conditions": list(CONDITIONS), "stress": STRESS.to_dict(),
              "drlab_threads": threads, "opencv_threads": cv2.getNumThreads(), "opencv": cv2.__version__,
              "load_average_1min": [load_start, load_end]}
    ctx.write_results(config=config, table_md=table,
                      metrics={"best_drlab": best_drlab, "goal_met": bool(best["pooled"]["d1"] < sgbm["pooled"]["d1"]),
                               "goal_met_stressed": bool(best["pooled_stressed"]["d1"] < sgbm["pooled_stressed"]["d1"]),
                               "robust_drlab": robust_drlab, "default_drlab": DEFAULT_NAME,
                               "methods": results, "tuning": tuning_log, "datasets": datasets})
    return 0


# --------------------------------------------------------------------------- one configuration

_SINGLE_OPTIONS = ("aggregation", "radius", "p1", "p2", "zncc_eps")


def single_config(args: Any) -> Any:
    """The one StereoConfig that --cost (and its companions) name, or None for the tuning run."""
    from research.stereo.matching import StereoConfig

    given = [name for name in _SINGLE_OPTIONS if getattr(args, name) is not None]
    if args.cost is None:
        if given:
            raise ValueError(f"--{given[0].replace('_', '-')}: applies with --cost only (one configuration)")
        return None
    agg = args.aggregation or "sgm8"
    radius = 2 if args.radius is None else args.radius
    params: dict[str, Any] = {"cost": args.cost, "aggregation": agg}
    if args.cost == "census":
        from kernels.stereo import CENSUS_MAX_BITS

        bits = (2 * radius + 1) * (2 * radius + 3) - 1
        if bits > CENSUS_MAX_BITS:
            raise ValueError(f"--radius: --cost census --radius {radius} is a {2 * radius + 1}x{2 * radius + 3} window "
                             f"of {bits} bits; expected at most {CENSUS_MAX_BITS} (radius <= 3)")
        params["census_radii"] = (radius, radius + 1)
    else:
        params["radius"] = radius
    if args.zncc_eps is not None:
        if args.cost != "zncc":
            raise ValueError(f"--zncc-eps: applies to --cost zncc only, got --cost {args.cost}")
        params["zncc_eps"] = args.zncc_eps
    if agg == "none" and (args.p1 is not None or args.p2 is not None):
        raise ValueError("--p1, --p2: apply to an SGM aggregation, got --aggregation none")
    p1 = P1_BASE[args.cost] if args.p1 is None else args.p1
    p2 = 8.0 * p1 if args.p2 is None else args.p2
    if p2 < p1:
        raise ValueError(f"--p2: expected P2 >= P1 = {p1:g}, got {p2:g}")
    if agg != "none":
        params.update(p1=p1, p2=p2)
    try:
        return StereoConfig(**params)
    except ValueError as e:  # e.g. a census window over 64 bits
        raise ValueError(f"--cost {args.cost} --radius {radius}: {e}") from None


def run_single(ctx: Context, cfg: Any, st: Setup, tuning: list[Pair], evaluation: list[Pair],
               datasets: dict[str, Any]) -> int:
    """Score one configuration on the tuning pairs (tuning_d1, what a sweep picks by) and the evaluation pairs."""
    m = drlab_method(cfg, st.dmax, ctx.device)
    tuning_d1 = float(np.mean([score(*m.run(p)[:2], p)["noc"]["d1"] for p in tuning]))
    r = evaluate_method(m, evaluation, tuning_d1, ctx)
    table = (f"One configuration (no tuning): **{m.name}** ({_short(m.params)}), scenes {', '.join(SCENES)} at "
             f"{st.res}x{st.res}, {st.spp} spp, disparities [0, {st.dmax}). Tuning D1: on the clean pairs p_000 of "
             "each scene (what a sweep over configurations chooses by); the rest on the evaluation pairs, noc "
             f"after KITTI fill, pooled over pairs, clean and stressed ({STRESS_NOTE}).\n\n"
             + markdown_table(["method", "condition", "tuning D1", "EPE px", "bad-2", "D1 noc", "D1 all", "time ms"],
                              [[m.name, c, f"{tuning_d1:.4f}", f"{r[POOLED[c]]['epe']:.3f}",
                                f"{r[POOLED[c]]['bad2']:.4f}", f"{r[POOLED[c]]['d1']:.4f}",
                                f"{r[POOLED[c]]['d1_all']:.4f}", f"{1000 * r['time_s_mean']:.1f}"]
                               for c in CONDITIONS]))
    config = {"scenes": list(SCENES), **asdict(st), "single": cfg.to_dict(),
              "tuning_pairs": [f"{p.scene}/{p.name}" for p in tuning], "stress": STRESS.to_dict(),
              "evaluation_pairs": [f"{p.scene}/{p.name}" for p in evaluation if p.condition == "clean"]}
    ctx.write_results(config=config, table_md=table,
                      metrics={"best_drlab": m.name, "methods": {m.name: r}, "datasets": datasets})
    return 0


# --------------------------------------------------------------------------- benchmarks

def benchmark_format(ctx: Context) -> str | None:
    """The benchmark format of --data (None: the Mitsuba run, --data is the dataset cache root)."""
    from research import registry
    from research.datasets.stereo_benchmarks import detect_format

    args = ctx.args
    # Without --data (the default cache root) this is the Mitsuba run whatever that folder holds.
    explicit = ctx.data.absolute() != registry.default_data_dir().absolute()
    fmt = args.format or (detect_format(ctx.data) if explicit else None)
    if fmt is None:
        if args.resolution != "full" or args.max_disp is not None or args.gt_scale is not None:
            raise ValueError("--resolution, --max-disp, --gt-scale: apply to a benchmark --data folder only, and "
                             f"{ctx.data} is not one")
        return None
    if args.gt_scale is not None and fmt != "middlebury2003":
        raise ValueError(f"--gt-scale: applies to --format middlebury2003 only, got {fmt}")
    if fmt == "middlebury2003" and args.resolution != "full":
        raise ValueError(f"--resolution: Middlebury 2001/2003 pairs are evaluated at their stored size only, got "
                         f"{args.resolution!r}")
    given = [name for name in ("cost", *_SINGLE_OPTIONS) if getattr(args, name, None) is not None]
    if given:
        raise ValueError(f"--{given[0].replace('_', '-')}: applies to the Mitsuba run only, not to a benchmark "
                         f"--data folder")
    if ctx.final_out == registry.default_out(ctx.name).absolute():
        raise ValueError(f"--out: a benchmark run needs its own results folder; the default {ctx.final_out} "
                         "holds the Mitsuba table")
    return fmt


def _short(params: dict[str, Any]) -> str:
    keep = {"radius", "census_radii", "zncc_eps", "p1", "p2", "temperature", "blockSize", "mode", "P1", "P2",
            "uniquenessRatio"}
    skip_radius = params.get("cost") == "census"
    items = [(k, v) for k, v in params.items() if k in keep and not (k == "radius" and skip_radius)
             and not (k == "census_radii" and params.get("cost") != "census")
             and not (k == "zncc_eps" and params.get("cost") != "zncc")
             and not (k in ("p1", "p2") and params.get("aggregation") == "none")
             and not (k == "temperature" and params.get("disparity") != "soft_argmin")]
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in items)


def add_options(p: Any) -> None:
    from research.datasets.stereo_benchmarks import FORMATS, RESOLUTIONS
    from research.stereo.matching import AGGREGATIONS, COSTS

    p.add_argument("--cost", choices=COSTS, default=None,
                   help="evaluate ONE drlab configuration instead of tuning the grid (a sweep spreads the grid "
                        "over tasks with this and the options below): this cost, scored on the tuning and the "
                        "evaluation pairs, without OpenCV")
    p.add_argument("--aggregation", choices=AGGREGATIONS, default=None,
                   help="with --cost: the aggregation (default sgm8)")
    p.add_argument("--radius", type=integer_type(0), default=None,
                   help="with --cost: the window radius R of sad/zncc/bt/adcensus/corr; census uses radii (R, R + 1), a "
                        "(2R+1) x (2R+3) window, as the tuning grid (default 2)")
    p.add_argument("--p1", type=number_type(0), default=None,
                   help="with --cost and SGM: P1 in the cost's units (research.stereo.matching: [0, 1] intensity for "
                        "sad/bt/corr, bits for census, 1 - correlation for zncc, fractions of one squashed term "
                        "for adcensus); default: the grid's base "
                        f"({', '.join(f'{k} {v:g}' for k, v in P1_BASE.items())})")
    p.add_argument("--p2", type=number_type(0), default=None,
                   help="with --cost and SGM: P2 >= P1 (default 8 P1)")
    p.add_argument("--zncc-eps", type=number_type(0), default=None,
                   help="with --cost zncc: the variance floor (default 1e-4)")

    p.add_argument("--format", choices=FORMATS, default=None,
                   help="the benchmark layout of --data (default: detected from its files)")
    p.add_argument("--resolution", choices=tuple(RESOLUTIONS), default="full",
                   help="Middlebury/ETH3D: evaluate at this fraction of the stored files' size (default: full)")
    p.add_argument("--gt-scale", type=number_type(0, low_open=True), default=None,
                   help="--format middlebury2003: the ground-truth scale (disparity = stored value / scale) for "
                        "every scene, overriding the table of the known scenes (tsukuba 16, venus 8, teddy 4, "
                        "cones 4); required for any other scene")
    p.add_argument("--max-disp", type=_max_disp, default=None,
                   help="benchmarks: disparity range [0, N), N a multiple of 16 (default: each pair's ndisp "
                        "rounded up to 16; KITTI 256)")


def _max_disp(value: str) -> int:
    import argparse

    try:
        n = int(value)
    except ValueError:
        n = -1
    if n < 16 or n % 16:
        raise argparse.ArgumentTypeError(f"expected a positive multiple of 16, got {value!r}")
    return n


main = Experiment("stereo_depth", __doc__, run, add_options,
                  data_help=rendered_cache_help("stereo", "stereo_depth") + "; or a Middlebury, KITTI or ETH3D "
                  "stereo folder, which the run then evaluates with that benchmark's protocol",
                  seed_help="dataset seed (camera poses, render noise)",
                  sizes="Quick: 128x128 pairs, 16 spp, 3 pairs per scene (a few minutes); smoke: 64x64, 4 spp, "
                        "2 pairs per scene, two candidates per tuning grid.").script(__name__)
