"""Warp start-up shared by the CLI and the experiment scripts.

Warp 1.19 ignores `wp.config.quiet` for its banner and per-module load lines; they go through its
logger, so the log level is what keeps them off stdout (and out of `--json` output and results logs).
"""

from __future__ import annotations


def init_warp(device: str | None = None) -> None:
    """Silence Warp's informational output and, when `device` is given, make it the default device."""
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.config.quiet = True
    if device is not None:
        wp.set_device(device)
