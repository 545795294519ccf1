"""Novel-view synthesis methods side by side, in the form of Table 1 of Kerbl et al. 2023 (3DGS).

One row per method: SSIM, PSNR, training time, rendering FPS and model size ("Mem"); LPIPS is not
computed in drlab, so its column is left out. The rows come from the metrics.json files that
experiments/fit_splats.py and experiments/fit_nerf.py write; each experiment's schema is read by
its own function below (no guessing of key names), and a missing key is an error.

Rows are only put in one table when they were evaluated the same way on the same data: every run
must report the same `eval_protocol` (research.metrics.EVAL_PROTOCOL for drlab's renders, the
dataset's Protocol description for NeRF-synthetic or Mip-NeRF 360 data, research.datasets), the
same dataset content hash (the manifest's SHA-256 over every file, so the same scene, views, splits
and render noise; for external data the hash over the files read) and the same dataset label
(format, scene and protocol, from metrics["data"]; empty for runs written before it existed).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from research import atomic
from research.results import markdown_table


@dataclass(frozen=True)
class MethodRow:
    method: str
    ssim: float
    psnr: float
    train_s: float
    fps: float
    size_bytes: int
    size_note: str
    eval_protocol: str
    dataset_hash: str
    device: str
    dataset: str = ""  # "<scene> (<format>, <protocol>)"; "" for results written before it was recorded


def _data_label(m: dict[str, Any]) -> str:
    d = m.get("data")
    return f"{d['scene']} ({d['format']}, {d['protocol']})" if isinstance(d, dict) else ""


def _require(tree: dict[str, Any], key: str, source: str) -> Any:
    if key not in tree:
        raise ValueError(f"{source}: metrics has no {key!r}; re-run the experiment with the current code")
    return tree[key]


def rows_fit_splats(doc: dict[str, Any], source: str) -> list[MethodRow]:
    m = doc["metrics"]
    return [MethodRow(
        method=_require(m, "method", source), ssim=_require(m, "test_ssim", source),
        psnr=_require(m, "test_psnr", source), train_s=_require(m, "train_seconds", source),
        fps=_require(m, "render_fps", source), size_bytes=int(_require(m, "ply_bytes", source)),
        size_note="PLY file", eval_protocol=_require(m, "eval_protocol", source),
        dataset_hash=_require(m, "dataset_hash", source), device=doc.get("device", "?"), dataset=_data_label(m))]


NERF_METHOD_NAMES = {"grid": "Voxel grid (Plenoxels/DVGO-style, drlab)",
                     "hashgrid": "Hash grid + MLP (instant-ngp-style, drlab)",
                     "pe_mlp": "PE + MLP (NeRF-style, drlab)"}


def rows_fit_nerf(doc: dict[str, Any], source: str) -> list[MethodRow]:
    m = doc["metrics"]
    protocol = _require(m, "eval_protocol", source)
    dataset_hash = _require(_require(m, "dataset", source), "content_hash", source)
    rows = []
    for name, f in _require(m, "fields", source).items():
        mean = f["eval"]["mean"]
        rows.append(MethodRow(
            method=NERF_METHOD_NAMES.get(name, name), ssim=mean["ssim"], psnr=mean["psnr"], train_s=f["train_s"],
            fps=1.0 / mean["seconds"], size_bytes=int(f["params"]) * int(_require(f, "bytes_per_param", source)),
            size_note="parameters", eval_protocol=protocol, dataset_hash=dataset_hash,
            device=doc.get("device", "?"), dataset=_data_label(m)))
    return rows


READERS: dict[str, Callable[[dict[str, Any], str], list[MethodRow]]] = {
    "fit_splats": rows_fit_splats, "fit_nerf": rows_fit_nerf}


def read_rows(path: Path) -> list[MethodRow]:
    doc = json.loads(Path(path).read_text())
    experiment = doc.get("experiment")
    if experiment not in READERS:
        raise ValueError(f"{path}: experiment {experiment!r} has no comparison reader; expected one of "
                         f"{sorted(READERS)}")
    return READERS[experiment](doc, str(path))


def _fmt_time(seconds: float) -> str:
    return f"{seconds / 60:.1f} min" if seconds >= 60 else f"{seconds:.0f} s"


def _fmt_size(n_bytes: int) -> str:
    return f"{n_bytes / 1e6:.1f} MB" if n_bytes >= 100_000 else f"{n_bytes / 1e3:.1f} kB"


def comparison_table(rows: list[MethodRow]) -> str:
    """The markdown table; raises ValueError when the rows were not evaluated alike on the same data."""
    if not rows:
        raise ValueError("rows: expected at least one method")
    for attr, what in (("eval_protocol", "evaluation protocols"), ("dataset_hash", "datasets"),
                       ("dataset", "dataset labels")):
        values = {getattr(r, attr) for r in rows}
        if len(values) != 1:
            detail = "; ".join(f"{r.method}: {getattr(r, attr)}" for r in rows)
            raise ValueError(f"rows: the {what} differ, so the rows are not comparable ({detail})")
    body = [[r.method, f"{r.ssim:.3f}", f"{r.psnr:.2f}", _fmt_time(r.train_s), f"{r.fps:.2f}",
             f"{_fmt_size(r.size_bytes)} ({r.size_note})", r.device] for r in rows]
    named = f"`{rows[0].dataset}`, " if rows[0].dataset else ""
    return ("In the form of Table 1 of Kerbl et al. 2023 (3DGS), without LPIPS. Every row: the same dataset "
            f"({named}content hash `{rows[0].dataset_hash[:12]}`), evaluated as `{rows[0].eval_protocol}`. "
            "Train = wall time of the fit on a 2-core CPU; FPS = forward renders per second at the test "
            "resolution; Mem = the stored model (the PLY file for splats, float32 parameters for the fields).\n\n"
            + markdown_table(["Method", "SSIM ↑", "PSNR ↑", "Train", "FPS", "Mem", "device"], body))


def write_comparison(metrics_paths: list[Path], out_dir: Path) -> Path | None:
    """Write out_dir/table.md for the runs whose metrics.json exist; None if fewer than two do."""
    present = [Path(p) for p in metrics_paths if Path(p).is_file()]
    if len(present) < 2:
        return None
    rows = [row for p in present for row in read_rows(p)]
    path = Path(out_dir) / "table.md"
    atomic.write_text(path, comparison_table(rows))
    return path


def update_comparison(results_root: Path) -> str:
    """Rewrite results_root/comparison/table.md from results_root/{fit_splats,fit_nerf}; says what it did."""
    root = Path(results_root)
    paths = [root / name / "metrics.json" for name in READERS]
    try:
        written = write_comparison(paths, root / "comparison")
    except ValueError as e:  # the other run is stale (older code or other data): say so, keep this run's results
        return f"comparison: not written: {e}"
    if written is None:
        missing = [str(p) for p in paths if not p.is_file()]
        return f"comparison: skipped ({', '.join(missing)} not there yet)"
    return f"comparison: {written}"
