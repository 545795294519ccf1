"""Second oracles: every kernel family's forward written again in Dr.Jit, differentiated by Dr.Jit's AD.

drlab's backward passes are written by hand and checked against finite differences of drlab's own
forward. Those checks cannot tell whether the forward follows its reference equations, and they
are too costly at full size. Each module here writes one family's forward from the equations in
its kernel module's docstring (never by calling drlab), with Dr.Jit's LLVM arrays
(`drjit.llvm.ad.Float` for float32, `drjit.llvm.ad.Float64` for float64; the `llvm_ad_rgb`
backend of docs/mitsuba.md, which needs libLLVM >= 17), and returns

    (forward values, VJPs)    with   VJP_x = d/dx sum_k <cotangent_k, output_k>

where the VJPs come from `drjit.backward` on that scalar. Comparing them with drlab's forward and
hand-written backward (tests/oracles/, experiments/oracle_conformance.py) is an independent check
of both, in float32 and float64 and at full size.

Loops. Loops over window taps, channels, disparities, samples or splats are Python loops that
Dr.Jit traces into one flat AD graph (unrolled), never Dr.Jit's symbolic loops: reverse-mode AD of
a symbolic loop needs loop-specific handling of the carried state, while an unrolled loop is a
plain graph of element-wise operations, gathers and scatters, whose adjoints are Dr.Jit's basic
rules. `drjit.eval` between iterations keeps the kernels small (one compile, reused).

Modules: `ssim`, `stereo`, `corr`, `volume` (dense grid, hash grid, MLP), `rays` (the volume renderer's
camera gradients), `splat`, `lens` (the splat projection through each lens model), `points` (the
chamfer distance), `geometry` (splat normals and expected depth), `appearance` (the bilateral-grid
slice), `mip` (Mip-Splatting's 3D filter), `proposal` (the proposal sampler's interval weights and
interlevel loss), `ba` (the reprojection and its Jacobians), `pointnet` (max-pool, grouping) and `icp`
(residual rows, pose Jacobians, robust weights, normal equations).

`research.oracles.cases` holds the comparisons themselves, one module per family (the family's
`oracle_cases` in research.registry.FAMILIES): each builds random inputs, runs drlab and the oracle
on them and returns both results; experiments/oracle_conformance.py runs every registered family's
cases at full size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


class OracleUnavailable(RuntimeError):
    """Dr.Jit or its LLVM backend cannot be used in this process."""


@dataclass(frozen=True)
class Backend:
    """The Dr.Jit module and the LLVM AD array types of one precision."""

    dr: Any
    Float: Any  # Float (float32) or Float64
    UInt: Any
    Int: Any
    Bool: Any
    np_dtype: Any

    def leaf(self, x: np.ndarray) -> Any:
        """A flat differentiable array holding x (C order)."""
        v = self.Float(np.ascontiguousarray(np.asarray(x, self.np_dtype)).ravel())
        self.dr.enable_grad(v)
        return v

    def const(self, x: np.ndarray) -> Any:
        """A flat array holding x (C order), without gradient."""
        return self.Float(np.ascontiguousarray(np.asarray(x, self.np_dtype)).ravel())

    def index(self, x: np.ndarray) -> Any:
        return self.UInt(np.ascontiguousarray(np.asarray(x, np.uint32)).ravel())

    def arange(self, n: int) -> Any:
        return self.dr.arange(self.UInt, n)

    def numpy(self, v: Any, shape: tuple[int, ...]) -> np.ndarray:
        return np.array(v, dtype=self.np_dtype).reshape(shape)

    def grad(self, v: Any, shape: tuple[int, ...]) -> np.ndarray:
        g = self.dr.grad(v)
        if self.dr.width(g) != int(np.prod(shape)):  # a leaf that received no gradient
            return np.zeros(shape, self.np_dtype)
        return np.array(g, dtype=self.np_dtype).reshape(shape)

    def dot(self, outputs: list[Any], cotangents: list[np.ndarray]) -> Any:
        """sum_k <cotangent_k, output_k> as a Dr.Jit scalar (the VJP's loss)."""
        loss = self.Float(0.0)
        for out, cot in zip(outputs, cotangents):
            loss = loss + self.dr.sum(out * self.const(cot))
        return loss


def backend(dtype: Any) -> Backend:
    """The Dr.Jit LLVM AD types for float32 or float64; OracleUnavailable when they cannot load."""
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype: expected float32 or float64, got {dtype}")
    try:
        import drjit as dr
        from drjit.llvm import ad
        ad.Float64(1.0) + ad.Float64(1.0)
    except Exception as exc:  # no drjit, or no libLLVM >= 17 (docs/mitsuba.md, section 1)
        raise OracleUnavailable(f"Dr.Jit's LLVM backend is unavailable: {exc}") from None
    F = ad.Float64 if dtype == np.float64 else ad.Float
    return Backend(dr, F, ad.UInt32, ad.Int32, ad.Bool, dtype.type)


def check_array(name: str, x: Any, shape: tuple) -> np.ndarray:
    """x as a finite float32/float64 NumPy array of `shape` (None matches any length); else ValueError
    naming the argument, before any Dr.Jit work."""
    if not isinstance(x, np.ndarray):
        raise ValueError(f"{name}: expected a NumPy array, got {type(x).__name__}")
    if x.dtype not in (np.float32, np.float64):
        raise ValueError(f"{name}: expected dtype float32 or float64, got {x.dtype}")
    if x.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, x.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name}: expected shape {want}, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name}: expected finite values, found NaN or infinite")
    return x
