"""The stereo benchmark run of experiments.stereo_depth (`--data PATH` of a benchmark folder).

For a Middlebury 2014/2021, Middlebury 2001/2003, KITTI 2012/2015 or ETH3D two-view folder
(research.datasets.stereo_benchmarks reads it), `run_benchmark` matches every pair with drlab's default
(research.stereo.matching.DEFAULT_CONFIG), the drlab configurations the Mitsuba run chose (BENCHMARK_DRLAB; none
tuned on benchmark data) and OpenCV StereoSGBM with standard parameters (blockSize 3 and 5, P1 = 8 cn bs^2,
P2 = 32 cn bs^2 for cn image channels, 3-way, uniqueness 10, speckle window 100 and range 32,
disp12MaxDiff 1, preFilterCap 63), over disparities [0, D) with D the pair's ndisp rounded up to a
multiple of 16 or `--max-disp`, scores them with the benchmark's protocol (research.stereo.matching.protocol_metrics)
and writes table.md (pooled, and per pair except for KITTI), metrics.json and disparity_maps.png (the
first pair). Every range and every volume is checked against the image and the free memory before any
matching. The experiment's docstring (experiments/stereo_depth.py) describes the options.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from research.experiment import Context
from research.results import finish_figure, markdown_table

DEFAULT_NAME = "drlab default"
# The Middlebury 2001/2003 scenes that took part in choosing research.stereo.matching.DEFAULT_CONFIG (its docstring).
DEFAULT_CHOSEN_ON = ("tsukuba", "venus")

# Configurations the default run chose on its Mitsuba tuning pairs (results/stereo_depth/metrics.json), none
# on benchmark data: the best drlab configuration there (BT + SGM-4 soft-argmin since BT joined the grid; SAD +
# SGM-4 soft-argmin before, kept for comparison), its robust choice (ZNCC + SGM-4: lowest mean of the clean and
# the stressed tuning D1), and census + SGM-8 (census is robust to gain and offset between cameras). BT matches
# colour images with its colour term.
BENCHMARK_DRLAB = {
    "BT + SGM-4 soft-argmin": {"cost": "bt", "aggregation": "sgm4", "p1": 0.02, "p2": 0.08, "radius": 3,
                               "disparity": "soft_argmin", "temperature": 0.02},
    "ZNCC + SGM-4": {"cost": "zncc", "aggregation": "sgm4", "p1": 0.4, "p2": 3.2, "radius": 5, "zncc_eps": 1e-3},
    "SAD + SGM-4 soft-argmin": {"cost": "sad", "aggregation": "sgm4", "p1": 0.02, "p2": 0.08, "radius": 4,
                                "disparity": "soft_argmin", "temperature": 0.02},
    "census + SGM-8": {"cost": "census", "aggregation": "sgm8", "p1": 16.0, "p2": 128.0, "census_radii": (3, 4)},
}
PROTOCOL_NAMES = {"middlebury": "Middlebury 2014/2021 (bad-0.5/1/2/4 and avgerr; nonocc and all masks)",
                  "middlebury2003": "Middlebury 2001/2003 (bad-0.5/1/2/4, avgerr = EPE, and D1: error > 3 px and > 5 % "
                                    "of the true disparity; over every pixel with known ground truth, as no occlusion "
                                    "masks are given)",
                  "kitti": "KITTI 2012/2015 stereo (D1: error > 3 px and > 5 % of the true disparity; noc and occ)",
                  "eth3d": "ETH3D two-view (bad-1, bad-2 and avgerr; nonocc and all masks)"}



SGBM_BLOCKS = (3, 5)  # the standard parameters below with blockSize 3 and with 5


def _sgbm(dmax: int, channels: int, block: int = 3) -> Any:
    import cv2

    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=dmax, blockSize=block, P1=8 * channels * block ** 2,
                                 P2=32 * channels * block ** 2, disp12MaxDiff=1, preFilterCap=63, uniquenessRatio=10,
                                 speckleWindowSize=100, speckleRange=32, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)


def benchmark_figure(p: Any, runs: dict[str, tuple[np.ndarray, np.ndarray, float]], path: Path) -> None:
    """One pair: left image, ground truth, and each method's filled disparity and |error| (clipped at 5 px)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research.stereo.matching import fill_invalid

    vmax = float(p.disparity[p.mask].max()) if p.mask.any() else 1.0
    panels: list[tuple[str, Any, dict]] = [
        ("left image", p.left_image, {"cmap": "gray"} if p.left_image.ndim == 2 else {}),
        ("ground truth", np.ma.masked_where(~p.mask, p.disparity), {"vmin": 0, "vmax": vmax})]
    for name, (d, v, _) in runs.items():
        dense = fill_invalid(d, v)
        panels.append((name, dense, {"vmin": 0, "vmax": vmax}))
        panels.append((f"|error| {name}", np.ma.masked_where(~p.mask, np.abs(dense - p.disparity)),
                       {"vmin": 0, "vmax": 5, "cmap": "inferno"}))
    cols = 2
    rows = (len(panels) + cols - 1) // cols
    aspect = p.disparity.shape[0] / p.disparity.shape[1]
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.2 * aspect * rows + 0.6), squeeze=False)
    for ax, (title, img, kw) in zip(axes.flat, panels):
        im = ax.imshow(img, **kw)
        if title != "left image":
            fig.colorbar(im, ax=ax, fraction=0.046)
        ax.set_title(title, fontsize=8)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    fig.suptitle(f"{p.benchmark} {p.name}: disparity (px) after KITTI fill; masked: no ground truth", fontsize=9)
    finish_figure(fig, path)


def _volume_bytes(shape: tuple[int, int], dmax: int) -> int:
    """drlab's peak for one pair: the largest over the benchmark configurations of the volumes `match`
    holds at once (research.stereo.matching.peak_volume_bytes: float32, or compact uint8/uint16 for census + SGM)."""
    from research.stereo.matching import DEFAULT_CONFIG, StereoConfig, peak_volume_bytes

    return max(peak_volume_bytes(c, int(shape[0]), int(shape[1]), int(dmax))
               for c in [DEFAULT_CONFIG] + [StereoConfig(**cfg) for cfg in BENCHMARK_DRLAB.values()])


def _free_memory() -> int | None:
    """MemAvailable of /proc/meminfo in bytes (None where there is no such file)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _as_u8(img: np.ndarray) -> np.ndarray:
    return img if img.dtype == np.uint8 else (img >> 8).astype(np.uint8)


def run_benchmark(ctx: Context, fmt: str) -> int:
    import cv2

    from kernels.launch import default_threads
    from research.datasets.stereo_benchmarks import load_benchmark
    from research.stereo.matching import DEFAULT_CONFIG, PROTOCOLS, StereoConfig, match, pool_protocol, protocol_metrics

    args = ctx.args
    if fmt == "kitti" and args.resolution != "full":
        raise ValueError(f"--resolution: KITTI's sparse ground truth is evaluated at full resolution only, got "
                         f"{args.resolution!r}")
    pairs = load_benchmark(ctx.data, fmt, args.resolution, scale=args.gt_scale)
    limit = 2 if ctx.smoke else 5 if ctx.quick else None
    pairs = pairs[:limit]

    def drange(p: Any) -> int:
        if args.max_disp is not None:
            return int(args.max_disp)
        if p.ndisp is None:  # KITTI: 256, or less where the image is narrower
            return int(min(256, max(16, (p.disparity.shape[1] - 1) // 16 * 16)))
        return int(-(-p.ndisp // 16) * 16)

    free = _free_memory() if ctx.device == "cpu" else None
    for p in pairs:  # before any matching: every range must fit its image, every volume the memory
        if drange(p) >= p.disparity.shape[1]:
            where = "--max-disp" if args.max_disp is not None else f"{p.source}/calib.txt: ndisp={p.ndisp}"
            raise ValueError(f"{where}: the disparity range [0, {drange(p)}) must be narrower than the image "
                             f"({p.disparity.shape[1]} px wide)")
        need = _volume_bytes(p.disparity.shape, drange(p))
        if free is not None and need > free:
            raise ValueError(f"{p.source}: drlab's volumes for {p.disparity.shape[1]}x{p.disparity.shape[0]}"
                             f" x {drange(p)} disparities need about {need / 2**30:.1f} GiB, more than the "
                             f"{free / 2**30:.1f} GiB available; use --resolution half or quarter, or --max-disp")
    peak = max(_volume_bytes(p.disparity.shape, drange(p)) for p in pairs)

    methods = {DEFAULT_NAME: DEFAULT_CONFIG, **{name: StereoConfig(**cfg) for name, cfg in BENCHMARK_DRLAB.items()}}
    results: dict[str, Any] = {name: {"family": "drlab", "params": cfg.to_dict(), "pairs": {}}
                               for name, cfg in methods.items()}
    for block in SGBM_BLOCKS:
        results[f"OpenCV StereoSGBM bs{block}"] = {"family": "opencv", "params": {
            "blockSize": block, "P1": f"8*cn*{block}^2", "P2": f"32*cn*{block}^2", "mode": "3WAY",
            "uniquenessRatio": 10, "speckleWindowSize": 100, "speckleRange": 32, "disp12MaxDiff": 1,
            "preFilterCap": 63}, "pairs": {}}
    for p in ctx.tqdm(pairs, desc=f"{fmt} pairs"):
        dmax = drange(p)
        runs = {}
        for name, cfg in methods.items():
            r = match(p.left_image, p.right_image, 0, dmax, cfg, ctx.device)
            runs[name] = (r.disparity, r.valid, r.timings["total_s"])
        left, right = _as_u8(p.left_image), _as_u8(p.right_image)
        channels = 1 if left.ndim == 2 else 3
        bgr = (lambda x: x) if channels == 1 else (lambda x: np.ascontiguousarray(x[..., ::-1]))
        for block in SGBM_BLOCKS:
            t0 = time.perf_counter()
            raw = _sgbm(dmax, channels, block).compute(bgr(left), bgr(right))
            seconds = time.perf_counter() - t0
            disp = raw.astype(np.float32) / 16.0
            runs[f"OpenCV StereoSGBM bs{block}"] = (disp, disp >= 0, seconds)
        for name, (d, v, s) in runs.items():
            row = protocol_metrics(fmt, d, v, p.disparity, p.noc, p.mask, p.foreground)
            results[name]["pairs"][p.name] = {**row, "seconds": s, "dmax": dmax}
        if p is pairs[0]:
            benchmark_figure(p, runs, ctx.out / "disparity_maps.png")
    for name, r in results.items():
        r["pooled"] = pool_protocol(fmt, list(r["pairs"].values()))
        r["time_s_mean"] = float(np.mean([x["seconds"] for x in r["pairs"].values()]))

    masks = PROTOCOLS[fmt]["masks"]
    res = sorted({f"{p.disparity.shape[1]}x{p.disparity.shape[0]}" for p in pairs})
    noc_note = ""
    if fmt == "middlebury2003":
        noc_note = " No occlusion masks: every score is over all pixels with known ground truth."
    elif fmt != "kitti" and not all(p.has_noc_mask for p in pairs):
        missing = [p.name for p in pairs if not p.has_noc_mask]
        noc_note = (f" Pairs without mask0nocc.png ({', '.join(missing)}): their nonocc scores are over all known "
                    "pixels.")
    if fmt == "kitti":
        has_fg = all(p.foreground is not None for p in pairs)
        parts = ("bg", "fg", "all") if has_fg else ("all",)
        headers = ["method"] + [f"D1-{part} {m}" for m in masks for part in parts] + ["density noc", "time ms"]
        fg_note = "" if has_fg else " No obj_map folder: D1-bg/fg need KITTI 2015's object maps, so D1-all only."

        def cells(r: dict) -> list[str]:
            return [f"{r[m][f'd1_{part}']:.4f}" for m in masks for part in parts]
    else:
        keys = [f"bad{t:g}" for t in PROTOCOLS[fmt]["thresholds"]] + (["d1"] if fmt == "middlebury2003" else [])
        headers = ["method"] + [f"{k.replace('bad', 'bad-').replace('d1', 'D1')} {m}" for m in masks
                                for k in keys + ["avgerr"]] + \
                  [f"density {masks[0]}", "time ms"]
        fg_note = ""

        def cells(r: dict) -> list[str]:
            return [f"{r[m][k]:.4f}" if k != "avgerr" else f"{r[m][k]:.3f}" for m in masks for k in keys + ["avgerr"]]

    rows = [[name] + cells(r["pooled"]) + [f"{r['pooled'][masks[0]]['density']:.3f}", f"{1000 * r['time_s_mean']:.1f}"]
            for name, r in results.items()]
    pooling = ("pixel-pooled over pairs (KITTI devkit)" if fmt == "kitti" else "mean over pairs (equal weights)")
    per_pair = ""
    if fmt != "kitti":
        m0 = masks[0]
        per_pair = ("\nPer pair, D1 / bad-2 / avgerr on " + m0 + ":\n\n" + markdown_table(
            ["method"] + [p.name for p in pairs],
            [[name] + [f"{r['pairs'][p.name][m0].get('d1', float('nan')):.4f} / "
                       f"{r['pairs'][p.name][m0].get('bad2', float('nan')):.4f} / {r['pairs'][p.name][m0]['avgerr']:.3f}"
                       for p in pairs] for name, r in results.items()]))
    held_out = [p.name for p in pairs if not (fmt == "middlebury2003" and p.name in DEFAULT_CHOSEN_ON)]
    if fmt == "middlebury2003" and held_out and len(held_out) < len(pairs):
        # The pooled table above mixes in pairs that chose drlab's default; this one pools only the others.
        rows_h = []
        for name, r in results.items():
            q = pool_protocol(fmt, [r["pairs"][n] for n in held_out])[masks[0]]
            r["pooled_held_out"] = {masks[0]: q}
            rows_h.append([name] + [f"{q[k]:.4f}" if k != "avgerr" else f"{q[k]:.3f}" for k in keys + ["avgerr"]])
        per_pair = (f"\nHeld out from every choice of drlab's default ({', '.join(held_out)}; "
                    f"{', '.join(n for n in DEFAULT_CHOSEN_ON if n in {p.name for p in pairs})} chose it), mean over "
                    "these pairs:\n\n" + markdown_table(headers[:1 + len(keys) + 1], rows_h) + per_pair)
    dranges = sorted({v["dmax"] for v in next(iter(results.values()))["pairs"].values()})
    table = (
        f"Dataset: {fmt} stereo benchmark at {ctx.data}, {len(pairs)} pair(s) ({', '.join(p.name for p in pairs)}), "
        f"resolution {args.resolution} of the stored files ({', '.join(res)}), disparities [0, D) with D in "
        f"{dranges}. Protocol: {PROTOCOL_NAMES[fmt]}; invalid estimates filled as KITTI's devkit does, scores "
        f"{pooling}.{noc_note}{fg_note} drlab configurations chosen on the Mitsuba tuning pairs of the default "
        f"run, not on this data; drlab default = research.stereo.matching.DEFAULT_CONFIG ({DEFAULT_CONFIG.label}), whose parameters "
        f"were chosen on Middlebury 2001 tsukuba + venus and the Mitsuba tuning pairs (p_000 of objects and cornell at "
        f"256 and 128 px, clean and stressed), never on teddy or cones. OpenCV StereoSGBM with standard parameters (P1 = 8 cn bs^2, "
        f"P2 = 32 cn bs^2, 3-way, uniqueness 10, speckle window 100 and range 32, disp12MaxDiff 1, preFilterCap 63), "
        f"blockSize 3 and 5, on the stored 8-bit images (colour as read), same disparity range. Colour inputs go to "
        f"drlab as read too (uint8, normalised by research.images). Time: wall per pair, drlab with "
        f"{default_threads()} CPU threads (device {ctx.device}), OpenCV with {cv2.getNumThreads()} threads; "
        f"drlab's cost volumes take up to {peak / 2**20:.1f} MiB per pair (research.stereo.matching.peak_volume_bytes: "
        f"float32 cost and aggregate; census + SGM in compact mode, uint8 costs and a uint16 aggregate).\n\n"
        + markdown_table(headers, rows) + per_pair)
    config = {"benchmark": fmt, "data": str(ctx.data), "resolution": args.resolution, "pairs": [p.name for p in pairs],
              "drlab_volume_peak_bytes": peak,
              "image_sizes": res, "disparity_ranges": dranges, "protocol": PROTOCOL_NAMES[fmt],
              "opencv": cv2.__version__, "drlab_threads": default_threads(), "opencv_threads": cv2.getNumThreads()}
    ctx.write_results(config=config, table_md=table,
                      metrics={"benchmark": fmt, "protocol": PROTOCOL_NAMES[fmt], "methods": results})
    return 0


