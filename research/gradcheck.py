"""Finite-difference gradient checks: the project's gradient truth.

A function ``f(**inputs)`` returns one or several float64 arrays. Its
hand-written vector-Jacobian product ``vjp(inputs, cotangents)`` returns, for
each input x, the gradient of the scalar

    g(x) = sum_k <c_k, f_k(x)>                                   (1)

for cotangents c_k shaped like the outputs f_k. ``check_vjp`` draws the c_k at
random (seeded, standard normal), then compares the VJP with central
differences of (1) in float64,

    D_h g(x) = (g(x + h) - g(x - h)) / (2 eps),   h = eps * v,

along ``n_directions`` random unit directions v per input, and along every
coordinate axis when the input has at most ``per_coord_limit`` elements
(otherwise along a random subset of ``per_coord_limit`` axes). The analytic
value compared with it is <grad, (x+h) - (x-h)> / (2 eps): it uses the step
actually taken after rounding x +- h, which removes step-rounding error.

Error model and defaults. With |g'''| ~ M3 and the terms of (1) summing to
S = sum_k |c_k * f_k(x)| (elementwise absolute values), the central difference
is off by about eps^2 M3 / 6 (truncation) plus u S / eps (rounding, u = 2.2e-16
the float64 unit roundoff). With eps = 1e-6 and quantities of order one the
truncation is ~1e-13 and the rounding ~2e-10 times S: a correct float64 VJP
lands near 1e-9 relative, well inside the default rtol = 1e-6, while a wrong
gradient (a factor 1.01, a wrong coordinate, a transpose) is off by far more.

A comparison of analytic value a with finite difference b passes when

    |a - b| <= atol + rtol * max(|a|, |b|).                      (2)

By default (``atol=None``) atol is the rounding floor of the finite difference,
``ROUNDING_FLOOR_FACTOR * u * S / eps``: derivatives smaller than the noise
of the difference cannot be resolved, so they are compared absolutely. Pass a
number to fix atol instead. The reported relative error is

    rel = |a - b| / (max(|a|, |b|) + atol / rtol),               (3)

so that rel <= rtol exactly when (2) holds; atol / rtol is the scale below
which values count as zero.

``eps``, ``rtol`` and ``atol`` accept a dict input-name -> value to set them
per input (missing names take ``DEFAULT_EPS`` etc.). Any loosening of rtol
beyond 1e-6 is the caller's responsibility and needs a written reason beside
the call.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Mapping, Union

import numpy as np

DEFAULT_EPS = 1e-6
DEFAULT_RTOL = 1e-6
UNIT_ROUNDOFF = float(np.finfo(np.float64).eps) / 2.0
# Multiples of u * S / eps allowed for the rounding noise of one central
# difference: each of g(x+h), g(x-h) may be off by a few u * S (per-output
# rounding plus the summation in (1)). Measured on smooth test functions
# (sizes 3..5000, 25 seeds): |vjp - fd| reached 4.1 u S / eps at worst.
ROUNDING_FLOOR_FACTOR = 16.0

Outputs = Union[np.ndarray, tuple, list, dict]
PerInput = Union[float, Mapping[str, float]]


@dataclass
class GradcheckResult:
    """Outcome of checking one input of one check.

    max_abs_err, max_rel_err: worst |a - b| and worst (3) over all comparisons.
    n_checks: number of comparisons (directions + coordinates).
    eps, rtol, atol: the step and tolerances actually used (atol resolved).
    worst: which comparison had the largest relative error, or an error text.
    """

    name: str
    input: str
    max_abs_err: float
    max_rel_err: float
    n_checks: int
    passed: bool
    eps: float
    rtol: float
    atol: float
    worst: str = ""


# --------------------------------------------------------------------------- outputs


def _flatten_outputs(out: Any) -> tuple[list[str], list[np.ndarray]]:
    """Output labels and arrays, in a fixed order (tuple order or dict order)."""
    if isinstance(out, dict):
        labels, arrays = [str(k) for k in out], list(out.values())
    elif isinstance(out, (tuple, list)):
        labels, arrays = [f"output[{i}]" for i in range(len(out))], list(out)
    else:
        labels, arrays = ["output"], [out]
    arrays = [np.asarray(a) for a in arrays]
    for label, a in zip(labels, arrays):
        if a.dtype != np.float64:
            raise ValueError(f"gradcheck: {label} of f has dtype {a.dtype}; outputs must be float64")
    return labels, arrays


def _like_outputs(out: Any, arrays: list[np.ndarray]) -> Outputs:
    """Pack `arrays` into the same structure (array, tuple, dict) as `out`."""
    if isinstance(out, dict):
        return dict(zip(out.keys(), arrays))
    if isinstance(out, (tuple, list)):
        return tuple(arrays)
    return arrays[0]


# --------------------------------------------------------------------------- inputs


def _validate_inputs(inputs: Mapping[str, Any], wrt: list[str] | None) -> list[str]:
    """Reject non-float64 floating inputs; return the names to differentiate."""
    for name, x in inputs.items():
        if isinstance(x, np.ndarray) and np.issubdtype(x.dtype, np.floating) and x.dtype != np.float64:
            raise ValueError(
                f"gradcheck: input {name!r} has dtype {x.dtype}; finite differences need float64 inputs"
            )
    if wrt is None:
        return [n for n, x in inputs.items() if isinstance(x, np.ndarray) and x.dtype == np.float64]
    for name in wrt:
        if name not in inputs:
            raise ValueError(f"gradcheck: wrt names {name!r}, which is not an input")
        x = inputs[name]
        if not isinstance(x, np.ndarray) or x.dtype != np.float64:
            kind = x.dtype if isinstance(x, np.ndarray) else type(x).__name__
            raise ValueError(f"gradcheck: input {name!r} is {kind}; inputs checked must be float64 ndarrays")
    return list(wrt)


def _per_input(value: PerInput | None, name: str, default: float | None) -> float | None:
    if isinstance(value, Mapping):
        return value.get(name, default)
    return default if value is None else value


def _index_label(shape: tuple[int, ...], flat: int) -> str:
    return str(tuple(int(i) for i in np.unravel_index(flat, shape))) if shape else "()"


# --------------------------------------------------------------------------- the check


def check_vjp(
    f: Callable[..., Outputs],
    vjp: Callable[[dict[str, Any], Outputs], Mapping[str, np.ndarray]],
    inputs: Mapping[str, Any],
    *,
    wrt: list[str] | None = None,
    seed: int = 0,
    eps: PerInput = DEFAULT_EPS,
    rtol: PerInput = DEFAULT_RTOL,
    atol: PerInput | None = None,
    n_directions: int = 8,
    per_coord_limit: int = 64,
    name: str = "",
) -> list[GradcheckResult]:
    """Check `vjp` against central differences of <c, f(x)>; one result per input in `wrt`.

    `wrt` defaults to every float64 ndarray input; other inputs (integer arrays,
    Python scalars, options) are passed through unchanged. Floating inputs that
    are not float64 raise ValueError. See the module docstring for the math,
    the tolerances and the meaning of `atol=None`.
    """
    names = _validate_inputs(inputs, wrt)
    base = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in inputs.items()}
    rng = np.random.default_rng(seed)

    out0 = f(**{k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in base.items()})
    _, arrays0 = _flatten_outputs(out0)
    cots = [rng.standard_normal(a.shape) for a in arrays0]
    # S of the module docstring: the magnitude of the terms summed in g.
    term_scale = float(sum(np.abs(c * a).sum() for c, a in zip(cots, arrays0)))

    def g(xname: str, x: np.ndarray) -> float:
        args = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in base.items()}
        args[xname] = x
        _, arrays = _flatten_outputs(f(**args))
        if [a.shape for a in arrays] != [a.shape for a in arrays0]:
            raise ValueError("gradcheck: output shapes changed under perturbation")
        return float(sum(np.dot(c.ravel(), a.ravel()) for c, a in zip(cots, arrays)))

    grads = vjp({k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in base.items()},
                _like_outputs(out0, [c.copy() for c in cots]))

    results = []
    for xname in names:
        x0 = base[xname]
        e = float(_per_input(eps, xname, DEFAULT_EPS))
        rt = float(_per_input(rtol, xname, DEFAULT_RTOL))
        at = _per_input(atol, xname, None)
        at = ROUNDING_FLOOR_FACTOR * UNIT_ROUNDOFF * term_scale / e if at is None else float(at)

        if xname not in grads:
            raise ValueError(f"gradcheck: vjp returned no gradient for input {xname!r}")
        grad = np.asarray(grads[xname])
        if grad.shape != x0.shape:
            raise ValueError(f"gradcheck: gradient of {xname!r} has shape {grad.shape}, input has {x0.shape}")
        grad = grad.astype(np.float64).ravel()

        n_coords = min(x0.size, per_coord_limit)
        coords = np.arange(x0.size) if x0.size <= per_coord_limit else rng.choice(x0.size, n_coords, replace=False)
        directions = [rng.standard_normal(x0.size) for _ in range(n_directions)]

        def steps() -> Iterator[tuple[str, np.ndarray]]:  # one perturbation vector alive at a time
            for i, v in enumerate(directions):
                norm = np.linalg.norm(v)
                yield f"direction {i}", (v / norm if norm > 0 else v)
            for k in coords:
                v = np.zeros(x0.size)
                v[k] = 1.0
                yield f"coord {_index_label(x0.shape, int(k))}", v

        max_abs, max_rel, worst, ok = 0.0, 0.0, "", True
        n_steps = 0
        for label, v in steps():
            n_steps += 1
            xp = (x0.ravel() + e * v).reshape(x0.shape)
            xm = (x0.ravel() - e * v).reshape(x0.shape)
            b = (g(xname, xp) - g(xname, xm)) / (2.0 * e)
            a = float(np.dot(grad, (xp - xm).ravel())) / (2.0 * e)
            err = abs(a - b)
            bound = at + rt * max(abs(a), abs(b))
            scale = max(abs(a), abs(b)) + (at / rt if rt > 0 else 0.0)
            rel = err / scale if scale > 0 else (0.0 if err == 0 else math.inf)
            if not err <= bound:  # also catches NaN
                ok = False
            if math.isnan(err):
                max_abs, max_rel, worst = math.nan, math.nan, f"{label}: NaN"
            elif not math.isnan(max_abs):
                max_abs = max(max_abs, err)
                if rel >= max_rel:
                    max_rel, worst = rel, f"{label}: vjp {a:.10g} fd {b:.10g}"
        results.append(GradcheckResult(name, xname, max_abs, max_rel, n_steps, ok, e, rt, at, worst))
    return results


# --------------------------------------------------------------------------- reporting


def format_table(results: list[GradcheckResult]) -> str:
    """A plain-text table: check, input, max abs err, max rel err, n, status."""
    headers = ["check", "input", "max abs err", "max rel err", "n", "status"]
    rows = [
        [r.name, r.input, f"{r.max_abs_err:.3e}", f"{r.max_rel_err:.3e}", str(r.n_checks),
         "ok" if r.passed else "FAIL"]
        for r in results
    ]
    widths = [max([len(h)] + [len(row[i]) for row in rows]) for i, h in enumerate(headers)]
    line = lambda cells: "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()  # noqa: E731
    return "\n".join([line(headers), line(["-" * w for w in widths])] + [line(r) for r in rows]) + "\n"


def assert_gradcheck(results: list[GradcheckResult]) -> None:
    """Raise AssertionError listing every failed result (or if there are none at all)."""
    if not results:
        raise AssertionError("gradcheck: no results (nothing was checked)")
    failed = [r for r in results if not r.passed]
    if failed:
        details = "\n".join(
            f"  {r.name or '<unnamed>'}/{r.input}: {r.worst} (eps {r.eps:g}, rtol {r.rtol:g}, atol {r.atol:.3g})"
            for r in failed
        )
        raise AssertionError(
            f"gradcheck: {len(failed)} of {len(results)} inputs failed\n{format_table(failed)}worst:\n{details}"
        )


# --------------------------------------------------------------------------- registry

CheckFn = Callable[[], list[GradcheckResult]]
CHECKS: dict[str, CheckFn] = {}


def register_check(name: str) -> Callable[[CheckFn], CheckFn]:
    """Decorator: register a zero-argument function returning list[GradcheckResult] as `name`.

    Names are "<family>.<what>" (e.g. "volume.render"); `run_checks(["volume"])`
    selects a whole family.
    """

    def deco(fn: CheckFn) -> CheckFn:
        old = CHECKS.get(name)
        if old is not None and (old.__module__, old.__qualname__) != (fn.__module__, fn.__qualname__):
            raise ValueError(f"gradient check {name!r} registered twice ({old.__module__}, {fn.__module__})")
        CHECKS[name] = fn
        return fn

    return deco


def load_checks() -> None:
    """Import the `checks` module of every family in research.registry.FAMILIES (which registers its checks)."""
    from research.registry import family_modules

    for module in family_modules("checks").values():
        importlib.import_module(module)


def _select(names: list[str] | None) -> list[str]:
    if not names:
        return sorted(CHECKS)
    chosen: list[str] = []
    for want in names:
        hits = [n for n in sorted(CHECKS) if n == want or n.startswith(want + ".")]
        if not hits:
            raise KeyError(f"no gradient check matches {want!r}; known: {', '.join(sorted(CHECKS)) or 'none'}")
        chosen += [h for h in hits if h not in chosen]
    return chosen


def run_checks(names: list[str] | None = None) -> list[GradcheckResult]:
    """Run the registered checks named (exactly, or by "<family>" prefix); all when `names` is None.

    A check that raises is reported as one failed result whose `worst` holds the exception.
    """
    load_checks()
    results: list[GradcheckResult] = []
    for check in _select(names):
        try:
            got = CHECKS[check]()
        except Exception as exc:  # reported as a failure row, not a crash of the whole table
            results.append(GradcheckResult(check, "(error)", math.nan, math.nan, 0, False, math.nan,
                                           math.nan, math.nan, f"{type(exc).__name__}: {exc}"))
            continue
        for r in got:
            if not r.name:
                r.name = check
        results.extend(got)
    return results
