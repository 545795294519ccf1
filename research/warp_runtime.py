"""Warp start-up shared by the CLI and the experiment scripts.

Warp 1.19 ignores `wp.config.quiet` for its banner and per-module load lines; they go through its
logger, so the log level is what keeps them off stdout (and out of `--json` output and results logs).

On a machine without the NVIDIA driver, Warp's native library prints "Warp CUDA warning: Could not
find or load the NVIDIA CUDA driver. GPU execution will not be available." with C `fprintf` to file
descriptor 2 while `wp.init()` runs (warp/native/cuda_util.cpp, `init_cuda_driver`; docs/warp.md,
section 7); no Warp setting turns it off. `init_warp` therefore runs `wp.init()` with descriptor 2
sent to a temporary file and copies every other line back to stderr, dropping exactly that one.
"""

from __future__ import annotations

import os
import sys
import tempfile

CUDA_DRIVER_WARNING = "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver."


def _warp_initialised() -> bool:
    try:
        from warp._src import context
    except ImportError:  # another layout: let wp.init() decide (it returns at once when already done)
        return False
    return getattr(context, "runtime", None) is not None


def _init_without_driver_warning() -> None:
    """`wp.init()`, with Warp's missing-CUDA-driver line filtered out of file descriptor 2."""
    import warp as wp

    if _warp_initialised():
        return
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no usable descriptor 2: nothing to filter
        wp.init()
        return
    with tempfile.TemporaryFile(mode="w+b") as capture:
        os.dup2(capture.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            kept = [line for line in capture.read().decode(errors="replace").splitlines(keepends=True)
                    if not line.startswith(CUDA_DRIVER_WARNING)]
            if kept:
                sys.stderr.write("".join(kept))
                sys.stderr.flush()


def init_warp(device: str | None = None) -> None:
    """Initialise Warp quietly (no banner, no missing-driver warning) and, when `device` is given, make it
    the default device."""
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.config.quiet = True
    _init_without_driver_warning()
    if device is not None:
        wp.set_device(device)
