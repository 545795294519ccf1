"""A 3DGS-style Table 1 (Kerbl et al. 2023): one row per method on the same scene and splits.

Columns: SSIM, PSNR, training time, rendering FPS and model size ("Mem"), read
from each experiment's metrics.json. The other experiments may name their
numbers differently, so every value is looked up under a list of likely keys
(first hit, searched depth-first through the nested "metrics" dict); a value
that is not found shows as "n/a". LPIPS is not computed in drlab, so the
column is left out. Rows are only comparable when the evaluation protocol
(`eval_protocol` in each file) and the scene/splits agree; the table prints
both beside the numbers.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from research import atomic
from research.results import markdown_table

KEYS = {
    "ssim": ("test_ssim", "ssim"),
    "psnr": ("test_psnr", "psnr"),
    "train_s": ("train_seconds", "train_s", "train_time_s", "training_seconds", "train_time"),
    "fps": ("render_fps", "fps", "test_fps"),
    "size_bytes": ("model_bytes", "ply_bytes", "size_bytes", "checkpoint_bytes", "memory_bytes"),
    "size_mb": ("size_mb", "model_mb", "memory_mb", "mem_mb"),
    "protocol": ("eval_protocol", "protocol"),
    "scene": ("scene", "dataset"),
}


def find(tree: Any, names: tuple[str, ...]) -> Any:
    """The value of the first of `names` found anywhere in `tree` (names in priority order)."""
    for name in names:
        stack = [tree]
        while stack:
            node = stack.pop()
            if isinstance(node, dict):
                if name in node and not isinstance(node[name], (dict, list)):
                    return node[name]
                stack.extend(reversed(list(node.values())))
    return None


def row_for(path: Path) -> dict[str, Any]:
    doc = json.loads(Path(path).read_text())
    tree = {"metrics": doc.get("metrics", {}), "config": doc.get("config", {})}
    row = {k: find(tree, names) for k, names in KEYS.items()}
    if row["size_mb"] is None and isinstance(row["size_bytes"], (int, float)):
        row["size_mb"] = row["size_bytes"] / 1e6
    row["method"] = doc.get("metrics", {}).get("method") or doc.get("experiment", Path(path).parent.name)
    row["device"] = doc.get("device", "?")
    return row


def _fmt(v: Any, fmt: str) -> str:
    return format(v, fmt) if isinstance(v, (int, float)) and not isinstance(v, bool) else "n/a"


def _fmt_time(seconds: Any) -> str:
    if not isinstance(seconds, (int, float)):
        return "n/a"
    return f"{seconds / 60:.1f} min" if seconds >= 60 else f"{seconds:.0f} s"


def comparison_table(metrics_paths: list[Path]) -> str:
    rows = [row_for(p) for p in metrics_paths]
    headers = ["Method", "SSIM ↑", "PSNR ↑", "Train", "FPS", "Mem", "eval protocol", "scene"]
    body = [[r["method"], _fmt(r["ssim"], ".3f"), _fmt(r["psnr"], ".2f"), _fmt_time(r["train_s"]),
             _fmt(r["fps"], ".2f"), (_fmt(r["size_mb"], ".1f") + " MB") if r["size_mb"] is not None else "n/a",
             str(r["protocol"] or "n/a"), str(r["scene"] or "n/a")] for r in rows]
    protocols = {r["protocol"] for r in rows}
    note = ("" if len(protocols) == 1 and None not in protocols else
            "\n**The evaluation protocols differ or are unknown: these rows are not directly comparable.**\n")
    return ("In the form of Table 1 of Kerbl et al. 2023 (3DGS), without LPIPS; each row from its experiment's "
            "metrics.json, on the CPU (2 cores) unless the device says otherwise. Train = wall time of the fit; "
            "FPS = forward renders per second at the test resolution; Mem = size of the stored model.\n\n"
            + markdown_table(headers, body) + note)


def write_comparison(metrics_paths: list[Path], out_dir: Path) -> Path | None:
    """Write out_dir/table.md comparing the runs whose metrics.json exist; None if fewer than two do."""
    present = [Path(p) for p in metrics_paths if Path(p).is_file()]
    if len(present) < 2:
        return None
    path = Path(out_dir) / "table.md"
    atomic.write_text(path, comparison_table(present))
    return path
