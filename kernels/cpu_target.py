"""Which CPU the Warp kernels are compiled for: the host's (default) or one named by DRLAB_CPU_TARGET.

Warp compiles CPU kernels, and with them the C++ fast paths (kernels/native), with clang for the host
CPU: its `wp.config.cpu_compiler_flags` default holds `-march=native`, which Warp resolves to the host's
features. With the environment variable DRLAB_CPU_TARGET set to an LLVM CPU name (`znver3`: AMD Zen 3,
AVX2 and FMA without AVX-512; `haswell`; `x86-64-v3`), `apply()` replaces that flag with clang's
frontend flag `-target-cpu NAME`, so every module is compiled as it would be on that CPU. Warp hashes
the resolved flags into each module's cache key, so objects for the host and for the target never mix.

What it is for: running the tests on an AVX-512 machine with the kernels compiled as on an AVX2-only
CPU (`make test-avx2`, which also points NumPy's SIMD dispatch and OpenBLAS at AVX2; docs/warp.md).
It reaches only Warp's kernels: Dr.Jit and Mitsuba still compile for the host. A module that sets
its own flags takes them from `module_flags(extra)`, which names the same CPU.

Reliance on Warp: Warp passes the flag string to its clang frontend (`-target-cpu` is a frontend flag;
`-march=NAME` other than `native` is refused by it), checked on Warp 1.19.
"""

from __future__ import annotations

import os
import re

ENV = "DRLAB_CPU_TARGET"
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
_NATIVE = "-march=native"


def requested() -> str | None:
    """The CPU named by DRLAB_CPU_TARGET, or None when it is unset or empty (the host's CPU)."""
    name = os.environ.get(ENV, "").strip()
    if not name:
        return None
    if not _NAME.fullmatch(name):
        raise ValueError(f"{ENV}: expected an LLVM CPU name such as znver3, haswell or x86-64-v3, got {name!r}")
    return name


def flags_for(name: str, flags: str | None) -> str:
    """`flags` (Warp's CPU compiler flags; None: Warp's default, `-march=native`) compiled for CPU `name`."""
    parts, kept = (flags if flags is not None else _NATIVE).split(), []
    i = 0
    while i < len(parts):
        if parts[i] == "-target-cpu":  # an earlier target and its name
            i += 2
            continue
        if parts[i] != _NATIVE:
            kept.append(parts[i])
        i += 1
    return " ".join(["-target-cpu", name, *kept])


def module_flags(extra: str = "") -> str:
    """CPU compiler flags for a module that sets its own (`module_options={"cpu_compiler_flags": ...}`):
    the CPU named by DRLAB_CPU_TARGET, else `-march=native` (the host), followed by `extra`."""
    name = requested()
    cpu = _NATIVE if name is None else f"-target-cpu {name}"
    return f"{cpu} {extra}".strip()


def apply() -> str | None:
    """Compile every Warp module from now on for DRLAB_CPU_TARGET's CPU; returns its name (None: the host).

    Call it before the first kernel is loaded (kernels/__init__.py does, at import).
    """
    name = requested()
    if name is None:
        return None
    import warp as wp

    wp.config.cpu_compiler_flags = flags_for(name, wp.config.cpu_compiler_flags)
    return name
