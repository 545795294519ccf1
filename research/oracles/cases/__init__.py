"""Oracle cases: drlab's forward and hand-written backward against its Dr.Jit oracle, per family.

A family's `oracle_cases` module (research.registry.FAMILIES) holds

    SIZES = {"full": {...}, "quick": {...}, "smoke": {...}}   # size keys per mode
    CASES = [Case("SSIM map", build), ...]

where `build(dtype, sizes, seed)` draws the case's inputs (with `Rounded`, so that one set of inputs
serves float64 and float32) and returns `(size text, drlab, oracle)`: `drlab(t)` runs drlab in NumPy
dtype t and `oracle(t)` the oracle (research/oracles) in dtype t, each returning
`(forward outputs, VJPs)`, two lists of arrays in the same order (an empty VJP list: a forward-only
case). `compare` runs one case in float64 and float32 and reports normwise differences;
`registered_cases` lists every registered family's cases in the registry's order, which is what
experiments/oracle_conformance.py runs.
"""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

MODES = ("full", "quick", "smoke")

# (dtype, sizes, seed) -> (size text, drlab(t), oracle(t)); each of the two returns (forward list, VJP list).
Builder = Callable[[Any, dict, int], tuple[str, Callable[[Any], tuple[list, list]], Callable[[Any], tuple[list, list]]]]


@dataclass(frozen=True)
class Case:
    """One oracle case: its name in the table and its builder."""

    name: str
    build: Builder


@dataclass(frozen=True)
class FamilyCases:
    """One family's oracle cases with their sizes per mode."""

    family: str
    sizes: dict[str, dict]
    cases: tuple[Case, ...]


class Rounded:
    """A NumPy generator whose draws are float64 arrays holding float32 values, so that the float64 and
    float32 runs of a case see the same inputs and one float64 oracle run serves both comparisons."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def uniform(self, *args, **kwargs) -> np.ndarray:
        return np.asarray(self.rng.uniform(*args, **kwargs)).astype(np.float32).astype(np.float64)

    def normal(self, *args, **kwargs) -> np.ndarray:
        return np.asarray(self.rng.normal(*args, **kwargs)).astype(np.float32).astype(np.float64)


def diff(pairs: list[tuple[Any, Any]]) -> tuple[float, float]:
    """(max |a - b|, that / max |b|) over the pairs (drlab, oracle)."""
    d = max(float(np.max(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)))) for a, b in pairs)
    s = max(float(np.max(np.abs(np.asarray(b, np.float64)))) for _, b in pairs)
    return d, d / s if s > 0 else d


def timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def load_family(family: str, module: str) -> FamilyCases:
    """The SIZES and CASES of one family's oracle_cases module, checked."""
    mod = importlib.import_module(module)
    sizes, cases = getattr(mod, "SIZES", None), getattr(mod, "CASES", None)
    if not isinstance(sizes, dict) or set(sizes) != set(MODES):
        raise ValueError(f"{module}.SIZES: expected a dict with the modes {', '.join(MODES)}")
    if not cases or not all(isinstance(c, Case) for c in cases):
        raise ValueError(f"{module}.CASES: expected a non-empty list of research.oracles.cases.Case")
    return FamilyCases(family, sizes, tuple(cases))


def registered_cases(families: list[str] | None = None) -> list[FamilyCases]:
    """The oracle cases of the named families (every registered one with cases when None), in the
    registry's order."""
    from research.registry import family_modules

    modules = family_modules("oracle_cases")
    names = list(families) if families else list(modules)
    unknown = [f for f in names if f not in modules]
    if unknown:
        raise KeyError(f"no oracle cases for {unknown}; families with cases: {', '.join(modules)}")
    return [load_family(f, modules[f]) for f in names]


def merged_sizes(families: list[FamilyCases], mode: str) -> dict:
    """Every family's size keys of `mode` in one dict (a key that two families share must agree)."""
    out: dict = {}
    for fc in families:
        for k, v in fc.sizes[mode].items():
            if k in out and out[k] != v:
                raise ValueError(f"oracle size {k!r} ({mode}): {fc.family} says {v!r}, another family {out[k]!r}")
            out[k] = v
    return out


def compare(family: str, case: Case, sizes: dict, warm_sizes: dict, seed: int) -> tuple[dict, bool]:
    """Run one case: warm drlab up at `warm_sizes` (Warp's kernels load once per dtype), then at `sizes`
    drlab and the oracle once each in float64 and in float32, timed.

    Returns (entry, has_vjp): entry holds "family", "size" and, for "float64", "float32" (both in
    float32) and "float32 vs oracle64" (drlab's float32 against the float64 oracle on the same inputs),
    the normwise fwd_abs, fwd_rel, vjp_abs, vjp_rel (NaN for a forward-only case) and drlab_s,
    oracle_s (None for the last comparison).
    """
    # The inputs hold float32 values (Rounded): float64 compares drlab and the oracle in float64;
    # float32 both in float32; "float32 vs oracle64" drlab's float32 result with the float64 oracle.
    _, warm, _ = case.build(np.float64, warm_sizes, seed)
    warm(np.float64)
    warm(np.float32)
    size, drlab, oracle = case.build(np.float64, sizes, seed)
    entry: dict[str, Any] = {"family": family, "size": size}
    d64, t_d64 = timed(lambda: drlab(np.float64))
    o64, t_o64 = timed(lambda: oracle(np.float64))
    d32, t_d32 = timed(lambda: drlab(np.float32))
    o32, t_o32 = timed(lambda: oracle(np.float32))
    for label, dl, orc, td, to in (("float64", d64, o64, t_d64, t_o64), ("float32", d32, o32, t_d32, t_o32),
                                    ("float32 vs oracle64", d32, o64, None, None)):
        fwd = diff(list(zip(dl[0], orc[0])))
        vjp = diff(list(zip(dl[1], orc[1]))) if dl[1] else (float("nan"), float("nan"))
        entry[label] = {"fwd_abs": fwd[0], "fwd_rel": fwd[1], "vjp_abs": vjp[0], "vjp_rel": vjp[1],
                        "drlab_s": td, "oracle_s": to}
    return entry, bool(d64[1])
