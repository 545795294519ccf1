"""Shared set-up of the Dr.Jit oracle tests (research/oracles): skip without the LLVM backend.

Comparisons are normwise: max |drlab - oracle| over an array against a tolerance on the scale of
the array. float64: relative 1e-10 of the oracle's largest value. float32: drlab in float32 against
the float64 oracle on the same (float32) inputs, within a bound derived in each test from the
accumulated rounding, n u kappa M, with u = 2^-24 the unit roundoff, n the length of the longest
chain of rounded operations, kappa a condition factor of the formula and M the magnitude the
rounding errors are relative to.
"""

from __future__ import annotations

import numpy as np
import pytest

U32 = 2.0**-24
REL64 = 1e-10


@pytest.fixture(autouse=True, scope="session")
def _llvm_backend():
    """Skip when Dr.Jit's LLVM backend cannot run (its probe runs in a child process, docs/mitsuba.md)."""
    from research.mitsuba_env import LLVM_VARIANT, select_variant

    if select_variant() != LLVM_VARIANT:
        pytest.skip("Dr.Jit's LLVM backend (libLLVM >= 17) is unavailable")


def close64(name: str, got, want) -> None:
    """max |got - want| <= 1e-10 max |want|."""
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    assert got.shape == want.shape, f"{name}: shape {got.shape} != {want.shape}"
    scale = float(np.max(np.abs(want))) if want.size else 0.0
    err = float(np.max(np.abs(got - want))) if want.size else 0.0
    assert scale > 0.0, f"{name}: the oracle's values are all zero (a degenerate test input)"
    assert err <= REL64 * scale, f"{name}: max |drlab - oracle| = {err:.3g}, above 1e-10 x {scale:.3g}"


def within(name: str, got, want, bound: float) -> None:
    """max |got - want| <= bound (a float32 bound derived by the caller)."""
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    assert got.shape == want.shape, f"{name}: shape {got.shape} != {want.shape}"
    err = float(np.max(np.abs(got - want)))
    assert np.isfinite(bound) and bound > 0.0
    assert err <= bound, f"{name}: max |drlab32 - oracle64| = {err:.3g} above the derived bound {bound:.3g}"
