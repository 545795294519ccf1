"""Sweep files: parsing and validating a sweep (TOML) into its runs (research.sweep documents the format)."""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

RUN_FILE = "sweep-run.json"
KEY_DIGITS = 16
_RESERVED = {"--out", "--seed", "--device", "--no-progress"}
_SPEC_SECTIONS = {"sweep", "grid", "list", "resources", "table"}


# --------------------------------------------------------------------------- the spec


@dataclass(frozen=True)
class Run:
    """One run of a sweep: the experiment, its device, seed and options (argv words), and its key."""

    experiment: str
    device: str
    seed: int
    options: tuple[tuple[str, Any], ...]  # (option, value as in the spec), in spec order

    def config(self) -> dict[str, Any]:
        return {"experiment": self.experiment, "device": self.device, "seed": self.seed,
                "options": {k: v for k, v in self.options}}

    @property
    def key(self) -> str:
        blob = json.dumps(self.config(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()[:KEY_DIGITS]

    def argv(self) -> list[str]:
        """The experiment's options (without --out, --seed, --device); `{seed}` in a value is the run's seed."""
        words: list[str] = []
        for name, value in self.options:
            if value is True:
                words.append(name)
            elif value is False:
                continue
            elif isinstance(value, list):
                words += [name, *(self.word(v) for v in value)]
            else:
                words += [name, self.word(value)]
        return words

    def word(self, value: Any) -> str:
        return word(value).replace("{seed}", str(self.seed))


def word(value: Any) -> str:
    return repr(value) if isinstance(value, float) else str(value)


@dataclass
class Spec:
    path: Path
    name: str
    experiment: str
    seeds: list[int]
    device: str
    fixed: list[str]  # argv words every run gets
    points: list[dict[str, Any]]  # option dicts (grid x list), without seeds
    cpus: float = 1.0
    gpus: float = 0.0
    max_retries: int = 2
    timeout_s: float = 3600.0
    group_by: list[str] = field(default_factory=list)
    rows: str | None = None
    metrics: list[str] = field(default_factory=list)
    figure: str | None = None

    def smoke_variant(self) -> "Spec":
        """The same sweep at smoke sizes: --smoke for every run (instead of --quick), into `<name>-smoke`."""
        from dataclasses import replace

        fixed = [w for w in self.fixed if w not in ("--quick", "--smoke")]
        return replace(self, name=f"{self.name}-smoke", fixed=["--smoke", *fixed])

    def runs(self) -> list[Run]:
        fixed = tuple(_fixed_options(self.fixed))
        out = []
        for point in self.points:
            for seed in self.seeds:
                out.append(Run(self.experiment, self.device, seed, fixed + tuple(point.items())))
        return out


def _fixed_options(words: list[str]) -> list[tuple[str, Any]]:
    """["--smoke", "--trials", "5"] -> [("--smoke", True), ("--trials", "5")] (for the run key and table)."""
    out: list[tuple[str, Any]] = []
    i = 0
    while i < len(words):
        name, vals = words[i], []
        i += 1
        while i < len(words) and not words[i].startswith("--"):
            vals.append(words[i])
            i += 1
        out.append((name, True if not vals else vals[0] if len(vals) == 1 else vals))
    return out


def load_spec(path: str | Path) -> Spec:
    """Read and check a sweep file; ValueError (one line naming the file and the entry) when it is wrong."""
    from research.registry import EXPERIMENTS

    try:
        import tomllib
    except ImportError:  # Python 3.10
        raise ValueError("sweep files need Python 3.11 or newer (tomllib)") from None
    path = Path(path)
    where = str(path)
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise ValueError(f"{where}: no such sweep file") from None
    except IsADirectoryError:
        raise ValueError(f"{where}: expected a sweep file (TOML), got a folder") from None
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{where}: not valid TOML: {e}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{where}: not valid TOML: not UTF-8 text") from None

    def bad(entry: str, expected: str, got: Any) -> ValueError:
        return ValueError(f"{where}: {entry}: expected {expected}, got {got!r}")

    unknown = sorted(set(doc) - _SPEC_SECTIONS)
    if unknown:
        raise bad(f"[{unknown[0]}]", "only the sections " + ", ".join(f"[{s}]" for s in sorted(_SPEC_SECTIONS)),
                  unknown[0])
    for section in ("sweep", "grid", "resources", "table"):
        if section in doc and not isinstance(doc[section], dict):
            raise bad(f"[{section}]", "a table", doc[section])
    sw = doc.get("sweep")
    if sw is None:
        raise ValueError(f"{where}: [sweep]: missing; it names at least the experiment")
    allowed = {"name", "experiment", "seeds", "device", "options"}
    if set(sw) - allowed:
        k = sorted(set(sw) - allowed)[0]
        raise bad(f"[sweep] {k}", "one of " + ", ".join(sorted(allowed)), k)
    experiment = sw.get("experiment")
    if experiment not in EXPERIMENTS:
        raise bad("[sweep] experiment", "a registered experiment (" + ", ".join(sorted(EXPERIMENTS)) + ")", experiment)
    name = sw.get("name", path.stem)
    if not isinstance(name, str) or not name or not all(c.isalnum() or c in "-_." for c in name) or name[0] == ".":
        raise bad("[sweep] name", "a folder name (letters, digits, - _ .)", name)
    seeds = sw.get("seeds", [0])
    if (not isinstance(seeds, list) or not seeds or len(set(map(repr, seeds))) != len(seeds)
            or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**32 for s in seeds)):
        raise bad("[sweep] seeds", "a non-empty list of distinct integers in [0, 2^32)", seeds)
    device = sw.get("device", "cpu")
    if not isinstance(device, str) or not (device == "cpu" or device.startswith("cuda")):
        raise bad("[sweep] device", "'cpu', 'cuda' or 'cuda:N'", device)
    fixed = sw.get("options", [])
    if not isinstance(fixed, list) or not all(isinstance(w, str) and w for w in fixed) or (fixed and not fixed[0].startswith("--")):
        raise bad("[sweep] options", "a list of argv words starting with an option (e.g. [\"--smoke\"])", fixed)
    for w in fixed:
        if w.split("=")[0] in _RESERVED:
            raise bad("[sweep] options", "no " + ", ".join(sorted(_RESERVED)) + " (the sweep sets them)", w)

    def check_values(entry: str, table: Any, as_list: bool) -> dict[str, Any]:
        if not isinstance(table, dict):
            raise bad(entry, "a table of option = value", table)
        for opt, val in table.items():
            if not opt.startswith("--") or len(opt) < 3:
                raise bad(f"{entry} {opt!r}", "an option name starting with --", opt)
            if opt in _RESERVED:
                raise bad(f"{entry} {opt!r}", "not " + opt + (" (use [sweep] seeds)" if opt == "--seed" else
                                                                 " (use [sweep] device)" if opt == "--device" else
                                                                 " (the sweep sets it)"), opt)
            if opt in _fixed_names:
                raise bad(f"{entry} {opt!r}", "an option not already in [sweep] options", opt)
            vals = val if as_list else [val]
            if as_list and (not isinstance(val, list) or not val):
                raise bad(f"{entry} {opt!r}", "a non-empty list of values", val)
            for v in vals:
                if isinstance(v, dict) or (isinstance(v, list) and not all(isinstance(x, (str, int, float)) for x in v)):
                    raise bad(f"{entry} {opt!r}", "strings, numbers, booleans or lists of them", v)
        return table

    _fixed_names = {n for n, _ in _fixed_options(fixed)}
    grid = check_values("[grid]", doc.get("grid", {}), as_list=True)
    points_list = doc.get("list", [{}])
    if not isinstance(points_list, list) or not points_list:
        raise bad("[[list]]", "one or more tables of option = value", points_list)
    points_list = [check_values(f"[[list]] #{i + 1}", p, as_list=False) for i, p in enumerate(points_list)]
    points: list[dict[str, Any]] = []
    names = list(grid)
    for combo in itertools.product(*(grid[n] for n in names)):
        for extra in points_list:
            both = set(names) & set(extra)
            if both:
                raise bad(f"[[list]] {sorted(both)[0]!r}", "an option not also in [grid]", sorted(both)[0])
            points.append({**dict(zip(names, combo)), **extra})
    keys = [json.dumps(p, sort_keys=True) for p in points]
    if len(set(keys)) != len(keys):
        raise ValueError(f"{where}: [grid] and [[list]] give the same configuration twice: "
                         f"{next(k for k in keys if keys.count(k) > 1)}")

    res = doc.get("resources", {})
    allowed_res = {"cpus", "gpus", "max_retries", "timeout_s"}
    if set(res) - allowed_res:
        k = sorted(set(res) - allowed_res)[0]
        raise bad(f"[resources] {k}", "one of " + ", ".join(sorted(allowed_res)), k)

    def number(key: str, default: float, lo: float, integer: bool = False) -> Any:
        v = res.get(key, default)
        ok = isinstance(v, int) if integer else isinstance(v, (int, float))
        if isinstance(v, bool) or not ok or not math.isfinite(v) or v < lo:
            raise bad(f"[resources] {key}", f"{'an integer' if integer else 'a number'} >= {lo:g}", v)
        return v

    cpus = number("cpus", 1, 0)
    gpus = number("gpus", 0, 0)
    max_retries = number("max_retries", 2, 0, integer=True)
    if max_retries > 10:
        raise bad("[resources] max_retries", "an integer in [0, 10] (bounded retries)", max_retries)
    timeout_s = number("timeout_s", 3600, 1)

    table = doc.get("table", {})
    allowed_table = {"group_by", "rows", "metrics", "figure"}
    if set(table) - allowed_table:
        k = sorted(set(table) - allowed_table)[0]
        raise bad(f"[table] {k}", "one of " + ", ".join(sorted(allowed_table)), k)
    varying = [n for n in dict.fromkeys(k for p in points for k in p)
               if len({json.dumps(p.get(n)) for p in points}) > 1]
    group_by = table.get("group_by", varying)
    all_opts = set(_fixed_names) | {k for p in points for k in p}
    if not isinstance(group_by, list) or not all(isinstance(g, str) and g in all_opts for g in group_by):
        raise bad("[table] group_by", "a list of options the sweep sets (" + ", ".join(sorted(all_opts)) + ")", group_by)
    rows = table.get("rows")
    if rows is not None and (not isinstance(rows, str) or not rows):
        raise bad("[table] rows", "a dotted path into metrics.json's metrics", rows)
    metrics = table.get("metrics")
    if not isinstance(metrics, list) or not metrics or not all(isinstance(m, str) and m for m in metrics):
        raise bad("[table] metrics", "a non-empty list of dotted paths into metrics.json's metrics", metrics)
    figure = table.get("figure", metrics[0])
    if figure not in metrics:
        raise bad("[table] figure", "one of [table] metrics", figure)
    return Spec(path, name, experiment, seeds, device, fixed, points, cpus, gpus, max_retries, timeout_s,
                group_by, rows, metrics, figure)


