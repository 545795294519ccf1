"""Sweeps: a grid of runs of one experiment, run locally or as Ray tasks, gathered into one table.

    drlab sweep SPEC [--jobs N] [--ray [--ray-address ADDRESS]] [--results DIR]

A sweep file (TOML) names an experiment, the options every run gets, a grid and/or a list of option
values, the seeds, the resources of one run, and how to gather the table:

    [sweep]
    name = "kalman-q"                 # results/<name>/ (default: the file's stem)
    experiment = "kalman_tracking"
    seeds = [0, 1, 2]                 # every configuration runs once per seed (default [0])
    device = "cpu"                    # --device of every run (default cpu)
    options = ["--smoke"]             # argv words every run gets

    [grid]                            # every combination of these values
    "--trials" = [20, 40]

    [[list]]                          # explicit points, each crossed with the grid and the seeds
    "--tune-trials" = 5

    [resources]                       # of one run
    cpus = 1                          # Ray: CPUs the task reserves (and --jobs sizes a local instance)
    gpus = 0                          # Ray: GPUs the task reserves (pass --device cuda in [sweep] too)
    max_retries = 2                   # Ray: retries of a task whose worker process died
    timeout_s = 3600                  # a run still going after this is killed and counted as failed

    [table]
    group_by = ["--trials"]           # options that key the rows (default: every option that varies)
    rows = "methods"                  # optional: a dict in metrics.json whose keys become rows too
    metrics = ["filter_rmse.mean"]    # dotted paths into metrics.json's "metrics" (under each row item)
    figure = "filter_rmse.mean"       # the metric drawn in figure.png (default: the first)

Option values: `true` is a flag, `false` leaves it out, a list is several words (`nargs="+"`),
anything else is one word; `{seed}` in a value (or in an [sweep] options word) becomes the run's seed.
`--out`, `--seed`, `--device` and `--no-progress` belong to the sweep. `--data` works as in `drlab
run` (a relative path is taken from the current directory, which every run keeps); an experiment that
renders its data into --data from its seed (stereo_depth, raft_flow) should get one folder per seed,
e.g. `options = ["--data", "data/sweeps/seed{seed}"]`, so that concurrent runs never share a cache
that depends on the seed. On a cluster --data must be a path every node sees (docs/sweeps.md).
`drlab sweep SPEC --smoke` runs the same sweep at smoke sizes into `<name>-smoke`.

Runs. Each run is `python -m experiments.<name> --out <results>/<sweep>/<run-key> --seed S ...`, the
experiment contract (research.experiment) with its atomic folder swap, so a half-finished run never
leaves a folder that looks finished. The run key is the first 16 hex digits of the SHA-256 of the
run's full configuration (experiment, device, seed and every option, as written in the spec). After a
run exits 0, `sweep-run.json` (key, configuration) is written into its folder; a run counts as
complete when its metrics.json names the experiment and seed and its sweep-run.json names its key.
Started again, a sweep skips complete runs and redoes all others (missing, half-written, failed).

Faults. A run that exits non-zero (or times out) is recorded as failed with the last line it printed,
in the table and in runs.json, and the sweep goes on. Under Ray, a task whose worker process dies is
retried up to `max_retries` times (Ray's own retries); the experiment process dies with its worker
(Linux: PR_SET_PDEATHSIG), so a retry never races an orphan. Each run's output goes to
`<sweep>/logs/<run-key>.log` (one header line per attempt).

Gathered at `<results>/<sweep>/`: table.md and table.json (mean ± std over seeds per group; no
timings, so the local and the Ray executor write identical files), figure.png and runs.json (every
run: key, configuration, status, error, wall time, host).

Exit status of `drlab sweep`: 0 when every run succeeded, else the number of failed runs (at most
100), after a last line `drlab sweep: N of M runs failed` on stderr. A bad spec is a usage error
(status 2, one line naming the file) before any run starts.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from research import atomic
from research.sweep.runs import (Executor, RayOptions, child_env, execute_run, is_complete, local_executor,
                                 ray_executor, ray_session, reproduce_jobs, require_ray)
from research.sweep.spec import KEY_DIGITS, RUN_FILE, Run, Spec, load_spec, word

# --------------------------------------------------------------------------- the sweep


def _job(spec: Spec, run: Run, sweep_dir: Path) -> dict[str, Any]:
    return {"key": run.key, "experiment": run.experiment, "device": run.device, "seed": run.seed,
            "argv": run.argv(), "config": run.config(), "out": str(sweep_dir / run.key),
            "log": str(sweep_dir / "logs" / f"{run.key}.log"), "cwd": os.getcwd(), "env": child_env(),
            "timeout_s": float(spec.timeout_s)}


@dataclass
class SweepResult:
    sweep_dir: Path
    runs: list[Run]
    outcomes: dict[str, dict[str, Any]]  # key -> outcome (status "ok", "failed" or "skipped")
    table_md: Path
    figure: Path | None

    @property
    def failed(self) -> list[str]:
        return [k for k, o in self.outcomes.items() if o["status"] == "failed"]

    @property
    def executed(self) -> list[str]:
        return [k for k, o in self.outcomes.items() if o["status"] != "skipped"]


def run_sweep(spec: Spec, results_root: Path, executor: Executor, *, progress: bool = True,
              executor_name: str = "local") -> SweepResult:
    """Run every incomplete run of `spec` with `executor`, then gather the table and the figure."""
    from tqdm import tqdm

    sweep_dir = (Path(results_root) / spec.name).absolute()
    runs = spec.runs()
    sweep_dir.mkdir(parents=True, exist_ok=True)
    outcomes: dict[str, dict[str, Any]] = {}
    todo = []
    for run in runs:
        if is_complete(run, sweep_dir / run.key):
            outcomes[run.key] = {"key": run.key, "status": "skipped", "error": ""}
        else:
            todo.append(_job(spec, run, sweep_dir))
    failures = 0
    bar = tqdm(total=len(runs), initial=len(runs) - len(todo), desc=f"sweep {spec.name}", unit="run",
               disable=not progress, dynamic_ncols=True)
    bar.set_postfix(failed=0)

    def done(outcome: dict[str, Any]) -> None:
        nonlocal failures
        outcomes[outcome["key"]] = outcome
        if outcome["status"] == "failed":
            failures += 1
            bar.set_postfix(failed=failures)
            bar.write(f"drlab sweep: run {outcome['key']} failed: {outcome['error']} "
                      f"(log: {sweep_dir / 'logs' / (outcome['key'] + '.log')})")
        bar.update(1)

    try:
        if todo:
            executor(todo, done)
    finally:
        bar.close()
        _write_runs(sweep_dir, spec, runs, outcomes, executor_name)
    table_md, figure = gather(spec, sweep_dir, runs, outcomes)
    return SweepResult(sweep_dir, runs, outcomes, table_md, figure)


def _write_runs(sweep_dir: Path, spec: Spec, runs: list[Run], outcomes: dict[str, dict[str, Any]],
                executor_name: str) -> None:
    rows = []
    for run in runs:
        o = outcomes.get(run.key, {"status": "not run", "error": "the sweep stopped before this run"})
        rows.append({"key": run.key, **run.config(), "status": o["status"], "error": o.get("error", ""),
                     "rc": o.get("rc"), "wall_s": o.get("wall_s"), "host": o.get("host")})
    atomic.write_json(sweep_dir / "runs.json", {"sweep": spec.name, "spec": str(spec.path),
                                                 "executor": executor_name, "runs": rows})


def _lookup(doc: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        if not isinstance(doc, dict) or part not in doc:
            return None
        doc = doc[part]
    return doc


def _fmt_value(v: Any) -> str:
    if isinstance(v, list):
        return " ".join(_fmt_value(x) for x in v)
    if v is True:
        return "yes"
    if v is False or v is None:
        return "no"
    return word(v)


def gather(spec: Spec, sweep_dir: Path, runs: list[Run], outcomes: dict[str, dict[str, Any]]
           ) -> tuple[Path, Path | None]:
    """table.md, table.json and figure.png from the runs' metrics.json: mean ± std over seeds per group."""
    from research.results import markdown_table

    groups: dict[tuple, dict[str, Any]] = {}
    failed_rows = []
    for run in runs:
        opts = dict(run.options)
        gkey = tuple(_fmt_value(opts.get(g, False)) for g in spec.group_by)
        o = outcomes.get(run.key, {"status": "not run"})
        group = groups.setdefault(gkey, {"values": {}, "seeds": [], "failed": []})
        if o["status"] == "failed" or o["status"] == "not run":
            group["failed"].append(run.seed)
            failed_rows.append([run.key, *gkey, run.seed, o.get("error", "not run")])
            continue
        try:
            metrics = json.loads((sweep_dir / run.key / "metrics.json").read_text())["metrics"]
        except (OSError, ValueError, KeyError) as e:
            group["failed"].append(run.seed)
            failed_rows.append([run.key, *gkey, run.seed, f"metrics.json unreadable: {e}"])
            continue
        group["seeds"].append(run.seed)
        items = {"": metrics}
        if spec.rows:
            base = _lookup(metrics, spec.rows)
            items = base if isinstance(base, dict) else {}
        for item, sub in items.items():
            for m in spec.metrics:
                v = _lookup(sub, m)
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    group["values"].setdefault((item, m), []).append(float(v))

    headers = [*spec.group_by] + ([spec.rows] if spec.rows else []) + spec.metrics + ["seeds", "failed"]
    md_rows, json_rows = [], []
    for gkey, group in groups.items():
        items = list(dict.fromkeys(item for item, _ in group["values"])) or [""]
        for item in items:
            cells, stats = [], {}
            for m in spec.metrics:
                vals = group["values"].get((item, m), [])
                if vals:
                    mean = sum(vals) / len(vals)
                    std = math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else 0.0
                    cells.append(f"{mean:.4g} ± {std:.2g}" if len(vals) > 1 else f"{mean:.4g}")
                    stats[m] = {"mean": mean, "std": std, "n": len(vals)}
                else:
                    cells.append("—")
                    stats[m] = None
            row = [*gkey] + ([item] if spec.rows else []) + cells + [
                ", ".join(map(str, group["seeds"])) or "none", ", ".join(map(str, group["failed"])) or "none"]
            md_rows.append(row)
            json_rows.append({"group": dict(zip(spec.group_by, gkey)), **({"row": item} if spec.rows else {}),
                              "metrics": stats, "seeds": group["seeds"], "failed_seeds": group["failed"]})
    text = (f"# sweep {spec.name}\n\n`{spec.experiment}` {' '.join(spec.fixed)}, seeds {spec.seeds}; mean ± std "
            f"(sample std) over the seeds that finished. Spec: `{spec.path.name}`.\n\n"
            + markdown_table(headers, md_rows))
    if failed_rows:
        text += ("\n## Failed runs\n\n" + markdown_table(["run", *spec.group_by, "seed", "error"],
                                                         [[f"`{r[0]}`", *r[1:-1], r[-1].replace("|", "\\|")]
                                                          for r in failed_rows]))
    atomic.write_text(sweep_dir / "table.md", text)
    atomic.write_json(sweep_dir / "table.json", {"sweep": spec.name, "experiment": spec.experiment,
                                                  "group_by": spec.group_by, "rows": spec.rows,
                                                  "metrics": spec.metrics, "table": json_rows,
                                                  "failed": [{"key": r[0], "seed": r[-2], "error": r[-1]}
                                                             for r in failed_rows]})
    figure = _figure(spec, sweep_dir, json_rows)
    return sweep_dir / "table.md", figure


# groups up to which the figure draws vertical bars in the spec's order (beyond: sorted horizontal bars)
_VERTICAL_MAX = 24


def _figure(spec: Spec, sweep_dir: Path, rows: list[dict[str, Any]]) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from research.results import save_figure

    shown = [r for r in rows if r["metrics"].get(spec.figure)]
    if not shown:
        return None
    labels = [(", ".join(f"{k.lstrip('-')}={v}" for k, v in r["group"].items())
               + (f" {r['row']}" if "row" in r else "")).strip() or "all" for r in shown]
    means = [r["metrics"][spec.figure]["mean"] for r in shown]
    stds = [r["metrics"][spec.figure]["std"] for r in shown]
    if len(shown) <= _VERTICAL_MAX:
        # few groups: vertical bars in the spec's order
        fig, ax = plt.subplots(figsize=(max(4.0, 0.45 * len(shown) + 2), 3.6))
        ax.bar(range(len(shown)), means, yerr=stds, capsize=3, color="tab:blue")
        ax.set_xticks(range(len(shown)), labels, rotation=60, ha="right", fontsize=7)
        ax.set_ylabel(spec.figure)
    else:
        # a large grid: one horizontal bar per group, sorted by the metric so the best and the worst
        # settings read off the ends, coloured by the value of the first grouping key
        order = sorted(range(len(shown)), key=lambda i: means[i])
        first = [str(next(iter(shown[i]["group"].values()), "")) for i in order]
        palette = {v: plt.get_cmap("tab10")(j % 10) for j, v in enumerate(dict.fromkeys(first))}
        fig, ax = plt.subplots(figsize=(9.0, 0.16 * len(shown) + 1.5))
        ax.barh(range(len(order)), [means[i] for i in order], xerr=[stds[i] for i in order],
                color=[palette[v] for v in first], error_kw={"elinewidth": 0.6})
        ax.set_yticks(range(len(order)), [labels[i] for i in order], fontsize=6)
        ax.invert_yaxis()
        ax.set_xlabel(spec.figure)
        ax.margins(y=0.002)
        if len(palette) > 1:
            from matplotlib.patches import Patch
            key = next(iter(shown[0]["group"]), "").lstrip("-")
            ax.legend([Patch(color=c) for c in palette.values()], [f"{key}={v}" for v in palette],
                      fontsize=7, loc="upper right")  # the shortest bars are at the top
    ax.set_title(f"{spec.name}: {spec.figure} (mean ± std over seeds)", fontsize=9)
    fig.tight_layout()
    path = sweep_dir / "figure.png"
    save_figure(fig, path)
    plt.close(fig)
    return path



__all__ = ["Executor", "KEY_DIGITS", "RUN_FILE", "RayOptions", "Run", "Spec", "SweepResult", "execute_run", "gather",
           "is_complete", "load_spec", "local_executor", "ray_executor", "ray_session", "reproduce_jobs",
           "require_ray", "run_sweep"]
