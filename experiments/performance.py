#!/usr/bin/env python3
"""drlab's kernels timed beside the libraries a researcher would otherwise use, on the same CPU.

Runs every registered bench family (research.bench, `drlab bench --compare`) in this process and
tabulates, for each case and phase, drlab's median time, the reference library's median time on
the same inputs (timed interleaved with drlab's in one `time_medians` call), and the ratio
reference / drlab (> 1: drlab is faster). The references come from the `[bench]` extra (PyTorch
CPU, OpenCV); where one is not installed the case says so (`ref_missing`) and only drlab's time is
shown. Cases with no reference library (a field's forward, the split launch) show drlab's times.
Every figure names the host CPU and thread count: timings from different machines are not
comparable.

Targets (checked at full size only; quick and smoke sizes print "n/a"): compositing forward plus
backward >= 10x PyTorch autograd at 65536 x 128, forward >= 2x PyTorch at 16384 x 128, forward
within 2x of the measured bandwidth bound (reading sigma, rgb and delta once; judged on the
faster of the bench's two reads, bound_max_s, an unsigned maximum of the bytes: the float sum of
bound_s is partly arithmetic-bound, so it would make the bound look slower than memory is; judged
for the forward that keeps the factors for a backward, fwd, and on its own line for the forward of
renders that are never backpropagated, fwd_no_factor, keep_factor=False), the
textbook spheres render <= 5 ms, hash grid + MLP forward plus backward at 1M points <= 2 s,
split launch >= 1.9x on 2 cores; RAFT correlation build no slower than PyTorch, dense lookup >= 2x
grid_sample, on-the-fly lookup within 3x of the dense one holding >= 10x less memory (judged on
the float16-feature case, the float32 case shown beside it); the default stereo SGM pipeline
(research.stereo.matching.DEFAULT_CONFIG, bench case stereo.default) <= 5x OpenCV StereoSGBM's time at
256x256x64 and 741x500x64, with census + SGM-8 (StereoConfig's field defaults, stereo.sgm) judged
on its own lines; splat rasteriser >= 100x the dense
PyTorch rasteriser at 2000 Gaussians, 128x128, and the splat forward <= 1 s at 1M Gaussians,
1920x1080. (The stereo memory and accuracy targets have no single number and are not checked here.)

Repeats (--repeats, default 3 at full size, 1 otherwise): every family runs that many times in turn
(family by family, then again), and each timed figure and ratio in the table is the median over the
runs, with the lowest and highest run beside it. A host whose speed drifts between runs (the Intel VM
this table was last made on disagreed with itself by up to 2x between back-to-back runs) then shows
its spread instead of one draw. A target is judged on the median and also counted run by run
("met in k of n runs").

Writes results/performance/{table.md, metrics.json (every bench row), figure.png}. A full run
into the default folder of a checkout (what `make reproduce` does) then copies table.md into
docs/performance.md between the markers README_START and README_END (its current table).
"""

from __future__ import annotations

import argparse
import operator
import statistics
from pathlib import Path
from typing import Any

from research import registry
from research.experiment import Context, Experiment
from research.results import markdown_table, save_figure

# (bench case, key, {size key: value} the row must match) -> (comparison, bound, text). Checked only on
# full-size rows. The corr and stereo keys are those of research/bench/corr.py and stereo.py.
TARGETS: dict[tuple[str, str, tuple], tuple[Any, float, str]] = {
    ("volume.composite", "speedup_fwd_bwd", ()): (operator.ge, 10.0, "fwd+bwd >= 10x PyTorch"),
    ("volume.composite_fwd", "speedup_fwd", ()): (operator.ge, 2.0, "fwd >= 2x PyTorch"),
    # Judged on the unsigned-max read (bound_max_s): the faster read of the same bytes is the tighter bound.
    # fwd keeps the per-sample factors for a backward; fwd_no_factor (keep_factor=False) is the forward of a render
    # that is never backpropagated (no per-sample state), judged on its own line.
    ("volume.composite", "fwd_over_bound", ()):
        (operator.le, 2.0, "fwd (factors kept for a backward) <= 2x the read bound (float-sum read, shown)"),
    ("volume.composite", "fwd_over_bound_max", ()):
        (operator.le, 2.0,
         "fwd (factors kept for a backward) <= 2x the read bound (unsigned-max read: the target's case)"),
    ("volume.composite", "fwd_no_factor_over_bound_max", ()):
        (operator.le, 2.0, "fwd_no_factor (keep_factor=False, no backward) <= 2x the read bound (unsigned-max read)"),
    ("volume.spheres_render", "render_s", ()): (operator.le, 0.005, "<= 5 ms (general path: packed samples)"),
    ("volume.spheres_render", "render_fused_s", ()):
        (operator.le, 0.005, "<= 5 ms (fused render_dense, as the experiment)"),
    ("volume.field.hashgrid", "fwd_bwd_s", ()): (operator.le, 2.0, "fwd+bwd <= 2 s at 1M points"),
    ("launch.split", "speedup", ()): (operator.ge, 1.9, ">= 1.9x on 2 cores"),
    ("corr.build", "speedup_build", ()): (operator.ge, 1.0, "build no slower than PyTorch matmul + pooling"),
    ("corr.lookup", "speedup_fwd", ()): (operator.ge, 2.0, "dense lookup >= 2x grid_sample"),
    # The on-the-fly targets are judged on the float16-feature case; the float32 rows stay beside them.
    ("corr.lookup_onthefly_float16", "ratio_to_dense_fwd", ()):
        (operator.le, 3.0, "on-the-fly within 3x of the dense lookup (float16 features: the target's case)"),
    ("corr.lookup_onthefly_float16", "memory_ratio", ()):
        (operator.ge, 10.0, "on-the-fly holds >= 10x less memory (float16 features: the target's case)"),
    ("corr.lookup_onthefly", "ratio_to_dense_fwd", ()):
        (operator.le, 3.0, "on-the-fly within 3x of the dense lookup (float32 features, shown beside it)"),
    ("corr.lookup_onthefly", "memory_ratio", ()):
        (operator.ge, 10.0, "on-the-fly holds >= 10x less memory (float32 features, shown beside it)"),
    # The default SGM pipeline is research.stereo.matching.DEFAULT_CONFIG ("adcensus" + SGM-8 + post-processing), timed by
    # stereo.default; stereo.sgm times StereoConfig()'s field defaults (census + SGM-8), judged on its own line.
    ("stereo.default", "speedup_total", (("height", 256), ("width", 256), ("disparities", 64))):
        (operator.ge, 0.2, "default SGM pipeline (DEFAULT_CONFIG) <= 5x OpenCV StereoSGBM's time at 256x256x64"),
    ("stereo.default", "speedup_total", (("height", 500), ("width", 741), ("disparities", 64))):
        (operator.ge, 0.2, "default SGM pipeline (DEFAULT_CONFIG) <= 5x OpenCV StereoSGBM's time at 741x500x64"),
    ("stereo.sgm", "speedup_total", (("height", 256), ("width", 256), ("disparities", 64))):
        (operator.ge, 0.2, "census + SGM-8 (StereoConfig field defaults) <= 5x SGBM at 256x256x64"),
    ("stereo.sgm", "speedup_total", (("height", 500), ("width", 741), ("disparities", 64))):
        (operator.ge, 0.2, "census + SGM-8 (StereoConfig field defaults) <= 5x SGBM at 741x500x64"),
    ("splat.render", "speedup_rasterize", (("gaussians", 2000), ("height", 128), ("width", 128))):
        (operator.ge, 100.0, "rasteriser >= 100x the dense reference at 2000 Gaussians, 128x128"),
    ("splat.render", "fwd_s", (("gaussians", 1_000_000), ("height", 1080), ("width", 1920))):
        (operator.le, 1.0, "forward <= 1 s at 1M Gaussians, 1920x1080"),
}
README_START = "<!-- performance table: written by experiments/performance.py (make reproduce) -->"
README_END = "<!-- end of the performance table -->"
# Keys that describe a case's size (shown in the sizes column), in this order when present.
_NOT_SIZES = {"bench", "device", "threads", "cpu", "ref", "ref_missing", "params"}


def add_options(p: argparse.ArgumentParser) -> None:
    from research.registry import family_modules

    p.add_argument("--families", nargs="+", default=None, metavar="FAMILY",
                   help=f"bench families to run (default: all of {', '.join(family_modules('bench'))})")
    p.add_argument("--repeats", type=int, default=None, metavar="N",
                   help="run every family N times and report per-figure medians with the lowest and highest run "
                        "(default: 3 at full size, 1 for --quick / --smoke)")


def _sizes(row: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in row.items()
                     if k not in _NOT_SIZES and isinstance(v, int) and not isinstance(v, bool))


def _lines(row: dict) -> list[dict]:
    """One line per timed phase (`<phase>_s`) of a bench row, with its reference where timed."""
    out = []
    for key, value in row.items():
        if (not key.endswith("_s") or key.endswith("_per_s") or key.startswith("ref_")
                or not isinstance(value, float)):
            continue
        phase = key[:-2]
        ref_s = row.get(f"ref_{phase}_s")
        if ref_s is not None:
            reference = row.get("ref", "")
        else:
            reference = f"not installed: {row['ref_missing'].split()[0]}" if "ref_missing" in row else ""
        out.append({"case": row["bench"], "sizes": _sizes(row), "phase": phase, "drlab_s": value,
                    "reference": reference, "ref_s": ref_s, "speedup": row.get(f"speedup_{phase}"),
                    "runs": row.get("runs", {})})
    return out


def _merge_runs(runs: list[list[dict]]) -> list[dict]:
    """One row per bench row of the repeated runs: every float is the median over the runs, and
    `runs` holds each float key's values run by run (for the spread and the per-run target count).

    The runs must list the same cases in the same order with the same integer sizes (the bench
    families are deterministic in their inputs); a mismatch raises rather than pairing wrong rows.
    """
    if not runs:
        return []
    if any(len(r) != len(runs[0]) for r in runs):
        raise ValueError(f"--repeats: the runs returned different numbers of rows {[len(r) for r in runs]}")
    merged = []
    for rows in zip(*runs):
        first = rows[0]
        for other in rows[1:]:
            same = {k: v for k, v in other.items() if not isinstance(v, float)}
            if same != {k: v for k, v in first.items() if not isinstance(v, float)}:
                raise ValueError(f"--repeats: run rows differ: {first.get('bench')} vs {other.get('bench')}")
        row = dict(first)
        per_run = {}
        for key, value in first.items():
            if isinstance(value, float):
                values = [r[key] for r in rows]
                row[key] = statistics.median(values)
                per_run[key] = values
        if len(rows) > 1:
            row["runs"] = per_run
        merged.append(row)
    return merged


def _shown(key: str, value: float) -> str:
    return f"{1e3 * value:.3g} ms" if key.endswith("_s") else f"{value:.3g}x" if "speedup" in key else f"{value:.3g}"


def _target_status(row: dict, full: bool) -> list[tuple[str, str, Any, str]]:
    """(case, target text, measured value, met / NOT met / n/a) for every target of this row.

    With repeated runs (a merged row's `runs`), the value is the median with the range beside it, the
    status is judged on the median, and the runs that met the target are counted."""
    found = []
    for (case, key, where), (op, bound, text) in TARGETS.items():
        if row["bench"] != case or key not in row or any(row.get(k) != v for k, v in where):
            continue
        value = row[key]
        status = ("met" if op(value, bound) else "NOT met") if full else "n/a (not full size)"
        shown = _shown(key, value)
        values = row.get("runs", {}).get(key)
        if values:
            shown += f" (runs {_shown(key, min(values))} to {_shown(key, max(values))})"
            if full:
                status += f", met in {sum(bool(op(v, bound)) for v in values)} of {len(values)} runs"
        found.append((case, text, shown, status))
    return found


def run(ctx: Context) -> int:
    from research.bench import run_bench
    from research.registry import family_modules
    from research.results import host

    benches = family_modules("bench")
    families = ctx.args.families or list(benches)
    unknown = [f for f in families if f not in benches]
    if unknown:
        raise ValueError(f"--families: unknown {unknown}; registered: {', '.join(benches)}")
    full = ctx.mode == "full"
    repeats = ctx.args.repeats if ctx.args.repeats is not None else (3 if full else 1)
    if repeats < 1:
        raise ValueError(f"--repeats: expected a positive count, got {repeats}")
    runs: list[list[dict]] = []
    with ctx.tqdm(total=repeats * len(families), desc="bench families", disable=None) as bar:
        for _ in range(repeats):
            rows: list[dict] = []
            for family in families:
                rows += run_bench([family], ctx.device, quick=ctx.quick, compare=True, tiny=ctx.smoke)
                bar.update(1)
            runs.append(rows)
    rows = _merge_runs(runs)

    lines = [line for row in rows for line in _lines(row)]
    ms = lambda s: None if s is None else 1e3 * s  # noqa: E731

    def spread(ln: dict, key: str, fmt) -> str:
        values = ln["runs"].get(key)
        return f"{fmt(min(values))}-{fmt(max(values))}" if values else "-"

    table_rows = [[ln["case"], ln["sizes"], ln["phase"],
                   ms(ln["drlab_s"]), ln["reference"] or "-", "-" if ln["ref_s"] is None else ms(ln["ref_s"]),
                   "-" if ln["speedup"] is None else f"{ln['speedup']:.2f}x"]
                  + ([spread(ln, f"{ln['phase']}_s", lambda v: f"{1e3 * v:.3g}"),
                      spread(ln, f"speedup_{ln['phase']}", lambda v: f"{v:.2f}x")] if repeats > 1 else [])
                  for ln in lines]
    headers = ["case", "sizes", "phase", "drlab ms", "reference", "reference ms", "ratio"]
    if repeats > 1:
        headers += ["drlab ms, runs (min-max)", "ratio, runs (min-max)"]
    targets = [t for row in rows for t in _target_status(row, full)]
    cpu = host()
    threads = sorted({r["threads"] for r in rows})
    table = (f"Host: {cpu['cpu']}, {cpu['cpus']} logical CPUs; drlab threads {threads}; device `{ctx.device}`; "
             f"sizes: {ctx.mode}. Times in ms, medians of 3-5 runs after a warm-up; the reference ran "
             "interleaved with drlab on the same inputs and thread count. Ratio = reference / drlab "
             "(> 1: drlab is faster)."
             + (f" Every family ran {repeats} times in turn: each figure is the median over those runs "
                "(ratios: the median of the runs' own interleaved ratios), with the lowest and highest run "
                "beside it." if repeats > 1 else "") + "\n\n"
             + markdown_table(headers, table_rows, floatfmt=".3g")
             + "\n\nTargets:\n\n"
             + markdown_table(["case", "target", "measured", "status"],
                              [[c, t, v, s] for c, t, v, s in targets], floatfmt=".3g") + "\n")
    figure(lines, ctx.out / "figure.png")
    metrics = {"rows": rows, "targets": [{"case": c, "target": t, "measured": v, "status": s}
                                         for c, t, v, s in targets],
               "host": cpu,
               "n_with_reference": sum(ln["ref_s"] is not None for ln in lines)}
    config = {"smoke": ctx.smoke, "families": families, "compare": True, "repeats": repeats}
    ctx.write_results(config=config, metrics=metrics, table_md=table)
    if full and registry.in_checkout() and ctx.final_out.resolve() == registry.default_out("performance").resolve():
        ctx.after_commit(lambda: refresh_readme(registry.REPO_ROOT / "docs" / "performance.md", table))
    return 0


def refresh_readme(readme: Path, table_md: str) -> str:
    """Replace the text between README_START and README_END in `readme` with `table_md`."""
    from research import atomic

    text = readme.read_text()
    start, end = text.find(README_START), text.find(README_END)
    if start < 0 or end < start:
        return f"{readme}: no performance-table markers; README not changed"
    body = text[:start + len(README_START)] + "\n" + table_md.strip() + "\n" + text[end:]
    atomic.write_text(readme, body)
    return f"{readme}: performance table refreshed"


def figure(lines: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    compared = [ln for ln in lines if ln["speedup"] is not None]
    fig, ax = plt.subplots(figsize=(8, 0.4 * max(len(compared), 1) + 1.2))
    if compared:
        labels = [f"{ln['case']} {ln['phase']}" for ln in compared]
        vals = [ln["speedup"] for ln in compared]
        ax.barh(labels, vals, color=["tab:green" if v >= 1 else "tab:red" for v in vals])
        ax.axvline(1.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_xlabel("reference time / drlab time (> 1: drlab faster)")
    else:
        ax.text(0.5, 0.5, "no reference library installed (pip install drlab[bench])", ha="center", va="center")
        ax.set_axis_off()
    ax.set_title("drlab vs reference libraries, same CPU, interleaved timing", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


main = Experiment("performance", __doc__, run, add_options, seed_help="unused: inputs use fixed seeds; recorded",
                  sizes="Full: each family's full sizes (the targets are checked there); quick: each family's "
                        "--quick sizes; smoke: each family's test sizes (seconds).").script(__name__)
