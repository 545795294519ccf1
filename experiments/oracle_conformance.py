#!/usr/bin/env python3
"""drlab's kernels against their second oracle, Dr.Jit's AD (research/oracles), at full size.

Every kernel family with an oracle (docs/conformance.md says which have none) has its forward
written again in Dr.Jit (LLVM backend, its own reverse-mode AD) from the equations in the kernel
modules' docstrings; the splat chain follows the original 3DGS code. For random inputs, each case
compares drlab's forward and its hand-written backward (the VJP for a random cotangent) with the
oracle's, in float64 and in float32 (drlab float32 against the oracle float32, and against the
oracle float64), at the sizes the kernels run at:

  * ssim          a 256x256x3 image pair (map, d/dx, d/dy);
  * stereo        SAD (r 2) and ZNCC (r 3) volumes 256x256x64; feature correlation 32 channels,
                  256x256x64 (volume, d features); soft-argmin over a 256x256x64 volume (disparity,
                  d cost);
  * corr          a RAFT pyramid at 46x62 (1/8 of 368x496), 64 channels, 4 levels, radius 4:
                  dense (volume, pyramid, lookup) and on-the-fly paths (lookup, d f1, d f2, d coords);
  * volume        a dense grid of 64^3 vertices with SH degree 2 colour at 65,536 points (sigma,
                  rgb, d density, d colour); a hash-grid field (16 levels, 2^19 entries, finest level
                  128^3, MLP 32-64-64-4) at 65,536 points (sigma, rgb, d of every parameter); the
                  renderer's camera gradients: 128x128 pixel rays x 64 fixed samples through a 32^3
                  grid with SH degree 2 colour, early termination at T < 0.01 (rgb, depth, opacity,
                  d pose xi (6) and d intrinsics (4), kernels/volume/rays.py);
  * splat         3,000 Gaussians (SH degree 3) rendered at 256x256 in the default ("3dgs") mode
                  (rgb, alpha, depth, d means, log-scales, quaternions, opacity logits, SH, background,
                  and the camera's pose (6) and intrinsics (4)).
  * points        the chamfer distance of two 4,096-point clouds (value, d x, d y; kernels/points/chamfer.py),
                  the oracle by brute force over all pairs;
  * lens          4,000 Gaussians projected through the opencv, fisheye and orthographic lenses (mean,
                  conic, depth, colour, opacity; d splat parameters, pose and intrinsics);
  * splat_geometry normals from a 256x256 depth map (d depth), 100,000 splats' shortest-axis normals
                  (d quaternions), the expected depth of a 256x256 image (d depth, d alpha);
  * mip_filter    Mip-Splatting's 3D filter of 200,000 Gaussians (d log-scales, d opacity logits);
  * appearance    a 256x256 image through an 8x16x16 bilateral grid and through one affine (d grid,
                  d image);
  * unbounded     the interval weights of 4,096 rays x 48 intervals (d density) and the interlevel
                  loss of 32 main against 48 proposal intervals (d proposal weights);
  * ba            200,000 reprojections into 20 cameras (residuals, depths; the pose, point and depth
                  Jacobians in the VJP columns);
  * pointnet      the max-pool of 4,096 sets of 32 rows x 128 channels and the grouping of 4,096
                  centres x 32 neighbours (d x, d points);
  * icp           200,000 correspondences with one in ten an outlier, point-to-point with Huber and
                  point-to-plane with Geman-McClure weights (residuals, weights, rho; the pose Jacobians
                  in the VJP columns) and their normal equations (cost; H and g, g also against the
                  oracle's AD gradient of the robust cost).

The cases are those of every family registered in research.registry.FAMILIES with an `oracle_cases`
module (research/oracles/cases/<family>.py: its sizes per mode and its case builders), in the
registry's order; a new family's cases join the table by that one registration.

Differences are normwise: max |drlab - oracle| over all outputs of a kind, and that divided by the
oracle's largest value of the same outputs (the "rel" columns). Times: one call each (the oracle's
includes Dr.Jit's tracing and, on the first run on a machine, its LLVM compilation; drlab's kernels
are loaded from Warp's cache after a warm-up call).

Writes results/oracle_conformance/{table.md, metrics.json, figure.png}.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from research.experiment import Context, Experiment
from research.oracles.cases import compare, merged_sizes, registered_cases
from research.results import markdown_table, save_figure


def run(ctx: Context) -> int:
    families = registered_cases()  # every family's cases (research.registry.FAMILIES), in its order
    rows, metrics = [], {}
    for fc, case in ctx.tqdm([(fc, c) for fc in families for c in fc.cases], desc="oracle cases"):
        # warm-up at the smoke size: Warp's kernels load once per dtype
        entry, has_vjp = compare(fc.family, case, fc.sizes[ctx.mode], fc.sizes["smoke"], ctx.seed)
        for label in ("float64", "float32", "float32 vs oracle64"):
            e = entry[label]
            td, to = e["drlab_s"], e["oracle_s"]
            rows.append([fc.family, case.name, entry["size"], label, e["fwd_abs"], e["fwd_rel"],
                         "-" if not has_vjp else e["vjp_abs"], "-" if not has_vjp else e["vjp_rel"],
                         "-" if td is None else f"{td:.2f}", "-" if to is None else f"{to:.2f}"])
        metrics[case.name] = entry
    worst64 = max(max(e["float64"]["fwd_rel"], np.nan_to_num(e["float64"]["vjp_rel"])) for e in metrics.values())
    table = ("Every kernel family that has a Dr.Jit oracle against it (research/oracles), normwise: abs = max |drlab - "
             "oracle| over the outputs, rel = abs / max |oracle|; fwd = forward outputs, VJP = every input's "
             "vector-Jacobian product for one random cotangent. `float32` compares drlab and the oracle both "
             "in float32; `float32 vs oracle64` drlab's float32 result against the float64 oracle on the same "
             f"inputs. Times: one call each, in seconds, on `{ctx.device}` (the oracle's include Dr.Jit's "
             "tracing and compilation). Seed " + str(ctx.seed) + ".\n\n"
             + markdown_table(["family", "case", "size", "precision", "fwd abs", "fwd rel", "VJP abs", "VJP rel",
                               "drlab s", "oracle s"], rows, floatfmt=".2e")
             + f"\nLargest float64 relative difference: {worst64:.1e} (the conformance target is 1e-10).\n")
    figure(metrics, ctx.out / "figure.png")
    S = merged_sizes(families, ctx.mode)
    ctx.write_results(config={"mode": ctx.mode, "sizes": {k: list(v) if isinstance(v, tuple) else v
                                                          for k, v in S.items()}},
                      metrics={"cases": metrics, "worst_float64_rel": worst64}, table_md=table, device="cpu")
    return 0


def figure(metrics: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(metrics)
    series = [("float64", "fwd_rel", "float64 forward"), ("float64", "vjp_rel", "float64 VJP"),
              ("float32", "fwd_rel", "float32 forward"), ("float32", "vjp_rel", "float32 VJP")]
    fig, ax = plt.subplots(figsize=(11, 4.2))
    width = 0.2
    x = np.arange(len(names))
    for i, (prec, key, label) in enumerate(series):
        vals = [metrics[n][prec][key] for n in names]
        vals = [v if np.isfinite(v) and v > 0 else np.nan for v in vals]
        ax.bar(x + (i - 1.5) * width, vals, width, label=label)
    ax.axhline(1e-10, color="k", lw=0.8, ls="--", label="1e-10")
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=25, ha="right", fontsize=8)
    ax.set_ylabel("max |drlab - oracle| / max |oracle|")
    ax.set_title("drlab vs its Dr.Jit AD oracle")
    ax.legend(fontsize=8, ncol=5)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


main = Experiment("oracle_conformance", __doc__, run, warp=False,
                  seed_help="seed of the random inputs",
                  sizes="Full (default): the sizes listed above, a few minutes on 2 cores. Quick: a quarter of "
                        "the pixels, a third of the points. Smoke: tiny sizes, seconds.").script(__name__)
