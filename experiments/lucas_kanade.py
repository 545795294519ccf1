#!/usr/bin/env python3
"""The Lucas-Kanade task of the Video and 3D Vision textbook chapter: a white 20x20 square moved 5 px right.

A 64x64 frame holds a white square at rows 20-40, columns 15-35; in the second
frame it sits 5 px further right. The textbook computes LK with a 7x7 window and
prints the average horizontal flow over the pixels of that region where a flow
was solved; the truth is 5.0 and it prints -0.00.

What goes wrong. Its "Ix" is `frame1[2:, :] - frame1[:-2, :]`, a difference
along axis 0, the ROWS: that is dI/dy. Its "Iy" is the column difference, dI/dx.
The normal equations are therefore solved for (v, u), and the printed "u" is the
VERTICAL flow, which is zero for a horizontal motion (-0.00 is its rounding
noise). The horizontal estimate sits in the unprinted "v". Correcting the labels
still leaves single-scale LK far from 5.0: one linearisation of a step edge
reaches about one pixel, and a 5 px motion needs coarse-to-fine (pyramidal)
estimation with re-warping, which recovers 5.0.

Rows of the table:
  1. the textbook code as written (NumPy port of its JAX loops);
  2. the same code with the gradient axes corrected (the only change);
  3. kernels.lucas_kanade.lucas_kanade, one step (the textbook's single-scale solve);
  4. kernels.lucas_kanade.lucas_kanade, 10 iterations with warping, still single scale;
  5. kernels.lucas_kanade.pyramidal_lucas_kanade, 3 levels, 10 iterations per level.

Writes results/lucas_kanade/{table.md, metrics.json, quiver.png}.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from research.experiment import Context, Experiment
from research.results import finish_figure, markdown_table

SIZE, ROWS, COLS, SHIFT = 64, (20, 40), (15, 35), 5
WINDOW = 7  # the textbook's window_size


def frames() -> tuple[np.ndarray, np.ndarray]:
    f1 = np.zeros((SIZE, SIZE))
    f1[ROWS[0]:ROWS[1], COLS[0]:COLS[1]] = 1.0
    f2 = np.zeros((SIZE, SIZE))
    f2[ROWS[0]:ROWS[1], COLS[0] + SHIFT:COLS[1] + SHIFT] = 1.0
    return f1, f2


def textbook_lk(frame1: np.ndarray, frame2: np.ndarray, window_size: int = WINDOW,
                fix_axes: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The textbook's loops, ported from JAX to NumPy; `fix_axes` swaps its gradient labels and nothing else.

    Returns its (u, v): with fix_axes False, u multiplies the row derivative (the vertical flow).
    """
    row_diff = np.zeros_like(frame1)
    col_diff = np.zeros_like(frame1)
    it = frame2 - frame1
    row_diff[1:-1, :] = (frame1[2:, :] - frame1[:-2, :]) / 2  # d/dy: the textbook calls this Ix
    col_diff[:, 1:-1] = (frame1[:, 2:] - frame1[:, :-2]) / 2  # d/dx: the textbook calls this Iy
    ix, iy = (col_diff, row_diff) if fix_axes else (row_diff, col_diff)
    h, w = frame1.shape
    half = window_size // 2
    u = np.zeros_like(frame1)
    v = np.zeros_like(frame1)
    for i in range(half, h - half):
        for j in range(half, w - half):
            win = (slice(i - half, i + half + 1), slice(j - half, j + half + 1))
            a = np.stack([ix[win].ravel(), iy[win].ravel()], axis=1)
            ata = a.T @ a
            atb = -a.T @ it[win].ravel()
            det = ata[0, 0] * ata[1, 1] - ata[0, 1] * ata[1, 0]
            if abs(det) > 1e-6:
                u[i, j], v[i, j] = np.linalg.solve(ata, atb)
    return u, v


def region_stats(u: np.ndarray, v: np.ndarray, valid: np.ndarray) -> dict:
    """The textbook's statistic (mean u over the nonzero u of the region) and a few more."""
    region = (slice(*ROWS), slice(*COLS))
    ur, vr, val = u[region], v[region], valid[region]
    return {
        "textbook_mean_u": float(ur[ur != 0].mean()) if np.any(ur != 0) else float("nan"),
        "mean_u_valid": float(ur[val].mean()) if val.any() else float("nan"),
        "mean_v_valid": float(vr[val].mean()) if val.any() else float("nan"),
        "valid_pixels": int(val.sum()),
        "max_abs_err_valid": float(np.abs(np.stack([ur[val] - SHIFT, vr[val]])).max()) if val.any() else float("nan"),
    }


def quiver_figure(f1: np.ndarray, f2: np.ndarray, panels: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]],
                  path: Path) -> None:
    """Frames, then one quiver panel per (title, u, v, valid): arrows at valid pixels only, true length."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2 + len(panels), figsize=(3.4 * (2 + len(panels)), 3.6))
    axes[0].imshow(f1, cmap="gray")
    axes[0].set_title("frame 1")
    axes[1].imshow(f2, cmap="gray")
    axes[1].set_title("frame 2 (+5 px in x)")
    step = 2
    yy, xx = np.mgrid[0:SIZE:step, 0:SIZE:step]
    for ax, (title, u, v, valid) in zip(axes[2:], panels):
        ax.imshow(0.5 * f1 + 0.25 * f2, cmap="gray", vmin=0, vmax=1)
        su, sv = u[::step, ::step], v[::step, ::step]
        keep = valid[::step, ::step]
        # Image coordinates: y down, so the arrows use angles="xy" with the axis inverted by imshow.
        ax.quiver(xx[keep], yy[keep], su[keep], -sv[keep], color="#e74c3c", angles="xy", scale_units="xy",
                  scale=1.0, width=0.006)
        ax.set_title(title, fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    finish_figure(fig, path)


def run(ctx: Context) -> int:
    from kernels import lucas_kanade as flow

    f1, f2 = frames()
    runs: dict[str, dict] = {}
    flows: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def record(name: str, u: np.ndarray, v: np.ndarray, valid: np.ndarray, seconds: float) -> None:
        runs[name] = {**region_stats(u, v, valid), "seconds": seconds}
        flows[name] = (u, v, valid)

    t0 = time.perf_counter()
    u, v = textbook_lk(f1, f2)
    # As written, the textbook's u is the vertical flow and its v the horizontal one.
    record("textbook as written (prints its u)", u, v, (u != 0) | (v != 0), time.perf_counter() - t0)
    runs["textbook as written (prints its u)"]["its_v_mean_nonzero"] = float(
        v[20:40, 15:35][v[20:40, 15:35] != 0].mean())
    t0 = time.perf_counter()
    u, v = textbook_lk(f1, f2, fix_axes=True)
    record("textbook, axes fixed", u, v, (u != 0) | (v != 0), time.perf_counter() - t0)

    half = WINDOW // 2
    settings = [("kernels.lucas_kanade single scale, 1 step", dict(iterations=1), False),
                ("kernels.lucas_kanade single scale, 10 steps", dict(iterations=10), False),
                ("kernels.lucas_kanade pyramidal, 3 levels x 10 steps", dict(levels=3, iterations=10), True)]
    for name, kwargs, pyramidal in settings:
        fn = flow.pyramidal_lucas_kanade if pyramidal else flow.lucas_kanade
        fn(f1, f2, half_window=half, device=ctx.device, **kwargs)  # warm-up: compilation is not timed
        t0 = time.perf_counter()
        fl, valid, _ = fn(f1, f2, half_window=half, device=ctx.device, **kwargs)
        record(name, fl[..., 0], fl[..., 1], valid, time.perf_counter() - t0)

    headers = ["method", "printed mean u (textbook statistic)", "mean u, valid px", "mean v, valid px",
               "valid px in region", "max abs error, valid px", "seconds"]
    rows = [[name, r["textbook_mean_u"], r["mean_u_valid"], r["mean_v_valid"], r["valid_pixels"],
             r["max_abs_err_valid"], r["seconds"]] for name, r in runs.items()]
    written = runs["textbook as written (prints its u)"]
    table = (
        "Square 20x20 moved 5 px right (truth u = 5.0, v = 0); 7x7 window. 'Printed mean u' is the textbook's "
        "statistic: the mean of u over the pixels of rows 20-40, columns 15-35 where u != 0. Valid pixels: the "
        "textbook's `|det| > 1e-6` for its rows, min-eigenvalue >= 1e-4 for kernels.lucas_kanade.\n\n"
        + markdown_table(headers, rows, floatfmt=".3f")
        + f"\nThe textbook's printed value is {written['textbook_mean_u']:.2f}: its `Ix` differentiates along the "
        "rows (dI/dy), so its `u` is the vertical flow, zero for this motion. Its unprinted `v` holds the "
        f"horizontal estimate ({written['its_v_mean_nonzero']:.2f}). With the axes fixed, single-scale LK still "
        f"reaches only {runs['textbook, axes fixed']['textbook_mean_u']:.2f} px, as one linearisation of a step "
        "edge cannot see a 5 px motion; the pyramid with warping gives "
        f"{runs['kernels.lucas_kanade pyramidal, 3 levels x 10 steps']['mean_u_valid']:.3f} px at its valid pixels.\n")
    quiver_figure(f1, f2, [("textbook as written: its (u, v) drawn as (x, y)",
                            *flows["textbook as written (prints its u)"]),
                           ("axes fixed, single scale", *flows["textbook, axes fixed"]),
                           ("pyramidal LK (valid pixels)", *flows["kernels.lucas_kanade pyramidal, 3 levels x 10 steps"])],
                  ctx.out / "quiver.png")
    ctx.write_results(config={"size": SIZE, "rows": ROWS, "cols": COLS, "shift": SHIFT,
                              "window": WINDOW, "min_eigenvalue": 1e-4},
                      metrics={"runs": runs, "truth_u": float(SHIFT)}, table_md=table)
    return 0


main = Experiment("lucas_kanade", __doc__, run, seed_help="unused: the task is deterministic; recorded",
                  sizes="The task is the same in every mode (it takes seconds).").script(__name__)
