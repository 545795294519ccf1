#!/usr/bin/env python3
"""Weight-free RAFT-style optical flow from correlation lookups, on Mitsuba flow pairs.

RAFT's correlation machinery (kernels.corr: all-pairs volume, 2x2-pooled
pyramid, radius-r lookups) drives a fixed, weight-free update
(research.flow.raft.CorrFlow): normalised multi-scale colour patches as
features at stride 4, and 12 lookups, coarse to fine, each turned into a
soft-argmax step around its window's peak. No learned weights exist here, so
this measures what the correlation machinery alone delivers.

Data: camera-path flow sequences rendered by Mitsuba (research.datasets, scenes
objects, spheres and cornell at 256x256, camera azimuth step 4 degrees), frame
k -> k+1, evaluated on non-occluded surface pixels (the datasets' `valid`).

Reported:
  * EPE (px) and F1-all (KITTI: % of pixels with EPE > 3 px and > 5% of |gt|)
    for the coarse-to-fine correlation flow (research.flow.coarse_to_fine, "C2F": normalised-patch
    lookups with warping between image-pyramid levels and a TV-L1 step, its defaults
    chosen on held-out data: the photograph's tuning split and Mitsuba pairs rendered
    with seed 7), the RAFT-style CorrFlow (levels 4,
    radius 4), pyramidal Lucas-Kanade (kernels.lucas_kanade), OpenCV's Farneback and
    DIS (medium preset) and zero flow;
  * the same methods on clean and radiometrically stressed versions of every pair
    (research.radiometry: per-frame exposure/gain, black level, vignetting, blur,
    noise, 8-bit sRGB; the stress seed is 1000 seed + pair index; the clean pair is
    the same 8-bit sRGB encoding without the stress);
  * the same methods on a real photograph warped by known smooth flows
    (research.flow.texture: matplotlib's grace_hopper.jpg, evaluation split, median
    motion 4 px; smoke: a 96x128 crop, one flow);
  * the RAFT-style CorrFlow ablation levels {1,2,3,4} x radius {1,2,3,4}, as in
    RAFT's ablations (`--levels L` and/or `--radius R` evaluate only those cells:
    one cell per run lets a sweep spread the grid over tasks,
    experiments/sweeps/raft_ablation.toml; metrics.json's "cell" holds the
    headline cell's pooled EPE and F1-all);
  * memory and time of the dense pyramid lookup against the on-the-fly one
    (which never stores the volume), and the largest difference between the
    flows they produce.

Writes results/raft_flow/{table.md, metrics.json, flow_<scene>.png, ablation.png}.

Benchmarks: `--data PATH` naming an MPI-Sintel, KITTI 2012/2015 flow or Middlebury flow training
folder (detected from its layout, or named by `--format sintel|kitti|middlebury`; `--pass
clean|final` picks Sintel's pass, clean by default) runs the headline CorrFlow and the same baselines
on every pair of it (quick: the first pair of each sequence; smoke: the first pair only) and writes
that benchmark's protocol (research.flow.metrics): Sintel EPE all / matched / unmatched, KITTI Fl-all
and EPE on noc and occ (with KITTI 2015's obj_map also Fl-bg and Fl-fg), Middlebury EPE and angular
error per sequence. The table names the dataset, the protocol and the pass. CorrFlow keeps the dense
correlation pyramid only while it fits in MEMORY_BUDGET_MIB; above it, it uses the on-the-fly lookup
(the same flow to float rounding), and the table says which ran. Without such a folder, --data is the cache root above and nothing changes.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

from research.experiment import Context, Experiment, rendered_cache_help
from research.results import markdown_table, save_figure

SCENES = ("objects", "spheres", "cornell")
LEVELS = (1, 2, 3, 4)
RADII = (1, 2, 3, 4)
STRIDE = 4
HEADLINE = (4, 4)  # levels, radius
RES, SPP, STEP_DEG = 256, 32, 4.0
SMOKE_RES, SMOKE_SPP = 128, 4  # 128: the LK baseline's 4 levels need a 9-px window at the coarsest
MEMORY_BUDGET_MIB = 1024  # benchmarks: the dense pyramid above this, the on-the-fly lookup instead
FORMATS = ("sintel", "kitti", "middlebury")
PASSES = ("clean", "final")


def _cell_value(name: str, allowed: tuple[int, ...]):
    def parse(text: str) -> int:
        import argparse

        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected one of {', '.join(map(str, allowed))}, got {text!r}")
        if value not in allowed:
            raise argparse.ArgumentTypeError(f"expected one of {', '.join(map(str, allowed))}, got {value}")
        return value

    parse.__name__ = name
    return parse


def add_options(p) -> None:
    p.add_argument("--levels", type=_cell_value("levels", LEVELS), default=None,
                   help="evaluate only this pyramid depth L of the RAFT-style ablation (one of 1-4; default: all)")
    p.add_argument("--radius", type=_cell_value("radius", RADII), default=None,
                   help="evaluate only this lookup radius r of the RAFT-style ablation (one of 1-4; default: all)")
    p.add_argument("--format", choices=FORMATS, default=None,
                   help="the benchmark layout --data holds (default: detected from the folder; without one, --data "
                        "is the cache root of the rendered datasets)")
    p.add_argument("--pass", dest="pass_", choices=PASSES, default=None,
                   help="MPI-Sintel's rendering pass (default: clean); Sintel only")


def datasets(quick: bool, seed: int, data: Path, smoke: bool = False) -> dict[str, Path]:
    from research.datasets import DatasetConfig, ensure

    scenes = SCENES[:1] if quick or smoke else SCENES
    frames = 2 if smoke else 3 if quick else 4
    res, spp = (SMOKE_RES, SMOKE_SPP) if smoke else (RES, SPP)
    suffix = "-smoke" if smoke else "-quick" if quick else ""
    out = {}
    for scene in scenes:
        cfg = DatasetConfig(scene, views=3, res=res, spp=spp, seed=seed, flow=True, flow_frames=frames,
                            flow_step_deg=STEP_DEG)
        out[scene] = ensure(cfg, data / f"raft_flow-{scene}{suffix}", show_progress=False)
    return out


def _unit(rgb: np.ndarray) -> np.ndarray:
    """Colour in [0, 1] as float64 (research.images' unit rule: uint8 / 255, floats kept)."""
    from research.images import to_unit

    return np.asarray(to_unit(rgb, "rgb"), dtype=np.float64)


C2F_NAME = "C2F correlation flow (default)"
RAFT_NAME = "CorrFlow (L={}, r={})"


def c2f(rgb1: np.ndarray, rgb2: np.ndarray, device: str) -> tuple[np.ndarray, float]:
    """research.flow.coarse_to_fine's coarse-to-fine flow at its defaults, and its seconds."""
    from research.flow.coarse_to_fine import coarse_to_fine_flow

    t0 = time.perf_counter()
    flow = coarse_to_fine_flow(rgb1, rgb2, device=device)
    return flow, time.perf_counter() - t0


def every_method(rgb1: np.ndarray, rgb2: np.ndarray, device: str) -> dict[str, tuple[np.ndarray, float]]:
    """C2F, the RAFT-style CorrFlow at the headline setting and the baselines: flow and seconds each."""
    from research.flow.raft import CorrFlow, CorrFlowConfig

    out = {C2F_NAME: c2f(rgb1, rgb2, device)}
    t0 = time.perf_counter()
    cf = CorrFlow(rgb1, rgb2, stride=STRIDE, max_levels=HEADLINE[0], device=device)
    flow = cf.estimate(CorrFlowConfig(levels=HEADLINE[0], radius=HEADLINE[1]))
    out[RAFT_NAME.format(*HEADLINE)] = (flow, time.perf_counter() - t0)
    out.update(baselines(rgb1, rgb2, device))
    return out


def baselines(rgb1: np.ndarray, rgb2: np.ndarray, device: str) -> dict[str, tuple[np.ndarray, float]]:
    """Flow (H, W, 2) and seconds of each baseline (colour images, uint8 or float in [0, 1])."""
    import cv2

    from kernels import lucas_kanade as lk
    from research.flow.raft import grey

    g1, g2 = grey(_unit(rgb1)), grey(_unit(rgb2))
    u1, u2 = (np.clip(g * 255.0 + 0.5, 0, 255).astype(np.uint8) for g in (g1, g2))
    out = {}
    t0 = time.perf_counter()
    fl, _, _ = lk.pyramidal_lucas_kanade(g1, g2, levels=4, half_window=4, iterations=5, device=device)
    out["pyramidal LK (4 levels, 9x9)"] = (fl, time.perf_counter() - t0)
    t0 = time.perf_counter()
    fb = cv2.calcOpticalFlowFarneback(u1, u2, None, 0.5, 5, 15, 3, 5, 1.2, 0)
    out["OpenCV Farneback"] = (fb.astype(np.float64), time.perf_counter() - t0)
    t0 = time.perf_counter()
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(u1, u2, None)
    out["OpenCV DIS (medium)"] = (dis.astype(np.float64), time.perf_counter() - t0)
    out["zero flow"] = (np.zeros(rgb1.shape[:2] + (2,)), 0.0)
    return out


class Pooled:
    """EPE and F1-all pooled over all evaluated pixels of several pairs."""

    def __init__(self) -> None:
        self.epe_sum = 0.0
        self.outliers = 0.0
        self.pixels = 0
        self.seconds: list[float] = []

    def add(self, metrics: dict, seconds: float) -> None:
        self.epe_sum += metrics["epe"] * metrics["pixels"]
        self.outliers += metrics["f1_all"] / 100.0 * metrics["pixels"]
        self.pixels += metrics["pixels"]
        self.seconds.append(seconds)

    def summary(self) -> dict:
        return {"epe": self.epe_sum / self.pixels, "f1_all": 100.0 * self.outliers / self.pixels,
                "pixels": self.pixels, "seconds_per_pair": statistics.mean(self.seconds)}


def memory_time(rgb1: np.ndarray, rgb2: np.ndarray, gt: np.ndarray, mask: np.ndarray, device: str) -> dict:
    """Dense vs on-the-fly correlation for the headline configuration on one pair."""
    from research.flow.raft import CorrFlow, CorrFlowConfig, flow_metrics

    cfg = CorrFlowConfig(levels=HEADLINE[0], radius=HEADLINE[1])
    rows = {}
    flows = {}
    for name, onthefly in (("dense pyramid", False), ("on the fly", True)):
        t0 = time.perf_counter()
        cf = CorrFlow(rgb1, rgb2, stride=STRIDE, max_levels=cfg.levels, onthefly=onthefly, device=device)
        setup = time.perf_counter() - t0
        coords = (np.stack(np.meshgrid(np.arange(cf.w) + 0.5, np.arange(cf.h) + 0.5))
                  + np.random.default_rng(0).uniform(-3, 3, (2, cf.h, cf.w))).astype(np.float32)
        cf.lookup(coords, cfg.levels, cfg.radius)  # warm-up
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            cf.lookup(coords, cfg.levels, cfg.radius)
            times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        flows[name] = cf.estimate(cfg)
        total = time.perf_counter() - t0
        rows[name] = {"features": list(cf.f1.shape), "setup_s": setup, "lookup_s": statistics.median(times),
                      "estimate_s": total, "bytes": cf.memory_bytes(cfg.levels, cfg.radius),
                      **flow_metrics(flows[name], gt, mask)}
    rows["max_flow_diff_px"] = float(np.abs(flows["dense pyramid"] - flows["on the fly"]).max())
    return rows


def flow_figure(scene: str, rgb1: np.ndarray, gt: np.ndarray, mask: np.ndarray,
                flows: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research.flow.raft import flow_to_color

    scale = float(np.linalg.norm(gt[mask], axis=-1).max())
    cols = 2 + len(flows)
    fig, axes = plt.subplots(2, cols, figsize=(2.6 * cols, 5.6))
    axes[0, 0].imshow(rgb1)
    axes[0, 0].set_title(f"{scene}: frame 1", fontsize=9)
    axes[0, 1].imshow(flow_to_color(np.where(mask[..., None], gt, 0.0), scale))
    axes[0, 1].set_title(f"ground truth (max {scale:.1f} px)", fontsize=9)
    axes[1, 0].imshow(mask, cmap="gray")
    axes[1, 0].set_title("evaluated (non-occluded)", fontsize=9)
    axes[1, 1].axis("off")
    for k, (name, fl) in enumerate(flows.items()):
        err = np.linalg.norm(fl - gt, axis=-1)
        axes[0, k + 2].imshow(flow_to_color(fl, scale))
        axes[0, k + 2].set_title(name, fontsize=8)
        im = axes[1, k + 2].imshow(np.where(mask, err, np.nan), cmap="magma", vmin=0, vmax=5)
        axes[1, k + 2].set_title(f"EPE {err[mask].mean():.2f} px", fontsize=8)
    fig.colorbar(im, ax=axes[1, :].tolist(), fraction=0.02, label="endpoint error (px, clipped at 5)")
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    save_figure(fig, path)
    plt.close(fig)


def ablation_figure(grid: np.ndarray, levels: tuple[int, ...], radii: tuple[int, ...], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.2, 3.6))
    im = ax.imshow(grid, cmap="viridis_r")
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            ax.text(j, i, f"{grid[i, j]:.2f}", ha="center", va="center", color="w", fontsize=9)
    ax.set_xticks(range(len(radii)), [str(r) for r in radii])
    ax.set_yticks(range(len(levels)), [str(lv) for lv in levels])
    ax.set_xlabel("radius r")
    ax.set_ylabel("pyramid levels L")
    ax.set_title("EPE (px), all pairs")
    fig.colorbar(im, ax=ax)
    save_figure(fig, path)
    plt.close(fig)


def benchmark_of(ctx: Context):
    """The benchmark folder --data names (checked from headers, before any work), or None for the cache root."""
    from research.datasets import detect_flow_format, open_flow_benchmark

    fmt, pass_ = getattr(ctx.args, "format", None), getattr(ctx.args, "pass_", None)
    if fmt is None and detect_flow_format(ctx.data) is None:
        if pass_ is not None:
            raise ValueError(f"--pass: needs --data naming an MPI-Sintel folder; {ctx.data} is not one")
        return None
    if pass_ is not None and (fmt or detect_flow_format(ctx.data)) != "sintel":
        raise ValueError(f"--pass: only MPI-Sintel has clean and final passes; {ctx.data} is a "
                         f"{fmt or detect_flow_format(ctx.data)} folder")
    return open_flow_benchmark(ctx.data, fmt, pass_)


_COLUMNS = {  # protocol -> (region, metric key, column header)
    "sintel": [("all", "epe", "EPE all"), ("matched", "epe", "EPE matched"), ("unmatched", "epe", "EPE unmatched")],
    "kitti": [("noc", "fl_percent", "Fl-all noc %"), ("occ", "fl_percent", "Fl-all occ %"),
              ("noc", "epe", "EPE noc"), ("occ", "epe", "EPE occ")],
    "middlebury": [("all", "epe", "EPE"), ("all", "ae_deg", "AE (deg)")],
}


def _mean_or_none(values: list) -> float | None:
    known = [v for v in values if v is not None]
    return statistics.mean(known) if known else None


def _cell(value) -> str:
    return "-" if value is None else f"{value:.3f}"


def run_benchmark(ctx: Context, bench) -> int:
    """CorrFlow (headline setting) and the baselines on a benchmark folder, scored by its protocol."""
    from kernels import corr
    from research.flow.metrics import FlowTally, protocol_regions
    from research.flow.raft import CorrFlow, CorrFlowConfig, srgb

    t_start = time.perf_counter()
    limit = 1 if ctx.quick else None  # pairs per sequence
    items = bench.items[:1] if ctx.smoke else bench.items
    ours_name = f"CorrFlow (L={HEADLINE[0]}, r={HEADLINE[1]})"
    tallies: dict[str, FlowTally] = {}
    per_seq: dict[str, dict[str, FlowTally]] = {}
    seconds: dict[str, list[float]] = {}
    lookup_paths: set[str] = set()
    n_pairs = sum(min(i.pairs, limit or i.pairs) for i in items)
    bench.verify(items)  # every file's contents, before any kernel runs
    bar = ctx.tqdm(total=n_pairs, desc=f"raft_flow {bench.format}", unit="pair")
    figure_done = False
    for item in items:
        seq = bench.load(item)
        for k in range(min(item.pairs, limit or item.pairs)):
            rgb1, rgb2 = srgb(seq.frames[k]), srgb(seq.frames[k + 1])
            gt = seq.flow[k].astype(np.float64)
            regions = protocol_regions(bench.format, seq, k)
            h, w = rgb1.shape[:2]
            fh, fw = h // STRIDE, w // STRIDE
            onthefly = corr.dense_bytes(fh, fw, HEADLINE[0]) > MEMORY_BUDGET_MIB * 2 ** 20
            lookup_paths.add("on the fly" if onthefly else "dense pyramid")
            t0 = time.perf_counter()
            cf = CorrFlow(rgb1, rgb2, stride=STRIDE, max_levels=HEADLINE[0], onthefly=onthefly, device=ctx.device)
            flows = {ours_name: (cf.estimate(CorrFlowConfig(levels=HEADLINE[0], radius=HEADLINE[1])),
                                 time.perf_counter() - t0)}
            flows[C2F_NAME] = c2f(rgb1, rgb2, ctx.device)
            flows.update(baselines(rgb1, rgb2, ctx.device))
            for name, (fl, sec) in flows.items():
                tallies.setdefault(name, FlowTally()).add(fl, gt, regions)
                per_seq.setdefault(name, {}).setdefault(item.name, FlowTally()).add(fl, gt, regions)
                seconds.setdefault(name, []).append(sec)
            mask = seq.valid[k]
            if not figure_done and mask.any() and np.linalg.norm(gt[mask], axis=-1).max() > 0:
                shown = {n: f for n, (f, _) in flows.items() if n != "zero flow"}
                flow_figure(f"{bench.format} {item.name}", rgb1, gt, mask, shown, ctx.out / "flow_benchmark.png")
                figure_done = True
            bar.update()
    bar.close()

    columns = _COLUMNS[bench.format]
    if bench.items and all(i.objects for i in bench.items):  # KITTI 2015's Fl-bg / Fl-fg split
        columns = columns[:2] + [(f"{r}_{part}", "fl_percent", f"Fl-{part} {r} %")
                                 for r in ("noc", "occ") for part in ("bg", "fg")] + columns[2:]
    if bench.year == "2012":  # KITTI 2012's tables count EPE > 3 px alone
        columns = columns[:2] + [("noc", "out3_percent", "Out-Noc (> 3 px) %"),
                                 ("occ", "out3_percent", "Out-All (> 3 px) %")] + columns[2:]
    rows, methods = [], {}
    for name, tally in tallies.items():
        pooled = tally.summary()
        seqs = {s: t.summary() for s, t in per_seq[name].items()}
        entry = {"pooled": pooled, "per_sequence": seqs, "seconds_per_pair": statistics.mean(seconds[name])}
        if bench.format == "middlebury":  # Middlebury's tables average the sequences
            entry["sequence_mean"] = {key: _mean_or_none([v["all"][key] for v in seqs.values()])
                                      for key in ("epe", "ae_deg")}
            cells = [entry["sequence_mean"]["epe"], entry["sequence_mean"]["ae_deg"]]
        else:
            cells = [pooled[region][key] for region, key, _ in columns]
        methods[name] = entry
        rows.append([name] + [_cell(c) for c in cells] + [f"{entry['seconds_per_pair']:.3f}"])
    headers = ["method"] + [c[2] for c in columns] + ["s / pair"]
    which = ("mean over sequences" if bench.format == "middlebury" else "pooled over all pixels of all pairs")
    sizes = sorted({f"{i.size[0]}x{i.size[1]}" for i in items})
    mode = "smoke: first pair only" if ctx.smoke else "quick: first pair of each sequence" if ctx.quick else "all"
    table = (f"Dataset: {bench.dataset}, {bench.root}. Pairs evaluated: {n_pairs} of {bench.pairs} ({mode}), "
             f"at {', '.join(sizes)}.\nProtocol: {bench.protocol}. Values: {which}.\n"
             f"CorrFlow: research/flow/raft.py at its headline setting (L={HEADLINE[0]}, r={HEADLINE[1]}, stride "
             f"{STRIDE}), correlation lookup: {' and '.join(sorted(lookup_paths))} (the dense pyramid is kept only "
             f"below {MEMORY_BUDGET_MIB} MiB). 's / pair' runs on a shared CPU.\n\n"
             + markdown_table(headers, rows))
    if bench.format in ("sintel", "middlebury") and len(items) > 1:
        region, key = columns[0][0], columns[0][1]
        label = "EPE px / AE deg" if bench.format == "middlebury" else f"EPE px, {region} pixels"
        seq_rows = []
        for item in items:
            cells = []
            for entry in methods.values():
                v = entry["per_sequence"][item.name][region]
                cells.append(f"{_cell(v['epe'])} / {_cell(v['ae_deg'])}" if bench.format == "middlebury"
                             else _cell(v[key]))
            seq_rows.append([item.name] + cells)
        table += f"\nPer sequence ({label}):\n\n" + markdown_table(["sequence"] + list(methods), seq_rows)
    metrics = {"benchmark": {"format": bench.format, "dataset": bench.dataset, "protocol": bench.protocol,
                             "pass": bench.pass_, "root": str(bench.root), "pairs_evaluated": n_pairs,
                             "pairs_in_folder": bench.pairs, "sequences": [i.name for i in items]},
               "methods": methods, "lookup": sorted(lookup_paths), "seconds": time.perf_counter() - t_start}
    config = {"format": bench.format, "pass": bench.pass_, "stride": STRIDE, "headline": HEADLINE,
              "corrflow": CorrFlowConfig().__dict__, "memory_budget_mib": MEMORY_BUDGET_MIB}
    ctx.write_results(config=config, metrics=metrics, table_md=table)
    return 0


def run(ctx: Context) -> int:
    bench = benchmark_of(ctx)
    if bench is not None:
        for flag in ("levels", "radius"):
            if getattr(ctx.args, flag) is not None:
                raise ValueError(f"--{flag}: selects a cell of the rendered pairs' ablation; a benchmark folder "
                                 "(--data) runs the headline setting only")
        return run_benchmark(ctx, bench)
    return run_rendered(ctx)


class _Table:
    """Pooled metrics per (group, method), e.g. per scene or per radiometric condition."""

    def __init__(self) -> None:
        self.pooled: dict[str, dict[str, Pooled]] = {}

    def add(self, group: str, name: str, metrics: dict, seconds: float) -> None:
        self.pooled.setdefault(group, {}).setdefault(name, Pooled()).add(metrics, seconds)

    def methods(self) -> list[str]:
        return list(next(iter(self.pooled.values())).keys())

    def overall(self, name: str) -> dict:
        allp = Pooled()
        for group in self.pooled.values():
            p = group[name]
            allp.epe_sum += p.epe_sum
            allp.outliers += p.outliers
            allp.pixels += p.pixels
            allp.seconds += p.seconds
        return allp.summary()

    def rows(self, with_all: bool = True) -> tuple[list[str], list[list]]:
        headers = ["method"] + [f"{g} {m}" for g in self.pooled for m in ("EPE", "F1-all %")]
        headers += (["all EPE", "all F1-all %"] if with_all else []) + ["s / pair"]
        rows = []
        for name in self.methods():
            cells: list = [name]
            for group in self.pooled.values():
                sm = group[name].summary()
                cells += [sm["epe"], sm["f1_all"]]
            sm = self.overall(name)
            rows.append(cells + ([sm["epe"], sm["f1_all"]] if with_all else []) + [sm["seconds_per_pair"]])
        return headers, rows

    def metrics(self) -> dict:
        return {g: {m: p.summary() for m, p in d.items()} for g, d in self.pooled.items()}


def real_texture(ctx: Context) -> tuple[_Table, dict]:
    """Every method on the photograph's evaluation split (research.flow.texture), pooled over its flows."""
    from research.flow import texture as tf
    from research.flow.raft import flow_metrics

    src = tf.split("eval")
    seeds = tf.EVAL_SEEDS[:1] if ctx.smoke else tf.EVAL_SEEDS[:2] if ctx.quick else tf.EVAL_SEEDS
    if ctx.smoke:
        src = src[60:156, 192:320]
    table = _Table()
    motion = []
    for seed in seeds:
        flow = tf.smooth_flow(src.shape[:2], 4.0, seed)
        f1, f2, valid = tf.warped_pair(src, flow)
        gt = np.moveaxis(flow, 0, -1)
        motion.append(np.linalg.norm(gt[valid], axis=-1))
        for name, (fl, sec) in every_method(f1, f2, ctx.device).items():
            table.add("photograph", name, flow_metrics(fl, gt, valid), sec)
    info = {"image": tf.PHOTO, "split": "eval (upper half)", "size": list(src.shape[:2]), "flow_seeds": list(seeds),
            "median_motion_px": float(np.median(np.concatenate(motion)))}
    return table, info


def run_rendered(ctx: Context) -> int:
    from research import radiometry
    from research.datasets import load_flow, provenance
    from research.flow.raft import CorrFlow, CorrFlowConfig, flow_metrics, srgb

    t0 = time.perf_counter()
    paths = datasets(ctx.quick, ctx.seed, ctx.data, ctx.smoke)
    t_data = time.perf_counter() - t0
    res, spp = (SMOKE_RES, SMOKE_SPP) if ctx.smoke else (RES, SPP)
    pairs = [(scene, k) for scene, p in paths.items() for k in range(len(load_flow(p).flow))]
    levels = LEVELS if ctx.args.levels is None else (ctx.args.levels,)
    radii = RADII if ctx.args.radius is None else (ctx.args.radius,)
    cell_mode = ctx.args.levels is not None or ctx.args.radius is not None
    headline = HEADLINE if HEADLINE[0] in levels and HEADLINE[1] in radii else (max(levels), max(radii))
    ours_name = RAFT_NAME.format(*headline)
    per_scene = _Table()
    conditions = _Table()
    ablation = {(lv, r): Pooled() for lv in levels for r in radii}
    per_pair = []
    memtime = None
    seqs = {scene: load_flow(p) for scene, p in paths.items()}
    gt_mag = np.concatenate([np.linalg.norm(seqs[sc].flow[k], axis=-1)[seqs[sc].valid[k]] for sc, k in pairs])
    motion = {"median_px": float(np.median(gt_mag)), "p90_px": float(np.percentile(gt_mag, 90)),
              "max_px": float(gt_mag.max())}
    bar = ctx.tqdm(total=len(pairs) * (len(levels) * len(radii) + 1), desc="raft_flow", unit="run")
    for index, (scene, k) in enumerate(pairs):
        seq = seqs[scene]
        rgb1, rgb2 = srgb(seq.frames[k]), srgb(seq.frames[k + 1])
        gt, mask = seq.flow[k].astype(np.float64), seq.valid[k]
        t0 = time.perf_counter()
        cf = CorrFlow(rgb1, rgb2, stride=STRIDE, max_levels=max(levels), device=ctx.device)
        build_s = time.perf_counter() - t0
        flows = {}
        row = {"scene": scene, "pair": k, "build_s": build_s, "ablation": {}}
        if not cell_mode:
            fl, seconds = c2f(rgb1, rgb2, ctx.device)
            per_scene.add(scene, C2F_NAME, flow_metrics(fl, gt, mask), seconds)
            flows[C2F_NAME] = fl
        for lv in levels:
            for r in radii:
                t0 = time.perf_counter()
                fl = cf.estimate(CorrFlowConfig(levels=lv, radius=r))
                seconds = time.perf_counter() - t0 + build_s
                m = flow_metrics(fl, gt, mask)
                ablation[(lv, r)].add(m, seconds)
                row["ablation"][f"L{lv}_r{r}"] = m
                if (lv, r) == headline:
                    flows[ours_name] = fl
                    per_scene.add(scene, ours_name, m, seconds)
                bar.update()
        for name, (fl, seconds) in baselines(rgb1, rgb2, ctx.device).items():
            m = flow_metrics(fl, gt, mask)
            per_scene.add(scene, name, m, seconds)
            row[name] = m
            if name != "zero flow":
                flows[name] = fl
        if not cell_mode:
            # Clean and radiometrically stressed 8-bit versions of the pair (research.radiometry).
            clean = (radiometry.clean(seq.frames[k]), radiometry.clean(seq.frames[k + 1]))
            stressed = radiometry.stress_pair(seq.frames[k], seq.frames[k + 1], seed=1000 * ctx.seed + index)
            for condition, (a, b) in (("clean", clean), ("stressed", stressed)):
                for name, (fl, seconds) in every_method(a, b, ctx.device).items():
                    conditions.add(condition, name, flow_metrics(fl, gt, mask), seconds)
        bar.update()
        per_pair.append(row)
        if k == 0:
            flow_figure(scene, rgb1, gt, mask, flows, ctx.out / f"flow_{scene}.png")
        if memtime is None and not cell_mode:
            memtime = memory_time(rgb1, rgb2, gt, mask, ctx.device)
    bar.close()

    # ------------------------------------------------------------------ tables
    main_headers, main_rows = per_scene.rows()
    grid = np.array([[ablation[(lv, r)].summary()["epe"] for r in radii] for lv in levels])
    f1_grid = np.array([[ablation[(lv, r)].summary()["f1_all"] for r in radii] for lv in levels])
    abl_rows = [[f"L={lv}"] + [f"{grid[i, j]:.3f} ({f1_grid[i, j]:.1f}%)" for j in range(len(radii))]
                for i, lv in enumerate(levels)]
    n_pairs = {scene: sum(1 for s, _ in pairs if s == scene) for scene in paths}
    table = (
        f"Mitsuba flow pairs at {res}x{res} ({spp} spp, camera azimuth step {STEP_DEG} deg), frame k -> k+1; "
        f"pairs per scene: {n_pairs}. Metrics over non-occluded surface pixels: EPE in px, F1-all = % of "
        "pixels with EPE > 3 px and > 5% of |gt| (KITTI). "
        + ("" if cell_mode else f"{C2F_NAME}: research/flow/coarse_to_fine.py (coarse-to-fine normalised-patch lookups with "
           "warping and a TV-L1 step; defaults chosen on held-out data: the photograph's tuning split and "
           "Mitsuba pairs rendered with seed 7, not on these pairs). ")
        + f"CorrFlow: kernels.corr lookups driving the RAFT-style weight-free update (research/flow/raft.py), "
        f"features at stride {STRIDE}, 12 lookups. 's / pair' includes building the correlation pyramid "
        "and runs on a shared 2-core CPU.\n\n"
        + markdown_table(main_headers, main_rows, floatfmt=".3f")
        + f"\nAblation (RAFT-style CorrFlow, all pairs pooled): EPE in px (F1-all %), pyramid levels L x lookup "
        f"radius r{' (only the cells asked for by --levels/--radius)' if cell_mode else ''}. "
        f"Ground-truth motion: median {motion['median_px']:.1f} px ({motion['median_px'] / STRIDE:.1f} feature "
        f"px), 90th percentile {motion['p90_px']:.1f} px, max {motion['max_px']:.1f} px: the iterated level-0 "
        "lookups reach most matches on their own, and with fixed (unlearned) features the pooled coarse levels add "
        "matching noise rather than reach, unlike RAFT's learned features and update.\n\n"
        + markdown_table(["levels \\ radius"] + [f"r={r}" for r in radii], abl_rows))
    metrics: dict = {
        "per_scene": per_scene.metrics(),
        "ablation": {f"L{lv}_r{r}": ablation[(lv, r)].summary() for lv in levels for r in radii},
        "cell": ablation[headline].summary() | {"levels": headline[0], "radius": headline[1]},
        "per_pair": per_pair, "dataset_seconds": t_data, "gt_motion": motion,
        "datasets": {scene: provenance(p) for scene, p in paths.items()},
    }
    if not cell_mode:
        cond_headers, cond_rows = conditions.rows()
        photo, photo_info = real_texture(ctx)
        photo_headers, photo_rows = photo.rows(with_all=False)
        mt_rows = [[name, "x".join(map(str, v["features"])), f"{v['bytes'] / 2**20:.1f}", f"{v['setup_s']:.3f}",
                    f"{v['lookup_s'] * 1e3:.1f}", f"{v['estimate_s']:.2f}", f"{v['epe']:.4f}"]
                   for name, v in memtime.items() if isinstance(v, dict)]
        table += (
            "\nClean and radiometrically stressed pairs (the same pairs, all scenes pooled; research/radiometry.py: "
            "per-frame exposure +-0.3 stops, black level, vignetting up to 25 %, blur up to 0.8 px, "
            "Poisson-Gaussian noise, 8-bit sRGB; 'clean' is the same 8-bit sRGB encoding without the stress; the "
            f"stress seed of pair i is 1000 x seed + i; seed {ctx.seed}).\n\n"
            + markdown_table(cond_headers, cond_rows, floatfmt=".3f")
            + f"\nReal photograph ({photo_info['image']} from matplotlib's sample data, {photo_info['split']}, "
            f"{photo_info['size'][0]}x{photo_info['size'][1]}) warped by smooth random flows (seeds "
            f"{photo_info['flow_seeds']}, median motion {photo_info['median_motion_px']:.1f} px; "
            "research/flow/texture.py). C2F's defaults were chosen on the other half of the photograph with "
            "other flow seeds (and on Mitsuba pairs of seed 7).\n\n"
            + markdown_table(photo_headers, photo_rows, floatfmt=".3f")
            + f"\nDense pyramid vs on-the-fly lookup (RAFT-style CorrFlow L={HEADLINE[0]}, r={HEADLINE[1]}, float32, "
            "first pair): 'setup' builds the volume and pyramid (dense) or pools f2 (on the fly); MiB is what each "
            "keeps between lookups (the on-the-fly path holds f1, the pooled f2 pyramid and one patch buffer); "
            f"largest difference between their flows: {memtime['max_flow_diff_px']:.2e} px.\n\n"
            + markdown_table(["path", "features C x h x w", "MiB", "setup s", "lookup ms", "estimate s (12 lookups)",
                              "EPE"], mt_rows))
        metrics.update(radiometric=conditions.metrics(), real_texture={"methods": photo.metrics()["photograph"],
                                                                       **photo_info}, memory_time=memtime)
    ablation_figure(grid, levels, radii, ctx.out / "ablation.png")
    from research.flow.coarse_to_fine import C2FConfig

    config = {"scenes": list(paths), "res": res, "spp": spp, "flow_step_deg": STEP_DEG,
              "stride": STRIDE, "headline": headline, "corrflow": CorrFlowConfig().__dict__,
              "c2f": C2FConfig().__dict__, "levels": levels, "radii": radii, "cell_mode": cell_mode}
    ctx.write_results(config=config, metrics=metrics, table_md=table)
    return 0


main = Experiment("raft_flow", __doc__, run, add_options,
                  data_help=rendered_cache_help("flow", "raft_flow") + "; or an MPI-Sintel, KITTI flow or "
                            "Middlebury flow folder, scored by that benchmark's protocol (--format, --pass)",
                  seed_help="dataset seed (camera path, render noise)",
                  sizes="Quick: scene `objects` only, 2 frame pairs; smoke: `objects` at 128x128, 4 spp, "
                        "one pair. On a benchmark folder: quick, the first pair of each sequence; smoke, the "
                        "first pair only.").script(__name__)
