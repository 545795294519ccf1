"""Choosing Mitsuba's variant: `llvm_ad_rgb` when Dr.Jit's LLVM backend works, else `scalar_rgb`.

Dr.Jit's LLVM backend needs a shared libLLVM 17 or newer (docs/mitsuba.md):
with 14 it refuses to start, and with 15 or 16 the *process aborts* on the first
kernel that uses `fminimum`. So the backend is probed in a child process, which
may die without taking the caller with it.

* `python -m research.mitsuba_env --ensure` (run by the Makefile at set-up)
  installs Debian's libllvm19 with apt-get when the probe fails, then probes again.
* `select_variant()` is what the rest of drlab calls before using Mitsuba. It
  honours DRLAB_MITSUBA_VARIANT, otherwise probes once per process and falls
  back to `scalar_rgb` with a single warning.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import warnings
from functools import lru_cache

LLVM_VARIANT = "llvm_ad_rgb"
SCALAR_VARIANT = "scalar_rgb"

# Exercises what breaks on old LLVMs: fminimum in a JIT kernel, then a tiny render.
_PROBE = r"""
import drjit as dr
from drjit.llvm import Float
x = dr.minimum(Float([1.0, 2.0, 3.0]), Float(2.5))
dr.eval(x)
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
scene = mi.load_dict({"type": "scene", "integrator": {"type": "path"}, "s": {"type": "sphere"},
    "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 4, "height": 4},
               "to_world": mi.ScalarTransform4f().translate([0, 0, -4])}})
mi.render(scene, spp=1)
print("DRLAB_LLVM_OK")
"""


def probe_llvm(timeout_s: float = 120.0) -> tuple[bool, str]:
    """Run the LLVM probe in a child process. Returns (works, diagnostic text)."""
    try:
        proc = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return False, f"probe timed out after {timeout_s} s"
    ok = proc.returncode == 0 and "DRLAB_LLVM_OK" in proc.stdout
    text = (proc.stdout + proc.stderr).strip().splitlines()
    diag = "\n".join(text[-3:]) if text else f"exit status {proc.returncode}"
    return ok, "LLVM backend works" if ok else diag


def install_libllvm19() -> bool:
    """apt-get install libllvm19 (Debian). Returns True if the command succeeded."""
    apt = shutil.which("apt-get")
    if apt is None:
        return False
    prefix: list[str] = []
    if os.geteuid() != 0:
        sudo = shutil.which("sudo")
        if sudo is None:
            return False
        prefix = [sudo, "-n"]
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (["update", "-qq"], ["install", "-y", "-qq", "libllvm19"]):
        if subprocess.run(prefix + [apt] + cmd, env=env).returncode != 0:
            return False
    return True


@lru_cache(maxsize=1)
def select_variant() -> str:
    """Set and return Mitsuba's variant for this process (see module docstring)."""
    import mitsuba as mi

    forced = os.environ.get("DRLAB_MITSUBA_VARIANT")
    if forced:
        mi.set_variant(forced)
        return forced
    ok, diag = probe_llvm()
    if ok:
        mi.set_variant(LLVM_VARIANT)
        return LLVM_VARIANT
    warnings.warn(
        "Dr.Jit's LLVM backend is unavailable (needs libLLVM >= 17; run `make test` or "
        "`apt-get install libllvm19`); falling back to Mitsuba's scalar_rgb variant, which is slower. "
        f"Probe said: {diag}",
        RuntimeWarning,
        stacklevel=2,
    )
    mi.set_variant(SCALAR_VARIANT)
    return SCALAR_VARIANT


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Check (and with --ensure, set up) Dr.Jit's LLVM backend.")
    parser.add_argument("--ensure", action="store_true", help="install Debian's libllvm19 if the probe fails")
    args = parser.parse_args(argv)
    ok, diag = probe_llvm()
    if not ok and args.ensure:
        print(f"drlab: Dr.Jit LLVM backend unavailable ({diag}); installing libllvm19 ...", flush=True)
        if install_libllvm19():
            ok, diag = probe_llvm()
    if ok:
        print(f"drlab: Mitsuba will use {LLVM_VARIANT}")
    else:
        print(f"drlab: WARNING: LLVM backend unavailable ({diag}); Mitsuba will fall back to {SCALAR_VARIANT}")
    return 0  # the fallback is a warning, not a failure


if __name__ == "__main__":
    sys.exit(main())
