"""One switch for every CPU fast path.

Each operation has a plain Warp kernel that reads like its maths and is the CUDA path too. On the
CPU some operations also have a fast path, and this switch turns off exactly these:

  * C++ through `wp.func_native` (files in kernels/native, clang vector extensions): compositing
    (volume/composite_cpu), the spheres' dense-render passes (volume/spheres_cpu), the hash grid
    (volume/hashgrid_cpu), the correlation windows (corr/window_cpu) and the on-the-fly patches,
    pixel grouping and float16 widening (corr/patch_cpu), the census rows (stereo/census's
    census_rows_f32), the splat row blend (splat/rowblend, with kernels._vexp's exp), the
    SSIM filter's rows (ssim) and the farthest-point sampling step (points/sampling);
  * NumPy, BLAS and host-side passes picked automatically on the CPU: the MLP's products
    (volume/mlp) and the all-pairs correlation volume (corr/volume), both backend "numpy"; the
    on-the-fly lookup's channels-last copies, full-product levels and every-level-at-once schedule
    (corr/onthefly*); the compositing factors by NumPy's exp, or by its copy in the kernel
    (volume/composite, kernels._npexp); the spheres' passes around NumPy's exp (volume/spheres);
    the splat tiles' counting sort (splat/tiles) and the per-tile rasteriser (splat/raster).

Not switched: C++ inside a Warp kernel with its own portable branch (the adcensus cost's 16-lane rho
and cells, stereo/adcensus_kernels), and CPU launch schedules of the same Warp kernels (chunk sizes,
the SGM sweeps of stereo/sweep, chosen by the device). The fast paths give the same results (bit for
bit where the module says so, else within the bound its tests derive), but they rely on the CPU
(AVX2 and FMA), on clang's vector extensions as Warp's CPU compiler builds them and on NumPy's float32
exp loop, so it must be possible to run without them.

`enabled()` says whether the fast paths may run. It is False when

  * the environment variable DRLAB_FAST_PATHS is 0 / off / false / no (1 / on / true / yes, or unset:
    enabled), or `set_enabled(False)` was called (`set_enabled(None)` returns to the environment);
  * the installed Warp or NumPy is outside the versions the fast paths were built and tested against
    (`SUPPORTED`; pyproject.toml states the same range): a warning says so, once, and the plain Warp
    kernels run.

Every dispatch that picks a fast path asks `enabled()` at the call (not at import), so the switch
takes effect for the next call. Results do not depend on the switch beyond what each module states.
An explicit backend argument ("numpy") is the caller's choice and is honoured either way.

    with fast_paths.disabled():   # the plain Warp kernels only, for this block
        ...
"""

from __future__ import annotations

import contextlib
import os
import re
import warnings
from collections.abc import Iterator

ENV = "DRLAB_FAST_PATHS"
_ON = ("1", "on", "true", "yes")
_OFF = ("0", "off", "false", "no")

# (lowest supported, first unsupported) release of each library the fast paths rely on: Warp's CPU
# code generation (func_native snippets, the CPU launch releasing the GIL, plain read-modify-write
# CPU atomics; kernels/launch.py) and NumPy's float32 exp loop (kernels/_npexp.py, which also checks
# NumPy's bits at first use).
SUPPORTED = {"warp": ((1, 19), (1, 20)), "numpy": ((1, 24), (3, 0))}

_override: bool | None = None
_versions_ok: bool | None = None


def _release(version: str) -> tuple[int, ...]:
    """The leading numeric components of a version string ("1.19.0.dev3" -> (1, 19, 0))."""
    parts = []
    for piece in version.split("."):
        m = re.match(r"\d+", piece)
        if m is None:
            break
        parts.append(int(m.group()))
        if m.end() != len(piece):
            break
    return tuple(parts)


def unsupported_versions(versions: dict[str, str] | None = None) -> list[str]:
    """One line for each library outside SUPPORTED (`versions` defaults to the installed ones)."""
    if versions is None:
        import numpy
        import warp

        versions = {"warp": warp.__version__, "numpy": numpy.__version__}
    lines = []
    for name, (lo, hi) in SUPPORTED.items():
        v = _release(versions[name])
        if not lo <= v < hi:
            lines.append(f"{name} {versions[name]} (the fast paths support {'.'.join(map(str, lo))} <= "
                         f"{name} < {'.'.join(map(str, hi))})")
    return lines


def _from_env() -> bool:
    value = os.environ.get(ENV, "").strip().lower()
    if value in ("",) + _ON:
        return True
    if value in _OFF:
        return False
    raise ValueError(f"{ENV}: expected one of {', '.join(_ON + _OFF)} (or unset), got {os.environ[ENV]!r}")


def enabled() -> bool:
    """Whether the CPU fast paths may run now (module docstring)."""
    global _versions_ok
    on = _from_env() if _override is None else _override
    if not on:
        return False
    if _versions_ok is None:
        bad = unsupported_versions()
        _versions_ok = not bad
        if bad:
            warnings.warn("drlab: CPU fast paths off, the plain Warp kernels run: " + "; ".join(bad),
                          RuntimeWarning, stacklevel=2)
    return _versions_ok


def on(device) -> bool:
    """Whether a call on `device` takes the CPU fast route: the device is the CPU and the fast paths
    are enabled. Where this is False the CPU runs the CUDA route (the plain Warp kernels)."""
    return device.is_cpu and enabled()


def set_enabled(on: bool | None) -> None:
    """Turn the fast paths on (True) or off (False) for this process; None: follow DRLAB_FAST_PATHS."""
    global _override
    if on is not None and not isinstance(on, bool):
        raise TypeError(f"on: expected True, False or None, got {on!r}")
    _override = on


@contextlib.contextmanager
def disabled() -> Iterator[None]:
    """The plain Warp kernels only inside the block; the previous setting after it."""
    global _override
    before = _override
    _override = False
    try:
        yield
    finally:
        _override = before
