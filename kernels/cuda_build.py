"""Every Warp module of drlab, compiled ahead of time for CUDA architectures, with no GPU needed.

Warp compiles CUDA kernels with NVRTC, which is linked into its native library, so a machine
without a GPU or a driver still produces CUDA binaries: `wp.compile_aot_module(module, arch=80,
module_dir=d)` writes `d/wp_<module>_<hash>.sm80.cubin`. This module finds drlab's Warp modules
and compiles them that way, so a CPU-only test run also proves that the kernels are valid CUDA
(tests/kernels/test_cuda_compile.py does it for sm_80 and sm_90).

`project_modules()` imports every module of the `kernels` package and builds the kernels that
exist only after a first call, made by factory functions per radius or dtype (the C++ fast paths
cached with `kernels.native.built_once`, each kernel its own Warp module through
`module="unique"`, and `kernels.stereo.census.census_kernel`). Each factory is called for every
float dtype and storage dtype its callers use and for a small set of radii (`CORR_RADII`,
`CENSUS_RADII`: a radius only changes compile-time constants). It returns every registered Warp
module that holds a kernel defined in drlab (a Python module under `kernels.` or `research.`);
the research modules that define kernels count once imported (this package never imports
`research`; the test imports them). `module_label` names a module stably: its Python module, or
for a per-kernel module the Python module and the kernel's function name.

`CPU_ONLY` maps a label (or a dot-separated prefix of labels) to the reason its modules are
CPU-only by design: C++ fast paths (`wp.func_native`) written in clang's vector extensions and
builtins, which NVRTC's front end does not know, with no `#if !defined(__CUDA_ARCH__)` guard. Their
callers launch them on the CPU only and run the plain Warp kernels on CUDA. The other fast paths
compile for CUDA: they either guard their C++ with `#if` on `__CUDA_ARCH__` (composite, spheres,
NumPy's exp, splat rows, census rows, AD-census, the farthest-point step), or are plain C++ (hash
grid, pixel grouping).

`compile_all(arch, out_dir)` compiles every module outside `CPU_ONLY` for one architecture and
returns one `CompileResult` (label, Warp module name, ok, error text) per module; `use_ptx=True`
stops at PTX for that architecture (NVRTC's front end and optimiser, not ptxas: about half the time).
"""

from __future__ import annotations

import concurrent.futures
import importlib
import os
import pkgutil
from dataclasses import dataclass
from typing import Any, Callable, Iterable

import warp as wp

# Python module prefixes of drlab code whose Warp kernels count as the project's.
PROJECT_PREFIXES = ("kernels.", "research.")

# Radii the factories are built for: the minimum and the default (RAFT's lookup radius 4; the census
# window 7 x 9, radii (3, 4)). The radius only changes integer literals in the generated code.
CORR_RADII = (1, 4)
CENSUS_RADII = ((1, 1), (3, 4))

_VECTOR_EXT = "clang's vector extension (`__attribute__((ext_vector_type(N)))`, lanes indexed as `v[l]`)"
# label (`module_label`) or a dot-separated prefix of labels -> why its modules are CPU-only by design
# (module docstring); each reason also names the Warp kernel that CUDA runs instead.
CPU_ONLY: dict[str, str] = {
    "kernels.corr.window_cpu.sample_levels_cpu":
        f"4-lane window sampling in {_VECTOR_EXT} and `__builtin_memcpy`; CUDA runs `_common.sample_levels`",
    "kernels.corr.window_cpu.sample_patches_cpu":
        f"4-lane window sampling from patches in {_VECTOR_EXT} and `__builtin_memcpy`; CUDA runs "
        "`_common.sample_windows`",
    "kernels.corr.patch_cpu.patch_groups_cpu":
        f"8/16-lane dot products in {_VECTOR_EXT}, `__builtin_shufflevector`, `__builtin_convertvector`, "
        "`__builtin_elementwise_fma` and `_Float16`; CUDA runs `onthefly_kernels._patch_level`",
    "kernels.corr.patch_cpu.widen_rows_cpu":
        f"float16 -> float32 rows by `__builtin_convertvector` on `_Float16` vectors of {_VECTOR_EXT}; "
        "CUDA runs `_common._pack_rows_v`",
}


@dataclass(frozen=True)
class CompileResult:
    """One module's CUDA compilation: its label (`module_label`), its Warp module name (label plus
    content hash), whether it compiled, and the error text if not."""

    module: str
    name: str
    ok: bool
    error: str = ""


def _import_kernels() -> None:
    """Import every module of the `kernels` package (each registers its Warp module)."""
    import kernels

    for info in pkgutil.walk_packages(kernels.__path__, "kernels."):
        importlib.import_module(info.name)


def _factories() -> list[tuple[str, Callable[[], Any]]]:
    """(name, call) for every kernel factory, one entry per representative argument set."""
    from kernels import _npexp
    from kernels._arrays import FLOATS
    from kernels.corr import patch_cpu, window_cpu
    from kernels.splat import rowblend
    from kernels.stereo import census
    from kernels.volume import composite_cpu, hashgrid_cpu, spheres_cpu

    out: list[tuple[str, Callable[[], Any]]] = [
        ("kernels._npexp._exp_kernel", _npexp._exp_kernel),
        ("kernels.volume.composite_cpu.forward_kernel", composite_cpu.forward_kernel),
        ("kernels.volume.composite_cpu.backward_kernel", composite_cpu.backward_kernel),
        ("kernels.volume.spheres_cpu.kernels", spheres_cpu.kernels),
        ("kernels.corr.patch_cpu.widen_rows_cpu", patch_cpu.widen_rows_cpu),
        # the fast paths' probes (kernels.native.native_flag builds a kernel per probe)
        ("kernels.splat.rowblend.rowblend_available", rowblend.rowblend_available),
        ("kernels.volume.spheres_cpu.available", spheres_cpu.available),
    ]
    for s in FLOATS:
        n = s.__name__
        out.append((f"kernels.volume.hashgrid_cpu.forward_kernel({n})", lambda s=s: hashgrid_cpu.forward_kernel(s)))
        out.append((f"kernels.volume.hashgrid_cpu.backward_kernel({n})", lambda s=s: hashgrid_cpu.backward_kernel(s)))
        for r in CORR_RADII:
            out.append((f"kernels.corr.window_cpu.sample_levels_cpu({r}, {n})",
                        lambda r=r, s=s: window_cpu.sample_levels_cpu(r, s)))
            out.append((f"kernels.corr.window_cpu.sample_patches_cpu({r}, {n})",
                        lambda r=r, s=s: window_cpu.sample_patches_cpu(r, s)))
            out.append((f"kernels.corr.patch_cpu.group_pixels_cpu({r}, {n})",
                        lambda r=r, s=s: patch_cpu.group_pixels_cpu(r, s)))
            # stored in the working dtype, or in float16 with float32 work (onthefly._cpu_patches)
            for storage in (s, wp.float16) if s == wp.float32 else (s,):
                out.append((f"kernels.corr.patch_cpu.patch_groups_cpu({r}, {n}, {storage.__name__})",
                            lambda r=r, s=s, st=storage: patch_cpu.patch_groups_cpu(r, s, st)))
    for ry, rx in CENSUS_RADII:
        out.append((f"kernels.stereo.census.census_kernel({ry}, {rx})", lambda ry=ry, rx=rx: census.census_kernel(ry, rx)))
    return out


def build_lazy_kernels() -> list[str]:
    """Call every kernel factory with its representative arguments (module docstring); returns their names."""
    _import_kernels()
    names = []
    for name, call in _factories():
        call()
        names.append(name)
    return names


def _python_modules(module: Any) -> set[str]:
    """The Python modules that define a Warp module's kernels."""
    return {kernel.func.__module__ for kernel in module.kernels.values()}


def module_label(module: Any) -> str:
    """A stable name for a Warp module: its Python module's name, or for a `module="unique"` module
    (named by its kernel and a content hash, one module per kernel) the Python module and the kernel
    function's name, e.g. `kernels.corr.patch_cpu.patch_groups_cpu` (the same label for each radius
    and dtype it is built for)."""
    sources = _python_modules(module)
    if module.name in sources or len(sources) != 1 or len(module.kernels) != 1:
        return module.name
    (source,) = sources
    (kernel,) = module.kernels.values()
    return f"{source}.{kernel.func.__name__}"


def project_modules() -> list[Any]:
    """Every registered Warp module (`warp` Module objects) holding a drlab kernel, after importing
    the `kernels` package and building its lazy kernels, sorted by `module_label`."""
    from warp._src.context import user_modules

    build_lazy_kernels()
    mods = [m for m in list(user_modules.values())
            if m.kernels and any(src.startswith(PROJECT_PREFIXES) for src in _python_modules(m))]
    return sorted(mods, key=lambda m: (module_label(m), m.name))


def cpu_only_reason(label: str) -> str | None:
    """The CPU_ONLY reason covering this module label (an exact key or a dot-separated prefix), or None."""
    for key, reason in CPU_ONLY.items():
        if label == key or label.startswith(key + "."):
            return reason
    return None


def nvrtc_archs() -> set[int]:
    """The CUDA architectures this Warp build's NVRTC compiles for (empty: no CUDA compilation)."""
    wp.init()
    from warp._src.context import runtime

    return set(runtime.nvrtc_supported_archs) if runtime.is_cuda_enabled else set()


def _compile_one(module: Any, arch: int, out_dir: str | None, use_ptx: bool) -> CompileResult:
    label = module_label(module)
    # a generic kernel without overloads would be skipped silently (Warp only warns): report it
    bare = sorted(key for key, k in module.kernels.items() if k.is_generic and not k.overloads)
    if bare:
        return CompileResult(label, module.name, False,
                             f"generic kernels without overloads (declare them, e.g. with "
                             f"kernels._arrays.declare_float_overloads): {', '.join(bare)}")
    try:
        wp.compile_aot_module(module, arch=arch, module_dir=out_dir, use_ptx=use_ptx)
    except Exception as e:  # noqa: BLE001 - the report carries every failure
        return CompileResult(label, module.name, False, f"{type(e).__name__}: {e}")
    return CompileResult(label, module.name, True)


def compile_all(arch: int, out_dir: str | os.PathLike | None, modules: Iterable[Any] | None = None,
                workers: int | None = None, use_ptx: bool = False) -> list[CompileResult]:
    """Compile every project module (or those given) not in CPU_ONLY for CUDA architecture `arch`
    (80: sm_80) into `out_dir`, as `wp.compile_aot_module(module, arch=arch, module_dir=out_dir)`
    (no device: NVRTC only, no GPU or driver); one CompileResult per module, in order, failures
    reported, not raised.

    Binaries are named by the module's content hash (`wp_<module>_<hash>.sm<arch>.cubin`) and Warp
    skips a module whose binary is already in `out_dir`; `out_dir=None` writes into Warp's kernel
    cache (`wp.config.kernel_cache_dir`, one folder per module), so a second run compiles only the
    modules that changed. Warp serialises its Python code generation and runs NVRTC unlocked, so
    `workers` threads (default: the CPU count) compile modules side by side."""
    wp.init()
    todo = [m for m in (project_modules() if modules is None else modules)
            if cpu_only_reason(module_label(m)) is None]
    out = None if out_dir is None else os.fspath(out_dir)
    n = max(1, min(workers or os.cpu_count() or 1, len(todo)))
    if n == 1:
        return [_compile_one(m, arch, out, use_ptx) for m in todo]
    with concurrent.futures.ThreadPoolExecutor(n) as pool:
        return list(pool.map(lambda m: _compile_one(m, arch, out, use_ptx), todo))
