"""Benchmark infrastructure: median timings, and running the benches of the registered families.

A family's bench is the module its research.registry.FAMILIES entry names as `bench`, exposing
`cases(device: str, quick: bool, tiny: bool = False)`, a generator of JSON-ready dicts, one per case
(`tiny`: every case, with the same keys and phases, at sizes that run in about a second in total,
so the tests can run it). A family may also accept `compare: bool = False`: with `compare=True`
and the reference library importable (PyTorch, OpenCV: the `[bench]` extra), each case times the
reference on the same inputs inside the same `time_medians` call (interleaved) and adds
`"ref": "<library and function>"`, `"ref_<phase>_s"` and `"speedup_<phase>"` (reference time /
drlab time; > 1 means drlab is faster); without the library those keys are absent and
`"ref_missing"` names it. `run_bench(..., compare=True)` passes `compare` only to families whose
`cases` accept it:

    {"bench": "<family>.<case>", "device": "cpu", "threads": 2,
     <size keys>..., "<phase>_s": seconds, ...}

`run_bench` adds "cpu", the host's CPU model (research.results.host): timings
from different machines are not comparable.

Every seconds figure is `time_median`: the median of at least 3 timed runs
after a warm-up, so compilation (first launch) is never timed.
"""

from __future__ import annotations

import importlib
import inspect
import statistics
import time
from typing import Any, Callable

from research.results import host


def time_median(
    fn: Callable[[], Any],
    *,
    repeats: int = 3,
    warmup: int = 1,
    sync: Callable[[], Any] | None = None,
) -> float:
    """Median wall time in seconds of `fn()` over `repeats` (>= 3) runs after `warmup` (>= 1) untimed runs.

    `sync` is called after each run inside the timed region; on CUDA pass e.g.
    `lambda: wp.synchronize_device(device)` so asynchronous launches are timed whole.
    """
    return time_medians({"fn": fn}, repeats=repeats, warmup=warmup, sync=sync)["fn"]


# Untimed idle before each timed run of a case that interleaves drlab with a reference library
# (`time_medians(settle_s=SETTLE_S)`): see time_medians.
SETTLE_S = 0.02


def time_medians(
    fns: dict[str, Callable[[], Any]],
    *,
    repeats: int = 3,
    warmup: int = 1,
    sync: Callable[[], Any] | None = None,
    settle_s: float = 0.0,
) -> dict[str, float]:
    """`time_median` of several functions, run interleaved (a, b, a, b, ...).

    Interleaving exposes every function to the same drift in machine speed
    (clock boost, neighbours on the host), so their ratio is steadier than
    timing one after the other.

    `settle_s` > 0 sleeps that long, untimed, before every timed run, so that
    what the previous function left running does not count against the next
    one: PyTorch's OpenMP workers (GNU libgomp) spin-wait after each parallel
    op -- measured ~2 ms of a core after every op on the 2-core host -- and a
    2-thread drlab call that starts right after one shares the cores with them.
    """
    if repeats < 3:
        raise ValueError(f"time_median: repeats must be >= 3, got {repeats}")
    if warmup < 1:
        raise ValueError(f"time_median: warmup must be >= 1 (compilation is never timed), got {warmup}")
    for _ in range(warmup):
        for fn in fns.values():
            fn()
            if sync is not None:
                sync()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            if settle_s > 0:
                time.sleep(settle_s)
            t0 = time.perf_counter()
            fn()
            if sync is not None:
                sync()
            times[name].append(time.perf_counter() - t0)
    return {name: statistics.median(ts) for name, ts in times.items()}


def accepts_compare(cases: Callable[..., Any]) -> bool:
    """Whether a family's `cases` takes a `compare` keyword (the reference-library timings)."""
    try:
        params = inspect.signature(cases).parameters
    except (TypeError, ValueError):
        return False
    return "compare" in params or any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())


def run_bench(families: list[str] | None, device: str, quick: bool, compare: bool = False,
              tiny: bool = False) -> list[dict]:
    """Run the cases of the named families (all registered ones when None or empty).

    `compare`: also time the reference libraries, in the families whose `cases` accept `compare`
    (the others run as without it). `tiny`: every case at its test size (experiments' --smoke).
    """
    from research.registry import family_modules

    benches = family_modules("bench")
    names = list(families) if families else list(benches)
    unknown = [f for f in names if f not in benches]
    if unknown:
        raise KeyError(f"unknown benchmark families {unknown}; known: {', '.join(benches)}")
    rows: list[dict] = []
    cpu = host()["cpu"]  # every figure names the machine it was measured on
    for family in names:
        module = importlib.import_module(benches[family])
        kwargs: dict[str, Any] = {"device": device, "quick": quick}
        if tiny:
            kwargs["tiny"] = True
        if compare and accepts_compare(module.cases):
            kwargs["compare"] = True
        for row in module.cases(**kwargs):
            if not str(row.get("bench", "")).startswith(family + ".") or "device" not in row:
                raise ValueError(f"benchmark family {family!r} yielded a malformed row: {row!r}")
            rows.append({**row, "cpu": cpu})
    return rows
