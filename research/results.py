"""Writing an experiment's results directory: metrics.json, table.md and figures.

Every file goes through research.atomic, so an interrupted experiment never
leaves a results directory whose files look whole but are not.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Any, Sequence

from research import atomic

_PACKAGES = ("drlab", "warp-lang", "mitsuba", "drjit", "numpy", "scipy", "OpenImageIO")


def host(cpuinfo: str | Path = "/proc/cpuinfo") -> dict[str, Any]:
    """The machine the numbers were measured on: CPU model, logical CPU count and widest SIMD.

    Timings depend on it. So, bit for bit, did Mitsuba's renders: with identical package versions,
    the 256x256 `objects` dataset of seed 0 had content hash c1affd34... on one 2-core machine and
    394a82c6... on an AVX-512 AMD EPYC (Dr.Jit compiles its LLVM kernels for the host CPU; the
    vector width is the likely cause). A content hash is reproducible on one kind of machine.
    """
    model, flags, ids = "", set(), {}
    try:
        with open(cpuinfo) as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and not model:
                    model = value.strip()
                elif key.strip() in ("flags", "Features") and not flags:
                    flags = set(value.split())
                elif key.strip() in ("cpu family", "model") and key.strip() not in ids:
                    ids[key.strip()] = value.strip()  # a virtual machine's model name may be just "AMD EPYC"
    except OSError:  # not Linux
        pass
    model = model or platform.processor() or platform.machine()
    if ids:
        model += " (" + ", ".join(f"{k} {v}" for k, v in ids.items()) + ")"
    simd = next((s for s in ("avx512f", "avx2", "avx", "sse4_2", "neon", "asimd") if s in flags), "unknown")
    return {"cpu": model or "unknown", "cpus": os.cpu_count() or 1, "simd": simd}


def versions() -> dict[str, str]:
    """Versions of Python and of the packages whose behaviour the numbers depend on."""
    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def source_revision() -> dict[str, Any]:
    """The git commit of the code that produced the numbers, and whether the tree had local changes.

    Read from the repository this module lives in; {"commit": None} outside a git checkout.
    """
    repo = Path(__file__).resolve().parent.parent

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    if commit is None:
        return {"commit": None}
    # Only tracked files outside results/ and other than Markdown count: data/, build/, the results
    # being written and documentation do not change the numbers.
    changes = git("status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)results", ":(exclude)*.md")
    return {"commit": commit, "dirty": bool(changes)}


# Taken when the experiment imports this module, i.e. for the code it loaded: a long run whose
# checkout changes before it writes its results still reports the commit it started from.
SOURCE_AT_IMPORT = source_revision()


def markdown_table(headers: Sequence[str], rows: Sequence[Sequence[Any]], floatfmt: str = ".4g") -> str:
    """A GitHub-flavoured Markdown table. Floats use `floatfmt`; other values use str()."""

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return format(v, floatfmt)
        return str(v)

    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    for row in rows:
        if len(row) != len(headers):
            raise ValueError(f"row {row!r} has {len(row)} cells, expected {len(headers)}")
        lines.append("| " + " | ".join(cell(v) for v in row) + " |")
    return "\n".join(lines) + "\n"


def write_results(
    out_dir: str | Path,
    *,
    experiment: str,
    config: dict[str, Any],
    seed: int,
    device: str,
    wall_time_s: float,
    metrics: dict[str, Any],
    table_md: str,
) -> Path:
    """Write `metrics.json` and `table.md` into `out_dir` (atomically, file by file)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    payload = {
        "experiment": experiment,
        "config": config,
        "seed": seed,
        "device": device,
        "wall_time_s": wall_time_s,
        "versions": versions(),
        "host": host(),
        "source": SOURCE_AT_IMPORT,
        "metrics": metrics,
    }
    atomic.write_json(out / "metrics.json", payload)
    atomic.write_text(out / "table.md", table_md)
    return out


def save_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Save a matplotlib figure as PNG atomically."""
    path = Path(path)
    with atomic.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight")
    return path


def finish_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Lay out a finished matplotlib figure, save it (save_figure) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = save_figure(fig, path, dpi=dpi)
    plt.close(fig)
    return path


def loss_figure(losses: dict[str, Any], ylabel: str, path: str | Path) -> Path:
    """Training-loss curves, one per name, each a running mean over 1/100 of its length, on a log axis."""
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    for name, loss in losses.items():
        loss = np.asarray(loss)
        w = max(1, len(loss) // 100)
        ax.plot(np.convolve(loss, np.ones(w) / w, mode="valid"), label=name)
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel(ylabel)
    ax.legend()
    return finish_figure(fig, path)


def trajectory_top_view(ax, gt, title: str) -> None:
    """Finish a top view (x, y) of camera centres whose lines are drawn: the ground truth's start
    marked, equal axes, labels, a small title and the legend. gt: (N, 4, 4) camera-to-world."""
    ax.scatter(gt[:1, 0, 3], gt[:1, 1, 3], c="k", marker="s", s=30, label="start", zorder=4)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)


def trajectory_error_panel(ax, errors: dict[str, tuple[Any, str]]) -> None:
    """Per-frame position errors after alignment, one curve per label: {label: (errors, colour)}."""
    for label, (err, colour) in errors.items():
        ax.plot(err, c=colour, label=label)
    ax.set_xlabel("frame")
    ax.set_ylabel("position error after alignment")
    ax.set_title("absolute trajectory error per frame", fontsize=10)
    ax.legend(fontsize=8)


def image_panel(fig, ax, img, title: str | None, colorbar: bool = False, fontsize: int = 9, **imshow) -> None:
    """One image panel of a figure: `ax.imshow(img, **imshow)`, a colour bar if asked, a small title (none if
    title is None) and no ticks."""
    im = ax.imshow(img, **imshow)
    if colorbar:
        fig.colorbar(im, ax=ax, fraction=0.046)
    if title is not None:
        ax.set_title(title, fontsize=fontsize)
    ax.set_xticks([])
    ax.set_yticks([])


def image_grid(panels: Sequence[Sequence[tuple[Any, str | None]]], path: str | Path, cell: tuple[float, float],
               fontsize: int = 9, **imshow) -> Path:
    """A figure of image panels, `panels[r][c] = (image, title)` (image_panel with `fontsize` and `imshow`), each
    cell `cell` = (width, height) inches; laid out, saved to `path` and closed (finish_figure)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = len(panels[0])
    fig, axes = plt.subplots(len(panels), cols, figsize=(cell[0] * cols, cell[1] * len(panels)), squeeze=False)
    for r, row in enumerate(panels):
        for c, (img, title) in enumerate(row):
            image_panel(fig, axes[r, c], img, title, fontsize=fontsize, **imshow)
    return finish_figure(fig, path)
